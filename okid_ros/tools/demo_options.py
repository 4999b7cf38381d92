"""What ``okid-ros demo`` runs (:class:`DemoOptions`), its parameter files, and the checks of both.

:func:`check_demo_options` refuses, before anything is simulated or started, a replay speed out of
:data:`DEMO_RATE_RANGE` and an experiment shorter than node 1's first window (no model would ever come).
"""

from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass
from pathlib import Path

from okid_ros.errors import OkidError
from okid_ros.service.options import ArxIdentificationParams
from okid_ros.tools.errors import ToolParameterError
from okid_ros.tools.node_parameters import load_node_parameters

__all__ = ["DEMO_RATE_RANGE", "OUTPUT_ONLY_DEMO_WINDOW", "OUTPUT_ONLY_OVERRIDES", "DemoOptions", "check_demo_options",
           "default_params_file"]

REPO_ROOT = Path(__file__).resolve().parents[2]
#: The demo's replay speeds [times real time]. At most 5: the demo's samples (125 Hz, output-only
#: 200 Hz) then reach the nodes at up to 1 kHz, the rate the nodes' benchmark keeps up with on 2 cores
#: (docs/benchmarks-nodes.md), beside the demo's own replay, recorder and monitor; faster, samples are
#: lost and the live models are not the experiment's (1e300 replayed it all at once). At least 0.1:
#: a 60 s experiment then takes 10 minutes.
DEMO_RATE_RANGE = (0.1, 5.0)
#: The output-only demo's window [samples] (60 s at 200 Hz; config/okid_output_only.yaml has 120 s).
OUTPUT_ONLY_DEMO_WINDOW = 12000
OUTPUT_ONLY_OVERRIDES = f"""# okid-ros demo --output-only: a window that fits the demo (the file's: 120 s)
/**/okid_arx_identifier:
  ros__parameters:
    arx:
      window_length: {OUTPUT_ONLY_DEMO_WINDOW}
"""


def default_params_file(name: str = "okid.yaml") -> Path:
    """``config/NAME`` of the repository, else of the installed package (share/okid_ros/config)."""
    candidates = [REPO_ROOT / "config" / name, Path(sys.prefix) / "share" / "okid_ros" / "config" / name]
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            candidates.append(Path(prefix) / "share" / "okid_ros" / "config" / name)
    for path in candidates:
        if path.is_file():
            return path
    raise OkidError(f"parameter file {name} not found (looked in {', '.join(str(c.parent) for c in candidates)})")


@dataclass(frozen=True)
class DemoOptions:
    """What ``okid-ros demo`` runs (see :func:`okid_ros.tools.demo.run_demo`)."""

    duration_s: float = 60.0
    rate: float = 1.0
    params: tuple[Path, ...] = ()
    sensors: bool = False
    seed: int = 1
    ansi: bool | None = None
    startup_timeout_s: float = 90.0
    output_only: bool = False

    @property
    def param_files(self) -> list[Path]:
        """The parameter files given, else the default ones for the input topics.

        Output-only: config/okid.yaml and config/okid_output_only.yaml; the demo adds its
        window (``_DemoRun``).
        """
        if self.params:
            return list(self.params)
        if self.output_only:
            return [default_params_file("okid.yaml"), default_params_file("okid_output_only.yaml")]
        return [default_params_file("okid_imu_wrench.yaml" if self.sensors else "okid.yaml")]


def check_demo_options(options: DemoOptions) -> None:
    """Refuse a ``rate`` out of :data:`DEMO_RATE_RANGE`, or a ``duration_s`` shorter than node 1's first window.

    Node 1's first window is read from the demo's parameter files as the nodes read them
    (:meth:`~okid_ros.service.options.ArxIdentificationParams.first_model_samples` samples of
    ``sample_time_s``): shorter, the demo waited 30 s after the replay to say that no model came.

    Raises
    ------
    ToolParameterError
        either is refused; the message names the numbers.
    """
    low, high = DEMO_RATE_RANGE
    if not low <= options.rate <= high:
        raise ToolParameterError(f"--rate must be from {low:g} to {high:g} (times real time: the nodes take the "
                                 f"samples live), got {options.rate!r}")  # not :g, which wrote 5.0000001 as 5
    demo_window = [f"arx.window_length={OUTPUT_ONLY_DEMO_WINDOW}"] if options.output_only and not options.params else []
    values = load_node_parameters(options.param_files, demo_window, report=lambda problem: None)[0]  # `up` says them
    arx = ArxIdentificationParams.from_parameters(values)
    samples = arx.first_model_samples()
    window = (f"arx.min_window_fill {arx.min_window_fill:g} of arx.window_length {arx.window_length} rows"
              if arx.window_length > 0 else
              f"arx.min_window_fill {arx.min_window_fill:g} with arx.forgetting_factor {arx.forgetting_factor:g}")
    if math.isinf(samples):
        raise ToolParameterError(f"node 1's window never fills to a first model ({window}): no model would come")
    first_s = samples * arx.sample_time_s
    if options.duration_s < first_s:
        raise ToolParameterError(
            f"--duration {options.duration_s:g} s is shorter than node 1's first window, {first_s:g} s ({samples} "
            f"samples of {arx.sample_time_s:g} s: {window}, plus arx.order {arx.order}): no model would come; "
            f"give at least {math.ceil(first_s)} s, or a shorter window")
