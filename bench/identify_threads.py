#!/usr/bin/env python3
"""``okid-ros identify`` with inputs, a base tree and this one in threads, and which LAPACK calls hold the GIL.

``--base BASE``: the command (defaults, input-output) run as a fresh process per call, the base
tree, this tree with one thread and with two (``tools.cores.identify_workers`` set), in turn on
each record, the first of the three changing every repeat; printed per record and tree: the
median wall and CPU seconds (user + system, both threads) of the whole command and the JSON's
``elapsed_s`` (the identification), and whether every JSON field but ``elapsed_s`` is the base's.

``--pieces RECORD``: the independent calls of the chain on one record (the jackknife's replicate
and its parts, each refinement), caught as the chain makes them, each called 16 times in one
thread and then in two (8 each): the speed-up and the CPU over the wall time of the two. Only
taken when a control (numpy products, which run side by side) shows two free cores before and
after (the machine is shared; the scheduler's autogroups give a session one core while another
session runs).

``--gil``: each LAPACK routine behind the chain's SciPy calls, called directly (no Python around
it), while a probe thread stamps the time in a Python loop: a stamp well inside a call (its
middle 80 %) means the GIL was free then. A call that holds it lets no Python run, whatever the
machine's load; one that releases it shows stamps as often as the probe gets a core.

Usage::

    git archive <commit> | tar -x -C BASE      # the base tree
    python bench/identify_threads.py --base BASE --records paper.bag,steel_subframe.npz --repeat 5
    python bench/identify_threads.py --pieces steel_subframe.npz
    python bench/identify_threads.py --gil
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import resource
import statistics
import subprocess
import sys
import threading
import time
from functools import partial
from pathlib import Path

TREE = Path(__file__).resolve().parent.parent
#: The command with its thread count set: ``python -c RUN THREADS identify ...``.
RUN = ("import sys; import okid_ros.tools.cores as c; c.identify_workers = lambda: int(sys.argv[1]); "
       "from okid_ros.cli import main; sys.exit(main(sys.argv[2:]))")


def _run(tree: Path, threads: int, record: str, out: Path) -> tuple[float, float, float, dict]:
    """Wall and CPU seconds of one ``okid-ros identify``, its ``elapsed_s`` and its JSON (without it)."""
    out.unlink(missing_ok=True)
    env = dict(os.environ, PYTHONPATH=str(tree), OPENBLAS_NUM_THREADS="1")
    before, start = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
    subprocess.run([sys.executable, "-c", RUN, str(threads), "identify", record, "--json", str(out)], cwd=tree,
                   env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall, after = time.perf_counter() - start, resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime
    document = json.loads(out.read_text())
    return wall, cpu, document.pop("elapsed_s"), document


def side_by_side(base: Path, records: list[str], repeat: int, out: Path) -> None:
    """Print the table of :func:`_run`'s medians per record and tree."""
    trees = [("base", base, 1), ("new, 1 thread", TREE, 1), ("new, 2 threads", TREE, 2)]
    runs: dict[tuple[str, str], list] = {}
    print("load average before:", " ".join(f"{x:.1f}" for x in os.getloadavg()), flush=True)
    for k in range(repeat):
        for record in records:
            for label, tree, threads in trees[k % 3:] + trees[: k % 3]:
                runs.setdefault((record, label), []).append(_run(tree, threads, record, out))
    print("load average after:", " ".join(f"{x:.1f}" for x in os.getloadavg()))
    print("| record | tree | wall s | CPU s | elapsed_s | JSON as the base's |\n|---|---|---|---|---|---|")
    for (record, label), found in runs.items():
        same = all(r[3] == runs[(record, "base")][0][3] for r in found)
        medians = [statistics.median(r[i] for r in found) for i in range(3)]
        print(f"| {Path(record).name} | {label} | {medians[0]:.2f} | {medians[1]:.2f} | {medians[2]:.2f} | {same} |")


def _released(call, calls: int = 20) -> tuple[float, float]:
    """Share of ``calls`` calls with a probe stamp in their middle 80 %, and the median call in ms."""
    stamps: list[float] = []
    stop = threading.Event()

    def probe() -> None:
        while not stop.is_set():
            stamps.append(time.perf_counter())

    thread = threading.Thread(target=probe)
    thread.start()
    spans = []
    for _ in range(calls):
        start = time.perf_counter()
        call()
        spans.append((start, time.perf_counter()))
    stop.set()
    thread.join()
    hits = 0
    for start, end in spans:
        inner = [t for t in stamps if start + 0.1 * (end - start) < t < end - 0.1 * (end - start)]
        hits += bool(inner)
    return hits / calls, 1e3 * statistics.median(end - start for start, end in spans)


def gil_table() -> None:
    """Print which LAPACK routines release the GIL (:func:`_released`), with controls."""
    import numpy as np
    from scipy.linalg import lapack

    sys.setswitchinterval(0.0002)
    rng = np.random.default_rng(0)
    tall = np.asfortranarray(rng.standard_normal((900, 450)))
    square = np.asfortranarray(rng.standard_normal((250, 250)))
    m = rng.standard_normal((700, 700))
    spd, rhs = np.asfortranarray(m @ m.T + 700 * np.eye(700)), np.asfortranarray(m[:, :300])
    calls = [("control: a Python loop (stamps at switches)", lambda: sum(i * i for i in range(200000))),
             ("control: numpy matmul (releases)", lambda: tall.T @ tall),
             ("dgesdd (scipy.linalg.svd)", lambda: lapack.dgesdd(tall, full_matrices=0)),
             ("dsyevd (scipy.linalg.eigh)", lambda: lapack.dsyevd(spd)),
             ("dgeqrf (scipy.linalg.qr)", lambda: lapack.dgeqrf(tall)),
             ("dgeev (scipy.linalg.eig)", lambda: lapack.dgeev(square)),
             ("dpotrf (scipy.linalg.cholesky, cho_factor)", lambda: lapack.dpotrf(spd, lower=1)),
             ("dpotrs (scipy.linalg.cho_solve)", lambda: lapack.dpotrs(lapack.dpotrf(spd)[0], rhs)),
             ("dsytrd (core/symmetric_eigen)", lambda: lapack.dsytrd(spd)),
             ("numpy.linalg.svd", lambda: np.linalg.svd(tall, full_matrices=False))]
    print("| call | calls with the GIL free inside | median call ms |\n|---|---|---|")
    for name, call in calls:
        share, ms = _released(call)
        print(f"| {name} | {share:.0%} | {ms:.0f} |", flush=True)
    print("load average:", " ".join(f"{x:.1f}" for x in os.getloadavg()))


def _in_threads(call, calls: int) -> tuple[float, float, float]:
    """Wall seconds of ``calls`` calls in one thread, in two, and the CPU over the wall time of the two."""
    call()
    walls, ratio = [], 0.0
    for threads in (1, 2):
        workers = [threading.Thread(target=lambda: [call() for _ in range(calls // threads)]) for _ in range(threads)]
        start, cpu = time.perf_counter(), time.process_time()
        for worker in workers:
            worker.start()
        for worker in workers:
            worker.join()
        walls.append(time.perf_counter() - start)
        ratio = (time.process_time() - cpu) / walls[-1]
    return walls[0], walls[1], ratio


def _caught(record: str) -> dict:
    """The chain's independent calls on ``record`` (name: a call without arguments), caught as it makes them."""
    import numpy as np

    from okid_ros.core import mode_jackknife, pipeline
    from okid_ros.tools.bag_record import load_any_record

    caught: dict = {}  # name: (function, args, kwargs) of its first call

    def catching(name, function):
        def call(*args, **kwargs):
            caught.setdefault(name, (function, args, kwargs))
            return function(*args, **kwargs)
        return call

    jk = mode_jackknife  # a replicate: its segment's Gram, its ARX fit, its realization (subspace, regression)
    jk.segment_lagged_gram = catching("jackknife: a segment's lagged Gram", jk.segment_lagged_gram)
    jk._ArxWindow.without = catching("jackknife: a replicate's ARX fit (Cholesky)", jk._ArxWindow.without)
    jk._leading_subspace = catching("jackknife: leading subspace (scipy.linalg.svd)", jk._leading_subspace)
    jk._regressed_poles = catching("jackknife: state regression and poles", jk._regressed_poles)
    jk._realized_poles = catching("jackknife: realization (subspace and regression)", jk._realized_poles)
    refine, count = pipeline.refine_prediction_error, itertools.count()

    def refinement(*args, **kwargs):
        return catching(f"refinement {next(count)}", refine)(*args, **kwargs)

    pipeline.refine_prediction_error = refinement
    loaded = load_any_record(record)[0]
    pipeline.identify(loaded.u, loaded.y, loaded.sample_time_s)
    subspace = caught.get("jackknife: leading subspace (scipy.linalg.svd)")
    if subspace:  # the same product by numpy's SVD
        h0, weight = subspace[1][:2]
        caught["jackknife: numpy.linalg.svd of the same"] = (np.linalg.svd, (h0 @ weight,), {"full_matrices": False})
    return {name: partial(function, *args, **kwargs) for name, (function, args, kwargs) in caught.items()}


def pieces(record: str, calls: int = 16) -> None:
    """Print :func:`_in_threads` of each of :func:`_caught`'s calls, on two free cores only."""
    import numpy as np

    product = np.random.default_rng(0).standard_normal((2000, 300))

    def control():
        return product.T @ product

    print("| call | ms per call | two threads: speed-up | CPU / wall | control CPU / wall before, after |")
    print("|---|---|---|---|---|")
    for name, call in {**_caught(record), "control: numpy product": control}.items():
        for _ in range(30):
            before = _in_threads(control, calls)[2]
            one, two, ratio = _in_threads(call, calls)
            after = _in_threads(control, calls)[2]
            if min(before, after) > 1.8:
                break
            time.sleep(2)
        print(f"| {name} | {1e3 * one / calls:.0f} | {one / two:.2f} | {ratio:.2f} | {before:.2f}, {after:.2f} |",
              flush=True)
    print("load average:", " ".join(f"{x:.1f}" for x in os.getloadavg()))


def main() -> None:
    """Parse the options and run the side-by-side timing or the GIL table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", type=Path, help="the base tree (git archive)")
    parser.add_argument("--records", default="", help="comma-separated records (bag, .npz)")
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--out", type=Path, default=Path("/tmp/identify_threads.json"))
    parser.add_argument("--gil", action="store_true", help="which LAPACK calls hold the GIL")
    parser.add_argument("--pieces", metavar="RECORD", help="the chain's independent calls in two threads")
    args = parser.parse_args()
    if args.gil:
        gil_table()
    if args.pieces:
        pieces(args.pieces)
    if args.base:
        side_by_side(args.base.resolve(), [str(Path(r).resolve()) for r in args.records.split(",") if r], args.repeat,
                     args.out)


if __name__ == "__main__":
    main()
