"""Long-run exactness and memory of the recursive ARX window over 10^6 samples.

Run:  python bench/recursive_drift.py [--samples N] [--check-every K]

Feeds N samples (default 10^6; d = 402: p = m = 2, q = 100; window W = 4000 rows) in blocks of
1000 and, every K samples, compares the coefficients solved from the window's normal equations
(``arx.solve_fixed_penalty``, fixed penalty, identity prior) with an independent batch solution
on exactly the window's rows (``numpy.linalg.lstsq`` of the stacked augmented
system ``[Phi; sqrt(penalty) L^T] Theta = [Y; 0]``). The outputs carry a large offset so that
the add/remove rounding is larger than with zero-mean data. The run is done twice: with the
default periodic refactorization, and with it switched off (to show what it prevents).
Prints the maximum relative deviation, the window's own memory (``memory_bytes``), the
memory traced by ``tracemalloc`` and the process RSS (first, second, largest and last checkpoint).
One BLAS thread.
"""

from __future__ import annotations

import argparse
import os

import checkout

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import time  # noqa: E402
import tracemalloc  # noqa: E402

import numpy as np  # noqa: E402
from scipy.signal import lfilter  # noqa: E402

checkout.add()
from okid_ros.core.arx import normal_equations, scaled_condition_number, solve_fixed_penalty  # noqa: E402
from okid_ros.core.recursive import SlidingWindowArx  # noqa: E402
from okid_ros.core.regressors import arx_regressors  # noqa: E402

Q, P, M, WINDOW, PENALTY, OFFSET = 100, 2, 2, 4000, 1e-2, 2.0


def make_data(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((n, M))
    y = 0.1 * rng.standard_normal((n, P)) + OFFSET
    for i in range(P):
        for j in range(M):
            y[:, i] += lfilter([0.0, rng.uniform(0.2, 1.0)], [1.0, -rng.uniform(0.3, 0.9)], u[:, j])
    return u, y


def rss_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def run(u: np.ndarray, y: np.ndarray, refactor_every: int | None, check_every: int) -> dict:
    est = SlidingWindowArx(Q, P, M, window=WINDOW, refactor_every=refactor_every)
    precision = np.eye(est.n_params)
    chol_t = np.linalg.cholesky(precision).T
    n = u.shape[0]
    worst, worst_fresh, cond, mem, traced, rss = 0.0, 0.0, 0.0, [], [], []
    tracemalloc.start()
    t0 = time.perf_counter()
    feed_s = 0.0
    for k0 in range(0, n, 1000):
        t1 = time.perf_counter()
        est.update(u[k0 : k0 + 1000], y[k0 : k0 + 1000])
        feed_s += time.perf_counter() - t1
        k = min(k0 + 1000, n)
        if k % check_every == 0 and k >= WINDOW + Q:
            theta = solve_fixed_penalty(est.normal_equations(), precision, PENALTY)
            # Memory first, before the reference allocates its own arrays.
            mem.append(est.memory_bytes())
            traced.append(tracemalloc.get_traced_memory()[0])
            rss.append(rss_bytes())
            phi, targets, _ = arx_regressors(u[k - WINDOW - Q : k], y[k - WINDOW - Q : k], Q)
            aug = np.vstack([phi, np.sqrt(PENALTY) * chol_t])
            rhs = np.vstack([targets, np.zeros((phi.shape[1], P))])
            ref = np.linalg.lstsq(aug, rhs, rcond=None)[0]
            worst = max(worst, float(np.linalg.norm(theta - ref) / np.linalg.norm(ref)))
            # The same normal equations formed afresh: isolates the drift of the recursion.
            fresh = solve_fixed_penalty(normal_equations(phi, targets), precision, PENALTY)
            worst_fresh = max(worst_fresh, float(np.linalg.norm(theta - fresh) / np.linalg.norm(fresh)))
            del phi, aug, rhs, ref, fresh
    cond = scaled_condition_number(est.normal_equations().R)
    tracemalloc.stop()
    return {
        "worst": worst,
        "worst_fresh": worst_fresh,
        "cond": cond,
        "checks": len(mem),
        "mem": (mem[0], mem[-1]),
        "traced": (traced[0], traced[1] if len(traced) > 1 else traced[0], max(traced), traced[-1]),
        "rss": (rss[0], rss[1] if len(rss) > 1 else rss[0], max(rss), rss[-1]),
        "refactorizations": est.status.refactorizations,
        "feed_us": feed_s / n * 1e6,
        "total_s": time.perf_counter() - t0,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=1_000_000)
    parser.add_argument("--check-every", type=int, default=50_000)
    args = parser.parse_args()
    u, y = make_data(args.samples)
    print(f"# recursive window over {args.samples} samples (d = 402, W = {WINDOW}, y offset {OFFSET})\n")
    print("| refactorization | checks | max rel. dev. vs batch lstsq | max rel. dev. vs fresh normal eq. "
          "| scaled cond(R) | refactorizations "
          "| window memory (MB) first -> last | traced (MB) first, second, max, last "
          "| RSS (MB) first, second, max, last "
          "| feed us/sample |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    mb = 1.0 / 2**20
    results = {}
    for label, every in (("every 100000 rows (default)", None), ("off", 10**15)):
        r = run(u, y, every, args.check_every)
        results[label] = r
        print(f"| {label} | {r['checks']} | {r['worst']:.2e} | {r['worst_fresh']:.2e} | {r['cond']:.3g} "
              f"| {r['refactorizations']} "
              f"| {r['mem'][0] * mb:.2f} -> {r['mem'][1] * mb:.2f} "
              f"| {', '.join(f'{x * mb:.2f}' for x in r['traced'])} "
              f"| {', '.join(f'{x * mb:.0f}' for x in r['rss'])} | {r['feed_us']:.1f} |")
    r = results["every 100000 rows (default)"]
    print()
    print(f"max_rel_deviation={r['worst']:.3e} drift={r['worst_fresh']:.3e} "
          f"memory_bytes={r['mem'][1]} flat={r['mem'][0] == r['mem'][1]}")


if __name__ == "__main__":
    main()
