#!/usr/bin/env python3
"""What glitches or a sensor re-zero in one output do to the live chain: node 1's window and node 2's models.

The paper's structure (2 inputs low-passed at 15 Hz, 2 outputs, 20000 samples, its three modes
known) run through both nodes' services as ``okid-ros process`` and the live nodes run them
(ARX order 50, window 3750 rows, a model every 500 samples): clean, and with a fault in one
output (chosen at random per seed) of ``SIZE`` output spreads. ``--fault glitch`` (default):
ten samples that far off (interference, a telemetry bit error). ``--fault step``: the output's
level steps by that much at sample 10123 and stays (a sensor re-zeroed, a cable replugged).
Per size over ``--seeds`` records: true modes found within 0.5 % over all model updates, modes
listed beside them (spurious), updates, structural changes declared, the samples node 1 took
for glitches and the level steps node 2 took off its samples. Run it with ``PYTHONPATH`` at an
older tree to compare (``checkout``).

Usage::

    python bench/live_glitches.py                       # sizes 0 30 300, 3 seeds: about 3 minutes
    python bench/live_glitches.py --sizes 0 100 --seeds 5 --out /tmp/glitches.md [--force]
    python bench/live_glitches.py --fault step --sizes 0 1 3 10 30
"""

from __future__ import annotations

import argparse
import sys

import blas_threads  # noqa: F401  (sets the BLAS threads before numpy loads)
import checkout

checkout.add()

import numpy as np  # noqa: E402

from okid_bench.live_chain import chain_modes  # noqa: E402
from okid_bench.report import add_output_options, print_table, refuse_existing  # noqa: E402
from okid_ros.sim.inputs import lowpass_input  # noqa: E402
from okid_ros.sim.paper_model import paper_model  # noqa: E402
from okid_ros.sim.simulators import simulate_innovation  # noqa: E402

N_SAMPLES, N_GLITCHES, STEP_AT = 20_000, 10, 10_123


def _record(fault: str, size: float, seed: int) -> tuple:
    truth = paper_model()
    u = lowpass_input(N_SAMPLES, 2, 15.0, truth.sample_time_s, seed=seed)
    y, _ = simulate_innovation(truth, u, seed=seed + 1)
    rng = np.random.default_rng(seed)
    samples = rng.choice(np.arange(100, N_SAMPLES - 1), N_GLITCHES, replace=False)
    output = int(rng.integers(y.shape[1]))
    y[samples if fault == "glitch" else slice(STEP_AT, None), output] += size * y[:, output].std()
    return truth, u, y


def _row(fault: str, size: float, seeds: int) -> list:
    """The table's cells for one fault size over ``seeds`` records."""
    scores = [chain_modes(*_record(fault, size, seed), order=50, window=3750, every=500)
              for seed in range(1, seeds + 1)]
    found, updates = sum(s.found for s in scores), sum(s.updates for s in scores)
    return [f"{size:g}", f"{found}/{3 * updates}", sum(s.spurious for s in scores), updates,
            sum(s.changes for s in scores), sum(s.arx_glitches for s in scores),
            sum(getattr(s, "level_steps", 0) for s in scores)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--fault", choices=["glitch", "step"], default="glitch",
                        help="ten glitches, or a step of the output's level that stays (default glitch)")
    parser.add_argument("--sizes", type=float, nargs="+", default=[0.0, 30.0, 300.0],
                        help="fault sizes in output spreads, 0: the clean record (default 0 30 300)")
    parser.add_argument("--seeds", type=int, default=3, help="records per size (default 3)")
    add_output_options(parser)
    args = parser.parse_args(argv)
    refuse_existing(parser, args)
    header = [f"{args.fault} size (spreads)", "found", "spurious", "updates", "changes", "node 1 glitches",
              "level steps"]
    print_table(header, (_row(args.fault, size, args.seeds) for size in args.sizes), args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
