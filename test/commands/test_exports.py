"""`identify --csv` and `--uff`: the modal table and the UFF datasets 55 (shapes) and 58 (FRFs), read back."""

from __future__ import annotations

import csv
import json
import os
import stat
import threading

import numpy as np
import pytest
import pyuff

from okid_ros.cli import main
from okid_ros.core.validation import h1_frf, model_frf
from okid_ros.errors import OkidWarning
from okid_ros.records import load_record, save_record
from okid_ros.sim.inputs import white_input
from okid_ros.sim.paper_model import paper_model
from okid_ros.sim.simulators import simulate_innovation
from okid_ros.tools.exports import write_uff

DT = 0.008


@pytest.fixture(scope="module")
def identified(tmp_path_factory):
    root = tmp_path_factory.mktemp("exports")
    u = white_input(3000, 2, seed=3)
    y, _ = simulate_innovation(paper_model(), u, seed=4)
    save_record(root / "paper.npz", u, y, DT)
    argv = ["identify", str(root / "paper.npz"), "--order", "20", "--states", "6", "--json", str(root / "m.json"),
            "--csv", str(root / "modes.csv"), "--uff", str(root / "model.uff")]
    assert main(argv) == 0
    return root, argv, json.loads((root / "m.json").read_text())


def test_csv_modal_table_matches_the_json(identified):
    root, _, document = identified
    rows = list(csv.DictReader((root / "modes.csv").open()))
    assert len(rows) == len(document["modes"]) == 3
    for row, mode in zip(rows, document["modes"]):
        for key in ("frequency_hz", "frequency_hz_std", "damping_ratio", "damping_ratio_std", "mpc", "msv"):
            assert float(row[key]) == mode[key]
        assert int(row["id"]) == mode["id"] and row["stable"] == "true"
        assert [float(row["shape_real_1"]), float(row["shape_real_2"])] == mode["shape_real"]
        assert row["emac"] == ("" if mode["emac"] is None else repr(mode["emac"]))


def test_uff_shapes_and_frfs_read_back_with_pyuff(identified):
    root, _, document = identified
    sets = pyuff.UFF(str(root / "model.uff")).read_sets()
    shapes = [s for s in sets if s["type"] == 55]
    frfs = [s for s in sets if s["type"] == 58]
    assert len(shapes) == 3 and len(frfs) == 2 * 4  # model and measured H1, 2 outputs x 2 inputs
    for dataset, mode in zip(shapes, document["modes"]):
        np.testing.assert_allclose(dataset["r1"], np.array(mode["shape_real"]) + 1j * np.array(mode["shape_imag"]),
                                   rtol=1e-4, atol=1e-6)
        assert abs(dataset["eig"]) == pytest.approx(2 * np.pi * mode["frequency_hz"], rel=1e-4)
        assert -dataset["eig"].real / abs(dataset["eig"]) == pytest.approx(mode["damping_ratio"], rel=1e-3)
        assert list(dataset["node_nums"]) == [1, 2]
    record = load_record(root / "paper.npz")
    freq, measured = h1_frf(record.u, record.y, DT)
    A, B, C, D = (np.array(document[k]) for k in "ABCD")
    modelled = model_frf(A, B, C, D, freq, DT)
    for dataset in frfs:
        i, j = int(dataset["rsp_node"]) - 1, int(dataset["ref_node"]) - 1
        want = modelled[:, i, j] if dataset["id2"].strip() == "model" else measured[:, i, j]
        np.testing.assert_allclose(dataset["x"], freq, rtol=1e-4, atol=1e-6)
        np.testing.assert_allclose(dataset["data"], want, rtol=1e-6, atol=1e-9 * np.abs(want).max())
        assert dataset["func_type"] == 4


def test_exports_are_not_replaced_without_force(identified, capsys):
    root, argv, _ = identified
    before = (root / "model.uff").read_bytes()
    (root / "m.json").unlink()
    capsys.readouterr()
    assert main(argv) == 2
    assert "modes.csv: exists already" in capsys.readouterr().err
    (root / "modes.csv").unlink()
    assert main(argv) == 2
    assert "model.uff: exists already" in capsys.readouterr().err
    assert (root / "model.uff").read_bytes() == before and not (root / "m.json").exists()
    assert main([*argv, "--force"]) == 0


def test_a_uff_to_a_fifo_is_written_into_not_replaced(identified, tmp_path):
    # Before, write_uff unlinked whatever stood at the path and pyuff made a regular file there
    # (as root with --uff /dev/null: the device replaced).
    root, _, _ = identified
    fifo = tmp_path / "uff.fifo"
    os.mkfifo(fifo)
    received = []
    reader = threading.Thread(target=lambda: received.append(fifo.read_bytes()), daemon=True)
    reader.start()
    assert main(["identify", str(root / "paper.npz"), "--order", "20", "--states", "6", "--json",
                 str(tmp_path / "m.json"), "--uff", str(fifo)]) == 0
    reader.join(timeout=30)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    assert received and received[0] == (root / "model.uff").read_bytes()


def test_uff_leaves_out_the_frequencies_a_measured_frf_does_not_determine(tmp_path):
    # NaN marks them (h1_frf where the inputs' cross-spectrum is singular); they were written as 0.
    freq = np.linspace(0.0, 10.0, 11)
    modelled = (1.0 + 1j * freq)[:, None, None] * np.ones((1, 2, 1))
    measured = modelled.copy()
    measured[[3, 4]] = np.nan
    with pytest.warns(OkidWarning, match="measured H1 FRF is undetermined at 2 of 11 frequencies"):
        count = write_uff(tmp_path / "m.uff", [], frequency_hz=freq, frfs={"model": modelled, "measured H1": measured})
    sets = pyuff.UFF(str(tmp_path / "m.uff")).read_sets()
    assert count == len(sets) == 4
    kept = np.delete(np.arange(freq.size), [3, 4])
    for dataset in sets:
        if dataset["id2"].strip() == "model":
            np.testing.assert_allclose(dataset["x"], freq, atol=1e-6)
            np.testing.assert_allclose(dataset["data"], modelled[:, 0, 0], rtol=1e-9)
        else:
            assert dataset["abscissa_spacing"] == 0
            np.testing.assert_allclose(dataset["x"], freq[kept], atol=1e-6)
            np.testing.assert_allclose(dataset["data"], measured[kept, 0, 0], rtol=1e-9)


def test_a_measured_frf_undetermined_everywhere_is_not_written_and_said(tmp_path, capsys):
    # 80 samples: one Welch segment, so the two inputs' 2 x 2 cross-spectrum is singular everywhere.
    u = white_input(80, 2, seed=3)
    save_record(tmp_path / "short.npz", u, simulate_innovation(paper_model(), u, seed=4)[0], DT)
    assert main(["identify", str(tmp_path / "short.npz"), "--json", str(tmp_path / "m.json"),
                 "--uff", str(tmp_path / "m.uff")]) == 0
    err = capsys.readouterr().err
    assert "warning: UFF: the measured H1 FRF is undetermined at every frequency: not written" in err
    frfs = [s for s in pyuff.UFF(str(tmp_path / "m.uff")).read_sets() if s["type"] == 58]
    assert len(frfs) == 4 and {s["id2"].strip() for s in frfs} == {"model"}
    assert all(np.all(np.isfinite(s["data"])) and np.any(s["data"] != 0) for s in frfs)
