#!/usr/bin/env python3
"""Rig2 of the two-rig DDS test offline: runs in which node 2 accepts no model while the samples flow.

``test_nodes_ros_conventions.py::test_two_namespaced_rigs_in_one_domain_never_cross`` publishes 1100
samples to rig2 (the paper's structure, 50 Hz low-passed inputs, 400 a second) and waits for rig2's
ModalStates; node 2 publishes them only for samples after its first accepted model, so one of the windows
it realizes while the samples flow must give a model. Here both nodes' services take rig2's stream
(``config/okid.yaml`` with the test's small problem: window 400 rows, valid from half of it, 6 states
without refinement, the ARX order of ``--orders``), each node losing its own samples (at random,
``--loss`` of them, in bursts of 1 to ``--burst``); node 1 gives a window every ``--tick`` samples (the
test: 4 Hz against 400 samples a second) at a random phase, which node 2 realizes at once. Columns: the
runs (of ``--runs``) in which node 2 accepted no model during the stream, and why its last was refused.

Usage::

    python bench/two_rig_windows.py                              # orders 10 20, loss 0 0.05 0.1; ~3 min
    python bench/two_rig_windows.py --orders 20 --loss 0.05 --burst 8 --runs 10
"""

from __future__ import annotations

import argparse
from collections import Counter
from pathlib import Path

import numpy as np

from okid_ros.service.estimation import ModalEstimationService
from okid_ros.service.identification import ArxIdentificationService
from okid_ros.service.options import ArxIdentificationParams, ModalEstimationParams
from okid_ros.sim import lowpass_input, paper_model, simulate_innovation
from okid_ros.tools.node_parameters import load_node_parameters

CONFIG = Path(__file__).resolve().parent.parent / "config" / "okid.yaml"
SAMPLES = 1100  # rig2's in the test
STREAM_SAMPLES = 1500  # the test's stream (rig1's): its filter and unit variance are over all of it
FIRST_STAMP_S = 5000.0


def rig_params(order: int) -> tuple[ArxIdentificationParams, ModalEstimationParams]:
    """Both nodes' options: the shipped file with the test's small problem at ARX order ``order``."""
    small = [f"arx.order={order}", "arx.window_length=400", "realization.n_states=6", "realization.refine=false"]
    arx_values, est_values = load_node_parameters([CONFIG], small)
    return ArxIdentificationParams.from_parameters(arx_values), ModalEstimationParams.from_parameters(est_values)


def lost_samples(rng: np.random.Generator, loss: float, burst: int) -> np.ndarray:
    """(SAMPLES,) bool: the samples a node loses, about ``loss`` of them, in bursts of 1 to ``burst``."""
    starts = np.flatnonzero(rng.random(SAMPLES) < loss / ((burst + 1) / 2))
    lost = np.zeros(SAMPLES, dtype=bool)
    for start in starts:
        lost[start:start + int(rng.integers(1, burst + 1))] = True
    return lost


def one_run(params: tuple[ArxIdentificationParams, ModalEstimationParams], u: np.ndarray, y: np.ndarray,
            rng: np.random.Generator, *, loss: float, burst: int, tick: int) -> tuple[int, str]:
    """One run of rig2's stream; the models node 2 accepted during it and its last reason."""
    arx_params, est_params = params
    node1, node2 = ArxIdentificationService(arx_params), ModalEstimationService(est_params)
    lost1, lost2 = lost_samples(rng, loss, burst), lost_samples(rng, loss, burst)
    dt, phase = est_params.sample_time_s, int(rng.integers(tick))
    last1 = last2 = -1
    for k in range(SAMPLES):
        stamp = FIRST_STAMP_S + k * dt
        if not lost1[k]:
            node1.push(stamp, u[k], y[k], gap_before=0 <= last1 < k - 1)
            last1 = k
        if not lost2[k]:
            node2.step(stamp, u[k], y[k], 0 if last2 < 0 else k - last2 - 1)
            last2 = k
        if k % tick == phase and last1 >= 0 and (snapshot := node1.snapshot()).valid:
            node2.submit_arx(snapshot.fit, snapshot.stamp_s, snapshot.model_id, snapshot.window_rows)
            node2.process_pending()  # delivered: switched in at node 2's next sample
    accepted = node2.model_id  # a model delivered after the last sample is not counted
    return accepted, str(node2.diagnostics()["last_reason"])


def main() -> None:
    """Print the markdown table of the runs without a model, by order, loss and burst."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--orders", type=int, nargs="+", default=[10, 20])
    parser.add_argument("--loss", type=float, nargs="+", default=[0.0, 0.05, 0.1])
    parser.add_argument("--burst", type=int, nargs="+", default=[1, 4])
    parser.add_argument("--runs", type=int, default=30)
    parser.add_argument("--tick", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    u = lowpass_input(STREAM_SAMPLES, 2, 50.0, 0.008, seed=4)  # the test's stream, rig2 its first samples
    y, _ = simulate_innovation(paper_model(), u, seed=5)
    print("| ARX order | lost | burst | runs without a model | the last reason in those runs |")
    print("|---|---|---|---|---|")
    for order in args.orders:
        params = rig_params(order)
        for loss in args.loss:
            for burst in args.burst if loss > 0 else [1]:
                rng = np.random.default_rng(args.seed)
                runs = [one_run(params, u, y, rng, loss=loss, burst=burst, tick=args.tick) for _ in range(args.runs)]
                why = Counter(reason.split(":")[0] or "no ArxModel" for accepted, reason in runs if not accepted)
                none = sum(not accepted for accepted, _ in runs)
                print(f"| {order} | {loss:g} | {burst} | {none} of {args.runs} | "
                      f"{', '.join(f'{n} {r}' for r, n in why.most_common()) or '-'} |", flush=True)


if __name__ == "__main__":
    main()
