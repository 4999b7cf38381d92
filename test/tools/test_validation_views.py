"""The data behind frf.png, mac.png, stabilization.png and the fits, and `identify --plot-dir/--csv`."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from scipy import linalg

from okid_bench.cases import benchmark_case
from okid_ros.cli import main
from okid_ros.core.pipeline import identify
from okid_ros.core.validation import fit_percent, h1_frf, mac_matrix, model_frf, prediction_fits
from okid_ros.errors import DataError
from okid_ros.records import save_record
from okid_ros.sim.inputs import white_input
from okid_ros.sim.paper_model import paper_model
from okid_ros.sim.simulators import simulate, simulate_innovation
from okid_ros.tools.validation_plots import (
    ModelView,
    frf_data,
    mac_data,
    parse_pairs,
    plot_stabilization,
    stabilization_points,
)

DT = 0.008


@pytest.fixture(scope="module")
def paper_record():
    case = benchmark_case("paper-lp15")
    u = case.make_input(15000, 1)
    y = simulate(case.system, u, seed=2)
    return case, u, y, identify(u, y, case.sample_time_s, order=case.arx_order)


def test_model_frf_is_the_transfer_matrix():
    truth = paper_model()
    f = np.array([0.0, 3.3, 5.9, 30.0])
    H = model_frf(truth.A, truth.B, truth.C, truth.D, f, DT)
    for k, fk in enumerate(f):
        z = np.exp(2j * np.pi * fk * DT)
        direct = truth.C @ linalg.solve(z * np.eye(truth.n_states) - truth.A, truth.B) + truth.D
        np.testing.assert_allclose(H[k], direct, rtol=1e-10, atol=1e-12)


def test_h1_recovers_the_true_frf_from_a_quiet_record():
    truth = paper_model(innovation_variance=1e-6)
    u = white_input(20000, 2, seed=5)
    y, _ = simulate_innovation(truth, u, seed=6)
    f, H = h1_frf(u, y, DT)
    Ht = model_frf(truth.A, truth.B, truth.C, truth.D, f, DT)
    away = (np.abs(f - 5.9) > 1.0) & (np.abs(f - 7.34) > 1.0) & (np.abs(f - 48.46) > 2.0) & (f > 0.5)
    err = np.abs(H - Ht)[away].max(axis=(1, 2)) / np.abs(Ht)[away].max(axis=(1, 2))
    assert np.median(err) < 0.02 and err.max() < 0.2


def test_frf_data_matches_the_truth_at_the_identified_modes(paper_record):
    case, u, y, model = paper_record
    data = frf_data(ModelView.of(model), u, y)
    truth = case.system
    assert data.measured.shape == data.model.shape == (data.frequency_hz.size, 2, 2)
    assert data.pairs == [(0, 0), (0, 1), (1, 0), (1, 1)]
    Ht = model_frf(truth.A, truth.B, truth.C, truth.D, data.mode_frequency_hz, DT)
    rel = np.abs(data.model_at_modes - Ht).max(axis=(1, 2)) / np.abs(Ht).max(axis=(1, 2))
    assert rel[:2].max() < 0.25, rel  # the two modes of the paper's table, at their peaks
    # the measured H1 follows the model between 2 and 12 Hz (where the 15 Hz input excites)
    band = (data.frequency_hz > 2) & (data.frequency_hz < 12)
    ratio = np.abs(data.measured[band]) / np.abs(data.model[band])
    assert 0.8 < np.median(ratio) < 1.25


def test_mac_data_has_a_unit_diagonal_and_compares_with_a_reference(paper_record):
    _, _, _, model = paper_record
    view = ModelView.of(model)
    data = mac_data(view, reference=[m.as_dict() for m in model.modes])
    n = len(model.modes)
    assert data["auto"].shape == (n, n)
    np.testing.assert_allclose(np.diag(data["auto"]), 1.0)
    np.testing.assert_allclose(data["auto"], data["auto"].T)
    np.testing.assert_allclose(np.diag(data["reference"]), 1.0)
    assert data["auto"][0, 1] < 0.2  # the paper's first two modes have distinct shapes
    # the truth's shapes: MAC of each identified mode with its true mode near 1
    z, psi = linalg.eig(paper_model().A)
    upper = np.argsort(np.abs(np.angle(z[z.imag > 0])))
    true_shapes = (paper_model().C @ psi[:, z.imag > 0])[:, upper]
    assert np.diag(mac_matrix(np.column_stack([m.shape for m in model.modes]), true_shapes)).min() > 0.95
    # shapes of another length cannot be compared: said, not left out of mac.png without a word
    with pytest.raises(DataError, match="1 of 1 mode"):
        mac_data(view, reference=[{"frequency_hz": 1.0, "shape_real": [1, 0, 0], "shape_imag": [0, 0, 0]}])


def test_fits_of_one_step_prediction_and_simulation(paper_record):
    case, u, y, model = paper_record
    assert fit_percent(y[:, 0], y[:, 0]) == pytest.approx(100.0)
    assert fit_percent(y[:, 0], np.full(y.shape[0], y[:, 0].mean())) == pytest.approx(0.0)
    fits = prediction_fits(model, u, y)
    oracle = prediction_fits(case.system.to_innovation_form() if hasattr(case.system, "to_innovation_form")
                             else case.system, u, y, burn_in=fits["burn_in_samples"])
    assert len(fits["one_step_pct"]) == 2 and fits["burn_in_samples"] == 100
    for got, best in zip(fits["one_step_pct"], oracle["one_step_pct"]):
        assert best - 2.0 < got <= best + 0.5  # near the true predictor's fit, not above it by much
    assert all(sim < pred for sim, pred in zip(fits["simulation_pct"], fits["one_step_pct"]))


def test_parse_pairs():
    assert parse_pairs("1:1,2:2", 2, 2) == [(0, 0), (1, 1)]
    assert len(parse_pairs(None, 28, 2)) == 16
    with pytest.raises(ValueError, match="out of range"):
        parse_pairs("3:1", 2, 2)
    with pytest.raises(ValueError, match="OUTPUT:INPUT"):
        parse_pairs("a", 2, 2)
    # A list repeated 50 times drew 200 panels (139 s, a 7 MB figure); each pair is drawn once now,
    # and a figure takes at most 64 listed pairs.
    assert parse_pairs(",".join(["1:1", "2:2", "1:2", "2:1"] * 50), 2, 2) == [(0, 0), (1, 1), (0, 1), (1, 0)]
    assert len(parse_pairs(",".join(f"{i}:{j}" for i in range(1, 29) for j in (1, 2)), 28, 2)) == 56
    with pytest.raises(ValueError, match="66 FRF pairs: at most 64 in one figure"):
        parse_pairs(",".join(f"{i}:1" for i in range(1, 67)), 66, 1)


def _stabilization() -> list[dict]:
    """Orders 2..10: a mode at 5.9 Hz stable from n = 4 (damping from 6, shape from 8), noise poles."""
    out = []
    for n in range(2, 12, 2):
        poles = [{"frequency_hz": 5.9 + 0.01 / n, "damping_ratio": 0.003, "stable_frequency": n >= 4,
                  "stable_damping": n >= 6, "stable_shape": n >= 8}]
        poles += [{"frequency_hz": 20.0 + n, "damping_ratio": 0.2, "stable_frequency": False,
                   "stable_damping": False, "stable_shape": False}]
        out.append({"n_states": n, "poles": poles})
    return out


def test_stabilization_points_by_criteria():
    points = stabilization_points(_stabilization())
    assert points[0][1] == [2, 2, 4, 6, 8, 10]  # n = 2 mode and every noise pole
    assert points[1][1] == [4] and points[2][1] == [6] and points[3][1] == [8, 10]
    assert all(abs(f - 5.9) < 0.01 for f in points[3][0])


def test_plot_stabilization_draws_poles_modes_and_cmif():
    from okid_ros.tools.plots import pyplot

    plt = pyplot()
    y = np.random.default_rng(0).normal(size=(2000, 2))
    fig = plot_stabilization(_stabilization(), [{"frequency_hz": 5.9}], y=y, sample_time_s=DT)
    ax = fig.axes[0]
    sizes = sorted(len(c.get_offsets()) for c in ax.collections)
    assert sizes == [1, 1, 2, 6]
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "+ shape" in labels and "chosen mode" in labels
    assert fig.axes[1].get_ylabel().startswith("singular value") and len(fig.axes[1].lines) == 2
    plt.close(fig)


@pytest.fixture(scope="module")
def record_file(tmp_path_factory):
    u = white_input(3000, 2, seed=3)
    y, _ = simulate_innovation(paper_model(), u, seed=4)
    path = tmp_path_factory.mktemp("identify") / "paper.npz"
    save_record(path, u, y, DT)
    return path


def test_identify_writes_fits_figures_csv_and_refuses_to_overwrite(record_file, tmp_path, capsys):
    out, figs, table = tmp_path / "m.json", tmp_path / "figs", tmp_path / "modes.csv"
    argv = ["identify", str(record_file), "--order", "20", "--states", "6", "--json", str(out),
            "--plot-dir", str(figs), "--csv", str(table), "--frf-pairs", "1:1,2:2"]
    assert main(argv) == 0
    stdout = capsys.readouterr().out
    assert "one-step prediction [" in stdout and "free-run simulation [" in stdout
    document = json.loads(out.read_text())
    assert len(document["fit_one_step_pct"]) == 2 and min(document["fit_one_step_pct"]) > 80
    # The orders tried around the fixed order 6, each with its poles.
    assert document["stabilization"][0]["n_states"] == 2
    assert 6 in [entry["n_states"] for entry in document["stabilization"]]
    assert sorted(p.name for p in figs.iterdir()) == ["frf.png", "mac.png", "stabilization.png"]
    rows = list(csv.DictReader(table.open()))
    assert [float(r["frequency_hz"]) for r in rows] == [m["frequency_hz"] for m in document["modes"]]
    assert [float(r["damping_ratio_std"]) for r in rows] == [m["damping_ratio_std"] for m in document["modes"]]
    (tmp_path / "m2.json").write_text("{}")
    before = (figs / "frf.png").read_bytes()
    assert main([*argv[:-6], "--json", str(tmp_path / "new.json"), "--plot-dir", str(figs)]) == 2
    assert "frf.png" in capsys.readouterr().err and (figs / "frf.png").read_bytes() == before
    assert not (tmp_path / "new.json").exists()
    assert main([*argv, "--force"]) == 0
