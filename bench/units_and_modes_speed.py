"""``record_units`` (core/channels.py) and ``IdentifiedModel.keep_modes`` of another checkout and this one.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=$PWD python bench/units_and_modes_speed.py --old-tree OLD_CHECKOUT

Each module is loaded from its file in either tree under a name of its own (the rest of ``okid_ros`` is this
checkout's), timed on the same arrays (best of 5), and its results compared for equality.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import timeit
from pathlib import Path

import checkout
import numpy as np
from scipy import linalg

checkout.add()

from okid_ros.core.modal import modal_form  # noqa: E402
from okid_ros.core.options import ModeCriteria  # noqa: E402


def _load(path: Path, name: str):
    """The module of the file ``path`` under the name ``name``."""
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def _best(call) -> float:
    """Seconds of the fastest of 5 calls."""
    return min(timeit.repeat(call, number=1, repeat=5))


def _units(old, new, rng) -> None:
    print("| record | old record_units (ms) | new (ms) | same units |\n|---|---|---|---|")
    for n, m, p, scale in [(60_000, 2, 4, 1.0), (200_000, 2, 6, 1e150), (1_000_000, 1, 8, 1.0)]:
        u, y = scale * rng.standard_normal((n, m)), rng.standard_normal((n, p))
        a, b = old.record_units(u, y), new.record_units(u, y)
        same = np.array_equal(a.input, b.input) and np.array_equal(a.output, b.output)
        t_old, t_new = _best(lambda: old.record_units(u, y)), _best(lambda: new.record_units(u, y))
        print(f"| {n} x ({m}+{p}), inputs x {scale:g} | {1e3 * t_old:.1f} | {1e3 * t_new:.1f} | {same} |")


def _modes(old, new, rng) -> None:
    print("\n| modes (kept) | old keep_modes (ms) | new (ms) | same A, C, K |\n|---|---|---|---|")
    criteria = ModeCriteria(max_damping=0.1, min_msv=0.0, min_mpc=0.0, min_dominance=0.0)
    for n_modes in (40, 400):
        poles = 0.99 * np.exp(1j * np.linspace(0.05, 3.0, n_modes))
        A = linalg.block_diag(*[[[z.real, z.imag], [-z.imag, z.real]] for z in poles])
        C = rng.standard_normal((3, 2 * n_modes))
        form = modal_form(A, C.T, C, C.T, 0.01, criteria=criteria)

        def kept(module):
            model = module.IdentifiedModel(A=form.A.copy(), B=np.zeros((2 * n_modes, 0)), C=form.C.copy(),
                                           D=np.zeros((3, 0)), K=form.K.copy(), innovation_covariance=np.eye(3),
                                           sample_time_s=0.01, modes=[type(mode)(**vars(mode)) for mode in form.modes])
            model.keep_modes(model.modes[::2])
            return model

        a, b = kept(old), kept(new)
        same = all(np.array_equal(getattr(a, name), getattr(b, name)) for name in "ACK")
        print(f"| {n_modes} ({n_modes // 2}) | {1e3 * _best(lambda: kept(old)):.2f} | "
              f"{1e3 * _best(lambda: kept(new)):.2f} | {same} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--old-tree", type=Path, required=True, help="the other checkout (git archive of main)")
    args = parser.parse_args()
    new_tree, rng = checkout.REPO, np.random.default_rng(0)
    _units(_load(args.old_tree / "okid_ros/core/channels.py", "old_channels"),
           _load(new_tree / "okid_ros/core/channels.py", "new_channels"), rng)
    _modes(_load(args.old_tree / "okid_ros/core/identified_model.py", "old_identified_model"),
           _load(new_tree / "okid_ros/core/identified_model.py", "new_identified_model"), rng)


if __name__ == "__main__":
    main()
