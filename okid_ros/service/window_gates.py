"""Node 1's glitch gates before its ARX window, in their order: the input gate, then the output gate.

One object for node 1's service (:class:`~okid_ros.service.identification.ArxIdentificationService`)
and ``okid-ros track``'s window (:class:`ScreenedWindow`): an input glitch is judged first
(:class:`~okid_ros.core.input_glitches.InputGlitchGate`: its far inputs go in as their neighbours'
mean), then the sample's outputs by the last fit's prediction
(:class:`~okid_ros.core.arx_glitches.ArxGlitchGate`: a glitch's outputs go in as their prediction).
Each sample waits at most one sample in each gate. No rclpy; numpy only.
"""

from __future__ import annotations

import numpy as np

from okid_ros.core.arx import ArxFit
from okid_ros.core.arx_glitches import ArxGlitchGate, window_intercept
from okid_ros.core.input_glitches import InputGlitchGate
from okid_ros.core.window_samples import accepted_run
from okid_ros.service.arx_solve import SolveCounts, SolveResult, WindowCapture, solve_capture
from okid_ros.service.change_restarts import restart_window
from okid_ros.service.options import ArxIdentificationParams

__all__ = ["BLOCK_SAMPLES", "ScreenedWindow", "WindowGates", "screened_block"]

#: Samples judged at once by :func:`screened_block` (their lag rows held at once: q (p + m) values each).
BLOCK_SAMPLES = 1024


class WindowGates:
    """The input gate, then the output gate, over the samples bound for an ARX window.

    Parameters
    ----------
    order : q; n_outputs : p; n_inputs : m.
    """

    def __init__(self, order: int, n_outputs: int, n_inputs: int) -> None:
        self.outputs = ArxGlitchGate(order, n_outputs, n_inputs)
        self.inputs = InputGlitchGate(n_inputs)  # before the output gate: it judges by the inputs

    def forget(self) -> None:
        """No model, no spread, nothing held (a reset of the window)."""
        self.outputs.forget_model()
        self.inputs.forget()

    def set_model(self, fit: ArxFit, intercept: np.ndarray | None = None) -> None:
        """The output gate judges by ``fit`` (``intercept`` (p,): a centred fit's constant) from now on."""
        self.outputs.set_model(fit, intercept)

    def accept(self, capture: WindowCapture, result: SolveResult) -> None:
        """A solved window's fit judges the next samples; a refused window's does not (the last good fit still does)."""
        if result.fit is not None:
            centred = capture.params.offsets == "remove"
            self.set_model(result.fit, window_intercept(capture.normal, result.fit) if centred else None)

    def offer(self, u: np.ndarray, y: np.ndarray, tag: object = None) -> list[tuple[np.ndarray, np.ndarray, object]]:
        """One sample ``u`` (m,), ``y`` (p,); the samples ``(u, y, tag)`` now due in the window, in order."""
        return [out for due in self.inputs.offer(u, y, tag) for out in self.outputs.offer(*due)]

    def ordinary_run(self, u: np.ndarray, y: np.ndarray) -> int:
        """How many of the next samples ``u`` (n, m), ``y`` (n, p) both gates would pass on at once as they came."""
        n = self.inputs.ordinary_run(u)
        return self.outputs.ordinary_run(u[:n], y[:n]) if n else 0

    def pass_run(self, u: np.ndarray, y: np.ndarray) -> None:
        """The samples of an :meth:`ordinary_run` passed on through both gates, as :meth:`offer` passes them."""
        self.inputs.pass_run(u)
        self.outputs.pass_run(u, y)

    def gap(self) -> list[tuple[np.ndarray, np.ndarray, object]]:
        """The sample stream breaks here: the held samples as they came, in order; the lag history forgotten."""
        return [out for due in self.inputs.gap() for out in self.outputs.offer(*due)] + self.outputs.gap()

    @property
    def glitches(self) -> int:
        """Samples whose outputs went in as their prediction."""
        return self.outputs.glitches

    @property
    def input_glitches(self) -> int:
        """Samples whose far inputs went in as their neighbours' mean."""
        return self.inputs.glitches


def screened_block(gates: WindowGates, record: tuple, accepted: np.ndarray, lo: int, hi: int) -> int:
    """Samples ``lo .. hi - 1`` of a record through ``gates``, as node 1's service offers them.

    ``record``: ``(u, y)`` (N, m), (N, p), written over in place where a gate replaces a sample;
    ``accepted`` (N,): the samples the window accepts (a refused one breaks the stream: the held
    samples go in as they came, as node 1 flushes its gates at a gap). Returns the first sample
    not yet due (held by a gate): the samples before it are final.
    """
    u, y = record
    due_to = k = lo
    while k < hi:
        # A run of ordinary samples goes on at once, the gates left as one by one; the rest one by one.
        end = accepted_run(accepted, k, min(k + BLOCK_SAMPLES, hi))
        if end > k and (n := gates.ordinary_run(u[k:end], y[k:end])):
            gates.pass_run(u[k : k + n], y[k : k + n])
            k = due_to = k + n
            continue
        due = gates.offer(u[k], y[k], k) if accepted[k] else gates.gap()
        for u_due, y_due, j in due:
            u[j], y[j] = u_due, y_due
            due_to = j + 1
        if not accepted[k]:
            due_to = k + 1
        k += 1
    return due_to


class ScreenedWindow:
    """``okid-ros track``'s sliding ARX window fed and solved as node 1 feeds and solves its own.

    Every sample goes through its gates; each update's window is solved by node 1's
    :func:`~okid_ros.service.arx_solve.solve_capture` (refused where node 1 refuses it, inputs silent over
    the window left out), and the fit of a window it takes judges the next samples.

    Parameters
    ----------
    window : the :class:`~okid_ros.core.recursive.SlidingWindowArx`; record : ``(u, y)`` (N, m), (N, p)
        (copied: the gates write their replacements into the copy); accepted : (N,) the samples the window accepts.
    params : node 1's options of the window (its solve, its fill rule).
    """

    def __init__(self, window, record: tuple, accepted: np.ndarray, *, params: ArxIdentificationParams) -> None:
        self.window, self.accepted, self.params = window, accepted, params
        self.gates = WindowGates(window.order, window.n_outputs, window.n_inputs)
        self.u, self.y = record[0].copy(), record[1].copy()
        self._fed = self._due = 0  # samples offered to the gates; samples the gates let into the window
        self._restarted = False  # at a structural change: node 1's fill rule after a restart
        self.solves = SolveCounts()  # the windows solved, as node 1 counts its snapshots

    def feed(self, hi: int) -> None:
        """The samples up to ``hi - 1`` offered; those the gates let through into the window."""
        newest = screened_block(self.gates, (self.u, self.y), self.accepted, self._fed, hi)
        self.window.update(self.u[self._due : newest], self.y[self._due : newest])
        self._fed, self._due = hi, newest

    def restart(self, first: int, hi: int) -> None:
        """The samples up to ``hi - 1`` offered, then the window restarted at sample ``first`` (a change), as node 1.

        Node 1 flushes its gates first (the held samples as they came, which the copy holds), then
        replays what its gates let through from the change on
        (:func:`~okid_ros.service.change_restarts.restart_window`).
        """
        screened_block(self.gates, (self.u, self.y), self.accepted, self._fed, hi)
        self.gates.gap()
        restart_window(self.window, self.u[first:hi], self.y[first:hi])
        self._fed = self._due = hi
        self._restarted = True

    def solve(self) -> SolveResult:
        """Node 1's solve of the window as it is; the fit of a window it takes judges the next samples, as node 1's."""
        capture = WindowCapture.of_window(self.window, self.params, restarted=self._restarted)
        result = solve_capture(capture)
        self.gates.accept(capture, result)
        self.solves.count(result)
        return result

    def gate_counts(self) -> dict:
        """Node 1's counts of the gates (its diagnostics' names)."""
        return {"glitches": self.gates.glitches, "input_glitches": self.gates.input_glitches}

    def counts(self) -> dict:
        """Node 1's counts of the gates and of the windows solved (its diagnostics' names)."""
        return {**self.gate_counts(), **self.solves.counts()}
