"""A small simulated campaign for the `okid-ros batch` tests: short bags, one corrupt, one without inputs.

Every good bag is the paper-like structure of :mod:`okid_ros.tools.simulate_bag` (modes at
5.906, 7.342 and 48.46 Hz), 8 s long with its own seed and a start one hour after the
previous one; the parameters (ARX order 20, 500-row window, one model a second, no
prediction-error refinement) give a few model updates per bag in about a second.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

from okid_ros.cli import main

DURATION_S = 8.0
START_NS = 1_700_000_000 * 1_000_000_000
#: True frequencies of the simulated structure [Hz] (okid_ros.sim.paper_model).
TRUE_HZ = (37.10 / (2 * math.pi), 46.13 / (2 * math.pi), 304.49 / (2 * math.pi))

# The refinement took 70 % of each realization here; these tests are about batch's campaign
# (tables, journal, reuse, workers, locks), and the refinement has tests of its own
# (test/core/test_core_refine.py, test_pipeline.py).
PARAMS = """\
/**/okid_arx_identifier:
  ros__parameters:
    publish_rate_hz: 1.0
    arx:
      order: 20
      window_length: 500
/**/okid_modal_estimator:
  ros__parameters:
    realization:
      refine: false
"""


def write_good_bag(path: Path, index: int, duration_s: float = DURATION_S) -> Path:
    """A simulated bag, seed and start stamp from ``index``."""
    from okid_ros.tools.simulate_bag import simulate_experiment, write_experiment_bag

    experiment = simulate_experiment(duration_s, seed=10 + index, start_ns=START_NS + index * 3600 * 1_000_000_000)
    write_experiment_bag(path, experiment)
    return path


def write_truncated_bag(source: Path, path: Path) -> Path:
    """A copy of the rosbag2 ``source`` whose MCAP file is cut in the middle (metadata intact).

    An 8 s bag is about 1.1 MB, its first chunk about 1 MB: the cut falls inside the first chunk,
    nothing before it is whole, and the bag fails (a later cut would be read up to it).
    """
    path.mkdir(parents=True)
    shutil.copy(source / "metadata.yaml", path / "metadata.yaml")
    data = next(source.glob("*.mcap")).read_bytes()
    (path / f"{path.name}.mcap").write_bytes(data[: len(data) // 2])
    (path / "metadata.yaml").write_text((path / "metadata.yaml").read_text().replace(source.name, path.name))
    return path


def write_bag_without_inputs(path: Path) -> Path:
    """A readable bag with one unrelated topic."""
    from okid_ros.tools.bagio import BagWriter

    with BagWriter(path) as bag:
        bag.add_topic("/chatter", "std_msgs/msg/String")
        string = bag.msg_class("std_msgs/msg/String")
        for k in range(10):
            bag.write("/chatter", START_NS + k * 1_000_000, string(data=f"hello {k}"))
    return path


def write_params(path: Path) -> Path:
    path.write_text(PARAMS)
    return path


def batch(*args: object) -> int:
    """`okid-ros batch ARGS...` in this process (no progress bar unless asked); returns the exit status."""
    argv = ["batch", *map(str, args)]
    return main(argv if "--progress" in argv else [*argv, "--no-progress"])


def read_summary(out_dir: Path) -> dict[str, dict]:
    """summary.csv as bag name -> row."""
    import csv

    with open(out_dir / "summary.csv") as stream:
        return {Path(row["bag"]).name: row for row in csv.DictReader(stream)}


def table_rows(out_dir: Path) -> list[dict]:
    """modes.parquet as rows (NaN replaced by None, so that equal tables compare equal)."""
    import pyarrow.parquet as pq

    rows = pq.read_table(out_dir / "modes.parquet").to_pylist()
    return [{k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in row.items()} for row in rows]


def build_campaign(root: Path) -> dict:
    """Three good bags and one truncated in ``root/bags``, the parameters, and the serial run's output.

    Returns ``root``, ``bags``, ``params``, ``serial`` (the output directory) and ``status`` (its exit status).
    """
    bags = root / "bags"
    bags.mkdir()
    for i in range(3):
        write_good_bag(bags / f"run_{i:03d}", i)
    write_truncated_bag(bags / "run_001", bags / "run_001_cut")
    params = write_params(root / "params.yaml")
    serial = root / "serial"
    status = batch(bags, "--params", params, "--out", serial, "--workers", 1)
    return {"root": root, "bags": bags, "params": params, "serial": serial, "status": status}
