"""The modal estimation service's counters and health as one flat dict (node 2's diagnostics).

:meth:`okid_ros.service.estimation.ModalEstimationService.diagnostics` hands out what
:func:`estimation_diagnostics` gathers from the service's parts; the node publishes it as the
key-values of its DiagnosticStatus, ``okid-ros process`` keeps it in its summary.
"""

from __future__ import annotations

from typing import Any

from okid_ros.service.results import ActiveModel, EstimationStats
from okid_ros.service.sample_buffer import SampleBuffer

__all__ = ["estimation_diagnostics"]


def estimation_diagnostics(stats: EstimationStats, buffer: SampleBuffer, watch: dict[str, Any],
                           active: ActiveModel | None, *, model_id: int, busy: bool, request_waiting: bool,
                           enabled: bool) -> dict[str, Any]:
    """Counters and health as a flat dict.

    Parameters
    ----------
    stats : the service's counters; buffer : its sample buffer.
    watch : the change test's part (:meth:`okid_ros.service.watch.InnovationWatch.diagnostics`).
    active : the model in use (None before the first).
    model_id, busy, request_waiting, enabled : the service's state.
    """
    st = stats
    model = None if active is None else active.model
    return {
        "samples": st.samples,
        "rejected_samples": st.rejected_samples,
        "input_glitches": st.input_glitches,
        "buffer_samples": min(buffer.count, buffer.cap),
        "buffer_capacity": buffer.cap,
        "arx_models_received": st.arx_received,
        "arx_models_replaced": st.arx_replaced,
        "arx_models_refused": st.arx_refused,
        "arx_models_refused_why": st.arx_refused_text(),
        "arx_models_unchanged": st.arx_unchanged,
        "realizations": st.realizations,
        "models_accepted": st.models_accepted,
        "models_rejected": st.models_rejected,
        "models_applied_idle": st.models_applied_idle,
        "consecutive_rejections": st.consecutive_rejections,
        "last_model_accepted": st.last_accepted,
        "forced_accepts": st.forced_accepts,
        "last_reason": st.last_reason,
        "last_realization_time_s": st.last_realization_time_s,
        "last_window_samples": st.last_window_samples,
        "last_switch_jump": st.last_switch_jump,
        "max_switch_jump": st.max_switch_jump,
        "switches_measured": st.switches_measured,
        "gaps_bridged": st.gaps_bridged,
        "window_samples_filled": st.window_samples_filled,
        "estimator_restarts": st.estimator_restarts,
        "diverged_samples": st.diverged_samples,
        "divergence_restarts": st.divergence_restarts,
        "divergences_beyond_window": st.divergences_beyond_window,
        "state_jumps": st.state_jumps,
        # Samples the estimators left out as glitches (core/estimator.py, core/glitches.py), over the service's life.
        "estimator_glitches": st.estimator_glitches + (0 if active is None else active.estimator.glitches),
        **watch,  # the change test's state (service/watch.py)
        "changes_detected": st.changes_detected,
        "last_change_stamp_s": st.last_change_stamp_s,
        "last_change_statistic": st.last_change_statistic,
        "last_change_delay_samples": st.last_change_delay_samples,
        "windows_refused_for_change": st.windows_refused_for_change,
        "modes_retired": st.modes_retired,
        "model_id": model_id,
        "n_modes": 0 if active is None else active.n_modes,
        "n_states": 0 if model is None else model.n_states,
        "busy": busy,
        "arx_request_waiting": request_waiting,
        "enabled": enabled,
        "order_limit_reached": bool(model is not None and model.max_states_reached),
        "model_warnings": "" if model is None else "; ".join(model.warnings),
    }
