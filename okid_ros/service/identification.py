"""Node 1 without ROS: windowed ARX identification on assembled samples.

:class:`ArxIdentificationService` feeds samples into the recursive sliding-window least squares
of :mod:`okid_ros.core.recursive` and, when asked (at the publish rate), solves the window's
regularized ARX problem (:func:`okid_ros.core.arx.fit_from_normal_equations`: the batch fit on
exactly the window's rows, ridge or TC prior, penalty by GCV or fixed) and packages it as an
:class:`ArxSnapshot` for the ``ArxModel`` message.

The solve costs O(d^3) (d = 402 for p = m = 2, q = 100: tens of milliseconds) and only reads a
copy of the normal equations, so a caller with a sample stream to serve can split it::

    capture = service.capture()               # cheap; on the thread that pushes samples
    result = solve_capture(capture)           # expensive; any thread
    snapshot = service.accept(capture, result)

:meth:`ArxIdentificationService.snapshot` does the three in a row. The capture, the solve and the
snapshot: :mod:`okid_ros.service.arx_solve` (its names re-exported here).

Sample policy (:meth:`ArxIdentificationService.push`): a sample with NaN/Inf, the wrong size or
a value beyond the window's bound (1e150, :mod:`okid_ros.core.window_samples`) is rejected and
counted; its stamp is checked by the sample grid's rule
(:class:`okid_ros.service.sample_grid.StampSequence`: it must advance by more than half a sample
time over the previous accepted one, else duplicate or out of order: rejected and counted); a
step of more than 1.5 sample times, or ``gap_before``, breaks the lag history so that no
regressor spans the gap. A glitch (one sample far off) goes in as its estimate, counted: an output's as the
last fit's prediction (:mod:`okid_ros.core.arx_glitches`), an input's as its neighbours' mean (``input_glitches``).

Structural change (:meth:`ArxIdentificationService.restart_at`): node 2 declares a change and
its estimated first sample; before the window's next solve it is rebuilt from the recent samples from
that stamp on (this service keeps one window of them; the newest of the changes since the last solve),
so the next models use post-change data only, and
snapshots are valid from ``restart_min_fill`` on (smaller than ``min_window_fill``) so that a
model of the new structure comes soon.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from okid_ros.core.arx import ArxFit
from okid_ros.core.recursive import SlidingWindowArx
from okid_ros.core.window_samples import in_bound
from okid_ros.service.arx_solve import ArxSnapshot, SolveCounts, SolveResult, WindowCapture, solve_capture
from okid_ros.service.change_restarts import (
    change_refusal,
    replay_rows,
    restart_window,
    started_refusal,
    superseded_refusal,
)
from okid_ros.service.options import ArxIdentificationParams, check_runtime_change
from okid_ros.service.results import count_why, why_text
from okid_ros.service.sample_buffer import SampleBuffer
from okid_ros.service.sample_grid import StampSequence, StampStep
from okid_ros.service.window_gates import WindowGates

__all__ = ["ArxIdentificationParams", "ArxIdentificationService", "ArxSnapshot", "WindowCapture", "SolveResult",
           "restart_window", "solve_capture"]


#: Generations of the window, unique across services: a capture solved after its window was reset,
#: restarted or rebuilt (a lifecycle cleanup and configure: a new service) is not accepted.
_WINDOW_GENERATIONS = itertools.count()


@dataclass
class _Counters:
    samples_seen: int = 0
    samples_used: int = 0
    rejected_nonfinite: int = 0
    rejected_wrong_size: int = 0
    rejected_duplicate: int = 0
    rejected_out_of_order: int = 0
    rejected_magnitude: int = 0  # a value beyond the window's bound (core.window_samples.MAX_SAMPLE_MAGNITUDE)
    gaps: int = 0
    window_restarts: int = 0
    restarts_ignored: int = 0
    #: Structural changes ignored, by why (an IgnoredChange phrase) -> (count, the last one's reason in full).
    restarts_ignored_why: dict = field(default_factory=dict)
    restart_samples: int = 0
    last_restart_stamp_s: float = math.nan

    @property
    def rejected(self) -> int:
        return (self.rejected_nonfinite + self.rejected_wrong_size + self.rejected_duplicate
                + self.rejected_out_of_order + self.rejected_magnitude)


@dataclass
class _Health(SolveCounts):
    last_reason: str = ""
    last_condition_number: float = math.nan
    last_solve_time_s: float = 0.0


class ArxIdentificationService:
    """Windowed recursive ARX identification: samples in, :class:`ArxSnapshot` out.

    Parameters
    ----------
    params : :class:`ArxIdentificationParams`.

    Raises
    ------
    ValueError on inconsistent parameters (from the core estimator).
    """

    def __init__(self, params: ArxIdentificationParams) -> None:
        self.params = params
        if params.regularization not in ("none", "ridge", "tc"):
            raise ValueError(f"regularization must be none, ridge or tc, got {params.regularization!r}")
        window = params.window_length if params.window_length > 0 else None
        self._est = SlidingWindowArx(
            params.order, params.n_outputs, params.n_inputs, window=window,
            forgetting=1.0 if window else params.forgetting_factor,
        )
        # The samples a restart at a change point replays: one window (or ~3 memory lengths).
        memory = params.window_length or int(min(3.0 / max(1.0 - params.forgetting_factor, 1e-6), 100_000))
        self._recent = SampleBuffer(memory + params.order + 64, params.n_inputs, params.n_outputs)
        self._stamps = StampSequence(params.sample_time_s)
        self._gates = WindowGates(params.order, params.n_outputs, params.n_inputs)
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget the window, the counters, the last good fit; model ids restart at 0."""
        self._est.reset()
        self._recent.clear()
        self._restarted = False
        self._frozen = False  # adaptation was off since the reset or the last restart
        self.last_ignored_change = ""  # the reason the last structural change was ignored for
        self._counters = _Counters()
        self._health = _Health()
        self._stamps.reset()
        self._gates.forget()
        self._last_good: ArxFit | None = None
        self._last_good_penalty = math.nan
        self._model_id = 0
        self._due_stamp: float | None = None
        self._pending_restart_s = math.nan  # the stamp of a structural change the window restarts at before it is read
        self._generation = next(_WINDOW_GENERATIONS)

    def set_params(self, params: ArxIdentificationParams) -> list[str]:
        """Take new options at once (the next solve and restart use them); returns the changed fields.

        Raises ValueError if an option that sizes the window changes (``runtime`` in the table).
        """
        changed = check_runtime_change(self.params, params)
        self.params = params
        return changed

    @property
    def adaptation_enabled(self) -> bool:
        return self._est.adaptation_enabled

    def set_adaptation(self, on: bool) -> None:
        """Adaptation off: samples are still checked and counted, but the window is frozen."""
        self.apply_pending_restart()  # with the adaptation the change came under
        self._est.adaptation_enabled = bool(on)
        self._frozen |= not on  # its rows are no longer the samples' since: a restart's replay differs

    @property
    def newest_stamp_s(self) -> float:
        return self._stamps.newest_stamp_s

    # ------------------------------------------------------------------ samples
    def push(self, stamp_s: float, u, y, gap_before: bool = False) -> bool:
        """Offer one sample; return whether it was accepted into the window's history.

        Parameters
        ----------
        stamp_s : sample time stamp [s].
        u : (m,) inputs; y : (p,) outputs.
        gap_before : the caller knows samples are missing before this one (or time restarted):
            the lag history is broken and the stamp need not advance.
        """
        c, prm = self._counters, self.params
        c.samples_seen += 1
        gaps_before = c.gaps
        u = np.asarray(u, dtype=float).reshape(-1)
        y = np.asarray(y, dtype=float).reshape(-1)
        if u.size != prm.n_inputs or y.size != prm.n_outputs:
            c.rejected_wrong_size += 1
            return False
        stamp_s = float(stamp_s)
        if not (math.isfinite(stamp_s) and np.isfinite(u).all() and np.isfinite(y).all()):
            c.rejected_nonfinite += 1
            return False
        step = StampStep.GAP if gap_before else self._stamps.check(stamp_s)
        if step is StampStep.OUT_OF_ORDER:
            c.rejected_out_of_order += 1
            return False
        if step is StampStep.DUPLICATE:
            c.rejected_duplicate += 1
            return False
        bounded = in_bound(u, y)
        if step is StampStep.GAP or not bounded:
            self._flush()
        if step is StampStep.GAP:
            self._est.mark_gap()
            c.gaps += 1
        if not bounded:
            self._est.push(u, y)  # refused and counted by the window, which breaks its lag history
            c.rejected_magnitude += 1
            return False
        self._stamps.accept(stamp_s)
        self._enter(self._gates.offer(u, y, (stamp_s, c.gaps != gaps_before)))
        c.samples_used += 1
        return True

    def _flush(self) -> None:
        """The glitch gates' held samples into the window as they came, before its history breaks."""
        self._enter(self._gates.gap())

    def _enter(self, due: list) -> None:
        """Samples ``(u, y, (stamp_s, after a gap))`` the glitch gates let into the window."""
        for u, y, (stamp_s, gap) in due:
            self._est.push(u, y)
            self._recent.append(stamp_s, u, y, int(gap))

    def restart_at(self, change_stamp_s: float) -> int:
        """Restart the window at a structural change before its next solve: only the samples from ``change_stamp_s`` on.

        The restart is pending until the window is next read (:meth:`apply_pending_restart`: by
        :meth:`capture`, :meth:`window_samples`, a switch of adaptation): one replay however many
        changes come before then, a later one superseding the pending one (counted as ignored, by why).
        Refused, counted by why (:mod:`okid_ros.service.change_restarts`), when the window starts at or
        after the change already (the same change again: node 2 reports each twice; or an older one, or
        the pending one's), it is stamped before the samples held, more than ``MAX_CHANGE_LEAD_S`` after
        the newest, or not at all, or none is held. Returns the samples held from the change on (the
        restart replays them and those that come before it is applied; -1: ignored).
        """
        c, est = self._counters, self._est
        change_stamp_s = float(change_stamp_s)
        pending_s = self._pending_restart_s
        first = self._replay_first(change_stamp_s)
        refused = change_refusal(change_stamp_s, oldest_s=self._recent.stamp_at(self._recent.first),
                                 newest_s=self._stamps.newest_stamp_s,
                                 last_restart_s=c.last_restart_stamp_s if math.isnan(pending_s) else pending_s,
                                 sample_time_s=self.params.sample_time_s)
        if refused is None and est.window is not None and not self._frozen:  # rows of the samples since
            gaps = self._recent.get(first, self._recent.count)[3]
            refused = started_refusal(change_stamp_s, rows_from_change=replay_rows(gaps, est.order),
                                      window_rows=est.status.rows_in_window)
        if refused is None and not math.isnan(pending_s):
            self._ignore_change(*superseded_refusal(pending_s, change_stamp_s))
        elif refused is not None:
            self._ignore_change(*refused)
            return -1
        self._pending_restart_s = change_stamp_s
        self._generation = next(_WINDOW_GENERATIONS)  # a solve of the window before the change is stale
        return self._recent.count - first

    def _ignore_change(self, why: str, reason: str) -> None:
        """Count a structural change ignored (an ``IgnoredChange`` phrase ``why``, ``reason`` in full)."""
        self._counters.restarts_ignored += 1
        count_why(self._counters.restarts_ignored_why, why, reason)
        self.last_ignored_change = reason

    def apply_pending_restart(self) -> int:
        """Restart the window at the pending structural change (:meth:`restart_at`); the samples replayed (-1: none)."""
        change_stamp_s, c, est = self._pending_restart_s, self._counters, self._est
        if math.isnan(change_stamp_s):
            return -1
        self._pending_restart_s = math.nan
        self._flush()  # a held sample is part of the samples to replay
        _, u, y, gaps = self._recent.get(self._replay_first(change_stamp_s), self._recent.count)
        restart_window(est, u, y, gaps)
        self._restarted = True
        self._frozen = not est.adaptation_enabled
        c.window_restarts += 1
        c.restart_samples = int(u.shape[0])
        c.last_restart_stamp_s = change_stamp_s
        self._generation = next(_WINDOW_GENERATIONS)  # the window rebuilt
        return int(u.shape[0])

    def _replay_first(self, change_stamp_s: float) -> int:
        """Index of the first sample held a restart at ``change_stamp_s`` replays (the count: none yet)."""
        first = self._recent.first_at_or_after(change_stamp_s, 0.5 * self.params.sample_time_s)
        return self._recent.count if first < 0 else first

    def push_block(self, stamps_s, u, y) -> int:
        """Push samples one by one (same checks); return how many were accepted."""
        return sum(self.push(t, uk, yk) for t, uk, yk in zip(stamps_s, u, y))

    # ------------------------------------------------------------------ solving
    def capture(self) -> WindowCapture:
        """Copy the window's normal equations and counters (cheap next to the solve, but a pending restart's replay)."""
        self.apply_pending_restart()
        return WindowCapture.of_window(self._est, self.params, restarted=self._restarted, stamp_s=self.newest_stamp_s,
                                       samples_used=self._counters.samples_used,
                                       samples_rejected=self._counters.rejected, generation=self._generation)

    def is_current(self, capture: WindowCapture) -> bool:
        """Whether ``capture`` is of this service's window as it is (not reset, restarted or another service's)."""
        return capture.generation == self._generation

    def accept(self, capture: WindowCapture, result: SolveResult) -> ArxSnapshot:
        """Turn a solved capture into the next snapshot (keeps the last good fit on failure)."""
        valid = result.fit is not None
        self._gates.accept(capture, result)
        if valid:
            self._last_good = result.fit
            self._last_good_penalty = float(result.fit.penalty)
        h = self._health
        h.count(result)
        h.last_reason, h.last_condition_number, h.last_solve_time_s = (result.reason, result.condition_number,
                                                                      result.solve_time_s)
        self._model_id += 1
        prm = self.params
        return ArxSnapshot(
            model_id=self._model_id,
            valid=valid,
            fit=result.fit if valid else self._last_good,
            stamp_s=capture.stamp_s,
            reason=result.reason,
            sample_time_s=prm.sample_time_s,
            order=prm.order,
            n_inputs=prm.n_inputs,
            n_outputs=prm.n_outputs,
            window_length=max(prm.window_length, 0),
            window_rows=capture.window_rows,
            window_fill=capture.window_fill,
            forgetting_factor=prm.forgetting_factor if prm.window_length == 0 else 1.0,
            condition_number=result.condition_number,
            penalty=self._last_good_penalty if self._last_good is not None else math.nan,
            samples_used=capture.samples_used,
            samples_rejected=capture.samples_rejected,
            solve_time_s=result.solve_time_s,
        )

    def snapshot(self) -> ArxSnapshot:
        """Capture, solve and accept in one call."""
        capture = self.capture()
        return self.accept(capture, solve_capture(capture))

    def due(self, stamp_s: float) -> bool:
        """For offline processing: True once per ``publish_period_s`` of sample time.

        The first call starts the clock; a stamp going backwards (a time jump) restarts it.
        """
        if self._due_stamp is None or stamp_s < self._due_stamp:
            self._due_stamp = stamp_s
            return False
        if stamp_s - self._due_stamp >= self.params.publish_period_s - 1e-9:
            self._due_stamp += self.params.publish_period_s * math.floor(
                (stamp_s - self._due_stamp) / self.params.publish_period_s + 1e-9
            )
            return True
        return False

    # ------------------------------------------------------------------ inspection
    def window_samples(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The samples the window's rows are built from: u (n, m), y (n, p), segment_start (n,)."""
        self.apply_pending_restart()
        return self._est.window_samples()

    def diagnostics(self) -> dict[str, Any]:
        """Counters and health as a flat dict (values are numbers, strings or bools)."""
        st = self._est.status
        c, h = self._counters, self._health
        return {
            "samples_seen": c.samples_seen,
            "samples_used": c.samples_used,
            "samples_rejected": c.rejected,
            "rejected_nonfinite": c.rejected_nonfinite,
            "rejected_wrong_size": c.rejected_wrong_size,
            "rejected_duplicate": c.rejected_duplicate,
            "rejected_out_of_order": c.rejected_out_of_order,
            "rejected_magnitude": c.rejected_magnitude,
            "gaps": c.gaps,
            "glitches": self._gates.glitches,  # samples whose outputs went in as their prediction
            "input_glitches": self._gates.input_glitches,  # ... whose inputs went in as their neighbours' mean
            "window_restarts": c.window_restarts,
            "window_restarts_ignored": c.restarts_ignored,
            "window_restarts_ignored_why": why_text(c.restarts_ignored_why),
            "last_restart_stamp_s": c.last_restart_stamp_s,
            "last_restart_samples": c.restart_samples,
            "pending_restart_stamp_s": self._pending_restart_s,  # nan: none
            "window_rows": int(st.rows_in_window),
            "window_fill": float(st.window_fill),
            "adaptation": bool(st.adapting),
            "condition_number": h.last_condition_number,
            "last_solve_time_s": h.last_solve_time_s,
            **h.counts(),  # snapshots, valid_snapshots, silent_input_snapshots
            "last_silent_input_warning": h.last_warning,
            "model_id": self._model_id,
            "has_good_model": self._last_good is not None,
            "last_reason": h.last_reason,
        }
