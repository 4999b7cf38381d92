"""Bags and records meet: `export BAG --npz`, and `identify` / `track` reading a bag directly."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from okid_ros.cli import main
from okid_ros.records import load_record
from okid_ros.tools.bagio import open_bag
from okid_ros.tools.simulate_bag import IO_SAMPLE_TOPIC

START_S = 1_700_000_000
SENSORS = ["--source", "wrench /thruster1/wrench force.x=u0", "--source", "wrench /thruster2/wrench force.x=u1",
           "--source", "imu /accel/tip1/imu linear_acceleration.x=y0",
           "--source", "imu /accel/tip2/imu linear_acceleration.x=y1"]


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    path = tmp_path_factory.mktemp("bagrec") / "experiment"
    assert main(["simulate", "--out", str(path), "--duration", "12", "--start-time", str(START_S)]) == 0
    return path


def test_export_writes_the_bags_samples_and_refuses_to_overwrite(bag, tmp_path, capsys):
    out = tmp_path / "run.npz"
    assert main(["export", str(bag), "--npz", str(out)]) == 0
    record = load_record(out)
    with open_bag(bag) as reader:
        io = [(np.array(m.u), np.array(m.y)) for _, _, m in reader.messages([IO_SAMPLE_TOPIC])]
    assert record.sample_time_s == 0.008 and record.u.shape == (1500, 2)
    np.testing.assert_array_equal(record.u, [u for u, _ in io])
    np.testing.assert_array_equal(record.y, [y for _, y in io])
    with np.load(out) as data:
        assert data["stamp_s"][0] == pytest.approx(START_S)
        assert np.allclose(np.diff(data["stamp_s"]), 0.008, rtol=0, atol=1e-6)
    # the sensor topics give the same record
    sensors = tmp_path / "sensors.npz"
    assert main(["export", str(bag), "--npz", str(sensors), *SENSORS]) == 0
    np.testing.assert_array_equal(load_record(sensors).y, record.y)
    before = out.read_bytes()
    capsys.readouterr()
    assert main(["export", str(bag), "--npz", str(out)]) == 2
    assert "exists already" in capsys.readouterr().err and out.read_bytes() == before
    assert main(["export", str(bag), "--npz", str(out), "--force"]) == 0


def test_export_refuses_one_sample_and_a_failed_forced_export_keeps_the_old_record(bag, tmp_path, capsys):
    # A bag of one complete sample (every later message at its stamp): export wrote a 1-sample
    # record with exit 0 where process refuses it; with --force it removed the old record first.
    from okid_ros.tools.bagio import BagWriter

    one = tmp_path / "one"
    with open_bag(bag) as reader, BagWriter(one) as writer:
        writer.add_topic(IO_SAMPLE_TOPIC, "okid_msgs/msg/IoSample")
        for _, log_ns, msg in reader.messages([IO_SAMPLE_TOPIC]):
            msg.header.stamp.sec, msg.header.stamp.nanosec = 0, 0  # every sample at one stamp
            writer.write(IO_SAMPLE_TOPIC, log_ns, msg)
    out = tmp_path / "run.npz"
    assert main(["export", str(bag), "--npz", str(out)]) == 0
    before = out.read_bytes()
    capsys.readouterr()
    assert main(["export", str(one), "--npz", str(out), "--force"]) == 2
    assert "complete sample" in capsys.readouterr().err
    assert out.read_bytes() == before


def test_export_refuses_a_record_shorter_than_identify_takes_and_identify_takes_the_shortest(bag, tmp_path, capsys):
    # export wrote 13 samples of 2 inputs and 2 outputs (the ARX fit of order 2), which identify refused:
    # "no model order gave a usable predictor: n=2: 12 samples are too few to fit a 2-state model".
    from okid_ros.tools.bagio import BagWriter

    for n_samples, status in ((13, 2), (14, 0)):
        short = tmp_path / f"first{n_samples}"
        with open_bag(bag) as reader, BagWriter(short) as writer:
            writer.add_topic(IO_SAMPLE_TOPIC, "okid_msgs/msg/IoSample")
            for _, (_, log_ns, msg) in zip(range(n_samples), reader.messages([IO_SAMPLE_TOPIC])):
                writer.write(IO_SAMPLE_TOPIC, log_ns, msg)
        out = tmp_path / f"first{n_samples}.npz"
        capsys.readouterr()
        assert main(["export", str(short), "--npz", str(out)]) == status
        if status:
            assert "is shorter than any command identifies from (14 samples with 2 inputs and 2 outputs)" in (
                capsys.readouterr().err) and not out.exists()
            continue
        assert main(["identify", str(out), "--order", "2", "--json", str(tmp_path / "m.json")]) == 0
        assert main(["identify", str(short), "--order", "2", "--json", str(tmp_path / "b.json")]) == 0


def test_a_sensor_topic_that_stops_half_way_is_said_by_export_and_process(bag, tmp_path, capsys):
    # One of the four sensor topics stops after 4 s of the 12 s bag: export wrote the 4 s and process
    # identified them, neither saying that two thirds of the sample times were dropped incomplete.
    from okid_ros.tools.bagio import BagWriter

    stops = tmp_path / "stops"
    with open_bag(bag) as reader, BagWriter(stops) as writer:
        added, first = set(), None
        for topic, msg_type, log_ns, raw in reader.raw_messages():
            first = log_ns if first is None else first
            if topic == "/accel/tip2/imu" and log_ns - first > 4e9:
                continue
            if topic not in added:
                writer.add_topic(topic, msg_type)
                added.add(topic)
            writer.write_raw(topic, log_ns, raw)
    capsys.readouterr()
    assert main(["export", str(stops), "--npz", str(tmp_path / "s.npz"), *SENSORS]) == 0
    assert re.search(r"warning: .*: 9\d\d sample times dropped incomplete", capsys.readouterr().err)
    out = ["--out", str(tmp_path / "s.out"), "--param", "arx.order=20", "--param", "arx.window_length=300"]
    assert main(["process", str(stops), *out, *SENSORS]) == 0
    captured = capsys.readouterr()
    assert "ArxModel" in captured.out or "mode" in captured.out, captured.out  # models came
    assert re.search(r"warning: 9\d\d samples dropped incomplete", captured.err), captured.err


def test_identify_and_track_read_a_bag_like_its_exported_record(bag, tmp_path):
    npz = tmp_path / "run.npz"
    assert main(["export", str(bag), "--npz", str(npz)]) == 0
    common = ["--order", "20", "--states", "6"]
    assert main(["identify", str(bag), *common, "--json", str(tmp_path / "bag.json"), *SENSORS]) == 0
    assert main(["identify", str(npz), *common, "--json", str(tmp_path / "npz.json")]) == 0
    from_bag, from_npz = (json.loads((tmp_path / f"{n}.json").read_text()) for n in ("bag", "npz"))
    assert from_bag["modes"] == from_npz["modes"] and "bag: 1500 samples" in from_bag["source"]
    track = ["--order", "20", "--window", "800", "--every", "300", "--states", "6", "--no-progress"]
    assert main(["track", str(bag), *track, "--jsonl", str(tmp_path / "bag.jsonl")]) == 0
    assert main(["track", str(npz), *track, "--jsonl", str(tmp_path / "npz.jsonl")]) == 0
    lines = [[json.loads(x) for x in (tmp_path / f"{n}.jsonl").read_text().splitlines()] for n in ("bag", "npz")]
    assert len(lines[0]) >= 2
    assert [line["modes"] for line in lines[0]] == [line["modes"] for line in lines[1]]


def test_a_bag_without_the_source_topic_is_a_one_line_error(bag, tmp_path, capsys):
    capsys.readouterr()
    assert main(["identify", str(bag), "--order", "20", "--json", str(tmp_path / "x.json"),
                 "--source", "io_sample /nowhere"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "/nowhere" in err


def test_an_npz_name_without_its_suffix_is_the_options_error_not_the_bags(bag, tmp_path, capsys):
    # It was a DataError, which the CLI prefixes with the bag: "BAG: --npz X: the record file must end in .npz".
    capsys.readouterr()
    assert main(["export", str(bag), "--npz", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert err == f"okid-ros export: error: --npz {tmp_path / 'run'}: the record file must end in .npz\n"


def test_a_bag_of_which_no_sample_fits_says_why(bag, tmp_path, capsys):
    # As process says it: every message of the wrong size for n_inputs / n_outputs.
    capsys.readouterr()
    assert main(["identify", str(bag), "--param", "n_inputs=0", "--json", str(tmp_path / "x.json")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no complete sample" in err
    assert "messages were rejected (1500 wrong size (n_inputs 0, n_outputs 2 expected" in err


@pytest.mark.parametrize("sample_time_s, reason, where", [
    ("3600.0", "1499 duplicate", "in a sample time already taken"),  # a float: the nodes refuse 3600
    ("0.016", "750 off grid", "between sample times"),
])
def test_export_says_when_the_sample_time_does_not_fit_the_stamps(bag, tmp_path, capsys, sample_time_s, reason,
                                                                  where):
    capsys.readouterr()
    out = tmp_path / "r.npz"
    one_sample = sample_time_s == "3600.0"  # the 12 s bag in one sample time: refused, the cause said
    assert main(["export", str(bag), "--npz", str(out), "--param", f"sample_time_s={sample_time_s}"]) == (
        2 if one_sample else 0)
    err = capsys.readouterr().err
    assert ("one complete sample only" in err) == one_sample, err
    assert f"of the 1500 messages were rejected ({reason}); most fell {where}: is sample_time_s" in err, err
    assert main(["export", str(bag), "--npz", str(tmp_path / "ok.npz")]) == 0
    assert "rejected" not in capsys.readouterr().err


def test_export_says_when_a_finer_sample_time_leaves_every_other_slot_empty(bag, tmp_path, capsys):
    # Half the bag's spacing refuses no message: before, one sample was exported and nothing said; then one
    # sample was exported (exit 0) with the cause as a warning. A record of one sample is none: refused, as a bag
    # that makes one sample is, the cause said.
    capsys.readouterr()
    assert main(["export", str(bag), "--npz", str(tmp_path / "r.npz"), "--param", "sample_time_s=0.004"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no two complete samples in a row on the topics /okid/io_sample (1500 " in err
    assert "most of the 1500 samples stand alone between empty sample times: is sample_time_s 0.004 s right?" in err
    assert not (tmp_path / "r.npz").exists()
    # identify fails on such a record (its outputs look dead between the empty slots): the cause is said first
    assert main(["identify", str(bag), "--json", str(tmp_path / "m.json"), "--param", "sample_time_s=0.004"]) == 2
    warning = capsys.readouterr().err.splitlines()[0]
    assert warning.startswith("okid-ros identify: warning: ") and "stand alone between empty sample times" in warning


def test_identify_and_track_fill_the_dropped_messages_of_a_bag(bag, tmp_path, capsys):
    """A best-effort topic loses messages: short gaps are missing samples, filled as on node 2.

    Before, the record shrank to the longest run without a loss (96 of 1500 samples here).
    """
    from okid_ros.tools.bagio import BagWriter

    lossy = tmp_path / "lossy"
    dropped = set(range(40, 1500, 97)) | {700, 701, 702}
    with open_bag(bag) as reader, BagWriter(lossy) as writer:
        writer.add_topic(IO_SAMPLE_TOPIC, "okid_msgs/msg/IoSample")
        for k, (_, _, stamp_ns, raw) in enumerate(reader.raw_messages([IO_SAMPLE_TOPIC])):
            if k not in dropped:
                writer.write_raw(IO_SAMPLE_TOPIC, stamp_ns, raw)
    common = ["--order", "20", "--states", "6"]
    assert main(["identify", str(lossy), *common, "--json", str(tmp_path / "lossy.json")]) == 0
    assert main(["identify", str(bag), *common, "--json", str(tmp_path / "whole.json")]) == 0
    err = capsys.readouterr().err
    assert f"{len(dropped)} of the 1500 samples hold NaN/Inf: identified on the whole record, its {len(dropped)} " \
           "missing samples filled by the ARX prediction" in err
    lossy_doc, whole = (json.loads((tmp_path / f"{n}.json").read_text()) for n in ("lossy", "whole"))
    assert f"bag: {1500 - len(dropped)} samples of 0.008 s and {len(dropped)} dropped slots between them" \
           in lossy_doc["source"]
    for mode in whole["modes"]:  # the modes of the lossless bag, within a few of their standard deviations
        near = min(lossy_doc["modes"], key=lambda m: abs(m["frequency_hz"] - mode["frequency_hz"]))
        assert abs(near["frequency_hz"] - mode["frequency_hz"]) < 0.005 * mode["frequency_hz"]
    # track counts the dropped slots as missing samples (as the nodes do) over the same 1500 slots.
    track = ["--order", "20", "--window", "800", "--every", "300", "--states", "6", "--no-progress"]
    assert main(["track", str(lossy), *track, "--jsonl", str(tmp_path / "lossy.jsonl")]) == 0
    assert f"{len(dropped)} of the 1500 samples hold NaN/Inf" in capsys.readouterr().err
    # export keeps writing the longest contiguous run (a record without missing samples).
    assert main(["export", str(lossy), "--npz", str(tmp_path / "run.npz")]) == 0
    assert load_record(tmp_path / "run.npz").u.shape[0] == 97 - 1


@pytest.mark.parametrize("sources, fragment", [
    # one source, the same field under its two names; two sources on one topic; an element as stamp and channel
    (["wrench /thruster1/wrench force.x=u0 wrench.force.x=u1", "imu /accel/tip1/imu linear_acceleration.x=y0",
      "imu /accel/tip2/imu linear_acceleration.x=y1"], "field wrench.force.x of /thruster1/wrench is mapped twice "
     "(to u0 and u1)"),
    (SENSORS[1:4:2] + ["imu /accel/tip1/imu linear_acceleration.x=y0", "imu /accel/tip1/imu linear_acceleration.x=y1"],
     "field linear_acceleration.x of /accel/tip1/imu is mapped twice (to y0 and y1)"),
    (["array /daq data[0]=stamp data[0]=u0 data[1]=u1 data[2]=y0 data[3]=y1"], "field data[0] of /daq is mapped twice"),
])
def test_a_message_field_mapped_to_two_channels_is_one_line_error(bag, tmp_path, capsys, sources, fragment):
    # Was: exported with u0 == u1 (or y0 == y1), status 0.
    out = tmp_path / "twice.npz"
    capsys.readouterr()
    assert main(["export", str(bag), "--npz", str(out), *[a for s in sources for a in ("--source", s)]]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("okid-ros export: error: ") and fragment in err, err
    assert not out.exists()
