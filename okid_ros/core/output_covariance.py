"""Output correlations of an ambient record and the lag window they are taken over.

Output-only identification starts from the output correlations
``R_k = E[y_{t+k} y_t^T]`` (p, p), k = 0 .. L (NExT: they are free responses of the structure
to its ambient excitation, ``R_k = C A^(k-1) G`` with ``G = E[x_{t+1} y_t^T]``). Three choices
are made from the data here:

- the **lag window**: long enough to span several periods of the slowest mode (a window
  shorter than one period merges close low modes, ``../shared/identification-findings.md``),
  from the lowest prominent peak of the output spectrum;
- the **reference channels**: with many outputs only the most independent channels serve as
  the Hankel's columns (pivoted QR of the normalized record);
- **segments**: the correlations of consecutive segments, whose mean is the record's
  estimate and whose spread gives the modes' standard deviations (jackknife).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import fft, linalg, signal

__all__ = [
    "OutputCorrelations",
    "output_correlations",
    "record_correlations",
    "RecordSums",
    "slowest_mode_hz",
    "choose_block_rows",
    "reference_channels",
]

#: The Hankel's block rows cover this many periods of the slowest mode (lags up to twice that).
PERIODS_PER_BLOCK_ROWS = 1.0
#: The correlations' lags stay below this fraction of a segment (their variance grows with lag).
MAX_LAG_FRACTION_OF_SEGMENT = 0.1
#: Peaks in the summed output spectrum at least this prominent (decades) count as modes.
PEAK_PROMINENCE_DECADES = 0.3
#: With ``held_peaks_only``, a peak sets the lag window only when the record holds at least this
#: many of its periods: a slower peak's period exceeds the record's cap on the block rows (a tenth
#: of a fifth of the record: a hundred periods at one period per block row), so its mode is not
#: resolved and, when the peak is a hump of drift or suspension motion below the modes, it only
#: sets the rows to that cap (the steel subframe's 7 Hz hump, 58 periods in its 8.3 s: 71 rows
#: where its lowest mode, 62 Hz, wants 17).
MIN_PEAK_PERIODS = 100.0
#: The canonical-variate route's weighted Hankel (``n_references i`` square) is at most this size:
#: its weights whiten the past and the future, so it needs fewer lags than the unweighted Hankel
#: for the same modes, and each of its decompositions costs ``(n_references i)^3``. The bound keeps
#: a margin over the smallest that lost accuracy on the bench's beams (docs/benchmarks-output-only.md,
#: forty-third session).
MAX_WEIGHTED_HANKEL = 1000


@dataclass
class OutputCorrelations:
    """Output correlations of a record, per segment.

    Attributes
    ----------
    segments : (S, L + 1, p, p) ``R_k`` of each segment, ``R_k[i, j] = mean(y_i[t + k] y_j[t])``.
    weights : (S,) samples of each segment (the record's estimate is the weighted mean).
    spans : (S, 2) each segment's first and past-the-end sample (None: not recorded).
    """

    segments: np.ndarray
    weights: np.ndarray
    spans: np.ndarray | None = None

    @property
    def mean(self) -> np.ndarray:
        """(L + 1, p, p) the record's correlations."""
        return np.tensordot(self.weights / self.weights.sum(), self.segments, axes=1)

    def leave_one_out(self, index: int) -> np.ndarray:
        """(L + 1, p, p) the correlations without segment ``index`` (jackknife)."""
        w = self.weights.copy()
        w[index] = 0.0
        return np.tensordot(w / w.sum(), self.segments, axes=1)


def _correlations(y: np.ndarray, max_lag: int, present: np.ndarray | None = None, *, biased: bool = False
                  ) -> np.ndarray:
    """(max_lag + 1, p, p) unbiased correlations of centred ``y`` (N, p), by FFT (N log N per pair).

    ``present`` (N,) bool: only the products of two present samples count (the lag's sum divided
    by the number of such pairs); ``y`` may hold anything at the other rows. ``biased``: every
    lag's sum divided by the present samples instead (a positive semidefinite sequence).
    """
    n = y.shape[0]
    nfft = _transform_length(n, max_lag)
    if present is not None:
        y = np.where(present[:, None], y, 0.0)
    if biased:
        pairs = np.full(max_lag + 1, float(n if present is None else max(present.sum(), 1)))
    elif present is None:
        pairs = n - np.arange(max_lag + 1.0)
    else:
        mask = np.fft.rfft(present.astype(float), nfft)
        pairs = np.maximum(np.rint(np.fft.irfft(mask * np.conj(mask), nfft)[: max_lag + 1]), 1.0)
    return _lag_sums(y, max_lag, nfft) / pairs[:, None, None]


def _transform_length(n_samples: int, max_lag: int) -> int:
    """The FFT length for lags up to ``max_lag`` of ``n_samples``: a power of two, no lag wrapped onto another."""
    return int(2 ** np.ceil(np.log2(n_samples + max_lag + 1)))


def _lag_sums(y: np.ndarray, max_lag: int, nfft: int, *, less: np.ndarray | None = None) -> np.ndarray:
    """(max_lag + 1, p, p) lag sums ``sum_t y_i[t + k] y_j[t]`` of ``y`` (N, p) by FFT of length ``nfft``.

    ``less`` (N, p): its lag sums are subtracted, in the cross spectra (one inverse transform for
    both). One inverse transform per channel pair ``i >= j``: its tail holds the negative lags,
    ``sum_t y_i[t - k] y_j[t]``, which are the pair ``(j, i)``'s; half the transforms of one per
    ordered pair, the same sums to rounding (docs/benchmarks-output-only.md, forty-fifth session).
    """
    p = y.shape[1]
    # Each channel's transform a contiguous row: scipy.fft's of rows are numpy.fft's of columns bit
    # for bit, in about half the time.
    spectrum = fft.rfft(np.ascontiguousarray(y.T), nfft, axis=1)  # (p, F)
    subtracted = None if less is None else fft.rfft(np.ascontiguousarray(less.T), nfft, axis=1)
    negative = (nfft - np.arange(max_lag + 1)) % nfft
    out = np.empty((max_lag + 1, p, p))
    for j in range(p):
        product = spectrum[j:] * np.conj(spectrum[j])
        if subtracted is not None:
            product -= subtracted[j:] * np.conj(subtracted[j])
        cross = fft.irfft(product, nfft, axis=1)  # (p - j, nfft): rows i = j .. p - 1
        out[:, j, j:] = cross[:, negative].T
        out[:, j:, j] = cross[:, : max_lag + 1].T  # on the diagonal the positive lags are kept
    return out


def output_correlations(y: np.ndarray, max_lag: int, n_segments: int = 8, *,
                        present: np.ndarray | None = None) -> OutputCorrelations:
    """Correlations ``R_0 .. R_max_lag`` of each of ``n_segments`` consecutive segments.

    Parameters
    ----------
    y : (N, p) outputs, means removed.
    max_lag : largest lag L (samples).
    n_segments : segments (at least 1; fewer when a segment would be shorter than
        ``max_lag / MAX_LAG_FRACTION_OF_SEGMENT``).
    present : (N,) bool, False at missing samples (a record with dropped readings): their
        lagged products are left out of every sum, so a filled value never enters the
        correlations (a prediction lacks the innovation's spread, which biases them), and each
        segment weighs by its present samples. None: every sample present.
    """
    n = y.shape[0]
    longest = int(n // max(max_lag / MAX_LAG_FRACTION_OF_SEGMENT, 1))
    n_segments = int(max(1, min(n_segments, longest)))
    bounds = np.linspace(0, n, n_segments + 1).astype(int)
    if present is not None and present.all():
        present = None
    spans = list(zip(bounds[:-1], bounds[1:]))
    if present is not None:  # a segment without a measured sample weighs nothing: its jackknife replicate was 0 / 0
        spans = [(lo, hi) for lo, hi in spans if present[lo:hi].any()]
    segments = np.stack([_correlations(y[lo:hi], max_lag, None if present is None else present[lo:hi])
                         for lo, hi in spans])
    weights = np.diff(bounds) if present is None else np.array([present[lo:hi].sum() for lo, hi in spans])
    return OutputCorrelations(segments, weights.astype(float), np.array(spans, dtype=int).reshape(-1, 2))


def record_correlations(y: np.ndarray, max_lag: int, *, present: np.ndarray | None = None) -> np.ndarray:
    """(max_lag + 1, p, p) biased correlations of the whole record: each lag's sum / the present samples.

    Their block Toeplitz matrices are positive semidefinite (the correlations of the record with
    its missing samples set to zero), as :mod:`.canonical_realization` needs; ``present`` as
    :func:`output_correlations`'s.
    """
    return _correlations(y, max_lag, present, biased=True)


@dataclass
class RecordSums:
    """The lag sums of a whole record, from which :func:`record_correlations` less one span follow cheaply.

    A jackknife replicate leaves a segment out: the pairs that touch it lie within ``max_lag`` of
    it, so its correlations are the record's sums less the stretch around the segment's sums
    with and without the segment, not a transform of the whole record again.
    """

    y: np.ndarray  # (N, p) missing samples set to zero
    max_lag: int
    correlations: np.ndarray  # (max_lag + 1, p, p) the whole record's, :func:`record_correlations`
    counted: np.ndarray  # (N + 1,) present samples before each index

    @classmethod
    def of(cls, y: np.ndarray, max_lag: int, present: np.ndarray | None = None) -> RecordSums:
        correlations = record_correlations(y, max_lag, present=present)
        present = np.ones(y.shape[0], bool) if present is None else present
        return cls(np.where(present[:, None], y, 0.0), int(max_lag), correlations, np.r_[0, np.cumsum(present)])

    @property
    def sums(self) -> np.ndarray:
        """(max_lag + 1, p, p) the whole record's lag sums."""
        return self.correlations * max(self.counted[-1], 1)

    def without(self, start: int, stop: int) -> np.ndarray:
        """(max_lag + 1, p, p) :func:`record_correlations` with samples ``start:stop`` absent too."""
        lo, hi, lag = int(start), int(stop), self.max_lag
        around = self.y[max(lo - lag, 0) : hi + lag]
        missed = around.copy()
        missed[lo - max(lo - lag, 0) : hi - max(lo - lag, 0)] = 0.0
        # The stretch's pairs less those that miss the span: those that touch it
        touching = _lag_sums(around, lag, _transform_length(around.shape[0], lag), less=missed)
        count = self.counted[-1] - (self.counted[hi] - self.counted[lo])
        return (self.sums - touching) / max(count, 1)


def slowest_mode_hz(y: np.ndarray, sample_time_s: float, *, held_peaks_only: bool = False) -> float:
    """Frequency (Hz) of the lowest prominent peak of the summed, normalized output spectrum.

    Welch spectrum with about 0.5 % of the sampling rate per bin or finer (at least 8 averages);
    the channels are scaled to unit variance so that every sensor counts. ``held_peaks_only``:
    only a peak the record holds :data:`MIN_PEAK_PERIODS` periods of counts. NaN when no peak
    stands out.
    """
    n = y.shape[0]
    scaled = y / np.maximum(y.std(axis=0), np.finfo(float).tiny)
    # At most the record (what welch takes, with a UserWarning, for a record shorter than 256 samples).
    nperseg = int(min(max(2 ** np.ceil(np.log2(200)), 2 ** np.floor(np.log2(max(n // 8, 16)))), 8192, n))
    freq, psd = signal.welch(scaled, fs=1.0 / sample_time_s, nperseg=nperseg, axis=0)
    total = np.log10(np.maximum(psd.sum(axis=1), np.finfo(float).tiny))
    peaks, _ = signal.find_peaks(total, prominence=PEAK_PROMINENCE_DECADES)
    peaks = peaks[peaks >= 2]  # the first bins hold the offsets and drifts, not a mode
    if held_peaks_only:
        peaks = peaks[freq[peaks] * n * sample_time_s >= MIN_PEAK_PERIODS]
    return float(freq[peaks[0]]) if peaks.size else float("nan")


def choose_block_rows(
    y: np.ndarray, sample_time_s: float, *, n_references: int, max_states: int, held_peaks_only: bool = False,
    weighted: bool = False
) -> tuple[int, float]:
    """Hankel block rows ``i`` (lags 1 .. 2 i) from the data, and the slowest mode found (Hz).

    ``i`` spans :data:`PERIODS_PER_BLOCK_ROWS` periods of the slowest mode, at least what the
    largest model order needs (``n_references i >= max_states + 2``), but at most a tenth of a
    fifth of the record and the Hankel at most 2000 rows. The record's bound keeps five segments
    for the jackknife, which tells modes from noise poles, and wins over the orders: with one or
    two channels and a short record the orders tried stop lower instead (1 channel, 6000
    samples: 60 block rows and orders to 60 rather than 103 rows, two segments, no jackknife and
    ~9 noise poles listed per record). It wins over the slowest mode's period as well (as it
    did before): a record shorter than about a hundred periods of its slowest spectral peak gets
    lags shorter than that period, which may lose that mode but lists no noise (with one channel
    the lowest "peak" is often noise, 0.15-2.2 Hz below a 3 Hz mode, and honouring it cost the
    jackknife). ``held_peaks_only`` (:func:`slowest_mode_hz`): a peak the record cannot hold does
    not set the rows, the next one does (the canonical-variate route's rule: measured, it wants
    the lags of the modes rather than the record's cap; the covariance route loses with it).
    ``weighted`` (the canonical-variate route): the Hankel is at most :data:`MAX_WEIGHTED_HANKEL`
    square as well (``n_references i``), a bound that wins over the slowest mode's period but not
    over the orders.
    """
    n, p = y.shape
    f_low = slowest_mode_hz(y, sample_time_s, held_peaks_only=held_peaks_only)
    fs = 1.0 / sample_time_s
    wanted = PERIODS_PER_BLOCK_ROWS * fs / f_low if np.isfinite(f_low) and f_low > 0 else 40.0
    needed = int(np.ceil((max_states + 2) / max(n_references, 1))) + 1
    cap = int(min(MAX_LAG_FRACTION_OF_SEGMENT * n / 5 / 2, 2000 // p))
    if weighted:
        wanted = min(wanted, MAX_WEIGHTED_HANKEL // max(n_references, 1))
    rows = int(min(max(np.ceil(wanted), needed), cap))
    return max(rows, 2), f_low


def reference_channels(y: np.ndarray, max_references: int) -> np.ndarray:
    """Indices of the ``max_references`` most independent outputs (all when p is small), sorted.

    Pivoted QR of the unit-variance record picks the channels that span it best; a Hankel with
    only these columns keeps every mode a reference sees and costs ``p / r`` times less.
    """
    p = y.shape[1]
    if p <= max_references:
        return np.arange(p)
    scaled = y / np.maximum(y.std(axis=0), np.finfo(float).tiny)
    step = max(1, y.shape[0] // 4000)  # 4000 rows rank the channels as well as all of them
    _, _, pivots = linalg.qr(scaled[::step], mode="economic", pivoting=True)
    return np.sort(pivots[:max_references])
