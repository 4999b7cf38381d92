"""`okid-ros identify --output-only` and a record without inputs: the JSON contract with n_inputs 0."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest
from ros_helpers import REPO_ROOT

from okid_ros import cli

KOMA = REPO_ROOT.parent / "shared" / "data" / "oma" / "koma-shear-frame"


@pytest.fixture(scope="module")
def koma_record() -> tuple[np.ndarray, float, list[dict]]:
    data = np.load(KOMA / "shear_frame.npz")
    return data["y"], float(data["sample_time_s"]), json.loads((KOMA / "truth.json").read_text())["modes"]


def _check_document(path: Path, truth: list[dict]) -> dict:
    document = json.loads(path.read_text())
    n, p = document["n_states"], document["n_outputs"]
    assert document["n_inputs"] == 0
    assert document["B"] == [[] for _ in range(n)] and document["D"] == [[] for _ in range(p)]
    assert np.array(document["K"]).shape == (n, p)
    assert document["spectral_radius"] < 1 and document["predictor_spectral_radius"] < 1
    frequencies = [m["frequency_hz"] for m in document["modes"]]
    assert len(frequencies) == len(truth)
    for f, true in zip(frequencies, truth):
        assert abs(f / true["discrete_frequency_hz"] - 1) < 0.005
    assert all(m["frequency_hz_std"] is not None for m in document["modes"])
    return document


def test_output_only_ignores_the_inputs_of_a_record(tmp_path: Path, koma_record, capsys) -> None:
    y, dt, truth = koma_record
    record = tmp_path / "with_u.npz"
    np.savez(record, u=np.random.default_rng(1).standard_normal((y.shape[0], 2)), y=y, sample_time_s=dt)
    out = tmp_path / "model.json"
    assert cli.main(["identify", str(record), "--output-only", "--json", str(out)]) == 0
    document = _check_document(out, truth)
    assert document["method"] == "ssi-cva"  # the default route
    stdout = capsys.readouterr().out
    assert "output-only" in stdout
    assert "one-step prediction [" in stdout and "free-run simulation" not in stdout, "no input: no free run"
    # Outputs are never replaced without --force.
    assert cli.main(["identify", str(record), "--output-only", "--json", str(out)]) == 2


def test_one_option_passed_over_is_named_in_the_singular() -> None:
    """Was: "--order apply to input-output identification"."""
    from okid_ros.commands._args import ignored_for_output_only
    from okid_ros.commands.identify import INPUT_OUTPUT_ONLY
    from okid_ros.core.options import RealizationOptions

    args = argparse.Namespace(order=5, states="auto", ar_order=None, method="okid", regularization=None,
                              no_refine=False, gain=RealizationOptions.gain, max_states=RealizationOptions.max_states)
    assert ignored_for_output_only(args, INPUT_OUTPUT_ONLY).startswith("--order applies to input-output")
    args.states = 4
    assert ignored_for_output_only(args, INPUT_OUTPUT_ONLY).startswith("--order, --states apply to input-output")


def test_options_an_output_only_run_passes_over_are_named(tmp_path: Path, koma_record, capsys) -> None:
    # And a record file's --params / --param: they describe a bag's topics.
    y, dt, _ = koma_record
    record = tmp_path / "y_only.npz"
    np.savez(record, y=y[:6000], sample_time_s=dt)
    code = cli.main(["identify", str(record), "--method", "paper", "--gain", "whitening", "--param",
                     "sample_time_s=0.5", "--json", str(tmp_path / "m.json")])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "warning: --method, --gain apply to input-output identification; ignored" in err
    assert "--params, --param and --source say how to read a bag's topics" in err
    assert json.loads((tmp_path / "m.json").read_text())["sample_time_s"] == dt


@pytest.mark.parametrize("kind", ["npz", "csv"])
def test_record_without_inputs_is_identified_output_only(tmp_path: Path, koma_record, kind: str) -> None:
    y, dt, truth = koma_record
    record = tmp_path / f"y_only.{kind}"
    if kind == "npz":
        np.savez(record, y=y, sample_time_s=dt)
    else:
        header = ",".join(f"y{i + 1}" for i in range(y.shape[1]))
        rows = "\n".join(",".join(map(repr, row.tolist())) for row in y)
        record.write_text(f"# sample_time_s={dt!r}\n{header}\n{rows}")
    out = tmp_path / "model.json"
    assert cli.main(["identify", str(record), "--json", str(out)]) == 0
    _check_document(out, truth)


def test_frequency_response_outputs_are_refused_in_one_line(tmp_path: Path, koma_record, capsys) -> None:
    y, dt, _ = koma_record
    record = tmp_path / "with_u.npz"
    np.savez(record, u=np.ones((y.shape[0], 1)), y=y, sample_time_s=dt)
    code = cli.main(["identify", str(record), "--output-only", "--uff", str(tmp_path / "x.uff"),
                     "--json", str(tmp_path / "m.json")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "output-only" in err[0]


def test_track_names_the_options_its_output_only_windows_pass_over(tmp_path: Path, koma_record, capsys) -> None:
    # track ignored --states, --max-states and --gain in silence where identify warns (one rule,
    # commands/_args.ignored_for_output_only); --order still sets the VAR that frames the window.
    y, dt, _ = koma_record
    record = tmp_path / "y_only.npz"
    np.savez(record, y=y[:3000], sample_time_s=dt)
    out = tmp_path / "t.jsonl"
    code = cli.main(["track", str(record), "--jsonl", str(out), "--window", "1500", "--every", "1500", "--order",
                     "12", "--states", "6", "--gain", "whitening", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "okid-ros track: warning: --states, --gain apply to input-output identification; ignored for this " \
           "output-only one" in err
    assert json.loads(out.read_text().splitlines()[0])["arx_order"] == 12


def test_the_output_only_method_is_chosen_on_the_command_line(tmp_path: Path, koma_record, capsys) -> None:
    # node 2's realization.output_only_method had no `identify` counterpart: a route only through the API.
    y, dt, truth = koma_record
    record = tmp_path / "y_only.npz"
    np.savez(record, y=y, sample_time_s=dt)
    out = tmp_path / "model.json"
    assert cli.main(["identify", str(record), "--output-only-method", "ssi-cov", "--json", str(out)]) == 0
    assert _check_document(out, truth)["method"] == "ssi-cov"
    with_u = tmp_path / "with_u.npz"
    rng = np.random.default_rng(2)
    u = rng.standard_normal((2000, 1))
    np.savez(with_u, u=u, y=np.convolve(u[:, 0], [0.0, 1.0, 0.5], "same")[:, None] + 0.01 * rng.standard_normal(
        (2000, 1)), sample_time_s=0.01)
    capsys.readouterr()
    code = cli.main(["identify", str(with_u), "--output-only-method", "ssi-cov", "--json", str(tmp_path / "io.json")])
    err = capsys.readouterr().err
    assert "--output-only-method applies to output-only identification" in err, err
    assert code == 0 and json.loads((tmp_path / "io.json").read_text())["n_inputs"] == 1


def test_track_realizes_its_output_only_windows_by_the_method_chosen(tmp_path: Path, koma_record, capsys) -> None:
    # track had no --output-only-method: its windows took the default route whatever the user wanted
    # (node 2 has realization.output_only_method). Each line says its route.
    y, dt, truth = koma_record
    record = tmp_path / "y_only.npz"
    np.savez(record, y=y[:6000], sample_time_s=dt)
    lines = {}
    for method in ("ssi-cva", "ssi-cov"):
        out = tmp_path / f"{method}.jsonl"
        code = cli.main(["track", str(record), "--jsonl", str(out), "--window", "5000", "--every", "5000",
                         "--output-only-method", method, "--no-progress"])
        assert code == 0, capsys.readouterr().err
        lines[method] = json.loads(out.read_text().splitlines()[0])
        assert lines[method]["method"] == method
    frequencies = {method: sorted(mode["frequency_hz"] for mode in line["modes"]) for method, line in lines.items()}
    assert frequencies["ssi-cva"] != frequencies["ssi-cov"]
    for found in frequencies.values():  # each route's own model of the window, not a failed one
        assert min(abs(f / truth[0]["discrete_frequency_hz"] - 1.0) for f in found) < 0.02
