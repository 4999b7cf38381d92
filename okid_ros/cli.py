"""`okid-ros`: the command-line entry point, one subcommand per module of okid_ros.commands."""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Sequence

from okid_ros import __version__
from okid_ros.errors import OkidError

PROG = "okid-ros"

# The work is many small matrix products: BLAS worker threads only contend with each other and
# with the nodes (measured: identify on the paper case 0.6 s with one thread, 8 s with the
# default threads while another process was busy). Honoured only if the user set nothing.
_BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")

# One line per subcommand, in the order `--help` lists them (see okid_ros/commands/__init__.py).
COMMAND_MODULES: tuple[str, ...] = (
    "okid_ros.commands.info",
    "okid_ros.commands.identify",
    "okid_ros.commands.track",
    "okid_ros.commands.simulate",
    "okid_ros.commands.replay",
    "okid_ros.commands.process",
    "okid_ros.commands.batch",
    "okid_ros.commands.monitor",
    "okid_ros.commands.record",
    "okid_ros.commands.plot",
    "okid_ros.commands.export",
    "okid_ros.commands.demo",
    "okid_ros.commands.up",
)


def build_parser() -> argparse.ArgumentParser:
    """Return the parser with every subcommand of COMMAND_MODULES registered."""
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Online system identification (OKID) for ROS 2 Jazzy: "
        "ARX identification, ERA realization and modal state estimation.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        # Importing only registers the parser; modules defer heavy imports to run().
        try:
            module = importlib.import_module(name)
        except ImportError as exc:
            # One command that cannot be imported (a dependency missing on this install, a
            # module not written yet) must not take --help and every other command down.
            # test_cli.py imports every module directly, so a real bug still fails the tests.
            _add_unavailable(subparsers, name.rsplit(".", 1)[-1], exc)
            continue
        module.add_parser(subparsers)
    return parser


def _add_unavailable(subparsers: argparse._SubParsersAction, command: str,
                     exc: ImportError) -> None:
    """Register `command` so that running it reports why it is unavailable."""
    # No option prefix: every argument after the command is accepted, so the user sees why
    # the command is unavailable instead of a complaint about its options.
    parser = subparsers.add_parser(command, help=f"(unavailable: {exc})", add_help=False,
                                   prefix_chars="\0")
    parser.add_argument("ignored", nargs="*", help=argparse.SUPPRESS)

    def run(args: argparse.Namespace) -> int:
        raise OkidError(f"this command is unavailable: {exc}")

    parser.set_defaults(func=run)


def main(argv: Sequence[str] | None = None) -> int:
    """Run `okid-ros` with `argv` (default: sys.argv[1:]) and return the exit status."""
    for name in _BLAS_THREAD_VARIABLES:
        os.environ.setdefault(name, "1")  # before any command imports numpy; children inherit it
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help(sys.stderr)
        return 2
    try:
        return int(args.func(args))
    except OkidError as exc:
        # Expected failures are one line, like argparse's own usage errors, never a traceback.
        print(f"{PROG} {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
