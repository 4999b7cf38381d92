"""REP 145's "no data" covariance: what it changes on bags that declare none, and what it costs per message.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=$PWD python bench/imu_no_data.py --old-tree OLD_CHECKOUT

1. A simulated bag (``okid-ros simulate``: the Imu's acceleration covariance all zeros, "unknown") read with
   ``config/okid_imu_wrench.yaml`` by ``export`` and ``process`` of either tree: the records and the JSON lines
   compared (``realization_time_s`` is a wall-clock time, left out).
2. The bytes reader of an Imu source (``nodes/raw_inputs.py``, the nodes' input thread): microseconds per
   message, best of 7 x 20000, each tree in a process of its own, twice in turn.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parents[1]
_READER = """
import timeit
from rclpy.serialization import serialize_message
from sensor_msgs.msg import Imu
from okid_ros.nodes.raw_inputs import raw_reader
from okid_ros.service.inputs import parse_source
reader = raw_reader(parse_source("imu /a linear_acceleration.x=y0", 0, 1), 0, 1)
msg = Imu()
msg.linear_acceleration.x, msg.header.frame_id = 1.5, "tip1"
raw = serialize_message(msg)
print(min(timeit.repeat(lambda: reader.read(raw), number=20000, repeat=7)) / 20000 * 1e6)
"""


def _run(tree: Path, *args: str) -> str:
    env = {**os.environ, "PYTHONPATH": str(tree), "OPENBLAS_NUM_THREADS": "1"}
    return subprocess.run([sys.executable, *args], env=env, check=True, capture_output=True, text=True).stdout


def _bag_outputs(tree: Path, bag: Path, out: Path) -> tuple[dict, list[dict]]:
    params = ["--params", str(HERE / "config" / "okid_imu_wrench.yaml")]
    _run(tree, "-m", "okid_ros.cli", "export", str(bag), *params, "--npz", str(out / "r.npz"))
    _run(tree, "-m", "okid_ros.cli", "process", str(bag), *params, "--out", str(out / "bag"), "--jsonl",
         str(out / "m.jsonl"), "--no-progress", "--param", "publish_rate_hz=0.25",
         "--param", "realization.max_states=8")
    with np.load(out / "r.npz") as data:
        record = {key: data[key] for key in data.files}
    lines = [json.loads(line) for line in (out / "m.jsonl").read_text().splitlines()]
    for line in lines:
        line.pop("realization_time_s", None)
    return record, lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--old-tree", type=Path, required=True)
    parser.add_argument("--duration", type=float, default=25.0)
    args = parser.parse_args()
    trees = {"old": args.old_tree.resolve(), "new": HERE}
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / "sim"
        _run(HERE, "-m", "okid_ros.cli", "simulate", "--out", str(bag), "--duration", f"{args.duration:g}",
             "--start-time", "1700000000")
        found = {}
        for name, tree in trees.items():
            (Path(tmp) / name).mkdir()
            found[name] = _bag_outputs(tree, bag, Path(tmp) / name)
    (old_record, old_lines), (new_record, new_lines) = found["old"], found["new"]
    same = old_record.keys() == new_record.keys() and all(np.array_equal(old_record[k], new_record[k])
                                                          for k in old_record)
    print(f"export: {len(new_record['y'])} samples, the same record bit for bit: {same}")
    print(f"process: {len(new_lines)} JSON lines, the same but realization_time_s: {old_lines == new_lines}")
    print("\n| run | old reader (us/message) | new (us/message) |\n|---|---|---|")
    for turn in (1, 2):
        times = {name: float(_run(tree, "-c", _READER)) for name, tree in trees.items()}
        print(f"| {turn} | {times['old']:.2f} | {times['new']:.2f} |")


if __name__ == "__main__":
    main()
