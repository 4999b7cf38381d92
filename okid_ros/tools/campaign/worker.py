"""One bag of a campaign, in whatever process runs it (the command's, a pool's, a Dask worker's).

:func:`run_bag_job` runs :func:`okid_ros.tools.process.process_bag` into a temporary folder
``DIR/bags/.tmp-LABEL-XXXX`` (output bag ``output``, ``models.jsonl``, ``result.json``) and
renames it to ``DIR/bags/LABEL`` only when complete. Any failure (unreadable or corrupt bag,
input topics missing) becomes a ``failed`` result with a one-line reason and
removes the temporary folder; it never raises, so one bad bag cannot stop the others.

The result is a plain JSON-ready dict (it travels between processes and machines and is kept
as ``result.json`` for reruns): the bag's counts and, per model update, its modes with their
shapes (read back from the output bag's StateSpaceModel messages; the JSON lines of
``process`` carry no shapes), which the campaign's mode matching needs.
"""

from __future__ import annotations

import contextlib
import json
import shutil
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["TMP_PREFIX", "BagJob", "run_bag_job", "failed_result"]

#: Name start of a bag's folder while it is processed (``DIR/bags/.tmp-LABEL-XXXX``); a killed run's are
#: removed by the next (campaign/lock.py).
TMP_PREFIX = ".tmp-"

#: Fields of a model update (a JSON line of `process`) kept in the result; wall-clock timings are
#: left out so that every engine gives the same result.
_UPDATE_FIELDS = ("stamp_s", "applied_at_stamp_s", "model_id", "arx_model_id", "n_states", "window_samples",
                  "change_detected", "applied_after_last_sample")


@dataclass
class BagJob:
    """Everything a worker needs for one bag (picklable; paths absolute).

    Attributes
    ----------
    bag : absolute path of the input bag.
    display : the bag as the user named it (the ``bag`` column).
    label : folder name of its outputs under ``out_dir/bags``.
    out_dir : absolute path of the campaign directory.
    arx_values, est_values : resolved parameters of both nodes.
    namespace : rig namespace (None: root).
    storage : storage plugin of the output bag.
    state_space_topic : resolved StateSpaceModel topic (shapes are read from it).
    provenance : recorded in the output bag's metadata, as `process` does.
    """

    bag: str
    display: str
    label: str
    out_dir: str
    arx_values: dict
    est_values: dict
    namespace: str | None = None
    storage: str = "mcap"
    state_space_topic: str = "/okid/state_space_model"
    provenance: dict = field(default_factory=dict)


def failed_result(job: BagJob, reason: str, seconds: float = 0.0, *, transient: bool = False) -> dict:
    """The result of a bag that could not be processed.

    ``transient``: the bag is not at fault (its worker died); not journaled, so a rerun tries again.
    """
    return {"transient": transient, "bag": job.display, "label": job.label, "status": "failed", "reason": reason,
            "models": 0, "samples": 0, "input_messages": 0, "duration_s": float("nan"), "start_s": float("nan"),
            "seconds": float(seconds), "updates": []}


def _one_line(exc: BaseException) -> str:
    from okid_ros.errors import one_line

    return one_line(exc) or type(exc).__name__


def run_bag_job(job: BagJob) -> dict:
    """Process one bag; returns its result (see the module docstring). Never raises but KeyboardInterrupt."""
    started, cpu_started = time.perf_counter(), time.process_time()
    bags_dir = Path(job.out_dir) / "bags"
    tmp = bags_dir / f"{TMP_PREFIX}{job.label}-{uuid.uuid4().hex[:8]}"
    try:
        bags_dir.mkdir(parents=True, exist_ok=True)
        tmp.mkdir()
        with _one_blas_thread():
            result = _process(job, tmp)
        result["seconds"] = time.perf_counter() - started
        result["cpu_s"] = time.process_time() - cpu_started  # for bench/batch.py; not in the tables
        (tmp / "result.json").write_text(json.dumps(result, allow_nan=True))
        from okid_ros.tools.campaign.manifest import replace_directory

        replace_directory(tmp, bags_dir / job.label)
        return result
    except KeyboardInterrupt:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    except Exception as exc:  # noqa: BLE001 - every failure of one bag is reported, the campaign goes on
        shutil.rmtree(tmp, ignore_errors=True)
        from okid_ros.errors import OkidError, shown_path

        reason = _one_line(exc) if isinstance(exc, OkidError) else f"{type(exc).__name__}: {_one_line(exc)}"
        bag, display = shown_path(job.bag), shown_path(job.display)  # as the message names them
        reason = reason.replace(bag, display)
        if display not in reason:
            reason = f"{display}: {reason}"
        return failed_result(job, reason, time.perf_counter() - started)


def _process(job: BagJob, tmp: Path) -> dict:
    from okid_ros.tools.process import process_bag

    output = tmp / "output"
    summary = process_bag(job.bag, output, job.arx_values, job.est_values, jsonl_path=tmp / "models.jsonl",
                          storage=job.storage, progress=False, provenance=job.provenance, namespace=job.namespace)
    shapes = _read_shapes(output, job.state_space_topic) if summary.updates else {}
    updates = []
    for line in summary.updates:
        update = {name: line[name] for name in _UPDATE_FIELDS if name in line}
        by_id = shapes.get(int(line["model_id"]), {})
        modes = []
        for mode in line["modes"]:
            real, imag = by_id.get(int(mode["id"]), ([], []))
            modes.append({**mode, "shape_real": real, "shape_imag": imag})
        update["modes"] = modes
        updates.append(update)
    reason = summary.input_note  # an ok bag read in part says so
    if not updates:
        diagnostics = summary.estimator_diagnostics.get("last_reason") or summary.arx_diagnostics.get("last_reason")
        reason = "; ".join(filter(None, [
            "no model was identified" + (f": {diagnostics}" if diagnostics else ""), summary.input_note]))
    return {"bag": job.display, "label": job.label, "status": "ok", "reason": reason, "models": len(updates),
            "samples": int(summary.samples), "input_messages": int(summary.input_messages),
            "duration_s": float(summary.data_duration_s), "start_s": float(summary.first_stamp_s),
            "seconds": 0.0, "process_s": float(summary.elapsed_s), "updates": updates}


def _read_shapes(output: Path, topic: str) -> dict[int, dict[int, tuple[list, list]]]:
    """model_id -> mode id -> (shape_real, shape_imag), from the StateSpaceModel messages written."""
    from okid_ros.tools.bagio import open_bag

    shapes: dict[int, dict[int, tuple[list, list]]] = {}
    with open_bag(output) as bag:
        if topic not in bag.topics:
            return shapes
        for _, _, msg in bag.messages([topic]):
            shapes[int(msg.model_id)] = {int(m.id): ([float(x) for x in m.shape_real], [float(x) for x in m.shape_imag])
                                         for m in msg.modes}
    return shapes


def _one_blas_thread() -> Any:
    """One BLAS thread while a bag is processed, whatever process runs it (same sums, same bits)."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # then OPENBLAS_NUM_THREADS=1, set by the CLI (and the docs for workers), does it
        return contextlib.nullcontext()
    return threadpool_limits(limits=1, user_api="blas")
