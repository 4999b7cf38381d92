"""What each node does with one assembled sample, written once for the live nodes and ``okid-ros process``.

:func:`identification_step` for node 1, :func:`estimation_step` for node 2; the offline pipeline
(:class:`~okid_ros.service.windowed.WindowedPipeline`) runs both on one stream. A module of its own so
that node 1 does not import node 2's estimation (filterpy, scipy.stats) with them.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from okid_ros.service.grid_samples import RESTART_SKIP, GridSample

if TYPE_CHECKING:  # annotations only (see the module's docstring)
    from okid_ros.service.estimation import ModalEstimationService, ModalStatesResult
    from okid_ros.service.identification import ArxIdentificationService

__all__ = ["estimation_step", "identification_step"]


def identification_step(service: ArxIdentificationService, sample: GridSample) -> bool:
    """Node 1 with one sample: into the window (a gap breaks the lag history); accepted or not."""
    return service.push(sample.stamp_s, sample.u, sample.y, gap_before=sample.gap_before)


def estimation_step(service: ModalEstimationService, sample: GridSample) -> ModalStatesResult | None:
    """Node 2 with one sample: the estimator's step (a restart of the grid restarts it too)."""
    skipped = RESTART_SKIP if sample.restart else sample.skipped
    return service.step(sample.stamp_s, sample.u, sample.y, skipped)
