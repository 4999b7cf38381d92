"""The real measured record (DaISy steel subframe) for the tests, and a bag of it written by rosbags alone.

Importable from test modules as `import real_helpers` (pytest puts test/ on sys.path). Used by
test_real_record.py (batch), test_real_bag.py (`okid-ros process`) and test_real_live.py (both
nodes over DDS).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from ros_helpers import rosbags_typestore

REPO_ROOT = Path(__file__).resolve().parent.parent
RECORD_DIR = REPO_ROOT.parent / "shared" / "data" / "real" / "daisy-steel-subframe"
IO_TOPIC = "/okid/io_sample"
IO_TYPE = "okid_msgs/msg/IoSample"
#: First stamp of the bags written here [s] (a whole second, like `okid-ros simulate`).
START_S = 1_700_000_000


def load_record() -> tuple[np.ndarray, np.ndarray, float, list[float]]:
    """Inputs, outputs, sample time and reference frequencies [Hz] of the steel subframe."""
    path = RECORD_DIR / "steel_subframe.npz"
    if not path.is_file():
        pytest.fail(f"the real record is missing: {path} (../shared must sit beside the repository)")
    data = np.load(path)
    truth = json.loads((RECORD_DIR / "truth.json").read_text())
    reference = [float(m["f_Hz"]) for m in truth["reference_estimates_not_published"]["modes"]]
    return data["u"], data["y"], float(data["sample_time_s"]), reference


def stamp_ns(k: int | np.ndarray, sample_time_s: float, start_s: int = START_S) -> int | np.ndarray:
    """Header stamp [ns] of sample ``k``: the grid ``start + k dt`` rounded to the nanosecond.

    1/1024 s is 976562.5 ns, so a stamp is off its grid slot by at most 0.5 ns (the nodes
    accept 0.25 sample times).
    """
    return start_s * 1_000_000_000 + np.rint(np.asarray(k) * sample_time_s * 1e9).astype(np.int64)


def sample_index(stamp_s: float, sample_time_s: float, n_samples: int, start_s: int = START_S) -> int:
    """Index into the record of a stamp [s] of a bag written by :func:`write_record_bag` (any pass)."""
    k = int(round((stamp_s - start_s) / sample_time_s))
    return k % n_samples


def write_record_bag(path: Path, u: np.ndarray, y: np.ndarray, sample_time_s: float, passes: int = 1) -> int:
    """Write the record as a rosbag2 (MCAP) of ``IoSample`` on /okid/io_sample with the rosbags library alone.

    One message per sample, header stamp = log time = :func:`stamp_ns`. With ``passes`` > 1
    the record is written that many times one after the other with continuing stamps (no
    jump back in time: the nodes keep their window and model across the seam, unlike a
    ``replay --loop``, whose stamps jump back and restart both nodes). Returns the number of
    messages.
    """
    from rosbags.rosbag2 import StoragePlugin, Writer

    store = rosbags_typestore()
    time_cls, header_cls = store.types["builtin_interfaces/msg/Time"], store.types["std_msgs/msg/Header"]
    io_cls = store.types[IO_TYPE]
    n = u.shape[0]
    stamps = stamp_ns(np.arange(passes * n), sample_time_s)
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connection = writer.add_connection(IO_TOPIC, IO_TYPE, typestore=store)
        for k, ns in enumerate(stamps.tolist()):
            header = header_cls(stamp=time_cls(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000),
                                frame_id="steel_subframe")
            msg = io_cls(header=header, u=np.array(u[k % n], dtype=np.float64),
                         y=np.array(y[k % n], dtype=np.float64))
            writer.write(connection, ns, store.serialize_cdr(msg, IO_TYPE))
    return len(stamps)


def node_parameters(*, order: int, window: int, max_states: int, publish_rate_hz: float, n_outputs: int,
                    sample_time_s: float, extra_shared: str = "", extra_arx: str = "",
                    extra_estimator: str = "") -> str:
    """A parameter YAML for both nodes, keyed ``/**/NODE`` like config/okid.yaml.

    ``extra_*``: further lines of each section's ``ros__parameters``, indented by 4 spaces.
    """
    return f"""/**:
  ros__parameters:
    sample_time_s: {sample_time_s!r}
    n_inputs: 2
    n_outputs: {n_outputs}
{extra_shared}
/**/okid_arx_identifier:
  ros__parameters:
    publish_rate_hz: {float(publish_rate_hz)!r}
    arx:
      order: {order}
      window_length: {window}
{extra_arx}
/**/okid_modal_estimator:
  ros__parameters:
    realization:
      max_states: {max_states}
{extra_estimator}
"""


def matched_errors(found_hz, reference_hz) -> np.ndarray:
    """Relative frequency error of the nearest found mode for each reference mode."""
    found = np.asarray(found_hz, dtype=float)
    if found.size == 0:
        return np.full(len(reference_hz), np.inf)
    return np.array([float(np.min(np.abs(found - f)) / f) for f in reference_hz])


def normalized_innovation_rms(innovations: np.ndarray, output_rms: np.ndarray) -> np.ndarray:
    """Per sample: RMS over the channels of the innovation, each channel divided by its output RMS.

    ``innovations`` is (K, p), ``output_rms`` (p,) the RMS of each mean-removed output over
    the record. 1 means innovations as large as the outputs themselves (no prediction at
    all); a working predictor stays far below (a few percent here), a diverging one grows.
    """
    return np.sqrt(np.mean((np.asarray(innovations) / output_rms) ** 2, axis=1))
