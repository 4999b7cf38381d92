"""The listed modes' standard deviations from a jackknife of more segments than the screening's.

The screening's jackknife (:class:`.output_only_support.Jackknife`) cuts the record into segments of
at least ten Hankel lag windows, which :func:`.output_covariance.choose_block_rows`'s record bound
holds to five on most records: each variance then has four degrees of freedom, and a difference of
two modes divided by their combined deviation is Student's t with about six, not the normal the
change test's limit assumes (docs/benchmarks-change.md, "The first stage's limit on stationary
records"). The canonical-variate route's replicates are the whole record's correlations less one
span (:meth:`.output_covariance.RecordSums.without`), which need no segment's own correlations, so
the listed modes' deviations are read from a second jackknife of shorter segments; the modes
screened and listed are the first one's.
"""

from __future__ import annotations

import numpy as np

from okid_ros.core.canonical_realization import canonical_replicates
from okid_ros.core.identified_model import IdentifiedModel
from okid_ros.core.output_covariance import OutputCorrelations, RecordSums
from okid_ros.core.uncertainty import UncertaintyResult

__all__ = ["STD_SEGMENTS", "FINER_SEGMENTS", "MIN_SEGMENT_LAGS", "std_segment_count", "std_spans", "std_replicates",
           "attach_finer_std"]

#: Most segments of the listed modes' standard deviations' jackknife by default: 0, the screening's. With
#: :data:`FINER_SEGMENTS` the change test's stationary tails beyond 4 deviations vanish, but the identification
#: takes 1.2-2.2 times the CPU (koma record 0.44 -> 0.78 s, behind koma's), docs/benchmarks-change.md.
STD_SEGMENTS = 0
FINER_SEGMENTS = 20
#: A segment of that jackknife spans at least this many of the Hankel's largest lag (2 block rows).
MIN_SEGMENT_LAGS = 2


def std_segment_count(n_samples: int, max_lag: int, most: int) -> int:
    """Segments of the standard deviations' jackknife: at most ``most``, each at least :data:`MIN_SEGMENT_LAGS` lags."""
    return int(max(0, min(most, n_samples // max(MIN_SEGMENT_LAGS * max_lag, 1))))


def std_spans(record: RecordSums, n_segments: int, present: np.ndarray | None) -> OutputCorrelations:
    """``n_segments`` consecutive spans of the record (a span without a present sample left out), no correlations.

    Only the spans and their weights are filled: the canonical-variate replicates take the
    record's sums less a span (:func:`.canonical_realization.canonical_replicates`).
    """
    n = record.y.shape[0]
    bounds = np.linspace(0, n, n_segments + 1).astype(int)
    spans = [(lo, hi) for lo, hi in zip(bounds[:-1], bounds[1:]) if present is None or present[lo:hi].any()]
    weights = np.array([hi - lo if present is None else present[lo:hi].sum() for lo, hi in spans], dtype=float)
    return OutputCorrelations(np.zeros((len(spans), 0, 0, 0)), weights, np.array(spans, dtype=int).reshape(-1, 2))


def std_replicates(record: RecordSums, n_segments: int, present: np.ndarray | None, references: np.ndarray,
                   block_rows: int, max_states: int):
    """(spans, ``replicate(j)``) of the standard deviations' jackknife (:func:`std_spans`)."""
    spans = std_spans(record, n_segments, present)
    return spans, canonical_replicates(record, spans, references, block_rows, max_states)


def attach_finer_std(model: IdentifiedModel, f_std: np.ndarray, z_std: np.ndarray, *, segments: int) -> None:
    """The listed modes' deviations ``f_std``, ``z_std`` (M,) from ``segments`` segments, where the low band gave none.

    A mode the decimated record re-estimated (:mod:`.output_only_low_band`, ``extras["decimation"]``)
    keeps that record's damping deviation, and its frequency's when it lists that record's frequency.
    Which modes are listed, their values and the low band's choice are the screening jackknife's.
    """
    for mode, fs, zs in zip(model.modes, f_std, z_std):
        low = "decimation" in mode.extras
        if not low or mode.frequency_hz == mode.extras["full_rate_frequency_hz"]:
            mode.frequency_hz_std = float(fs)
        if not low:
            mode.damping_ratio_std = float(zs)
    model.uncertainty = UncertaintyResult(True, "", 0, int(segments), method="jackknife")
