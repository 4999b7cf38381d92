"""What node 2's sample path repeats per sample, per gap and per model switch, at 28 channels.

Run:  .venv/bin/python bench/sample_path_parts.py [--window 3000] [--calls 500]

Realizes one model of the DaISy steel-subframe record (``bench/live_pace_profile.py``'s job: p = 28,
m = 2, ARX order 20) and times, with one BLAS thread and the thread's CPU clock (the best of five
rounds of ``--calls`` calls each), the parts of :meth:`ModalEstimationService._step` and ``_apply``
that a sample, a sample after missing ones and a model switch run: the estimator's step, the
bridge over one missing slot (``service/realization.bridge_state``), the switch's jump reference
(``SwitchJump.before_switch``, without and after a gap), the modes' power update
(``SwitchJump.after_sample``) and the mode matching of a switch (``ModeRegistry.match``, ``assign``).
Run it with ``PYTHONPATH=<an older tree>`` to time that code (``bench/checkout.py``).
"""

from __future__ import annotations

import argparse
import copy
import os
import sys
import time
from types import SimpleNamespace

import checkout

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # as in the nodes (before numpy is imported)


def best_of_five(call, calls: int) -> float:
    """The least mean CPU time of ``call`` over five rounds of ``calls`` calls [us]."""
    call()
    rounds = []
    for _ in range(5):
        start = time.thread_time_ns()
        for _ in range(calls):
            call()
        rounds.append((time.thread_time_ns() - start) / calls / 1e3)
    return min(rounds)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--window", type=int, default=3000, help="ARX window rows of the model (default 3000)")
    parser.add_argument("--calls", type=int, default=500, help="calls per round (default 500)")
    args = parser.parse_args()
    checkout.add()
    checkout.add("bench")
    import numpy as np
    from live_pace_profile import RECORD, make_job

    from okid_ros.core.estimator import ModalStateEstimator
    from okid_ros.service import realization
    from okid_ros.service.mode_registry import ModeRegistry
    from okid_ros.service.model_switch import SwitchJump
    from okid_ros.service.results import EstimationStats

    job = make_job(argparse.Namespace(record=str(RECORD), start=0, window=args.window, order=20, order_hint=None))
    model = realization.realize(job).model
    if model is None:
        raise SystemExit("sample_path_parts.py: the window gave no model")
    modes = [copy.copy(mode) for mode in model.modes]
    estimator = ModalStateEstimator.from_model(model)
    active = SimpleNamespace(model=model, estimator=estimator, modes=modes, n_modes=len(modes))
    x, u, y = np.zeros(model.n_states), np.ones(model.n_inputs), np.zeros(model.n_outputs)
    jump = SwitchJump(EstimationStats())
    coords = np.random.default_rng(1).random((len(modes), 2))
    registry = ModeRegistry(max_frequency_change=0.05, min_mac=0.7, mode_memory=5)
    registry.assign(modes, registry.match(modes))
    print(f"p = {model.n_outputs}, m = {model.n_inputs}, {model.n_states} states, {len(modes)} modes; load average "
          f"(1 min) {os.getloadavg()[0]:.2f}; CPU per call [us], the best of 5 rounds of {args.calls}\n")
    print("| part | when | CPU [us] |\n|---|---|---|")
    rows = [
        ("estimator step", "every sample", lambda: estimator.step(u, y)),
        ("modes' power update (`after_sample`)", "every sample", lambda: jump.after_sample(active, coords, False)),
        ("bridge over 1 missing slot (`bridge_state`)", "a sample after a gap",
         lambda: realization.bridge_state(model, x, u, 1, 5)),
        ("jump reference (`before_switch`)", "a switch", lambda: jump.before_switch(active, u, y, 0, u, 5)),
        ("the same after a gap", "a switch after a gap", lambda: jump.before_switch(active, u, y, 1, u, 5)),
        ("mode matching (`ModeRegistry.match`)", "a switch", lambda: registry.match(modes)),
        ("ids and memory (`match` + `assign`)", "a switch", lambda: registry.assign(modes, registry.match(modes))),
    ]
    for name, when, call in rows:
        print(f"| {name} | {when} | {best_of_five(call, args.calls):.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
