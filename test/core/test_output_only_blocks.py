"""A listed mode dropped after the modal form: every other listed mode keeps its own state block.

ssi-cva drops a listed mode whose jackknife scatter is beyond the limits after the model was put in
modal form (:func:`okid_ros.core.output_only_support.listed_within_limits`); the modes after it were
then read from their neighbours' blocks (shapes, modal coordinates).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import linalg

from okid_ros.core import output_only
from okid_ros.core.estimator import ModalStateEstimator
from okid_ros.core.identified_model import IdentifiedModel
from okid_ros.core.modal import modal_form
from okid_ros.core.options import ModeCriteria
from okid_ros.core.output_only import identify_output_only
from okid_ros.core.output_only_support import listed_within_limits
from okid_ros.sim.models import modal_structure
from okid_ros.sim.simulators import simulate_noisy


def _record() -> np.ndarray:
    """(4000, 4) ambient response of 3, 7 and 12 Hz modes at 1 %, 50 Hz sampling."""
    system = modal_structure([3.0, 7.0, 12.0], 0.01, 1, 4, 0.02, seed=1)
    return simulate_noisy(system, np.zeros((4000, 1)), seed=5)


def _upper(A: np.ndarray, first: int) -> complex:
    """The upper-half-plane eigenvalue of the 2x2 diagonal block of ``A`` at state ``first`` (NaN: no pair)."""
    eigenvalues = np.linalg.eigvals(A[first:first + 2, first:first + 2])
    return complex(eigenvalues[np.argmax(eigenvalues.imag)]) if eigenvalues.imag.max() > 0 else complex(np.nan)


def _block_of(A: np.ndarray, eigenvalue: complex) -> int:
    """The first state of the 2x2 diagonal block of ``A`` whose upper eigenvalue is ``eigenvalue``."""
    gaps = [abs(_upper(A, i) - eigenvalue) for i in range(A.shape[0] - 1)]
    return int(np.nanargmin(gaps))


@pytest.fixture(scope="module")
def dropped_first():
    """The record's model with its slowest listed mode dropped by the listed-std screening."""
    y = _record()
    full = identify_output_only(y, 0.02, low_band=False)
    assert len(full.modes) == 3, "the record no longer lists its three modes: the test tests nothing"
    slowest = min(m.frequency_hz for m in full.modes)
    patch = pytest.MonkeyPatch()
    patch.setattr(output_only, "listed_within_limits", lambda modes, scattered: listed_within_limits(
        modes, lambda fs, zs, f, z: f == slowest or scattered(fs, zs, f, z)))
    try:
        model = identify_output_only(y, 0.02, low_band=False)
    finally:
        patch.undo()
    return y, full, model


def test_each_listed_mode_is_its_own_block_after_one_before_it_is_dropped(dropped_first) -> None:
    _, full, model = dropped_first
    assert [m.frequency_hz for m in model.modes] == [m.frequency_hz for m in full.modes[1:]]
    assert [m.id for m in model.modes] == [0, 1]
    for i, mode in enumerate(model.modes):
        assert abs(_upper(model.A, 2 * i) - mode.eigenvalue) < 1e-9, f"mode {i} listed with another pole's block"
        shape = model.C[:, 2 * i] + 1j * model.C[:, 2 * i + 1]
        np.testing.assert_allclose(shape, mode.shape, atol=1e-9)
    # The dropped mode's block stays in the model (the same A), after the listed ones.
    np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(model.A)), np.sort_complex(np.linalg.eigvals(full.A)),
                               rtol=1e-9, atol=1e-12)
    assert _block_of(model.A, full.modes[0].eigenvalue) >= model.n_physical_states


def test_modal_coordinates_of_a_listed_mode_are_its_blocks_states(dropped_first) -> None:
    y, _, model = dropped_first
    estimator = ModalStateEstimator.from_model(model, reject_glitches=False)
    states = np.array([estimator.step(np.zeros(0), sample)[0] for sample in y[:400]])
    coordinates = estimator.modal_coordinates(states)
    assert coordinates.shape == (400, len(model.modes), 2)
    for i, mode in enumerate(model.modes):
        block = _block_of(model.A, mode.eigenvalue)
        np.testing.assert_array_equal(coordinates[:, i], states[:, block:block + 2])


def test_the_estimator_runs_an_output_only_models_record_as_sample_by_sample(dropped_first) -> None:
    y, _, model = dropped_first
    stepped = ModalStateEstimator.from_model(model, reject_glitches=False)
    states = np.array([stepped.step(np.zeros(0), sample)[0] for sample in y[:200]])
    out = ModalStateEstimator.from_model(model, reject_glitches=False).run(np.zeros((200, 0)), y[:200])
    np.testing.assert_array_equal(out.states, states)
    np.testing.assert_array_equal(out.modal_coordinates, stepped.modal_coordinates(states))


def test_keep_modes_moves_a_dropped_modes_block_behind_the_listed_ones_and_keeps_the_response() -> None:
    rng = np.random.default_rng(0)
    poles = 0.99 * np.exp(1j * np.array([0.3, 0.9, 1.7]))
    A = linalg.block_diag(*[[[z.real, z.imag], [-z.imag, z.real]] for z in poles], [[0.5]])
    C, K = rng.standard_normal((3, 7)), rng.standard_normal((7, 3))
    criteria = ModeCriteria(max_damping=0.1, min_msv=0.0, min_mpc=0.0, min_dominance=0.0)
    form = modal_form(A, K, C, K, 0.01, criteria=criteria)  # the noise input stands for B, as in output_only
    model = IdentifiedModel(A=form.A, B=np.zeros((7, 0)), C=form.C, D=np.zeros((3, 0)), K=form.K,
                            innovation_covariance=np.eye(3), sample_time_s=0.01, modes=form.modes,
                            x0=rng.standard_normal(7))
    markov, response = [model.C @ np.linalg.matrix_power(model.A, k) @ model.K for k in range(4)], model.C @ model.x0
    first, _, last = model.modes
    model.keep_modes([first, last])
    assert [m.id for m in model.modes] == [0, 1] and model.n_physical_states == 4
    for i, mode in enumerate(model.modes):
        assert abs(_upper(model.A, 2 * i) - mode.eigenvalue) < 1e-12
    assert abs(_upper(model.A, 4) - poles[1]) < 1e-12
    np.testing.assert_allclose([model.C @ np.linalg.matrix_power(model.A, k) @ model.K for k in range(4)], markov,
                               rtol=0, atol=1e-12)
    np.testing.assert_allclose(model.C @ model.x0, response, rtol=0, atol=1e-12)
