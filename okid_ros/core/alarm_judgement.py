"""The judgement of a change test's alarm before it is declared: model error, state jump, noise change.

The calibrated CUSUM (:class:`~okid_ros.core.change_detection.ChangeDetector`) raises an alarm
when the power of the whitened innovations rises; :class:`AlarmJudgement` decides whether it is
declared as a structural change.

Power also rises when the unmeasured excitation or the sensor noise grows, with the structure
unchanged. With a :class:`~okid_ros.core.model_error_check.ModelErrorCheck` attached
(``check``, as :class:`~okid_ros.core.change_monitor.StructuralChangeMonitor` does), an alarm is
declared only when the residuals of its excursion carry a model error: a part the past inputs
and residuals predict beyond what the calibration's did. Otherwise it is counted
(``unconfirmed_alarms``), the CUSUM goes on, and the excursion is judged again later. Excitation
that changes relative to the sensor noise colours the innovations too (the optimal gain depends
on that ratio), and the check confirms it: a ``noise_test`` (the monitor attaches a
:class:`~okid_ros.core.noise_change.NoiseChangeTest`) judges a confirmed excursion that no state
jump explains, and one that a change of the noise model explains ends (``noise_changes``; the
caller re-arms with the new noise model).

A jump of the state raises the power too, and the model-error check confirms it (an impact,
a bag replayed in a loop: the decaying mismatch is predictable from its own lags), but it is
not a change: the excursion is the free response of the reference predictor to the jump. With
a ``jump_test`` attached (the monitor attaches a
:class:`~okid_ros.core.state_jump.StateJumpTest`), a confirmed alarm is judged as a state jump
before it is declared; an excursion that a jump explains ends there (the statistic returns to
0, the tracked mean takes the fit's constant, the whitening's lags refill), it is counted
(``state_jumps``) and the caller corrects its predictor (``jump_at``). The judgement waits for
enough samples after the excursion's loud samples begin (``StateJumpTest.needed_samples``).

No rclpy; numpy only (through the tests it is given).
"""

from __future__ import annotations

import enum
from collections.abc import Callable

from okid_ros.core.model_error_check import ModelErrorCheck, ModelErrorVerdict
from okid_ros.core.state_jump import StateJump

__all__ = ["AlarmJudgement", "Judged"]


class Judged(enum.Enum):
    """What :meth:`AlarmJudgement.judge` made of an alarm."""

    DECLARED = "declared"  # a structural change
    PENDING = "pending"  # not declared now; the excursion goes on and is judged again later
    EXPLAINED = "explained"  # a state jump or a noise change: the excursion ends


class AlarmJudgement:
    """Whether a CUSUM alarm is declared (see the module docstring); counts over its life.

    Attributes
    ----------
    check : judges each alarm before it is declared (None: every alarm is declared); the
        detector gives it the tested residuals, the caller the inputs.
    last_verdict : the check's judgement of the last alarm, if any.
    unconfirmed_alarms : excursions whose alarm the check did not confirm, since construction.
    jump_test : ``(change_index, alarm_index, index) -> StateJump | None`` judging at sample
        ``index`` the excursion from ``change_index`` whose alarm at ``alarm_index`` the check
        confirmed, as a state jump, before it is declared (None: no such judgement); None from
        it: not yet (too few samples).
    state_jumps : excursions explained as a state jump, since construction.
    jump_at : the sample of the last explained excursion's alarm, until the caller takes it
        (sets it to None) and corrects its predictor by ``last_jump``.
    noise_test : ``(change_index, index) -> NoiseVerdict | None``, as ``jump_test`` for a noise
        change; ``noise_changes``, ``noise_at`` and ``last_noise`` as ``state_jumps``, ``jump_at``, ``last_jump``.
    """

    def __init__(self) -> None:
        self.check: ModelErrorCheck | None = None
        self.jump_test: Callable[[int, int, int], StateJump | None] | None = None
        self.noise_test = None
        self.unconfirmed_alarms = 0
        self.state_jumps = 0
        self.noise_changes = 0
        self.restart()

    def restart(self) -> None:
        """Forget the last verdicts and the excursion under judgement (the counts and tests are kept)."""
        self.last_verdict: ModelErrorVerdict | None = None
        self.last_jump: StateJump | None = None
        self.jump_at: int | None = None
        self.last_noise = None
        self.noise_at: int | None = None
        self.excursion_ended()

    def excursion_ended(self) -> None:
        """The statistic returned to 0: the next excursion's alarm is judged afresh."""
        self._confirmed_at = -1  # the sample whose alarm the check confirmed, awaiting the state-jump test
        self._jump_open = True  # the confirmed alarm is judged as a state jump first
        self._judge_from = -1  # no judgement of this excursion before this sample (-1: none refused yet)

    def judge(self, change_index: int, index: int) -> Judged:
        """Judge the alarm at sample ``index`` of the excursion from ``change_index``."""
        if index < self._judge_from:
            return Judged.PENDING
        if self._confirmed_at < 0:
            if not self._confirmed(change_index, index):
                return Judged.PENDING
            self._confirmed_at = index  # declared unless a state jump or a noise change explains it
        return self._explained_or_declared(change_index, index)

    def _explained_or_declared(self, change_index: int, index: int) -> Judged:
        """A confirmed alarm judged as a state jump, then as a noise change: declared if neither explains it."""
        if self.jump_test is not None and self._jump_open:
            jump = self.jump_test(change_index, self._confirmed_at, index)
            if jump is None:  # too few samples of the excursion yet
                self._judge_from = index + 1
                return Judged.PENDING
            if jump.explained:
                self.excursion_ended()
                self.state_jumps += 1
                self.last_jump, self.jump_at = jump, index
                return Judged.EXPLAINED
            self._jump_open = False
        if self.noise_test is not None:
            noise = self.noise_test(change_index, index)
            if noise is None:  # judged on more samples
                self._judge_from = index + 1
                return Judged.PENDING
            if noise.explained:
                self.excursion_ended()
                self.noise_changes += 1
                self.last_noise, self.noise_at = noise, index
                return Judged.EXPLAINED
        self._confirmed_at = -1
        return Judged.DECLARED

    def _confirmed(self, change_index: int, alarm_index: int) -> bool:
        """Whether the check confirms the alarm; if not, its excursion is judged again later."""
        if self.check is None:
            return True
        self.last_verdict = self.check.judge(change_index, alarm_index)
        if self.last_verdict.confirmed:
            return True
        if self._judge_from < 0:  # the excursion's first refusal (reset when g returns to 0)
            self.unconfirmed_alarms += 1
        self._judge_from = alarm_index + self.check.judge_period
        return False
