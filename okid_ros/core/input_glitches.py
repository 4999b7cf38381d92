"""Input glitches kept out of both nodes: one input sample absurdly far outside its channel's spread.

An output glitch is judged by the model's prediction (:mod:`.arx_glitches`); an input has no
prediction, and a large input is often real (an impact hammer's blow lies thousands of the
force's quiet spreads off). So an input sample is a glitch *candidate* only when some input lies
beyond :data:`INPUT_GLITCH_SPREADS` robust standard deviations (1.4826 times the median absolute
deviation) from its channel's median over the last :data:`INPUT_SPREAD_SAMPLES` samples passed on,
a multiple no acquisition resolves (a 24-bit converter spans 1.7e7 of its steps); it is a glitch
when the next sample's inputs are all within that bound again, as an output glitch's successor
must be as the model expects. A glitch goes into the window with its far inputs replaced by the
mean of that input before and after it (the next alone after a gap), the rest as they came: on
the paper's structure that mean left the ARX fits closer to the clean record's than a gap in the
lag history or the channel's median did. Otherwise it goes in as it came; so does the second
sample of a run beyond the bound (an excitation switched on over a quiet floor). A channel of
spread 0 (an input held at one value, exactly 0 between blows) is not judged: nothing to judge by;
nor one whose spread is float noise (:func:`float_noise_spread`: within a few rounding steps of its
centre, a held value's jitter, or subnormal, a filter's tail at 0).
Node 2's estimator cannot wait for the next sample: it refuses a glitch at once (:meth:`InputGlitchGate.refused`),
as a sample beyond 1e150. No rclpy; numpy only.
"""

from __future__ import annotations

import numpy as np

from okid_ros.core.output_spikes import MAD_TO_STD
from okid_ros.core.window_samples import accepted_run

__all__ = ["FLOAT_NOISE_STEPS", "INPUT_GLITCH_SPREADS", "INPUT_SPREAD_SAMPLES", "InputGlitchGate",
           "float_noise_spread", "input_glitch_warning", "without_input_glitches"]

#: Robust standard deviations of its channel beyond which an input is a glitch candidate. The
#: impact-hammer records of the tests reach 5e3 (blows of 50 over a quiet force of 0.01), a
#: 24-bit converter's full scale over one step 1.7e7; a force of 1e149 N lies at about 1e149.
INPUT_GLITCH_SPREADS = 1e9
#: The inputs passed on that give each channel's median and spread (refreshed every quarter of them).
INPUT_SPREAD_SAMPLES = 1024
#: Rounding steps (units in the last place) of a channel's centre within which its spread is float
#: noise: a value held and recomputed (0.3 as 0.1 * 3, a gain and an offset applied) jitters by a few.
FLOAT_NOISE_STEPS = 16


def float_noise_spread(spread: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Whether each channel's ``spread`` (m,) about its ``centre`` (m,) is float noise: (m,) bool.

    Within :data:`FLOAT_NOISE_STEPS` rounding steps of the centre, or below the smallest normal float64
    (subnormal: an IIR filter's tail at 0). A sample 1e9 such spreads off is no glitch but the first
    real value of the channel (an excitation switched on), which node 2 refused for one.
    """
    return spread <= np.maximum(FLOAT_NOISE_STEPS * np.spacing(np.abs(centre)), np.finfo(float).tiny)


class InputGlitchGate:
    """One-sample verdicts on input glitches before node 1's window (see the module docstring).

    Parameters
    ----------
    n_inputs : m.
    """

    def __init__(self, n_inputs: int) -> None:
        self.n_inputs = int(n_inputs)
        self._recent = np.zeros((INPUT_SPREAD_SAMPLES, self.n_inputs))
        self._held: tuple[np.ndarray, np.ndarray, object] | None = None
        self.forget()

    def forget(self) -> None:
        """Forget the inputs seen, the spread and any held sample (a reset of the window)."""
        self._seen = 0
        self._limit: np.ndarray | None = None
        self._centre = np.zeros(self.n_inputs)
        self.glitches = 0
        self.gap()

    def gap(self) -> list[tuple[np.ndarray, np.ndarray, object]]:
        """The sample stream breaks here: the held sample, if any, as it came (no neighbour after it)."""
        held = [] if self._held is None else [self._held]
        self._held = None
        self._previous: np.ndarray | None = None
        self._after_far = False  # the last sample offered lay beyond the bound
        return held

    def _far(self, u: np.ndarray) -> np.ndarray:
        """The inputs of ``u`` (m,) beyond the bound: (m,) bool (all False before a spread is known)."""
        if self._limit is None:
            return np.zeros(self.n_inputs, bool)
        return np.abs(u - self._centre) > self._limit

    def _passed(self, u: np.ndarray) -> None:
        """Remember an input that goes on as it came; refresh the spread every quarter of the span."""
        self._recent[self._seen % INPUT_SPREAD_SAMPLES] = u
        self._seen += 1
        self._previous = u
        if self._seen % (INPUT_SPREAD_SAMPLES // 4) == 0:
            recent = self._recent[: min(self._seen, INPUT_SPREAD_SAMPLES)]
            self._centre = np.median(recent, axis=0)
            spread = MAD_TO_STD * np.median(np.abs(recent - self._centre), axis=0)
            self._limit = np.where(float_noise_spread(spread, self._centre), np.inf, INPUT_GLITCH_SPREADS * spread)

    def ordinary_run(self, u: np.ndarray) -> int:
        """How many of the next samples' inputs ``u`` (n, m) :meth:`offer` would each pass on at once as they came.

        Nothing held and none beyond the bound, up to the spread's next refresh; the gate is left as it was.
        """
        if self._held is not None:
            return 0
        if self.n_inputs == 0:
            return len(u)
        n = min(len(u), INPUT_SPREAD_SAMPLES // 4 - self._seen % (INPUT_SPREAD_SAMPLES // 4))
        if self._limit is None:
            return n
        far = (np.abs(u[:n] - self._centre) > self._limit).any(axis=1)  # :meth:`_far` of each sample
        return int(np.argmax(far)) if far.any() else n

    def pass_run(self, u: np.ndarray) -> None:
        """The samples' inputs ``u`` (n, m) of an :meth:`ordinary_run` passed on, as :meth:`offer` passes them."""
        if self.n_inputs == 0 or not len(u):
            return
        n = len(u)
        self._recent[(self._seen + np.arange(n - 1)) % INPUT_SPREAD_SAMPLES] = u[:-1]
        self._seen += n - 1
        self._after_far = False
        self._passed(u[-1])  # the last one refreshes the spread where it is due

    def refused(self, u: np.ndarray) -> bool:
        """Judge ``u`` (m,) at once, for a path that cannot wait for the next sample (node 2): True for a glitch.

        By the same bound; without the next sample a glitch is any sample beyond it after one within
        it, so the first sample of an excitation switched on is refused too (and the rest taken).
        """
        far = self.n_inputs > 0 and bool(self._far(u).any())
        after_far, self._after_far = self._after_far, far
        if far and not after_far:
            self.glitches += 1
            return True
        self._passed(u)
        return False

    def offer(self, u: np.ndarray, y: np.ndarray, tag: object = None) -> list[tuple[np.ndarray, np.ndarray, object]]:
        """One sample ``u`` (m,), ``y`` (p,); returns the samples ``(u, y, tag)`` now due, in order.

        Empty when the sample is held for the next one's verdict; two samples when a held one is
        judged by this one. Without inputs every sample is passed on at once.
        """
        if self.n_inputs == 0:
            return [(u, y, tag)]
        far_inputs = self._far(u)
        far = bool(far_inputs.any())
        after_far, self._after_far = self._after_far, far
        due = []
        if self._held is not None:
            (u_held, y_held, tag_held), held_far = self._held, self._held_far
            self._held = None
            if far:  # not alone: as it came
                self._passed(u_held)
                due.append((u_held, y_held, tag_held))
            else:
                self.glitches += 1
                before = u if self._previous is None else self._previous
                due.append((np.where(held_far, 0.5 * (before + u), u_held), y_held, tag_held))
        if far and not after_far:  # a glitch is one sample: the second of a run goes on as it came
            self._held, self._held_far = (u, y, tag), far_inputs
            return due
        self._passed(u)
        return due + [(u, y, tag)]


def without_input_glitches(u: np.ndarray, *, accepted: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A record's inputs ``u`` (N, m) with each glitch replaced as node 1's window takes it (``track``, ``identify``).

    Returns the inputs (a new array) and the glitches' samples (K,). ``accepted`` (N,): the samples
    node 1's window accepts (finite and within its bound in inputs and outputs,
    :func:`~okid_ros.core.window_samples.accepted_samples`; None: those with finite inputs); a refused
    one breaks the stream as a gap does on node 1 (a glitch held before it goes on as it came); the
    record's last sample, held, goes on as it came.
    """
    gate, out, glitches = InputGlitchGate(u.shape[1]), u.copy(), []
    finite = np.isfinite(u).all(axis=1) if accepted is None else accepted
    k = 0
    while k < u.shape[0]:
        # A run of ordinary samples goes on as it came at once; the rest one by one.
        end = accepted_run(finite, k, min(k + INPUT_SPREAD_SAMPLES, u.shape[0]))
        if end > k and (n := gate.ordinary_run(u[k:end])):
            gate.pass_run(u[k : k + n])
            k += n
            continue
        for u_due, _, j in gate.offer(u[k], u[k], k) if finite[k] else gate.gap():
            if not np.array_equal(u_due, u[j]):
                out[j] = u_due
                glitches.append(j)
        k += 1
    return out, np.array(glitches, dtype=np.int64)


def input_glitch_warning(samples: np.ndarray) -> str:
    """What a record's input glitches (their samples, (K,)) are said as."""
    shown = ", ".join(str(int(k)) for k in samples[:5]) + (", ..." if samples.size > 5 else "")
    return (f"{samples.size} input sample(s) lie alone beyond {INPUT_GLITCH_SPREADS:.0e} robust standard deviations "
            f"of their channel ({shown}): glitches, no measured force; each replaced by the mean of its neighbours, "
            "as node 1 takes them")
