"""The whole chain against known truth: the paper's published model and designed structures."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from okid_ros.cli import main as okid_ros_main
from okid_ros.core.estimator import ModalStateEstimator
from okid_ros.core.pipeline import IdentificationError, identify
from okid_ros.core.statespace import one_step_prediction
from okid_ros.sim.inputs import lowpass_input, white_input
from okid_ros.sim.paper_model import paper_model
from okid_ros.sim.simulators import simulate_innovation

DT = 0.008
PAPER_MODES = [(37.097, 0.002763), (46.1325, 0.028684)]  # computed from the published A


def _paper_record(n_samples: int, cutoff_hz: float | None, seed: int):
    truth = paper_model()
    total = n_samples + 4000  # the last 4000 samples are held out for validation
    u = white_input(total, 2, seed=seed) if cutoff_hz is None else lowpass_input(total, 2, cutoff_hz, DT, seed=seed)
    y, _ = simulate_innovation(truth, u, seed=seed + 1000)
    return truth, u[:n_samples], y[:n_samples], u[n_samples:], y[n_samples:]


def _ratio(model, truth, u, y, burn_in: int = 500) -> float:
    _, e = one_step_prediction(model, u, y)
    _, e0 = one_step_prediction(truth, u, y)
    return float(np.trace(np.cov(e[burn_in:].T)) / np.trace(np.cov(e0[burn_in:].T)))


def _closest(modes, frequency_rad_s):
    return min(modes, key=lambda m: abs(m.frequency_rad_s - frequency_rad_s))


def test_paper_case_low_pass_input_recovers_both_modes():
    """The paper's experiment: 15 Hz low-pass thruster inputs, 3750 samples at 125 Hz, q = 100.

    Judged by RMS errors over noise seeds (one seed can be lucky or unlucky). Measured over 6
    seeds: mode 1 RMS 0.16 % / 0.13 pp, mode 2 RMS 0.6 % / 0.35 pp, ratio <= 1.02.
    """
    errors = []
    for seed in range(3):
        truth, u, y, u_val, y_val = _paper_record(3750, 15.0, seed)
        model = identify(u, y, DT, order=100)
        row = []
        for freq, zeta in PAPER_MODES:
            mode = _closest(model.modes, freq)
            row += [100 * (mode.frequency_rad_s / freq - 1), 100 * (mode.damping_ratio - zeta)]
        errors.append(row)
        assert _ratio(model, truth, u_val, y_val) < 1.10
    rms = np.sqrt(np.mean(np.square(errors), axis=0))
    assert np.abs(errors).max(axis=0)[[0, 2]].max() < 3.0  # every seed finds both modes
    assert rms[0] < 0.5 and rms[1] < 0.3  # mode 1: frequency %, damping pp
    assert rms[2] < 1.2 and rms[3] < 1.0  # mode 2


def test_paper_method_as_published_works_with_broadband_input():
    truth, u, y, u_val, y_val = _paper_record(15000, None, seed=3)
    model = identify(u, y, DT, order=100, method="paper", n_states=6)
    assert model.method == "paper" and model.gain_method == "whitening"
    # Less accurate than the robust chain (measured: up to 1 % and 1.3 pp on mode 2), but it works.
    for freq, zeta in PAPER_MODES:
        mode = _closest(model.modes, freq)
        assert abs(mode.frequency_rad_s / freq - 1) < 0.02
        assert abs(mode.damping_ratio - zeta) * 100 < 1.5
    assert _ratio(model, truth, u_val, y_val) < 1.5


def test_whitening_gain_option_gives_a_working_predictor():
    truth, u, y, u_val, y_val = _paper_record(15000, 50.0, seed=4)
    refit = identify(u, y, DT, order=100, refine=False)
    white = identify(u, y, DT, order=100, gain="whitening", refine=False)
    assert white.gain_method == "whitening"
    np.testing.assert_allclose(white.A, refit.A)
    assert _ratio(refit, truth, u_val, y_val) < 1.03
    assert _ratio(white, truth, u_val, y_val) < 1.5


def test_estimator_reproduces_the_innovation_form_predictor_and_modal_coordinates():
    truth, u, y, _, _ = _paper_record(3750, 15.0, seed=5)
    model = identify(u, y, DT, order=100)
    estimator = ModalStateEstimator.from_model(model)
    out = estimator.run(u, y)
    # The model applies to the signals less the offsets it removed (the record's means).
    u0, y0 = u - model.input_offset, y - model.output_offset
    _, e = one_step_prediction(model, u0, y0)
    np.testing.assert_allclose(out.innovations, e, atol=1e-9 * np.abs(y).max())
    assert out.modal_coordinates.shape == (3750, len(model.modes), 2)
    # Filtered outputs are closer to the measurements than the one-step predictions.
    assert np.mean((y - out.y_estimated) ** 2) < np.mean(e**2)
    # Physical states reproduce most of the output (the modal coordinates are in output units).
    y_modes = out.states[:, : model.n_physical_states] @ model.C[:, : model.n_physical_states].T
    assert np.var(y0 - y_modes) < 0.1 * np.var(y)


def test_estimator_start_up_gain_converges_to_the_steady_gain():
    truth = paper_model()
    est = ModalStateEstimator(truth, n_physical_states=6, initial_covariance=100.0)
    u = white_input(3000, 2, seed=6)
    y, _ = simulate_innovation(truth, u, seed=7)
    out = est.run(u, y)
    np.testing.assert_allclose(est.kf.K, truth.K)
    steady = ModalStateEstimator(truth, n_physical_states=6)
    out_steady = steady.run(u, y)
    # The start-up filter is no worse early on and identical once converged.
    assert np.mean(out.innovations[:200] ** 2) <= np.mean(out_steady.innovations[:200] ** 2) * 1.05
    np.testing.assert_allclose(out.innovations[-100:], out_steady.innovations[-100:], atol=1e-3)


def test_prediction_error_refinement_does_not_worsen_the_predictor():
    """The refinement is kept only when it lowers the cost; on held-out data it should help."""
    ratios = []
    for seed in (10, 11):
        truth, u, y, u_val, y_val = _paper_record(3750, 50.0, seed)
        plain = identify(u, y, DT, order=100, refine=False)
        refined = identify(u, y, DT, order=100, refine=True)
        assert refined.refined and not plain.refined
        ratios.append((_ratio(plain, truth, u_val, y_val), _ratio(refined, truth, u_val, y_val)))
    assert np.mean([r[1] for r in ratios]) <= np.mean([r[0] for r in ratios]) + 1e-3


def test_the_order_is_chosen_again_after_refining():
    """Refining the next best orders too and taking the lowest BIC after refinement predicts new data better.

    On these records BIC before the refinement prefers 8 states on most seeds; after it, the
    true order (6) wins on several, and the held-out one-step prediction is better on average.
    """
    ratios, changed = [], 0
    for seed in range(10, 16):
        truth, u, y, u_val, y_val = _paper_record(3750, 50.0, seed)
        winner_only = identify(u, y, DT, order=100, refined_orders=1)
        default = identify(u, y, DT, order=100)
        assert default.refined and winner_only.refined
        changed += default.n_states != winner_only.n_states
        ratios.append((_ratio(winner_only, truth, u_val, y_val), _ratio(default, truth, u_val, y_val)))
    assert changed >= 2
    assert np.mean([r[1] for r in ratios]) < np.mean([r[0] for r in ratios])


def test_identify_errors_are_one_line_reasons():
    u, y = np.zeros((300, 2)), np.random.default_rng(0).standard_normal((300, 2))
    with pytest.raises(IdentificationError, match="at least 503 needed"):
        identify(u, y, DT, order=100)
    with pytest.raises(IdentificationError, match="sample_time_s"):
        identify(u, y, -1.0, order=10)
    with pytest.raises(IdentificationError, match="method"):
        identify(u, y, DT, order=10, method="magic")


def test_identify_command_writes_the_json_contract(tmp_path, capsys):
    _, u, y, _, _ = _paper_record(3750, 15.0, seed=8)
    data = tmp_path / "run.npz"
    np.savez(data, u=u, y=y, sample_time_s=DT)
    out = tmp_path / "model.json"
    assert okid_ros_main(["identify", str(data), "--order", "100", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    keys = ("sample_time_s", "n_states", "A", "B", "C", "D", "K", "innovation_covariance",
            "hankel_singular_values", "modes")
    for key in keys:
        assert key in doc
    n = doc["n_states"]
    assert np.array(doc["A"]).shape == (n, n) and np.array(doc["K"]).shape == (n, 2)
    assert doc["sample_time_s"] == DT
    freqs = [m["frequency_rad_s"] for m in doc["modes"]]
    assert min(abs(f - 37.097) for f in freqs) < 0.4
    for mode in doc["modes"]:
        assert {"frequency_rad_s", "frequency_hz", "damping_ratio", "mpc", "msv", "emac"} <= set(mode)
        assert mode["frequency_hz"] == pytest.approx(mode["frequency_rad_s"] / (2 * np.pi))
        assert 0 <= mode["damping_ratio"] < 0.2


@pytest.mark.parametrize(
    "arrays, reason",
    [
        ({"u": np.zeros((600, 2)), "y": np.zeros((599, 2)), "sample_time_s": DT}, "length mismatch"),
        ({"u": np.zeros((600, 2)), "y": np.full((600, 2), np.nan), "sample_time_s": DT}, "NaN"),
        ({"u": np.zeros((300, 2)), "y": np.random.default_rng(0).standard_normal((300, 2)), "sample_time_s": DT},
         "503 needed"),
        ({"u": np.random.default_rng(1).standard_normal((600, 2)), "y": np.ones((600, 2)), "sample_time_s": DT},
         "output channel 0 carries no response"),
        ({"u": np.zeros((600, 2)), "y": np.ones((600, 2))}, "missing key"),
        ({"u": np.zeros((600, 2, 2)), "y": np.ones((600, 2)), "sample_time_s": DT}, "2-D"),
    ],
)
def test_identify_command_rejects_bad_input_without_traceback(tmp_path, capsys, arrays, reason):
    data = tmp_path / "bad.npz"
    np.savez(data, **arrays)
    status = okid_ros_main(["identify", str(data), "--order", "100", "--json", str(tmp_path / "o.json")])
    err = capsys.readouterr().err
    assert status == 2
    assert reason in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_identify_reads_csv(tmp_path):
    _, u, y, _, _ = _paper_record(1500, 15.0, seed=9)
    path = tmp_path / "run.csv"
    rows = "\n".join(",".join(f"{v:.10g}" for v in row) for row in np.hstack([u, y]))
    path.write_text(f"# sample_time_s=0.008\nu1,u2,y1,y2\n{rows}\n")
    out = tmp_path / "m.json"
    assert okid_ros_main(["identify", str(path), "--order", "40", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["sample_time_s"] == DT


def test_arx_order_is_chosen_by_gcv_when_not_given():
    truth, u, y, _, _ = _paper_record(3750, 15.0, seed=21)
    model = identify(u, y, DT)
    scores = model.arx_order_scores
    assert model.arx.order == min(scores, key=scores.get)
    # At least what the Hankel matrix of max_states (40) needs with 2 outputs: 2 * 20 + 1 lags.
    assert min(scores) >= 41
    assert len(scores) >= 2
    assert model.stability_problem() == ""


def test_offsets_are_removed_kept_and_reported():
    truth, u, y, _, _ = _paper_record(3750, 15.0, seed=22)
    plain = identify(u, y, DT, order=60, n_states=6)
    shifted = identify(u + [5.0, -3.0], y + [40.0, 2.0], DT, order=60, n_states=6)
    np.testing.assert_allclose(shifted.input_offset - plain.input_offset, [5.0, -3.0], atol=1e-9)
    np.testing.assert_allclose(shifted.output_offset - plain.output_offset, [40.0, 2.0], atol=1e-9)
    np.testing.assert_allclose([m.frequency_hz for m in shifted.modes], [m.frequency_hz for m in plain.modes],
                               rtol=1e-6)
    assert any("large offsets removed" in w and "input 0" in w for w in shifted.warnings)
    assert not any("offsets" in w for w in plain.warnings)
    raw = identify(u + [5.0, -3.0], y + [40.0, 2.0], DT, order=60, n_states=6, offsets="none")
    assert any("NOT removed" in w for w in raw.warnings)
    with pytest.raises(IdentificationError, match="offsets"):
        identify(u, y, DT, order=60, offsets="mean")


def test_order_search_goes_past_max_states_and_says_when_it_cannot():
    truth, u, y, _, _ = _paper_record(3750, 15.0, seed=23)
    grown = identify(u, y, DT, order=60, max_states=2)  # BIC is lowest at the cap: the search goes on
    assert grown.n_states >= 6 and not grown.max_states_reached
    capped = identify(u, y, DT, order=60, max_states=2, max_states_limit=4)
    assert capped.max_states_reached and capped.n_states == 4
    assert any("largest model order" in w for w in capped.warnings)
    assert json.loads(json.dumps(capped.to_json_dict()))["max_states_reached"] is True


def test_every_model_handed_out_has_a_stable_a_and_predictor():
    """Each benchmark system, automatic orders, both completions."""
    from okid_bench.cases import benchmark_cases
    from okid_ros.sim import simulate

    for case in benchmark_cases():
        u = case.make_input(3000, 31)
        y = simulate(case.system, u, 32)
        for completion in ("predictor", "states"):
            model = identify(u, y, case.sample_time_s, completion=completion, refine=False)
            assert model.spectral_radius() < 1.0, (case.name, completion)
            assert model.predictor_spectral_radius() < 1.0, (case.name, completion)


def test_a_record_too_short_for_the_whole_state_search_is_still_identified():
    """400 samples of one accelerometer: the order a 40-state search needs (81) does not fit.

    The chain falls back to the largest ARX order the record fits and says so; no mode it lists
    is spurious and most models hold both modes (4 s of data: BIC may keep only the stronger);
    a fixed state order the record cannot hold, or a record too short for any search, is
    refused with a one-line reason.
    """
    from okid_ros.sim import simulate
    from okid_ros.sim.models import modal_structure

    dt, truth = 0.01, (3.0, 11.0)
    both = 0
    for seed in range(12):  # "most": a majority of 12 draws (4 were too few: 3 of 4 on one machine, 2 on another)
        system = modal_structure(truth, 0.02, 1, 1, dt, seed=4 + seed)
        u = white_input(400, 1, seed=5 + seed)
        y = simulate(system, u, 6 + seed)
        model = identify(u, y, dt)
        assert model.arx.order < 81
        assert any("too few for the ARX order" in w for w in model.warnings)
        assert model.stability_problem() == ""
        listed = [md.frequency_hz for md in model.modes]
        assert listed and all(min(abs(g - f) / f for f in truth) < 0.02 for g in listed), listed
        z = np.linalg.eigvals(model.A)
        poles_hz = np.abs(np.log(z[z.imag > 0])) / (2 * np.pi * dt)
        both += all(np.min(np.abs(poles_hz - f)) / f < 0.02 for f in truth)
    assert both >= 7
    # Said as the states' bound (was: "no ARX order can be fitted ...", the order not given).
    with pytest.raises(IdentificationError, match="^60 states: needs an ARX order of at least 121 for its Hankel "
                       "matrix with 1 output; at most 39 states fit within the 400 samples of the fit"):
        identify(u, y, dt, n_states=60)
    with pytest.raises(IdentificationError, match="no ARX order can be fitted|too few"):
        identify(u[:12], y[:12], dt)


@pytest.mark.parametrize("kind, convert", [
    ("complex", lambda a: a + 1j * a),  # the imaginary part was dropped with a warning only
    ("string", lambda a: a.astype(str)),  # numeric strings were parsed
    ("object", lambda a: a.astype(object)),
])
def test_records_of_other_than_real_numbers_are_refused_by_every_path(kind, convert) -> None:
    from okid_ros.core.output_only import identify_output_only

    rng = np.random.default_rng(0)
    u, y = rng.standard_normal((1000, 1)), rng.standard_normal((1000, 2))
    runs = {"u": lambda: identify(convert(u), y, 0.01),
            "y": lambda: identify(u, convert(y), 0.01),
            "valid": lambda: identify(convert(u), y, 0.01, valid=np.ones(1000, bool)),
            "output-only": lambda: identify_output_only(convert(y), 0.01)}
    for name, run in runs.items():
        with pytest.raises(IdentificationError, match=f"must hold real numbers, got an? {kind} array"):
            run()


@pytest.mark.parametrize("sample_time_s", [1e-300, 1e308, 0.0, float("nan")])
def test_a_sample_time_outside_the_range_is_refused_by_both_paths(sample_time_s: float) -> None:
    """1e-300 s gave frequencies of 1e299 Hz and NaN standard deviations, 1e308 s frequencies of 0."""
    from okid_ros.core.output_only import identify_output_only

    rng = np.random.default_rng(0)
    u, y = rng.standard_normal((1000, 1)), rng.standard_normal((1000, 2))
    for run in (lambda: identify(u, y, sample_time_s), lambda: identify_output_only(y, sample_time_s)):
        with pytest.raises(IdentificationError, match="between 1e-06 and 3600 s"):
            run()


@pytest.mark.parametrize("arguments, reason", [
    ({"sample_time_s": "0.01"}, "sample_time_s must be a number of seconds, got '0.01'"),  # was numpy's TypeError
    ({"sample_time_s": 3600.0000001}, "between 1e-06 and 3600 s, got 3600.0000001"),  # said "got 3600"
    ({"regularization": "l1"}, "regularization must be one of"),  # was solved as "tc" in silence
    ({"order": 20.5}, "order must be an integer ARX order or 'auto', got 20.5"),  # was cut to 20
    ({"order": True}, "order must be an integer"),  # was "ARX order must be >= 2, got 1"
    ({"options": "fast"}, "options must be of type RealizationOptions, got str"),  # was an AttributeError
    ({"arx_orders": "fast"}, "arx_orders must be of type ArxOrderOptions, got str"),  # the same
    ({"ar_order": 0}, "ar_order must be a positive integer or None, got 0"),  # was the ARX order, in silence
    ({"ar_order": 5.5}, "ar_order must be a positive integer or None, got 5.5"),  # was a TypeError
    ({"hankel_rows": 0}, "hankel_rows must be a positive integer or None, got 0"),  # was the default, in silence
    ({"refine": "no"}, "refine must be True or False, got 'no'"),  # was taken for True
])
def test_arguments_of_the_wrong_kind_are_refused_with_their_name(arguments, reason) -> None:
    """The Python API as users call it: one IdentificationError naming the argument, before any work."""
    from okid_ros.core.output_only import identify_output_only

    rng = np.random.default_rng(0)
    u, y = rng.standard_normal((1000, 1)), rng.standard_normal((1000, 2))
    kwargs = {"sample_time_s": 0.01, "order": 10, **arguments}
    with pytest.raises(IdentificationError, match=re.escape(reason)):
        identify(u, y, **kwargs)
    if "sample_time_s" in arguments:
        with pytest.raises(IdentificationError, match=re.escape(reason)):
            identify_output_only(y, arguments["sample_time_s"])


def test_a_record_with_dropped_samples_is_identified_whole_with_them_filled():
    """1 % of the samples lost at random: the whole record, the lost samples filled.

    The longest run without a loss is a few hundred samples; the ARX fit leaves out the rows that
    reach a lost sample, the realization runs with them filled by the ARX prediction.
    """
    errors = []
    for seed in range(3):
        truth, u, y, u_val, y_val = _paper_record(3750, 15.0, seed)
        lost = np.random.default_rng(seed).random(3750) < 0.01
        lost[[0, -1]] = False
        y_lost = y.copy()
        y_lost[lost, seed % 2] = np.nan
        model = identify(u, y_lost, DT, order=100, valid=~lost)
        assert not model.stability_problem()
        assert _ratio(model, truth, u_val, y_val) < 1.10
        errors.append([100 * (_closest(model.modes, f).frequency_rad_s / f - 1) for f, _ in PAPER_MODES]
                      + [100 * (_closest(model.modes, f).damping_ratio - z) for f, z in PAPER_MODES])
    rms = np.sqrt(np.mean(np.square(errors), axis=0))
    assert rms[0] < 0.5 and rms[1] < 1.2 and rms[2] < 0.3 and rms[3] < 1.0  # as the whole records
    # Nothing missing: the same model as without the mask.
    plain = identify(u, y, DT, order=100, n_states=6)
    masked = identify(u, y, DT, order=100, n_states=6, valid=np.ones(3750, dtype=bool))
    np.testing.assert_array_equal(masked.A, plain.A)


def test_dropped_samples_beyond_what_can_be_filled_are_one_line_reasons():
    _, u, y, _, _ = _paper_record(3000, 15.0, 0)
    valid = np.ones(3000, dtype=bool)
    valid[1000:1020] = False
    with pytest.raises(IdentificationError, match="20 samples are missing in a row before sample 1020"):
        identify(u, y, DT, order=40, valid=valid)
    valid[1000:1020], valid[::5] = True, False
    valid[[0, -1]] = True
    with pytest.raises(IdentificationError, match="599 of the 3000 samples are missing; at most 10% are filled"):
        identify(u, y, DT, order=40, valid=valid)
    with pytest.raises(IdentificationError, match="the paper's method needs contiguous samples"):
        identify(u, y, DT, order=40, method="paper", valid=valid)
    with pytest.raises(IdentificationError, match="one flag per sample"):
        identify(u, y, DT, order=40, valid=valid[:10])


def test_an_era_hankel_larger_than_the_arx_model_is_refused_with_its_reason():
    # Was a ValueError from the Gram of past data (the API's options are not checked against
    # the ARX model they are used with).
    from okid_ros.core.options import RealizationOptions
    from okid_ros.core.pipeline import identify_from_arx

    truth = paper_model()
    u = lowpass_input(3000, 2, 15.0, truth.sample_time_s, seed=1)
    y, _ = simulate_innovation(truth, u, seed=2)
    arx = identify(u, y, truth.sample_time_s, order=40).arx
    with pytest.raises(IdentificationError, match="needs an ARX order of at least 60"):
        identify_from_arx(arx, u, y, truth.sample_time_s, options=RealizationOptions(hankel_rows=30, hankel_cols=30))
    model = identify_from_arx(arx, u, y, truth.sample_time_s,
                              options=RealizationOptions(hankel_rows=20, hankel_cols=20))
    assert model.stability_problem() == ""


def test_a_few_outputs_over_a_long_record_are_refined():
    """6 outputs, 14 states, 8000 samples: the refinement runs (its cost bound counts what it computes).

    The bound counted the tall Jacobian's N p P^2 flops (2.4e9 here, above it), which the
    refinement no longer forms; refined, the held-out prediction and the modes of this case
    are closer to the truth (docs/benchmarks-realization.md).
    """
    from identification_accuracy import simulate_record

    from okid_bench.cases import benchmark_case
    from okid_ros.core.pipeline import MAX_REFINE_FLOPS_PER_ITERATION
    from okid_ros.core.refine import refinement_flops, refinement_size

    case = benchmark_case("more-outputs")
    u, y, _, _ = simulate_record(case, 8000, 0, 10)
    # The order fixed: BIC's choice moves with the machine's rounding (12 states on one), and the
    # old bound's count needs 14 to exceed its limit.
    model = identify(u.copy(), y.copy(), case.sample_time_s, n_states=14)
    n_par = refinement_size(model.n_states, 6, 2)
    assert y.size * n_par**2 > MAX_REFINE_FLOPS_PER_ITERATION >= refinement_flops(model.n_states, 6, 2, 8000)
    assert model.refined and model.stability_problem() == ""


def test_the_mode_criteria_are_given_whole_or_by_name():
    """``identify(..., modes=ModeCriteria(...))`` was refused ("multiple values for 'modes'")."""
    from okid_ros.core.options import ModeCriteria, RealizationOptions

    whole = RealizationOptions().with_changes(modes=ModeCriteria(min_mpc=0.1))
    assert whole.modes.min_mpc == 0.1 and whole.modes.min_dominance == ModeCriteria().min_dominance
    both = RealizationOptions().with_changes(modes=ModeCriteria(min_mpc=0.1), min_dominance=0.3, refine=False)
    assert (both.modes.min_mpc, both.modes.min_dominance, both.refine) == (0.1, 0.3, False)
    by_name = RealizationOptions().with_changes(min_mpc=0.2)
    assert by_name.modes.min_mpc == 0.2
