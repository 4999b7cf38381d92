"""Standard deviations of the modes.

Calibration on a few seeds, the eigenvalue derivatives, the
bounded cost for many outputs, and the fields in Mode, its message and the JSON outputs.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import linalg

from okid_bench.cases import benchmark_case
from okid_bench.scoring import modes_of
from okid_ros.core import uncertainty as unc
from okid_ros.core.modal import Mode
from okid_ros.core.pipeline import identify
from okid_ros.core.uncertainty import attach_mode_uncertainty
from okid_ros.sim.simulators import simulate


def test_std_fields_default_to_nan_and_are_null_in_as_dict():
    mode = Mode(1.0, 1 / (2 * np.pi), 0.01, 0.99 + 0.01j, np.ones(2, complex), 1.0, 1.0, 1.0, True, True)
    assert math.isnan(mode.frequency_hz_std) and math.isnan(mode.damping_ratio_std)
    assert mode.as_dict()["frequency_hz_std"] is None and mode.as_dict()["damping_ratio_std"] is None
    mode.frequency_hz_std, mode.damping_ratio_std = 0.01, 0.002
    assert mode.as_dict()["frequency_hz_std"] == 0.01 and mode.as_dict()["damping_ratio_std"] == 0.002


def test_the_standard_deviations_cover_the_true_modes_on_a_few_seeds():
    """The standard deviations are calibrated on the paper model.

    15 Hz low-pass input, 3750 samples: z = (estimate - truth) / std over 8
    records and 3 modes (48 values per quantity) behaves like a standard normal variable.
    """
    case = benchmark_case("paper-lp15")
    truth = modes_of(case.system.A, case.sample_time_s)
    z_f, z_d = [], []
    for seed in range(8):
        u = case.make_input(3750, seed)
        y = simulate(case.system, u, seed=10_000 + seed)
        model = identify(u, y, case.sample_time_s, order=case.arx_order)
        assert attach_mode_uncertainty(model, u, y).computed
        for true in truth:
            mode = min(model.modes, key=lambda md: abs(md.frequency_hz - true.frequency_hz))
            assert abs(mode.frequency_hz / true.frequency_hz - 1) < 0.05
            assert 0 < mode.frequency_hz_std < 0.01 * true.frequency_hz
            z_f.append((mode.frequency_hz - true.frequency_hz) / mode.frequency_hz_std)
            z_d.append((mode.damping_ratio - true.damping_ratio) / mode.damping_ratio_std)
    for z in (np.array(z_f), np.array(z_d)):
        assert np.mean(np.abs(z) <= 2) >= 0.85, z
        assert 0.6 < np.sqrt(np.mean(z**2)) < 1.5, z  # neither too small nor too large


def _random_predictor(rng, n_pairs: int, n_real: int, p: int, m: int):
    lam = np.concatenate([0.95 * np.exp(1j * rng.uniform(0.2, 2.5, n_pairs)), rng.uniform(-0.5, 0.8, n_real)])
    g = rng.normal(size=(n_pairs + n_real, p + m)) + 1j * rng.normal(size=(n_pairs + n_real, p + m))
    c = rng.normal(size=(p, n_pairs + n_real)) + 1j * rng.normal(size=(p, n_pairs + n_real))
    g[n_pairs:], c[:, n_pairs:], lam[n_pairs:] = g[n_pairs:].real, c[:, n_pairs:].real, lam[n_pairs:].real
    return lam, g, c


def _A_c(lam, g, c, n_pairs, p):
    lam_c = np.concatenate([lam[:n_pairs], np.conj(lam[:n_pairs]), lam[n_pairs:]])
    L_c = np.vstack([g[:n_pairs, :p], np.conj(g[:n_pairs, :p]), g[n_pairs:, :p]])
    C_c = np.hstack([c[:, :n_pairs], np.conj(c[:, :n_pairs]), c[:, n_pairs:]])
    return np.diag(lam_c) + L_c @ C_c, L_c, C_c


def test_eigenvalue_gradient_matches_finite_differences():
    rng = np.random.default_rng(0)
    n_pairs, n_real, p, m = 2, 1, 3, 2
    lam, g, c = _random_predictor(rng, n_pairs, n_real, p, m)
    refs = [int(np.argmax(np.abs(c[:, i]))) for i in range(n_pairs + n_real)]
    layout = unc._Layout(refs[:n_pairs], refs[n_pairs:], p, m)
    A_c, L_c, C_c = _A_c(lam, g, c, n_pairs, p)
    mu, R = linalg.eig(A_c)
    Lf = linalg.inv(R)
    j = int(np.argmax(mu.imag))
    grad = unc._eigenvalue_gradient(Lf[j], R[:, j], C_c, L_c, n_pairs, layout)

    def perturbed(col: int, h: float) -> complex:
        lam2, g2, c2 = lam.copy(), g.copy(), c.copy()
        for i, cols in enumerate(layout.pairs):
            if col in (cols["lam"], cols["lam"] + 1):
                lam2[i] += h if col == cols["lam"] else 1j * h
            for key, unit in (("g_re", 1), ("g_im", 1j)):
                if cols[key] <= col < cols[key] + layout.w:
                    g2[i, col - cols[key]] += unit * h
            for key, unit in (("c_re", 1), ("c_im", 1j)):
                if cols[key] <= col < cols[key] + cols["keep"].size:
                    c2[cols["keep"][col - cols[key]], i] += unit * h
        for r, cols in enumerate(layout.reals):
            i = n_pairs + r
            if col == cols["lam"]:
                lam2[i] += h
            if cols["g"] <= col < cols["g"] + layout.w:
                g2[i, col - cols["g"]] += h
            if cols["c"] <= col < cols["c"] + cols["keep"].size:
                c2[cols["keep"][col - cols["c"]], i] += h
        eig = linalg.eigvals(_A_c(lam2, g2, c2, n_pairs, p)[0])
        return eig[np.argmin(np.abs(eig - mu[j]))]

    h = 1e-6
    numeric = np.array([(perturbed(col, h) - perturbed(col, -h)) / (2 * h) for col in range(layout.size)])
    np.testing.assert_allclose(grad, numeric, atol=1e-6 * np.abs(numeric).max())
    assert np.abs(numeric).max() > 0.1


def test_many_outputs_degrade_quickly_with_a_reason():
    """28 outputs and 40 states: thousands of parameters; NaN and a reason, without the work."""
    import time

    rng = np.random.default_rng(1)
    n, p, m, N = 40, 28, 2, 6000
    z = 0.97 * np.exp(1j * np.linspace(0.1, 2.8, n // 2))
    A = linalg.block_diag(*[[[zi.real, zi.imag], [-zi.imag, zi.real]] for zi in z])
    modes = [SimpleNamespace(eigenvalue=complex(zi)) for zi in z]
    model = SimpleNamespace(A=A, B=rng.normal(size=(n, m)), C=rng.normal(size=(p, n)), D=np.zeros((p, m)),
                            K=np.zeros((n, p)), sample_time_s=0.01, modes=modes)
    started = time.perf_counter()
    result = attach_mode_uncertainty(model, rng.normal(size=(N, m)), rng.normal(size=(N, p)))
    assert time.perf_counter() - started < 5.0
    assert not result.computed and "not computed" in result.reason and result.n_parameters > 2000
    assert all(math.isnan(md.frequency_hz_std) and math.isnan(md.damping_ratio_std) for md in modes)


def test_the_parameter_count_and_the_cost_check_need_no_eigendecomposition():
    """``n (2 p + m) + p m`` whatever the poles (pairs and real ones); the check says what attach does."""
    for pairs, reals, p, m in ((3, 0, 2, 2), (2, 3, 5, 1), (0, 4, 28, 2), (6, 1, 1, 0)):
        layout = unc._Layout([0] * pairs, [0] * reals, p, m)
        assert layout.size == unc.n_parameters(2 * pairs + reals, p, m)
    case = benchmark_case("paper-lp15")
    u = case.make_input(3750, 3)
    y = simulate(case.system, u, seed=3)
    model = identify(u, y, case.sample_time_s, order=case.arx_order)
    n, (p, m) = model.A.shape[0], model.D.shape
    for budget in (unc.DEFAULT_MAX_FLOPS, 1e5):
        problem = unc.uncertainty_problem(n, p, m, y.shape[0], burn_in=case.arx_order, max_flops=budget)
        result = attach_mode_uncertainty(model, u, y, burn_in=case.arx_order, max_flops=budget)
        assert result.computed == (problem == "") and result.reason == problem
    assert problem.startswith("not computed")


def test_subsampled_rows_give_about_the_same_standard_deviations():
    case = benchmark_case("paper-lp15")
    u = case.make_input(3750, 3)
    y = simulate(case.system, u, seed=3)
    model = identify(u, y, case.sample_time_s, order=case.arx_order)
    full = attach_mode_uncertainty(model, u, y)
    f_full = [md.frequency_hz_std for md in model.modes]
    d_full = [md.damping_ratio_std for md in model.modes]
    small = attach_mode_uncertainty(model, u, y, max_flops=2.0 * 2 * full.n_parameters**2 * 1000)
    assert full.computed and small.computed and small.rows_used < full.rows_used / 3
    np.testing.assert_allclose([md.frequency_hz_std for md in model.modes], f_full, rtol=0.35)
    np.testing.assert_allclose([md.damping_ratio_std for md in model.modes], d_full, rtol=0.35)


def test_mode_message_and_conversions_carry_the_standard_deviations():
    from okid_ros.nodes.conversions import MessageTypes, mode_from_msg, mode_msg
    from okid_ros.tools.bagio import okid_typestore

    mode = Mode(1.0, 1 / (2 * np.pi), 0.01, 0.99 + 0.01j, np.ones(2, complex), 1.0, 1.0, 1.0, True, True)
    mode.frequency_hz_std, mode.damping_ratio_std = 0.25, 0.003
    msg = mode_msg(mode, MessageTypes.from_typestore(okid_typestore()))
    back = mode_from_msg(msg)
    assert back["frequency_hz_std"] == 0.25 and back["damping_ratio_std"] == 0.003
    assert math.isnan(mode_from_msg(mode_msg(Mode(1.0, 0.2, 0.01, 0.9j, np.ones(2, complex), 1, 1, 1, True, True),
                                             MessageTypes.from_typestore(okid_typestore())))["frequency_hz_std"])


def test_process_json_lines_have_the_standard_deviations():
    from okid_ros.tools.process import mode_summary

    mode = Mode(1.0, 0.2, 0.01, 0.9j, np.ones(2, complex), 1, 1, 1, True, True)
    assert mode_summary(mode)["frequency_hz_std"] is None
    mode.frequency_hz_std, mode.damping_ratio_std = 0.5, 0.001
    assert mode_summary(mode)["frequency_hz_std"] == 0.5 and mode_summary(mode)["damping_ratio_std"] == 0.001


@pytest.mark.parametrize("n_samples", [400])
def test_a_record_that_does_not_fit_the_model_is_refused_with_nan(n_samples):
    case = benchmark_case("paper-lp15")
    u = case.make_input(3750, 1)
    y = simulate(case.system, u, seed=1)
    model = identify(u, y, case.sample_time_s, order=case.arx_order)
    result = attach_mode_uncertainty(model, u[:n_samples, :1], y[:n_samples])
    assert not result.computed and "does not fit" in result.reason
    assert all(math.isnan(md.frequency_hz_std) for md in model.modes)


def test_a_noisy_pole_is_judged_against_its_width_or_the_record_resolution():
    """Noisy: frequency std above NOISY_STD_PER_WIDTH half-widths, the width at least 1 / T."""

    def mode(frequency_hz, damping_ratio, frequency_hz_std, eigenvalue):
        m = Mode(2 * np.pi * frequency_hz, frequency_hz, damping_ratio, eigenvalue, np.ones(2, complex),
                 1.0, 1.0, 1.0, True, True)
        m.frequency_hz_std = frequency_hz_std
        return m

    k = unc.NOISY_STD_PER_WIDTH
    broad = mode(40.0, 0.03, 1.01 * k * 1.2, 0.5 + 0.5j)  # width 1.2 Hz, std just above k widths
    sharp = mode(40.0, 0.03, 0.99 * k * 1.2, 0.6 + 0.5j)  # just below
    light = mode(5.9, 0.0015, 3 * k * 0.00885, 0.9 + 0.1j)  # 3 k widths, but under k / T for T = 30 s
    unknown = mode(10.0, 0.01, float("nan"), 0.7 + 0.5j)
    assert unc.noisy_poles([broad, sharp, light, unknown], 30.0) == [broad.eigenvalue]
    assert unc.noisy_poles([light], 300.0) == [light.eigenvalue]  # a long record resolves its width


def test_noise_poles_of_a_many_output_record_are_not_listed():
    """The many-outputs case, seed 2 at 3750 samples, identify's defaults: no spurious mode.

    The model holds three poles at 27.4, 39.9 and 46.0 Hz (no true mode above 16.5 Hz) that pass
    the stabilization, MPC and dominance criteria; their frequency std is 2.6-5.7 half-power
    half-widths (the true modes' at most 0.63): they were listed before the noise-pole rule.
    """
    from okid_bench.scoring import assign_by_frequency

    case = benchmark_case("more-outputs")
    base = 1000 * (2 + 1)  # bench/identification_accuracy.py's seed 2
    u = case.make_input(3750, base + 1)
    y = simulate(case.system, u, base + 2)
    model = identify(u, y, case.sample_time_s)
    truth = [mode.frequency_hz for mode in modes_of(case.system.A, case.sample_time_s)]
    listed = [mode.frequency_hz for mode in model.modes]
    pairs = assign_by_frequency(listed, truth, 0.02)
    assert None not in pairs and len(listed) == len(truth), (listed, truth)


def test_an_output_only_model_gets_calibrated_standard_deviations():
    """No inputs (m = 0, ``u`` with no columns): the prediction-error optimum's scatter is what the stds say.

    The one-channel output-only case (3 modes at 1 % damping, white forces, 6000 samples): from
    the true Kalman predictor, the refinement's optimum on each of 8 records, its modes against
    the truth in units of the standard deviations computed at that optimum.
    """
    from okid_bench.output_only_cases import output_only_case
    from okid_ros.core.refine import refine_prediction_error
    from okid_ros.core.statespace import InnovationModel

    case = output_only_case("one-channel")
    inner = case.system.to_innovation_form()
    n, p = inner.A.shape[0], inner.C.shape[0]
    truth = InnovationModel(inner.A, np.zeros((n, 0)), inner.C, np.zeros((p, 0)), inner.K,
                            inner.innovation_covariance, inner.sample_time_s)
    true_modes = modes_of(truth.A, case.sample_time_s)
    z_f, z_d = [], []
    for seed in range(8):
        y = case.simulate(seed)
        y = y - y.mean(axis=0)
        u = np.zeros((y.shape[0], 0))
        fit = refine_prediction_error(truth, u, y, burn_in=200, max_evaluations=100)
        assert fit is not None
        estimate = modes_of(fit.model.A, case.sample_time_s)
        modes = [SimpleNamespace(eigenvalue=min(estimate, key=lambda e: abs(e.z - t.z)).z,
                                 frequency_hz_std=np.nan, damping_ratio_std=np.nan) for t in true_modes]
        carrier = SimpleNamespace(A=fit.model.A, B=fit.model.B, C=fit.model.C, D=fit.model.D, K=fit.model.K,
                                  sample_time_s=case.sample_time_s, modes=modes)
        assert attach_mode_uncertainty(carrier, u, y, burn_in=200).computed
        for true, mode in zip(true_modes, modes):
            found = min(estimate, key=lambda e: abs(e.z - mode.eigenvalue))
            z_f.append((found.frequency_hz - true.frequency_hz) / mode.frequency_hz_std)
            z_d.append((found.damping_ratio - true.damping_ratio) / mode.damping_ratio_std)
    for z in (np.array(z_f), np.array(z_d)):
        assert np.all(np.isfinite(z)), z
        assert np.mean(np.abs(z) <= 2) >= 0.85, z
        assert 0.6 < np.sqrt(np.mean(z**2)) < 1.5, z
    # An output-only model with an input column offered is refused, not read wrongly.
    carrier.modes = [SimpleNamespace(eigenvalue=true_modes[0].z, frequency_hz_std=0.0, damping_ratio_std=0.0)]
    result = attach_mode_uncertainty(carrier, np.zeros((y.shape[0], 1)), y)
    assert not result.computed and math.isnan(carrier.modes[0].frequency_hz_std)
