"""BLAS threads for the benchmarks, set before numpy loads.

Imported first by a benchmark script (``import blas_threads`` works because Python puts the
script's folder on ``sys.path``): ``--threads N`` on its command line, else 1, goes into
OMP_NUM_THREADS, OPENBLAS_NUM_THREADS and MKL_NUM_THREADS unless they are set already, so that
timings are comparable and the machine stays usable.
"""

from __future__ import annotations

import os
import sys


def threads_from_argv(argv: list[str]) -> str:
    """The value of ``--threads`` in ``argv`` (``--threads N`` or ``--threads=N``), else "1"."""
    threads = "1"
    for i, a in enumerate(argv):
        if a == "--threads" and i + 1 < len(argv):
            threads = argv[i + 1]
        elif a.startswith("--threads="):
            threads = a.split("=", 1)[1]
    return threads


def set_blas_threads(argv: list[str]) -> None:
    """Set the BLAS thread variables from ``argv`` (see the module docstring)."""
    threads = threads_from_argv(argv)
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, threads)


set_blas_threads(sys.argv[1:])
