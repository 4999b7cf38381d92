"""Property-based tests of the `okid-ros` entry points on generated records and files.

Whatever the record (channel units from 1e-150 to 1e300, dead or constant inputs, dead or
repeated outputs, no inputs (output-only), NaN, too short, damaged bytes), `identify` and `track`
end with status 0 or 2 and print only lines starting with ``okid-ros COMMAND:`` on stderr (no
traceback, no bare warning); a success writes JSON without NaN or null in the model, a failure
writes nothing. Bag commands on random bytes fail in one line.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from _hypothesis_profiles import SLOW
from hypothesis import event, given
from hypothesis import strategies as st

from okid_ros import cli


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    capsys.readouterr()
    try:
        status = cli.main(argv)
    except SystemExit as exc:  # argparse usage errors
        status = exc.code
    err = capsys.readouterr().err
    return status, err


def _assert_one_line_messages(err: str, command: str) -> None:
    for line in err.splitlines():
        assert line.startswith(f"okid-ros {command}: "), line
    assert "Traceback" not in err and "internal error" not in err
    assert not re.search(r"\b[A-Z]\w*(Error|Exception)\b", err), err  # a Python exception's name: not said clearly


def _finite_numbers(value, where: str = "") -> None:
    """No NaN, no Inf, no null anywhere in a JSON value."""
    if isinstance(value, dict):
        for key, item in value.items():
            if key in {"uncertainty", "reason", "error", "waiting", "source", "decay"} or key.endswith("_std"):
                continue  # documented nulls: not computed, not applicable
            _finite_numbers(item, f"{where}.{key}")
    elif isinstance(value, list):
        for item in value:
            _finite_numbers(item, where)
    else:
        assert value is not None or where.endswith(("offset", "arx_penalty", "mac_previous", "stability",
                                                      "emac", "condition_number")), where
        if isinstance(value, float):
            assert math.isfinite(value), where


def _run_on_record(tmp_path_factory, capsys, arrays: dict, command: str, out_name: str,
                   options: list[str]) -> Path | None:
    """Run ``command RECORD OPTION OUT ...`` on the arrays; the output path, or None after a one-line error."""
    tmp = tmp_path_factory.mktemp(command)
    record, out = tmp / "r.npz", tmp / out_name
    np.savez(record, **arrays)
    status, err = _run([command, str(record), options[0], str(out), *options[1:]], capsys)
    assert status in (0, 2), err
    _assert_one_line_messages(err, command)
    if status == 2:
        assert not out.exists() and err.count("error:") == 1 and str(record) in err
        event(f"{command}: refused")  # --hypothesis-show-statistics: how often each path ran
        return None
    event(f"{command}: a model")
    return out


@st.composite
def records(draw):
    n = draw(st.sampled_from([40, 700, 900]))
    m, p = draw(st.integers(1, 2)), draw(st.integers(1, 2))
    seed = draw(st.integers(0, 2**16))
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((n, m))
    y = np.zeros((n, p))
    for k in range(2, n):
        y[k] = 1.6 * y[k - 1] - 0.9 * y[k - 2] + u[k - 1].sum() + 0.05 * rng.standard_normal(p)
    u *= draw(st.lists(st.sampled_from([1.0, 1e-150, 1e150, 3e-7]), min_size=m, max_size=m))
    y *= draw(st.lists(st.sampled_from([1.0, 1e-150, 1e150, 2e5, 1e300]), min_size=p, max_size=p))
    fault = draw(st.sampled_from(["none", "none", "dead", "constant", "all_dead", "nan", "no_u", "no_u",
                                  "dead_output", "repeated_output"]))
    if fault == "dead":
        u[:, -1] = 0.0
    elif fault == "constant":
        u[:, 0] = 4.25
    elif fault == "all_dead":
        u[:] = 1.5
    elif fault == "nan":
        y[draw(st.integers(0, n - 1)), 0] = np.nan
    elif fault == "dead_output":
        y[:, 0] = 2.5
    elif fault == "repeated_output":
        y[:, -1] = -3.0 * y[:, 0]
    arrays = {"y": y, "sample_time_s": 0.01}
    if fault != "no_u":
        arrays["u"] = u
    return arrays


@SLOW
@given(arrays=records())
def test_identify_on_any_record_is_a_model_or_one_line(tmp_path_factory, capsys, arrays) -> None:
    out = _run_on_record(tmp_path_factory, capsys, arrays, "identify", "m.json",
                         ["--json", "--order", "8", "--no-refine", "--max-states", "6"])
    if out is None:
        return
    document = json.loads(out.read_text())
    _finite_numbers({key: document[key] for key in ("A", "B", "C", "D", "K", "innovation_covariance")})
    for mode in document["modes"]:
        assert math.isfinite(mode["frequency_rad_s"]) and math.isfinite(mode["damping_ratio"])


@SLOW
@given(arrays=records())
def test_track_on_any_record_is_updates_or_one_line(tmp_path_factory, capsys, arrays) -> None:
    out = _run_on_record(tmp_path_factory, capsys, arrays, "track", "t.jsonl",
                         ["--jsonl", "--order", "6", "--window", "300", "--every", "250", "--states", "4",
                          "--no-progress"])
    if out is None:
        return
    for line in out.read_text().splitlines():
        entry = json.loads(line)
        assert entry["n_states"] is not None or entry.get("error") or entry.get("waiting")
        for mode in entry["modes"]:
            assert math.isfinite(mode["frequency_rad_s"]) and math.isfinite(mode["damping_ratio"])


@given(payload=st.binary(max_size=600), command=st.sampled_from(["process", "export", "identify"]),
       suffix=st.sampled_from([".mcap", ".db3", ".bag", ""]))
def test_bag_commands_on_random_bytes_fail_in_one_line(tmp_path_factory, capsys, payload, command, suffix) -> None:
    tmp = tmp_path_factory.mktemp("bag")
    bag = tmp / f"b{suffix}"
    if suffix:
        bag.write_bytes(payload)
    else:
        bag.mkdir()
        (bag / "metadata.yaml").write_bytes(payload)
    argv = {"process": ["process", str(bag), "--out", str(tmp / "o")],
            "export": ["export", str(bag), "--npz", str(tmp / "o.npz")],
            "identify": ["identify", str(bag), "--json", str(tmp / "o.json")]}[command]
    status, err = _run(argv, capsys)
    assert status == 2 and err.count("\n") == 1 and err.startswith(f"okid-ros {command}: error: "), err
    assert sorted(p.name for p in tmp.iterdir()) == [bag.name]


def test_the_record_strategy_reaches_success_and_failure(tmp_path: Path, capsys) -> None:
    """The properties above are not vacuous: a clean record succeeds, one with NaN in every other sample fails."""
    rng = np.random.default_rng(1)
    u = rng.standard_normal((700, 1))
    y = np.convolve(u[:, 0], [0, 1, 0.5], "same")[:, None] + 0.01 * rng.standard_normal((700, 1))
    np.savez(tmp_path / "ok.npz", u=u, y=y, sample_time_s=0.01)
    status, err = _run(["identify", str(tmp_path / "ok.npz"), "--json", str(tmp_path / "m.json"), "--order", "8",
                        "--no-refine"], capsys)
    assert status == 0, err
    y[::2] = np.nan
    np.savez(tmp_path / "bad.npz", u=u, y=y, sample_time_s=0.01)
    status, err = _run(["identify", str(tmp_path / "bad.npz"), "--json", str(tmp_path / "n.json")], capsys)
    assert status == 2 and "no two samples in a row are free of NaN/Inf" in err


@st.composite
def output_only_records(draw):
    """Outputs of three resonances as a user might store them: dtypes, dead, copied, loud, missing, transposed."""
    from scipy.signal import lfilter

    n, p = draw(st.sampled_from([150, 400, 1500])), draw(st.integers(1, 4))
    rng = np.random.default_rng(draw(st.integers(0, 2**16)))
    modes = [lfilter([1.0], [1.0, -2 * 0.995 * np.cos(w), 0.995**2], rng.standard_normal(n)) for w in (0.1, 0.25, 0.6)]
    y = np.column_stack(modes) @ rng.standard_normal((3, p)) + 0.05 * rng.standard_normal((n, p))
    fault = draw(st.sampled_from(["none", "constant", "zeros", "copy", "loud", "nan_run", "inf_run", "transposed"]))
    channel, start = draw(st.integers(0, p - 1)), draw(st.integers(0, n - 1))
    if fault == "constant":
        y[:, channel] = 2.5
    elif fault == "zeros":
        y[:, channel] = 0.0
    elif fault == "copy":
        y = np.column_stack([y, y[:, channel]])
    elif fault == "loud":
        y[:, channel] *= 1e6
    dtype = draw(st.sampled_from(["float64", "float32", "int32", "int64"]))
    counts = min(1000.0, 1e9 / np.abs(y).max()) if dtype == "int32" else 1000.0  # a loud channel within int32
    y = np.round(counts * y).astype(dtype) if dtype.startswith("int") else y.astype(dtype)
    if fault in ("nan_run", "inf_run"):  # an integer array holds neither: stored as float64
        y = y.astype(np.result_type(y, np.float16))
        y[start : start + draw(st.integers(1, 60)), channel] = np.nan if fault == "nan_run" else np.inf
    arrays = {"y": y.T if fault == "transposed" else y, "sample_time_s": draw(st.sampled_from([0.005, 0.01, 2e-4]))}
    inputs = draw(st.sampled_from(["none", "empty", "zeros"]))
    if inputs != "none":
        arrays["u"] = np.zeros(0) if inputs == "empty" else np.zeros((n, 1))
    return arrays


@SLOW
@given(arrays=output_only_records(), command=st.sampled_from(["identify", "track"]))
def test_any_output_only_record_is_a_model_or_one_clear_line(tmp_path_factory, capsys, arrays, command) -> None:
    """Exit 0 with finite modes, or exit 2 with one line naming the record and no Python exception's name."""
    options = (["--json", "--output-only"] if command == "identify" else
               ["--jsonl", "--output-only", "--window", "600", "--every", "500", "--no-progress"])
    out = _run_on_record(tmp_path_factory, capsys, arrays, command, "out", options)
    if out is None:
        return
    lines = out.read_text().splitlines() if command == "track" else [out.read_text()]
    for document in map(json.loads, lines):
        assert document.get("error") or document.get("waiting") or document["n_inputs"] == 0
        for mode in document.get("modes", []):
            assert math.isfinite(mode["frequency_rad_s"]) and math.isfinite(mode["damping_ratio"])
