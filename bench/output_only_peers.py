"""Output-only identification by okid_ros and by its peers, one call each, modes as plain dicts.

Every method gets the centred record, the sample time, the Hankel block rows and the highest
model order, and returns its modes as ``{"frequency_hz", "damping_ratio", "shape", and
optionally "frequency_hz_std", "damping_ratio_std"}``:

* ``okid-ssi-cov`` / ``okid-var`` / ``okid-ssi-cva``: :func:`okid_ros.core.output_only.identify_output_only`
  with its defaults (block rows and orders from the data; the arguments are not used);
* ``pyoma2``: pyOMA2's ``SSI(method="cov")`` at the given block rows and orders 2..max (step 2),
  its automatic clustering with the "Magalhaes" preset (hierarchical, deterministic; most other
  presets draw unseeded random numbers, ``../shared/identification-findings.md``);
* ``koma``: ``koma.oma.covssi`` at the same block rows and orders, ``find_stable_poles``
  (stability level 2, criteria of koma's example) and its HDBSCAN ``PoleClusterer``
  (minimum cluster size 10, probability threshold 0.5, as koma's example).

The peers are bench dependencies only (``pyoma-2``, ``koma-python``).
"""

from __future__ import annotations

import contextlib
import io
import logging

import numpy as np

__all__ = ["METHODS", "run_method"]

METHODS = ("okid-ssi-cov", "okid-var", "pyoma2", "koma", "okid-ssi-cva")


def _okid(method: str):
    def run(y, dt, block_rows, max_states):
        from okid_ros.core.output_only import identify_output_only

        try:  # the threads `okid-ros identify` gives it (a tree before them: one)
            from okid_ros.tools.cores import identify_workers
            options = {"workers": identify_workers()}
        except ImportError:
            options = {}
        model = identify_output_only(y, dt, method=method, **options)
        return [{"frequency_hz": m.frequency_hz, "damping_ratio": m.damping_ratio, "shape": m.shape,
                 "frequency_hz_std": m.frequency_hz_std, "damping_ratio_std": m.damping_ratio_std}
                for m in model.modes]
    return run


def _pyoma2(y, dt, block_rows, max_states):
    from pyoma2.algorithms import SSI
    from pyoma2.algorithms.data.run_params import Clustering
    from pyoma2.setup import SingleSetup

    logging.getLogger("pyoma2").setLevel(logging.ERROR)
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        setup = SingleSetup(y, fs=1.0 / dt)
        algorithm = SSI(name="ssicov", method="cov", br=int(block_rows), ordmin=2, ordmax=int(max_states), step=2)
        setup.add_algorithms(algorithm)
        setup.run_by_name("ssicov")
        algorithm.add_clustering(Clustering(name="auto", quick="Magalhaes"))
        algorithm.run_clustering("auto")
        result = algorithm.result.clustering_results["auto"]
    fn, xi, phi = np.atleast_1d(result.Fn), np.atleast_1d(result.Xi), np.atleast_2d(result.Phi)
    return [{"frequency_hz": float(fn[k]), "damping_ratio": float(xi[k]), "shape": phi[:, k]}
            for k in range(fn.size)]


def _koma(y, dt, block_rows, max_states):
    from koma import clustering, oma

    orders = np.arange(2, int(max_states) + 2, 2)
    with contextlib.redirect_stdout(io.StringIO()):
        lambd, phi, orders_flat = oma.covssi(y, 1.0 / dt, int(block_rows), orders, showinfo=False)
        lambd_s, phi_s, orders_s, _ = oma.find_stable_poles(
            lambd, phi, orders_flat, 2, stabcrit={"freq": 0.05, "damping": 0.2, "mac": 0.3},
            valid_range={"freq": [0, np.inf], "damping": [0, 0.2]}, indicator="freq")
        if len(lambd_s) == 0:
            return []
        clusterer = clustering.PoleClusterer(lambd_s, phi_s, orders_s, min_cluster_size=10, min_samples=10)
        args = clusterer.postprocess(prob_threshold=0.5, normalize_and_maxreal=True)
        if len(args[0]) == 0:
            return []
        xi, omega_n, phi_c, *_ = clustering.group_clusters(*args)
    return [{"frequency_hz": float(np.median(w)) / (2 * np.pi), "damping_ratio": float(np.median(z)),
             "shape": np.median(ph, axis=1)} for z, w, ph in zip(xi, omega_n, phi_c)]


_RUNNERS = {"okid-ssi-cov": _okid("ssi-cov"), "okid-var": _okid("var"), "pyoma2": _pyoma2, "koma": _koma,
            "okid-ssi-cva": _okid("ssi-cva")}


def run_method(name: str, y: np.ndarray, sample_time_s: float, block_rows: int, max_states: int) -> list[dict]:
    """The modes found by method ``name`` (one of :data:`METHODS`) on the centred record ``y`` (N, p)."""
    return _RUNNERS[name](y, sample_time_s, block_rows, max_states)
