"""The identified state estimator, run on filterpy's KalmanFilter, returning modal states.

The identified innovation model (paper Eqs. 30-31)

    x_{k+1} = A x_k + B u_k + A K e_k,        y_k = C x_k + D u_k + e_k,

is run as a Kalman filter with ``F = A``, ``B``, ``H = C`` and the gain ``K``:

    e_k      = y_k - C xhat_k - D u_k               (innovation)
    xpost_k  = xhat_k + K e_k                        (update_steadystate on y_k - D u_k)
    xhat_k+1 = A xpost_k + B u_k                     (predict_steadystate)

(the two steady-state steps are written out on the filter's arrays with filterpy's operations,
without the copies of z and P its methods make at every sample)

which is ``xhat_{k+1} = A xhat_k + B u_k + A K e_k``. The published modal state is the filtered
``xpost_k`` in the normalized modal form (two coordinates per physical mode); the estimated
output is ``C xpost_k + D u_k``.

Start-up (optional): from an uncertain initial state ``P_0`` the optimal gain is time varying.
In this model the process noise ``A K e_k`` and the measurement noise ``e_k`` are the same
white sequence, so with ``S_k = C P_k C^T + Re``

    K_k     = (P_k C^T + K Re) S_k^{-1}
    P_{k+1} = A (P_k + K Re K^T - K_k S_k K_k^T) A^T,

which tends to ``K_k -> K`` and ``P_k -> 0``. The gain is handed to the KalmanFilter each step.

Glitches (:mod:`okid_ros.core.glitches`, the change test's rule): in a sample whose innovation
is a glitch candidate the outputs beyond ``QUIET_STD`` are replaced by their prediction: the
published state is ``xhat_k + K e'_k`` (``e'_k``: ``e_k`` with those outputs' innovations 0) and
the filter goes on from ``A (xhat_k + K e'_k) + B u_k``. The next sample judges it: if that
sample's innovation is settled, the glitch stays out (:attr:`glitches` counts it); else it was
an event (an impact, a jump) and the filter takes the state it would have had,
``A xpost_k + B u_k``, before that sample, so from there on it is the filter without the rule,
exactly. No sample waits: only a candidate found to be no glitch was published without its far
outputs. (Its other outputs taken, rather than the whole sample's prediction as the change test
does: the glitch's own sample loses less, and the next sample is settled more often; see
docs/benchmarks-change.md.) ``P_k`` and ``K_k`` do not depend on the outputs: the start-up
filter is unchanged (the rule measures its innovations by ``S_k``). The innovations returned
are the samples' own (a glitch's is its full size).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from filterpy.kalman import KalmanFilter
from numpy import dot

from okid_ros.core.glitches import GLITCH_STD, QUIET_STD, glitch_candidates, settled
from okid_ros.core.statespace import InnovationModel

__all__ = ["EstimatorOutput", "ModalStateEstimator"]


@dataclass
class EstimatorOutput:
    """Estimator results for a block of N samples.

    Attributes
    ----------
    modal_coordinates : (N, n_modes, 2) filtered modal states of the physical modes.
    states : (N, n) all filtered states.
    y_estimated : (N, p) ``C xpost + D u``.
    innovations : (N, p) ``y - C xhat - D u`` (one-step prediction errors).
    """

    modal_coordinates: np.ndarray
    states: np.ndarray
    y_estimated: np.ndarray
    innovations: np.ndarray


class ModalStateEstimator:
    """Steady-state (or start-up time-varying) estimator of an identified modal model.

    Parameters
    ----------
    model : the innovation model in normalized modal form (paper convention for K).
    n_physical_states : the first states that belong to physical modes (2 per mode).
    initial_covariance : (n, n) or scalar ``P_0`` of the start-up filter; ``None`` runs the
        steady-state filter from the first sample.
    input_offset, output_offset : (m,), (p,) means removed from the signals before the model
        applies (``u - input_offset``, ``y - output_offset``); the estimated output has the
        output offset added back. None: no offsets.
    reject_glitches : leave glitches out (see the module docstring); False: every sample taken.

    Attributes
    ----------
    glitches : samples left out as glitches, over the estimator's life.
    """

    def __init__(
        self,
        model: InnovationModel,
        *,
        n_physical_states: int,
        initial_covariance: np.ndarray | float | None = None,
        input_offset: np.ndarray | None = None,
        output_offset: np.ndarray | None = None,
        reject_glitches: bool = True,
    ) -> None:
        n, m, p = model.n_states, model.n_inputs, model.n_outputs
        if n_physical_states % 2 or not 0 <= n_physical_states <= n:
            raise ValueError(f"n_physical_states must be even and <= {n}, got {n_physical_states}")
        self.n_states, self.n_inputs, self.n_outputs = n, m, p
        self.n_physical_states = n_physical_states
        self.D = model.D
        self.K_steady = model.K
        self.innovation_covariance = model.innovation_covariance
        self.input_offset = np.zeros(m) if input_offset is None else np.asarray(input_offset, float).reshape(m)
        self.output_offset = np.zeros(p) if output_offset is None else np.asarray(output_offset, float).reshape(p)
        kf = KalmanFilter(dim_x=n, dim_z=p, dim_u=m)
        kf.F = model.A
        kf.B = model.B
        kf.H = model.C
        kf.K = self.K_steady.copy()
        kf.R = self.innovation_covariance.copy()
        kf.x = np.zeros((n, 1))
        self.kf = kf
        self._set_innovation_std(self.innovation_covariance)
        # One output: a glitch and an unmeasured impact look alike (glitch_candidates finds none).
        self._gate = bool(reject_glitches) and p >= 2 and bool(np.all(np.isfinite(self._inverse_variance)))
        self._held: np.ndarray | None = None  # (n, 1) the next prediction had a held candidate been taken
        self._held_outputs: tuple[np.ndarray, np.ndarray] | None = None  # its far outputs, their predictions
        self.glitches = 0
        # The last glitch left out, (far outputs (p,) bool, their predictions (p,)), set when the next
        # sample settles it, for the caller to take (and set to None): node 2's buffer keeps the prediction.
        self.last_glitch: tuple[np.ndarray, np.ndarray] | None = None
        self._start_up = initial_covariance is not None
        if self._start_up:
            P0 = np.asarray(initial_covariance, dtype=float)
            kf.P = P0 * np.eye(n) if P0.ndim == 0 else P0.copy()
        else:
            kf.P = np.zeros((n, n))

    @classmethod
    def from_model(cls, model, initial_covariance: np.ndarray | float | None = None, *,
                   reject_glitches: bool = True) -> "ModalStateEstimator":
        """Build from an ``IdentifiedModel`` (its physical states and offsets)."""
        return cls(
            model,
            n_physical_states=model.n_physical_states,
            initial_covariance=initial_covariance,
            input_offset=getattr(model, "input_offset", None),
            output_offset=getattr(model, "output_offset", None),
            reject_glitches=reject_glitches,
        )

    def _set_innovation_std(self, covariance: np.ndarray) -> None:
        """The innovations' standard deviations (p,) the glitch rule measures by, from their covariance (p, p)."""
        self._innovation_std = np.sqrt(np.diag(covariance))
        with np.errstate(divide="ignore"):
            self._inverse_variance = 1.0 / self._innovation_std ** 2

    @property
    def state(self) -> np.ndarray:
        """(n,) the current one-step prediction ``xhat_k``.

        While a glitch candidate waits for the next sample's verdict: the prediction had it been
        taken, which is what holds when no next sample judges it (the caller bridges a gap,
        restarts or corrects the state by :meth:`set_state`), as the change test runs it.
        """
        return (self.kf.x if self._held is None else self._held)[:, 0].copy()

    @property
    def holding(self) -> bool:
        """The last sample stepped was a glitch candidate, its far outputs not taken (the next one judges it)."""
        return self._held is not None

    def set_state(self, x: np.ndarray) -> None:
        """Set the predicted state ``xhat_k`` (n,), e.g. after a warm start (a candidate's verdict is dropped)."""
        self._held = None
        self.kf.x = np.asarray(x, dtype=float).reshape(self.n_states, 1).copy()

    def _start_up_gain(self) -> None:
        """Time-varying gain K_k from P_k (see module docstring); switches off once converged."""
        kf, Re, K = self.kf, self.innovation_covariance, self.K_steady
        P, C = kf.P, kf.H
        S = C @ P @ C.T + Re
        gain = np.linalg.solve(S.T, (P @ C.T + K @ Re).T).T
        kf.K = gain
        kf.P = kf.F @ (P + K @ Re @ K.T - gain @ S @ gain.T) @ kf.F.T
        kf.P = 0.5 * (kf.P + kf.P.T)
        self._set_innovation_std(S)  # the rule measures this sample's innovation by its covariance S_k
        if np.abs(gain - K).max() <= 1e-9 * max(np.abs(K).max(), 1e-300):
            kf.K = K.copy()
            self._start_up = False
            self._set_innovation_std(Re)

    def step(self, u: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Process one sample: returns (filtered state (n,), estimated output (p,), innovation (p,)).

        A glitch candidate's filtered state is without its far outputs (see the module docstring).
        """
        u = np.asarray(u, dtype=float).reshape(self.n_inputs) - self.input_offset
        y = np.asarray(y, dtype=float).reshape(self.n_outputs) - self.output_offset
        if self._start_up:
            self._start_up_gain()
        kf = self.kf
        # ndarray.dot: numpy.dot's product (bit for bit) without its function dispatch, @ without the ufunc's.
        du = self.D.dot(u)
        # KalmanFilter.update_steadystate and predict_steadystate, written out with the same
        # operations on the filter's arrays: the methods also copy z, P (twice) and x at every
        # step, bookkeeping this estimator never reads, which cost as much as the step itself.
        z = (y - du).reshape(self.n_outputs, 1)
        kf.y = z - kf.H.dot(kf.x)
        if self._held is not None:
            self._judge_held(z)
        innovation = kf.y[:, 0].copy()
        u = u.reshape(self.n_inputs, 1)
        x_prior = kf.x
        kf.x = kf.x + kf.K.dot(kf.y)
        # sum_i (e_i / sigma_i)^2 bounds every output's (e_i / sigma_i)^2: an ordinary sample pays one dot.
        if (self._gate and (innovation * innovation).dot(self._inverse_variance) > GLITCH_STD ** 2
                and glitch_candidates(innovation[None, :], self._innovation_std)[0]):
            with np.errstate(invalid="ignore", over="ignore"):  # an infinite output: used only if no glitch
                self._held = dot(kf.F, kf.x) + dot(kf.B, u)  # the filter's next prediction without the rule
            # (p,) the sample as the model predicts it, from the state (the sample less its innovation
            # is lost to rounding beside a glitch of 1e20 spreads)
            predicted = dot(kf.H, x_prior)[:, 0] + du + self.output_offset
            # The outputs far off replaced by their prediction (innovation 0), the others taken.
            near = np.abs(kf.y) <= QUIET_STD * self._innovation_std[:, None]
            kf.x = x_prior + dot(kf.K, np.where(near, kf.y, 0.0))
            self._held_outputs = (~near[:, 0], predicted)
        x_post = kf.x[:, 0].copy()
        y_est = kf.H.dot(x_post) + du + self.output_offset
        kf.x = kf.F.dot(kf.x) + kf.B.dot(u)
        return x_post, y_est, innovation

    def _judge_held(self, z: np.ndarray) -> None:
        """The held candidate's verdict by this sample (``z`` (p, 1): ``y - D u``, ``kf.y`` its innovation).

        Settled: a glitch (counted), the filter goes on as it is. Else the filter takes the state
        it would have had without the rule, and this sample's innovation from it.
        """
        kf, held, self._held = self.kf, self._held, None
        if settled(kf.y[:, 0], self._innovation_std):
            self.glitches += 1
            self.last_glitch = self._held_outputs
            return
        kf.x = held
        kf.y = z - dot(kf.H, kf.x)

    def run(self, u: np.ndarray, y: np.ndarray) -> EstimatorOutput:
        """Process a block ``u`` (N, m), ``y`` (N, p); ``u`` (N, 0) for an output-only model."""
        u = np.asarray(u, dtype=float)
        # reshape(-1, 0) is ambiguous: an output-only model's (N, 0) inputs raised a ValueError.
        u = u.reshape(-1, self.n_inputs) if self.n_inputs else u.reshape(u.shape[0] if u.ndim else 0, 0)
        y = np.asarray(y, dtype=float).reshape(-1, self.n_outputs)
        if u.shape[0] != y.shape[0]:
            raise ValueError(f"u and y have different lengths: {u.shape[0]} and {y.shape[0]}")
        n_samples = u.shape[0]
        states = np.empty((n_samples, self.n_states))
        y_est = np.empty((n_samples, self.n_outputs))
        innov = np.empty((n_samples, self.n_outputs))
        for k in range(n_samples):
            states[k], y_est[k], innov[k] = self.step(u[k], y[k])
        return EstimatorOutput(self.modal_coordinates(states), states, y_est, innov)

    def modal_coordinates(self, states: np.ndarray) -> np.ndarray:
        """(..., n_modes, 2) the physical modes' coordinates of states (..., n)."""
        phys = np.asarray(states)[..., : self.n_physical_states]
        return phys.reshape(*phys.shape[:-1], self.n_physical_states // 2, 2)
