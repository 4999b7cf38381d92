"""Speed of the recursive ARX window (okid_ros.core.recursive) against the classic methods.

Run:  python bench/recursive_speed.py [--threads N] [--quick]

One BLAS thread by default (OPENBLAS_NUM_THREADS / OMP_NUM_THREADS / MKL_NUM_THREADS are set
before numpy is imported; ``--threads 2`` to compare). Prints markdown tables:

1. microseconds per sample at d = 402 (p = m = 2, q = 100) and d = 162 (q = 40), window
   W = 4000 rows, once the window is full (every sample adds one row and removes one):
   - ``push``: the window fed one sample per call (as the identification service feeds it);
   - ``update(100)``: the same fed blocks of 100 samples (as ``okid-ros track`` feeds it);
   - refactorization (recompute of G from the window every ``refactor_every`` rows), amortized;
   - a fixed-penalty solve of the window's normal equations (``arx.solve_fixed_penalty``,
     Cholesky) and the per-sample cost when solving every 250 samples;
   - the service's fit of the window (``arx.fit_from_normal_equations``, ridge prior, penalty by
     GCV: what node 1 runs at its publish rate);
   - classic RLS: the per-sample covariance update ``P <- (P - g phi^T P) / lambda``, O(d^2);
   - ``numpy.linalg.lstsq`` of the whole window at each sample: timed on a few windows and
     reported per sample as the time of one solve (each new sample needs one): extrapolated.
2. a scaling curve over the number of outputs p in (2, 4, 8, 16, 32) at m = 2, q = 40.

The last line is ``d=402 us_per_sample=<push figure>`` for the window.
"""

from __future__ import annotations

import argparse
import os

import checkout

_parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
_parser.add_argument("--threads", type=int, default=1, help="BLAS threads (default 1)")
_parser.add_argument("--quick", action="store_true", help="fewer samples (for a smoke run)")
_args = _parser.parse_args()
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = str(_args.threads)

import time  # noqa: E402

import numpy as np  # noqa: E402
from scipy.linalg import blas  # noqa: E402

checkout.add()
from okid_ros.core.arx import fit_from_normal_equations, solve_fixed_penalty  # noqa: E402
from okid_ros.core.recursive import SlidingWindowArx  # noqa: E402
from okid_ros.core.regressors import arx_regressors, regressor_length  # noqa: E402

WINDOW = 4000


def make_data(n: int, p: int, m: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """White inputs, outputs a sum of first-order responses plus noise (well excited)."""
    from scipy.signal import lfilter

    rng = np.random.default_rng(seed)
    u = rng.standard_normal((n, m))
    y = 0.1 * rng.standard_normal((n, p))
    for i in range(p):
        for j in range(m):
            y[:, i] += lfilter([0.0, rng.uniform(0.2, 1.0)], [1.0, -rng.uniform(0.3, 0.9)], u[:, j])
    return u, y


def filled(q: int, p: int, m: int, u: np.ndarray, y: np.ndarray) -> SlidingWindowArx:
    est = SlidingWindowArx(q, p, m, window=WINDOW)
    est.update(u[: WINDOW + q], y[: WINDOW + q])
    est.normal_equations()
    return est


def segments(n: int, repeats: int) -> list[slice]:
    """``repeats`` consecutive slices of a run of ``n`` samples."""
    size = n // repeats
    return [slice(i * size, (i + 1) * size) for i in range(repeats)]


def time_push(est: SlidingWindowArx, u: np.ndarray, y: np.ndarray, repeats: int = 5) -> tuple[float, float]:
    """Best and median us/sample over ``repeats`` segments.

    The machine is shared: the minimum is the figure least disturbed by other processes, the
    median shows the spread.
    """
    push, per = est.push, []
    for seg in segments(u.shape[0], repeats):
        us, ys = u[seg], y[seg]
        t0 = time.perf_counter()
        for k in range(us.shape[0]):
            push(us[k], ys[k])
        est._flush()
        per.append((time.perf_counter() - t0) / us.shape[0] * 1e6)
    return min(per), float(np.median(per))


def time_update(
    est: SlidingWindowArx, u: np.ndarray, y: np.ndarray, block: int = 100, repeats: int = 5
) -> tuple[float, float]:
    per = []
    for seg in segments(u.shape[0], repeats):
        us, ys = u[seg], y[seg]
        t0 = time.perf_counter()
        for k in range(0, us.shape[0], block):
            est.update(us[k : k + block], ys[k : k + block])
        est._flush()
        per.append((time.perf_counter() - t0) / us.shape[0] * 1e6)
    return min(per), float(np.median(per))


def time_solve(est: SlidingWindowArx, repeats: int = 5) -> float:
    """Best of ``repeats`` fixed-penalty solves of the window's normal equations, ms."""
    precision = np.eye(est.n_params)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        solve_fixed_penalty(est.normal_equations(), precision, 1e-3)
        times.append(time.perf_counter() - t0)
    return min(times) * 1e3


def time_service_fit(est: SlidingWindowArx, repeats: int = 3) -> float:
    """Best of ``repeats`` fits as the identification service runs them (ridge, GCV), ms."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fit_from_normal_equations(est.normal_equations(), est.order, est.n_outputs, est.n_inputs, "ridge", "gcv")
        times.append(time.perf_counter() - t0)
    return min(times) * 1e3


def time_refactor(est: SlidingWindowArx, repeats: int = 3) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        est.refactor()
        times.append(time.perf_counter() - t0)
    return min(times) * 1e3


def time_classic_rls(phi: np.ndarray, targets: np.ndarray, lam: float = 0.999) -> float:
    """Per-sample RLS with forgetting: gain, coefficient and covariance update, O(d^2)."""
    d, p = phi.shape[1], targets.shape[1]
    P = 1e3 * np.eye(d)
    theta = np.zeros((d, p))
    per = []
    for seg in segments(phi.shape[0], 3):
        t0 = time.perf_counter()
        for x, target in zip(phi[seg], targets[seg]):
            Px = P @ x
            g = Px / (lam + x @ Px)
            theta += np.outer(g, target - x @ theta)
            P -= np.outer(g, Px)  # P is symmetric, so g (P x)^T == g x^T P
            P *= 1.0 / lam
        per.append((time.perf_counter() - t0) / (seg.stop - seg.start) * 1e6)
    return min(per)


def time_lstsq(phi: np.ndarray, targets: np.ndarray, repeats: int) -> float:
    """One lstsq of a full window (W x d) per new sample: ms per solve = ms per sample."""
    times = []
    for i in range(repeats):
        t0 = time.perf_counter()
        np.linalg.lstsq(phi[i : i + WINDOW], targets[i : i + WINDOW], rcond=None)
        times.append(time.perf_counter() - t0)
    return min(times) * 1e6


def syrk_gflops(D: int, k: int = 128) -> float:
    a = np.random.default_rng(0).standard_normal((k, D))
    c = np.zeros((D, D), order="F")
    best = 0.0
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(5):
            c = blas.dsyrk(1.0, a.T, beta=1.0, c=c, trans=0, lower=0, overwrite_c=1)
        best = max(best, 5 * k * D * D / (time.perf_counter() - t0) / 1e9)
    return best


def main() -> None:
    quick = _args.quick
    n_meas = 2500 if quick else 10000
    print(f"# recursive ARX window speed (W = {WINDOW} rows, BLAS threads = {_args.threads})\n")
    print("Times are the best of 5 segments, the median in parentheses (the machine is shared).\n")
    print("| d | p | m | q | push (us/sample) | update(100) (us/sample) | refactor (ms; amortized us/sample) "
          "| solve (ms) | push + solve every 250 (us/sample) | service fit, ridge GCV (ms) | classic RLS (us/sample) "
          "| lstsq of window per sample (us/sample, extrapolated) | dsyrk bound (us/sample) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    push_402 = None
    for q in (100, 40):
        p, m = 2, 2
        d = regressor_length(q, p, m)
        u, y = make_data(WINDOW + q + 2 * n_meas, p, m)
        est = filled(q, p, m, u, y)
        sl = slice(WINDOW + q, WINDOW + q + n_meas)
        push_us, push_med = time_push(est, u[sl], y[sl])
        sl2 = slice(WINDOW + q + n_meas, WINDOW + q + 2 * n_meas)
        update_us, update_med = time_update(est, u[sl2], y[sl2])
        refactor_ms = time_refactor(est)
        amortized = refactor_ms * 1e3 / est.refactor_every
        solve_ms = time_solve(est)
        fit_ms = time_service_fit(est, 2 if quick else 3)
        phi, targets, _ = arx_regressors(u[: WINDOW + 400], y[: WINDOW + 400], q)
        rls_us = time_classic_rls(phi[: 600 if quick else 2000], targets[: 600 if quick else 2000])
        lstsq_us = time_lstsq(phi, targets, 3 if quick else 5)
        D = (q + 1) * (p + m)
        gflops = syrk_gflops(D)
        bound_us = 2 * D * D / (gflops * 1e9) * 1e6  # one row in, one row out
        print(f"| {d} | {p} | {m} | {q} | {push_us:.1f} ({push_med:.1f}) | {update_us:.1f} ({update_med:.1f}) "
              f"| {refactor_ms:.1f}; {amortized:.2f} "
              f"| {solve_ms:.2f} | {push_us + amortized + solve_ms * 1e3 / 250:.1f} | {fit_ms:.0f} | {rls_us:.0f} "
              f"| {lstsq_us:.0f} | {bound_us:.1f} ({gflops:.0f} GFlop/s) |")
        if d == 402:
            push_402 = push_us + amortized
    print()
    print("## scaling over outputs (m = 2, q = 40, W = 4000)\n")
    print("| p | d | D = d + p | push (us/sample) | update(100) (us/sample) | dsyrk bound (us/sample) |")
    print("|---|---|---|---|---|---|")
    q, m = 40, 2
    n_scale = 1500 if quick else 4000
    for p in (2, 4, 8, 16, 32):
        d = regressor_length(q, p, m)
        D = (q + 1) * (p + m)
        u, y = make_data(WINDOW + q + 2 * n_scale, p, m, seed=p)
        est = filled(q, p, m, u, y)
        push_us, push_med = time_push(est, u[WINDOW + q : WINDOW + q + n_scale], y[WINDOW + q : WINDOW + q + n_scale])
        update_us, update_med = time_update(est, u[WINDOW + q + n_scale :], y[WINDOW + q + n_scale :])
        bound_us = 2 * D * D / (syrk_gflops(D) * 1e9) * 1e6
        print(f"| {p} | {d} | {D} | {push_us:.1f} ({push_med:.1f}) | {update_us:.1f} ({update_med:.1f}) "
              f"| {bound_us:.1f} |")
    print()
    print(f"d=402 us_per_sample={push_402:.1f}")


if __name__ == "__main__":
    main()
