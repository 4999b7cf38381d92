"""The rules each output-only route has its own (``core.options.OUTPUT_ONLY_METHODS``), in one table.

Every other rule of :mod:`.output_only` is shared by the three routes; the measurements behind
each entry are in docs/benchmarks-output-only.md.
"""

from __future__ import annotations

from dataclasses import dataclass

from okid_ros.core.output_only_var import VAR_ROUTE_WARNING

__all__ = ["OutputOnlyRoute", "ROUTES"]


@dataclass(frozen=True)
class OutputOnlyRoute:
    """The rules one route of ``OUTPUT_ONLY_METHODS`` has its own; every other rule is shared by the three.

    Attributes
    ----------
    canonical_lags : the lag window from the spectral peaks the record holds, the weighted Hankel
        bounded (:func:`~.output_covariance.choose_block_rows` ``held_peaks_only``, ``weighted``):
        the canonical-variate route's, measured (docs/benchmarks-output-only.md, forty-second and
        forty-third sessions); the covariance route lost with them.
    steady_frequency_std_per_width : a candidate whose jackknife frequency scatter is below this
        times ``zeta f`` (and its damping's below :data:`.output_only.STEADY_DAMPING_CV`) needs no spectral share:
        a weak mode beside a strong one of nearly its shape (two outputs, 9.65 Hz at 1.7 % under
        9.51 Hz at 0.45 %) has almost none but a steady pole. Noise poles that passed the noise
        limits scattered at least 1.8 (ssi-cov) and 1.3 (ssi-cva) times more; the var route takes
        the stricter limit (not measured on its own noise poles).
    screens_listed_std : listed modes screened again by their own standard deviations
        (:func:`~.output_only_support.listed_within_limits`): under ssi-cva a one-channel noise pole
        passed the screening and listed a std of 16.6 widths; 1065 true modes of the bench at most 1.
    low_band : the slowest modes re-estimated from a decimated record (:mod:`.output_only_low_band`).
    drops_unresolved_groups : a listed mode whose cluster stands for an unresolved group of modes
        (:func:`~.output_only_support.stands_for_a_group`) is not listed: under ssi-cva a plate's pole
        between a pair 0.65 % apart and its neighbour was listed 2.3 % off the nearest true mode.
    warning : said on every model of the route ("" for none).
    """

    canonical_lags: bool
    steady_frequency_std_per_width: float
    screens_listed_std: bool
    low_band: bool
    warning: str = ""
    drops_unresolved_groups: bool = False


#: Each output-only route's own rules, by its name in ``OUTPUT_ONLY_METHODS``.
ROUTES = {
    "ssi-cva": OutputOnlyRoute(canonical_lags=True, steady_frequency_std_per_width=0.3, screens_listed_std=True,
                               low_band=True, drops_unresolved_groups=True),
    "ssi-cov": OutputOnlyRoute(canonical_lags=False, steady_frequency_std_per_width=0.2, screens_listed_std=False,
                               low_band=True),
    "var": OutputOnlyRoute(canonical_lags=False, steady_frequency_std_per_width=0.2, screens_listed_std=False,
                           low_band=False, warning=VAR_ROUTE_WARNING),
}
