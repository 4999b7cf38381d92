"""Strict JSON in every output (null, never NaN/Infinity) and no silent overwrite by identify/track."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from okid_ros.cli import main
from okid_ros.jsonio import dumps, to_strict
from okid_ros.records import save_record
from okid_ros.sim.inputs import white_input
from okid_ros.sim.paper_model import paper_model
from okid_ros.sim.simulators import simulate_innovation

DT = 0.008


def strict_loads(text: str):
    """``json.loads`` that fails on NaN, Infinity and -Infinity, like JavaScript's JSON.parse."""
    def refuse(token: str):
        raise ValueError(f"non-standard JSON token {token}")

    return json.loads(text, parse_constant=refuse)


def test_strict_loads_refuses_what_plain_json_writes():
    with pytest.raises(ValueError, match="NaN"):
        strict_loads(json.dumps({"emac": float("nan")}))


def test_to_strict_turns_non_finite_numbers_into_null():
    value = {"a": float("nan"), "b": [np.inf, -np.inf, np.float64(1.5)], 3: np.array([np.nan, 2.0]),
             "c": (np.int64(4), np.bool_(True))}
    assert to_strict(value) == {"a": None, "b": [None, None, 1.5], "3": [None, 2.0], "c": [4, True]}
    assert strict_loads(dumps(value)) == {"a": None, "b": [None, None, 1.5], "3": [None, 2.0], "c": [4, True]}


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    u = white_input(2600, 2, seed=3)
    y, _ = simulate_innovation(paper_model(), u, seed=4)
    path = tmp_path_factory.mktemp("json") / "paper.npz"
    save_record(path, u, y, DT)
    return path


@pytest.fixture
def nan_emac(monkeypatch):
    """Every identified model gets a mode whose EMAC could not be computed (NaN)."""
    import okid_ros.core.pipeline as pipeline
    import okid_ros.service.realization as realization  # track's windows (identify_window)

    for module, name in ((pipeline, "identify"), (pipeline, "identify_from_arx"), (realization, "identify_from_arx")):
        original = getattr(module, name)

        def wrapped(*args, _original=original, **kwargs):
            model = _original(*args, **kwargs)
            model.modes[0].emac = math.nan
            return model

        monkeypatch.setattr(module, name, wrapped)


def test_identify_json_is_strict_and_not_overwritten_without_force(record, tmp_path, capsys, nan_emac):
    out = tmp_path / "model.json"
    argv = ["identify", str(record), "--order", "20", "--states", "6", "--json", str(out)]
    assert main(argv) == 0
    document = strict_loads(out.read_text())
    assert document["modes"][0]["emac"] is None
    out.write_text("keep me")
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "exists already" in err and "--force" in err and err.count("\n") == 1
    assert out.read_text() == "keep me"
    assert main([*argv, "--force"]) == 0
    assert strict_loads(out.read_text())["n_states"] == 6


def test_track_jsonl_is_strict_and_not_overwritten_without_force(record, tmp_path, capsys, nan_emac):
    out = tmp_path / "track.jsonl"
    argv = ["track", str(record), "--order", "20", "--window", "1500", "--every", "600", "--states", "6",
            "--jsonl", str(out), "--no-progress"]
    assert main(argv) == 0
    lines = [strict_loads(line) for line in out.read_text().splitlines()]
    assert lines and all(line["modes"][0]["emac"] is None for line in lines)
    out.write_text("keep me")
    capsys.readouterr()
    assert main(argv) == 2
    assert "exists already" in capsys.readouterr().err
    assert out.read_text() == "keep me"
    assert main([*argv, "--force"]) == 0
    assert len(out.read_text().splitlines()) == len(lines)


def test_identify_with_the_papers_method_writes_its_modes_and_their_standard_deviations(tmp_path, capsys):
    """``--method paper`` once failed after identifying (the model carried no uncertainty result)."""
    u = white_input(15000, 2, seed=3)  # the paper's method needs a long broadband record to stay stable
    y, _ = simulate_innovation(paper_model(), u, seed=4)
    record, out = tmp_path / "broadband.npz", tmp_path / "paper.json"
    save_record(record, u, y, DT)
    assert main(["identify", str(record), "--order", "100", "--states", "6", "--method", "paper",
                 "--json", str(out)]) == 0, capsys.readouterr().err
    document = strict_loads(out.read_text())
    assert document["method"] == "paper" and document["uncertainty"]["computed"] is True
    assert len(document["modes"]) == 3
    assert all(mode["frequency_hz_std"] > 0 for mode in document["modes"])


def test_identify_names_the_jackknife_when_it_gives_the_standard_deviations(tmp_path, capsys):
    """16 outputs: beyond the covariance's budget, the modes' stds come from the jackknife."""
    from okid_bench.cases import benchmark_case
    from okid_ros.sim.simulators import simulate

    case = benchmark_case("many-outputs")
    u = case.make_input(3000, 0)
    y = simulate(case.system, u, seed=1)
    record, out = tmp_path / "many.npz", tmp_path / "many.json"
    save_record(record, u, y, case.sample_time_s)
    assert main(["identify", str(record), "--order", "20", "--json", str(out)]) == 0, capsys.readouterr().err
    document = strict_loads(out.read_text())
    assert document["uncertainty"] == {"computed": True, "reason": None,
                                       "method": "delete-one jackknife over consecutive segments of the record"}
    assert document["modes"] and all(mode["frequency_hz_std"] > 0 and mode["damping_ratio_std"] > 0
                                     for mode in document["modes"])
