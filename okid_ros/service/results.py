"""What the modal estimation service hands out and passes between its parts (node 2).

:class:`ModalStatesResult` per sample (with a :class:`ModelUpdate` when a model was accepted
at it and a :class:`StructuralChangeEvent` when a change was declared or re-identified), an
:class:`IdleSwitch` when a model is accepted while no samples arrive, and the
:class:`RealizationJob` / :class:`RealizationOutcome` of a model update, which cross to a
worker thread or process. The serialized shapes of these (JSON lines, messages, CSV):
:mod:`okid_ros.service.records`.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from okid_ros.core.arx import ArxFit
from okid_ros.core.identified_model import IdentifiedModel
from okid_ros.core.modal import Mode
from okid_ros.service.options import ModalEstimationParams

if TYPE_CHECKING:  # a field's type only: the estimator's filterpy pulls in scipy.stats, which node 1 never needs
    from okid_ros.core.estimator import ModalStateEstimator

__all__ = [
    "ActiveModel",
    "BufferedWindow",
    "EstimationStats",
    "IdleSwitch",
    "ModalStatesResult",
    "ModelUpdate",
    "RealizationJob",
    "RealizationOutcome",
    "StructuralChangeEvent",
    "count_why",
    "why_text",
]


@dataclass
class ModelUpdate:
    """An accepted model, as ``StateSpaceModel`` carries it."""

    model: IdentifiedModel
    model_id: int
    arx_model_id: int
    stamp_s: float  # newest sample of the window it was identified from
    modes: list[Mode]  # physical modes with persistent ids, in state order
    realization_time_s: float
    window_samples: int


@dataclass
class IdleSwitch:
    """A model accepted while no samples arrived (``ModalEstimationService.apply_ready_if_idle``).

    Attributes
    ----------
    update : the accepted model, to publish as one accepted at a sample.
    change : the structural change it is the first model after, if any (``modes_after`` set).
    stamp_s : stamp of the newest buffered sample; the switch is after it [s].
    """

    update: ModelUpdate
    change: StructuralChangeEvent | None
    stamp_s: float


@dataclass
class StructuralChangeEvent:
    """A structural change declared by the innovation monitor, as ``StructuralChange`` carries it.

    Reported twice: when it is declared (``modes_after`` empty) and when the first model
    identified from post-change data only is accepted (``modes_after`` set).

    Attributes
    ----------
    change_id : 1 for the first change since start or reset, then 2, ...
    stamp_s : stamp of the sample at which the change was declared [s].
    change_stamp_s : estimated stamp of the first sample of the new structure [s].
    statistic, threshold : the CUSUM statistic at the declaration and its threshold [nats].
    variance_ratio : mean normalized innovation power since the change point (1: no change).
    modes_before : the modes of the model in use when the change was declared.
    modes_after : the modes of the first model of the new structure (empty until accepted).
    retired_ids : ids of the modes before that no mode after matched (retired).
    detection_delay_samples : samples from the change point to the declaration.
    """

    change_id: int
    stamp_s: float
    change_stamp_s: float
    statistic: float
    threshold: float
    variance_ratio: float
    modes_before: list[Mode]
    modes_after: list[Mode] = field(default_factory=list)
    retired_ids: list[int] = field(default_factory=list)
    detection_delay_samples: int = 0
    change_index: int = -1  # buffer index of the change point (internal)


@dataclass
class ModalStatesResult:
    """The estimate for one sample, as ``ModalStates`` carries it.

    Attributes
    ----------
    stamp_s : the sample's stamp [s].
    model_id : id of the model that produced it.
    modes : the model's physical modes (persistent ids), in the order of ``coordinates``.
    coordinates : (n_modes, 2) normalized modal states.
    y_estimated : (p,) ``C x + D u`` (filtered).
    innovation : (p,) ``y - C xhat - D u`` (one-step prediction error).
    update : the model accepted at this sample, if any (publish it before the states).
    change : a structural change declared or re-identified at this sample, if any.
    """

    stamp_s: float
    model_id: int
    modes: list[Mode]
    coordinates: np.ndarray
    y_estimated: np.ndarray
    innovation: np.ndarray
    update: ModelUpdate | None = None
    change: StructuralChangeEvent | None = None


@dataclass(frozen=True)
class BufferedWindow:
    """A job's window as buffered: what :func:`~okid_ros.service.realization.realize` prepares first.

    The filling of short gaps and spikes (:func:`okid_ros.core.realization_window.realization_window`)
    runs in the realization's worker, not under the lock the sample path waits for.

    Attributes
    ----------
    skipped : (N,) missing slots just before each of the job's samples (< 0: a time restart).
    need : the window's samples (ARX rows plus order).
    refit : the samples are not those the fit was made of (a re-zero taken off): refit it.
    """

    skipped: np.ndarray
    need: int
    refit: bool = False


#: Generations of realization jobs, unique across services: a node reconfigured (a lifecycle cleanup
#: and configure) has a new service, which took the outcome of its predecessor's job still running
#: when both counted from 0 (a model of the window before the cleanup, applied after activate).
JOB_GENERATIONS = itertools.count()


@dataclass
class RealizationJob:
    """Everything :meth:`ModalEstimationService.run_job` needs (a copy; thread-safe)."""

    fit: ArxFit
    arx_model_id: int
    stamp_end_s: float
    u: np.ndarray
    y: np.ndarray
    end_index: int  # absolute buffer index of the window's last sample
    params: ModalEstimationParams
    generation: int = 0  # outcomes of jobs taken before a reset, or by another service, are dropped
    valid: np.ndarray | None = None  # (N,) False at samples filled in short gaps (core/gap_fill.py)
    order_hint: int | None = None  # the order of the model in use: warm-starts the order search
    buffered: BufferedWindow | None = None  # set: u, y as buffered, prepared by realize(); None: as realized

    @property
    def first_index(self) -> int:
        """Absolute buffer index of the window's first sample (filled samples are not buffered)."""
        received = self.u.shape[0] if self.valid is None else int(np.count_nonzero(self.valid))
        return self.end_index - received + 1


@dataclass
class RealizationOutcome:
    """Result of :meth:`ModalEstimationService.run_job`.

    ``model`` is None when the realization failed its checks (``reason``); otherwise
    ``state`` is the new model's predicted state for the sample after ``last_index``.
    ``whiten`` (from the realization's check) and ``estimator`` (made by :meth:`follow`) are
    the parts of the switch that need only the model, prepared off the sample path.
    """

    job: RealizationJob
    model: IdentifiedModel | None
    reason: str = ""
    state: np.ndarray | None = None
    last_index: int = -1
    last_input: np.ndarray | None = None
    realization_time_s: float = 0.0
    warm_start_samples: int = 0
    whiten: np.ndarray | None = None
    estimator: ModalStateEstimator | None = None
    window_filled: int = 0  # slots of the window filled by prediction (gaps, spikes)


@dataclass
class ActiveModel:
    """The model in use, its estimator and its modes with their ids."""

    model: IdentifiedModel
    estimator: ModalStateEstimator
    model_id: int
    modes: list[Mode]
    n_modes: int
    whiten: np.ndarray  # (p, p) inverse Cholesky factor of the innovation covariance
    window_samples: int


class RefusedArx:
    """Why node 2 refuses an ArxModel (:meth:`EstimationStats.refuse_arx`), as "N ..." reads them."""

    DIMENSIONS = "of other dimensions than node 2's"
    STAMP = "without a stamp"
    FUTURE = "whose window ends far after node 2's newest sample"
    BUFFER = "whose window node 2's buffer cannot hold"
    NO_SAMPLE = "whose window's end node 2 holds no sample at or before"
    CHANGE = "whose window starts before a structural change"
    GAP = "with too few samples after a gap (or a time jump) in their window"
    SHORT = "whose window is shorter than a realization needs"
    NOT_HELD = "of whose window node 2 holds too few samples (started or reset within it)"


@dataclass
class EstimationStats:
    """Counters of the estimation service (its diagnostics)."""

    samples: int = 0
    rejected_samples: int = 0
    input_glitches: int = 0  # of them: an input absurdly far beyond its spread (core/input_glitches.py)
    arx_received: int = 0
    arx_replaced: int = 0
    arx_refused: int = 0
    arx_unchanged: int = 0
    realizations: int = 0
    models_accepted: int = 0
    models_rejected: int = 0
    models_applied_idle: int = 0  # accepted while no samples arrived (apply_ready_if_idle)
    consecutive_rejections: int = 0
    forced_accepts: int = 0
    estimator_restarts: int = 0
    gaps_bridged: int = 0
    window_samples_filled: int = 0
    last_reason: str = ""
    last_accepted: bool = False
    last_realization_time_s: float = math.nan
    last_window_samples: int = 0
    last_switch_jump: float = math.nan
    max_switch_jump: float = 0.0
    switches_measured: int = 0
    diverged_samples: int = 0
    divergence_restarts: int = 0
    divergences_beyond_window: int = 0  # divergences after a restart not declared: an input beyond the model's window
    state_jumps: int = 0  # divergences explained as a jump of the state (estimator corrected, no restart)
    estimator_glitches: int = 0  # glitches the estimators of replaced models left out (estimator.py)
    changes_detected: int = 0
    windows_refused_for_change: int = 0
    last_change_stamp_s: float = math.nan
    last_change_statistic: float = math.nan
    last_change_delay_samples: int = 0
    modes_retired: int = 0
    #: ArxModels refused, by why (a RefusedArx phrase) -> (count, the last one's reason in full).
    arx_refused_why: dict = field(default_factory=dict)

    def refuse_arx(self, why: str, reason: str) -> None:
        """Count an ArxModel refused for ``why`` (a :class:`RefusedArx` phrase); ``reason`` says it in full."""
        self.arx_refused += 1
        self.last_reason = reason
        count_why(self.arx_refused_why, why, reason)

    def arx_refused_text(self) -> str:
        """"N WHY (the last: REASON); ..." of the refused ArxModels ("" if none)."""
        return why_text(self.arx_refused_why)


def count_why(counts: dict, why: str, reason: str) -> None:
    """Count one refusal for ``why`` in ``counts`` (why -> (count, the last one's reason)), ``reason`` in full."""
    counts[why] = (counts.get(why, (0, ""))[0] + 1, reason)


def why_text(counts: dict) -> str:
    """"N WHY (the last: REASON); ..." of refusals counted by :func:`count_why` ("" if none)."""
    return "; ".join(f"{count} {why} (the last: {reason})" for why, (count, reason) in counts.items())
