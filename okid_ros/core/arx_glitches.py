"""Glitches kept out of node 1's window: a sample far off in some outputs, judged by the ARX predictor.

A glitch (interference, a telemetry bit error: one output sample far off) enters the windowed
least squares as a residual of hundreds of standard deviations, and every one of the ``q + 1``
regressor rows that reach it; it holds its weight for the whole window. :class:`ArxGlitchGate`
judges each sample by the one-step prediction of the window's last good ARX fit, by the rule the
change test uses for the reference model's innovations (:mod:`okid_ros.core.glitches`): a sample
whose prediction error lies beyond ``GLITCH_STD`` of the fit's residual standard deviations in
some outputs, not every output, is held; when the next sample's prediction error, the held one's
outputs replaced by their prediction, is as the model expects in every output, the held sample goes
into the window with its prediction in place of its outputs (its inputs as they came). Otherwise
it goes in as it came. An ordinary sample is passed on at once; a candidate waits one sample.

Before the first fit, and for the first ``q`` samples after a gap (no full lag history), samples
are passed on as they come. No rclpy; numpy only.
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from okid_ros.core.arx import ArxFit
from okid_ros.core.glitches import GLITCH_STD, glitch_candidates, settled
from okid_ros.core.least_squares import NormalEquations

__all__ = ["ArxGlitchGate", "window_intercept"]


def window_intercept(normal: NormalEquations, fit: ArxFit) -> np.ndarray | None:
    """The constant (p,) of ``fit`` solved from ``normal`` centred: ``(t - theta^T s) / n``; None without sums."""
    if normal.phi_sum is None or normal.y_sum is None or normal.n_rows < 1:
        return None
    return (normal.y_sum - fit.theta.T @ normal.phi_sum) / normal.n_rows


class ArxGlitchGate:
    """One-sample verdicts on samples bound for an ARX window (see the module docstring).

    Parameters
    ----------
    order : q; n_outputs : p; n_inputs : m.
    """

    def __init__(self, order: int, n_outputs: int, n_inputs: int) -> None:
        self.order, self.n_outputs, self.n_inputs = int(order), int(n_outputs), int(n_inputs)
        # The last q samples' rows [y, u], twice over: history[pos : pos + q] is oldest..newest.
        self._history = np.zeros((2 * self.order, self.n_outputs + self.n_inputs))
        self._theta_u: np.ndarray | None = None
        self.glitches = 0
        self.reset()

    def reset(self) -> None:
        """Forget the lag history and any held sample (keeps the model)."""
        self._pos = 0
        self._run = 0  # samples since the last gap in the history
        self._held: tuple[np.ndarray, np.ndarray, object] | None = None

    def forget_model(self) -> None:
        """No model: pass every sample on (a reset of the window)."""
        self._theta_u = None
        self.reset()
        self.glitches = 0

    def set_model(self, fit: ArxFit, intercept: np.ndarray | None = None) -> None:
        """Judge by ``fit`` from now on; ``intercept`` (p,) the constant of a centred fit (None: 0)."""
        m, p, q = self.n_inputs, self.n_outputs, self.order
        if (fit.order, fit.n_outputs, fit.n_inputs) != (q, p, m):
            raise ValueError(f"ARX fit of order {fit.order}, p={fit.n_outputs}, m={fit.n_inputs} for a gate of "
                             f"order {q}, p={p}, m={m}")
        self._theta_u = fit.theta[:m]
        # theta's lag blocks are newest first ([y_(k-1), u_(k-1)], ...): reversed to the history's order.
        self._theta_lags = fit.theta[m:].reshape(q, p + m, p)[::-1].reshape(q * (p + m), p).copy()
        self._intercept = np.zeros(p) if intercept is None else np.asarray(intercept, float).reshape(p)
        self._residual_std = np.sqrt(np.maximum(np.diag(fit.residual_covariance), 0.0))
        self._limit = GLITCH_STD * self._residual_std

    def _prediction(self, u: np.ndarray) -> np.ndarray:
        lags = self._history[self._pos: self._pos + self.order].reshape(-1)
        return u @ self._theta_u + lags @ self._theta_lags + self._intercept

    def _remember(self, u: np.ndarray, y: np.ndarray) -> None:
        p, h = self.n_outputs, self._history
        for at in (self._pos, self._pos + self.order):
            h[at, :p] = y
            h[at, p:] = u
        self._pos = (self._pos + 1) % self.order
        self._run += 1

    def ordinary_run(self, u: np.ndarray, y: np.ndarray) -> int:
        """How many of the next samples ``u`` (n, m), ``y`` (n, p) :meth:`offer` would pass on at once as they came.

        Nothing held and no candidate: the block's predictions by one product, a sample taken as ordinary only where
        its error lies within the limit by more than the rounding of any order of the sums (the product's and
        :meth:`_prediction`'s differ in the last bits), the first other sample left to :meth:`offer`. The gate is
        left as it was.
        """
        n, q = len(y), self.order
        if self._theta_u is None or q == 0 or self.n_outputs < 2:
            return n
        if self._held is not None:
            return 0
        free = min(n, max(q - self._run, 0))  # no full lag history yet: passed on unjudged
        if free == n:
            return n
        rows = np.concatenate([self._history[self._pos : self._pos + q], np.hstack([y, u])])
        lags = sliding_window_view(rows, (q, rows.shape[1]))[free:n, 0].reshape(n - free, -1)  # oldest..newest
        error = y[free:] - (u[free:] @ self._theta_u + lags @ self._theta_lags + self._intercept)
        scale = np.abs(u[free:]) @ np.abs(self._theta_u) + np.abs(lags) @ np.abs(self._theta_lags) \
            + np.abs(self._intercept) + np.abs(y[free:])
        rounding = 4.0 * (lags.shape[1] + self.n_inputs + 3) * np.finfo(float).eps * scale
        ordinary = (np.abs(error) + rounding <= self._limit).all(axis=1)  # NaN: not ordinary
        return free + (int(np.argmin(ordinary)) if not ordinary.all() else n - free)

    def pass_run(self, u: np.ndarray, y: np.ndarray) -> None:
        """The samples ``u`` (n, m), ``y`` (n, p) of an :meth:`ordinary_run` passed on, as :meth:`offer` passes them."""
        n, q = len(y), self.order
        if self._theta_u is None or q == 0 or self.n_outputs < 2 or not n:
            return
        last = min(n, q)
        at = (self._pos + np.arange(n - last, n)) % q  # :meth:`_remember`'s place of each of the last q samples
        self._history[at] = self._history[at + q] = np.hstack([y[n - last :], u[n - last :]])
        self._pos = (self._pos + n) % q
        self._run += n

    def gap(self) -> list[tuple[np.ndarray, np.ndarray, object]]:
        """The lag history breaks here: the held sample, if any, as it came; the history forgotten."""
        held = [] if self._held is None else [self._held]
        self.reset()
        return held

    def offer(self, u: np.ndarray, y: np.ndarray, tag: object = None) -> list[tuple[np.ndarray, np.ndarray, object]]:
        """One sample ``u`` (m,), ``y`` (p,); returns the samples ``(u, y, tag)`` now due in the window, in order.

        ``tag`` travels with the sample (its stamp, say). Empty when the sample is held for the
        next one's verdict; two samples when a held one is settled by this one.
        """
        if self._theta_u is None or self.order == 0 or self.n_outputs < 2:
            return [(u, y, tag)]  # one output: a glitch and an unmeasured impact look alike
        due = []
        if self._held is not None:
            due.append(self._verdict(u, y))
        if self._run < self.order:
            self._remember(u, y)
            return due + [(u, y, tag)]
        prediction = self._prediction(u)
        error = y - prediction
        # The common case costs one comparison: no output past the limit (NaN compares False).
        if (np.abs(error) > self._limit).any() and glitch_candidates(error[None, :], self._residual_std)[0]:
            self._held = (u, y, tag)
            self._held_prediction = prediction  # not y - error: a glitch 1e20 times the signal leaves 0 of it
            self._remember(u, self._held_prediction)  # the next verdict reads the prediction in its place
            return due
        self._remember(u, y)
        return due + [(u, y, tag)]

    def _verdict(self, u: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, object]:
        """The held sample as it goes into the window, judged by the next sample ``(u, y)``."""
        u_held, y_held, tag = self._held
        self._held = None
        if settled(y - self._prediction(u), self._residual_std):
            self.glitches += 1
            return u_held, self._held_prediction, tag
        newest = (self._pos - 1) % self.order  # put the sample back as it came
        self._history[newest, : self.n_outputs] = y_held
        self._history[newest + self.order, : self.n_outputs] = y_held
        return u_held, y_held, tag
