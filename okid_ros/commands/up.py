"""`okid-ros up --params FILE`: both nodes as separate processes, for installs without launch_ros.

    okid-ros up --params config/okid.yaml
    okid-ros up --params config/okid.yaml --params my_overrides.yaml --use-sim-time
    okid-ros up --params config/okid.yaml --namespace /rig1     # /rig1/io_sample, /rig1/modal_states, ...

Starts ``python -m okid_ros.nodes.arx_identifier_node --ros-args --params-file FILE ...`` and
the same for ``modal_estimator_node``, with this interpreter and environment; their output goes
straight to this terminal. Ctrl-C or SIGTERM stops both: SIGINT to each, then SIGTERM and SIGKILL
to what is still running after the grace period (further signals to `up` while it stops are
ignored, so it never leaves a node behind). If one node exits on its own (for example a
parameter out of range), the other is stopped too and `up` exits with the node's status.
The nodes die with `up` even if it is killed (parent-death signal).
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import time

from okid_ros.commands._args import namespace, positive_finite_float
from okid_ros.errors import OkidError
from okid_ros.tools.parent_death import die_with_parent
from okid_ros.tools.ros_domain import check_ros_environment

NODE_MODULES = {
    "okid_arx_identifier": "okid_ros.nodes.arx_identifier_node",
    "okid_modal_estimator": "okid_ros.nodes.modal_estimator_node",
}


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register `up`."""
    parser = subparsers.add_parser(
        "up",
        help="run both nodes (ARX identifier and modal estimator) until Ctrl-C",
        description="Start okid_arx_identifier and okid_modal_estimator as separate processes with "
        "the given ROS parameter file(s), forward their output and stop both cleanly on Ctrl-C or "
        "SIGTERM. The pip-route equivalent of `ros2 launch okid_ros okid.launch.py`.",
    )
    parser.add_argument("--params", action="append", required=True, metavar="FILE",
                        help="ROS 2 parameter YAML keyed by node name; repeat to layer files "
                        "(later files win), e.g. config/okid.yaml")
    parser.add_argument("--namespace", type=namespace, default=None, metavar="NS",
                        help="run both nodes in namespace NS (-r __ns:=NS): every topic and service of the rig "
                        "moves there, e.g. /rig1/io_sample, /rig1/modal_states, /rig1/okid_arx_identifier/reset "
                        "(default: the root namespace, topics under /okid)")
    parser.add_argument("--strict-params", action="store_true",
                        help="the nodes refuse to start when a parameter file sets a name they do not declare "
                        "(strict_parameters:=true; default: a warning)")
    parser.add_argument("--lifecycle", action="store_true",
                        help="run both as managed (lifecycle) nodes, configured and activated at once")
    parser.add_argument("--no-autostart", action="store_true",
                        help="with --lifecycle: leave the nodes unconfigured for a lifecycle manager "
                        "(ros2 lifecycle set NODE configure / activate)")
    parser.add_argument("--use-sim-time", action="store_true", help="run the nodes' timers on /clock")
    parser.add_argument("--log-level", default="info", choices=("debug", "info", "warn", "error"),
                        help="ROS log level of both nodes (default: %(default)s)")
    parser.add_argument("--grace", type=positive_finite_float, default=5.0, metavar="S",
                        help="seconds each node gets to stop after SIGINT before SIGTERM (default: %(default)s)")
    parser.set_defaults(func=run)
    return parser


def node_command(module: str, params: list[str], use_sim_time: bool, log_level: str, *,
                 namespace: str | None = None, strict_params: bool = False, lifecycle: bool = False,
                 autostart: bool = True) -> list[str]:
    """The command line of one node process."""
    cmd = [sys.executable, "-m", module]
    if lifecycle:
        cmd += ["--lifecycle"] + ([] if autostart else ["--no-autostart"])
    cmd += ["--ros-args"]
    for path in params:
        cmd += ["--params-file", path]
    if use_sim_time:
        cmd += ["-p", "use_sim_time:=true"]
    if strict_params:
        cmd += ["-p", "strict_parameters:=true"]
    if namespace is not None and namespace != "/":
        cmd += ["-r", f"__ns:={namespace}"]
    return cmd + ["--log-level", log_level]


class _Stop(Exception):
    pass


def _stop(processes: dict[str, subprocess.Popen], grace_s: float) -> None:
    """SIGINT to every running node, then SIGTERM, then SIGKILL, each after ``grace_s``."""
    for sig, wait_s in ((signal.SIGINT, grace_s), (signal.SIGTERM, 5.0), (signal.SIGKILL, 5.0)):
        running = [p for p in processes.values() if p.poll() is None]
        if not running:
            return
        for proc in running:
            try:
                proc.send_signal(sig)
            except ProcessLookupError:
                pass
        deadline = time.monotonic() + wait_s
        for proc in running:
            try:
                proc.wait(timeout=max(deadline - time.monotonic(), 0.01))
            except subprocess.TimeoutExpired:
                pass


def run(args: argparse.Namespace) -> int:
    """Start both nodes and supervise them until a signal or until one exits."""
    from okid_ros.service.param_files import files_for_nodes

    params = files_for_nodes(args.params)
    check_ros_environment()  # before the nodes start (they ended with rcl's or Fast DDS's lines)
    if args.no_autostart and not args.lifecycle:
        raise OkidError("--no-autostart needs --lifecycle")

    def on_signal(signum, frame):
        raise _Stop(signal.Signals(signum).name)

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    processes: dict[str, subprocess.Popen] = {}
    status = 0
    try:
        for name, module in NODE_MODULES.items():
            # Own session: a terminal's Ctrl-C reaches only `up`, which stops the nodes in order.
            processes[name] = subprocess.Popen(
                node_command(module, params, args.use_sim_time, args.log_level,
                             namespace=args.namespace, strict_params=args.strict_params,
                             lifecycle=args.lifecycle, autostart=not args.no_autostart),
                start_new_session=True, preexec_fn=die_with_parent,
            )
        print(f"okid-ros up: started {', '.join(f'{n} (pid {p.pid})' for n, p in processes.items())}; "
              "Ctrl-C stops both", flush=True)
        running = dict(processes)
        while running:
            for name, proc in list(running.items()):
                code = proc.poll()
                if code == 0 and args.lifecycle:  # its lifecycle shutdown (or a signal): the other node is the user's
                    print(f"okid-ros up: {name} exited with status 0 (its lifecycle shutdown, or a signal)"
                          + ("; the other node runs on" if len(running) > 1 else ""), flush=True)
                    del running[name]
                elif code is not None:
                    print(f"okid-ros up: {name} exited with status {code}; stopping the other node",
                          file=sys.stderr, flush=True)
                    status = code if code != 0 else 1
                    raise _Stop(name)
            time.sleep(0.2)
    except _Stop:
        pass
    finally:
        # Already stopping: a second Ctrl-C or a SIGTERM must not leave the nodes behind.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        _stop(processes, args.grace)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    codes = {name: proc.returncode for name, proc in processes.items()}
    if status == 0:
        print("okid-ros up: stopped (" + ", ".join(f"{n}: {c}" for n, c in codes.items()) + ")", flush=True)
    return status
