"""`okid-ros`: the command-line entry point, one subcommand per module of okid_ros.commands."""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import signal
import sys
import threading
import warnings
from collections.abc import Callable, Iterator, Sequence

from okid_ros import __version__
from okid_ros.errors import DataError, OkidError, OkidWarning, OutputError, one_line, shown_path
from okid_ros.tools.output_paths import made_folders_removed_on_failure

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


class _OneLineParser(argparse.ArgumentParser):
    """argparse's parser whose usage errors are one line, as every other error (the usage is in --help)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {one_line(message)} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """Return the parser with every subcommand of COMMAND_MODULES registered (their parsers of its class)."""
    parser = _OneLineParser(
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
    # The file a command reads (identify/track DATA, process/export/replay/plot BAG): named in its
    # data errors (below), so no command has to repeat it.
    source = getattr(args, "data", None) or getattr(args, "bag", None)
    return run_command(args.command, lambda: int(args.func(args)), source=source)


def run_command(command: str, work: Callable[[], int], *, source: str | None = None) -> int:
    """Run one subcommand's ``work`` and turn every failure into one line on stderr.

    The one place where failures become exit statuses, for every command: an
    :class:`~okid_ros.errors.OkidError` (bad input or option, the message names the file and
    what is wrong) gives status 2; running out of memory (a record or option too large for this
    machine) also 2; any other exception is a bug in okid-ros: one line asking to report it,
    status 70 (EX_SOFTWARE), the traceback only with ``OKID_ROS_TRACEBACK=1``. Python warnings
    (numpy's floating-point warnings among them) are printed as one line each, naming the command;
    okid-ros's own (:class:`~okid_ros.errors.OkidWarning`: a parameter file's problems, ...) once per run.
    A command that fails leaves no empty folder it made for its outputs
    (:func:`~okid_ros.tools.output_paths.made_folders_removed_on_failure`).
    A data error that does not name ``source`` (the file the command reads) is prefixed with it.
    """
    with warnings.catch_warnings(), _terminate_as_interrupt():
        warnings.showwarning = _one_line_warning(command)
        warnings.simplefilter("default", OkidWarning)  # once per run: a new filter forgets earlier runs
        try:
            with made_folders_removed_on_failure():  # a failed command leaves no empty folder it made
                return work()
        except OkidError as exc:
            # Expected failures are one line, like argparse's own usage errors, never a traceback.
            print(f"{PROG} {command}: error: {_naming_source(exc, source)}", file=sys.stderr)
            return 2
        except KeyboardInterrupt:
            print(f"{PROG} {command}: interrupted", file=sys.stderr)
            return 130
        except BrokenPipeError:
            # The reader of the output went away (`okid-ros identify ... | head -1`): end silently with
            # 128 + SIGPIPE as a piped Unix tool does, after the outputs the command wrote so far.
            _stdout_to_devnull()
            return 128 + signal.SIGPIPE
        except MemoryError:
            print(f"{PROG} {command}: error: out of memory (the data or the options need more memory than "
                  f"this machine has; try a shorter record or smaller orders)", file=sys.stderr)
            return 2
        except Exception as exc:  # noqa: BLE001 - the last guard: a bug still prints one line
            if os.environ.get("OKID_ROS_TRACEBACK"):
                raise
            print(f"{PROG} {command}: error: internal error, please report it with the command line "
                  f"({type(exc).__name__}: {one_line(exc)}; set OKID_ROS_TRACEBACK=1 "
                  f"for the traceback)", file=sys.stderr)
            return 70


@contextlib.contextmanager
def _terminate_as_interrupt() -> Iterator[None]:
    """SIGTERM (``timeout``, ``docker stop``, systemd) ends a command as Ctrl-C does: its outputs closed.

    Only in the main thread, where Python can install a handler; the previous one is restored.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    from okid_ros.tools.interrupts import interrupt

    # Ctrl-C too, where Python's default raises at once: a bag record is not cut in two (tools/interrupts.py).
    ctrl_c = signal.getsignal(signal.SIGINT) is signal.default_int_handler
    signals = [signal.SIGTERM, signal.SIGINT] if ctrl_c else [signal.SIGTERM]
    previous = {signum: signal.signal(signum, interrupt) for signum in signals}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def _stdout_to_devnull() -> None:
    """Point the process's stdout at /dev/null: the flush at exit would meet the broken pipe again."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # a captured stdout (tests): nothing to redirect
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, fd)
    os.close(devnull)


def _naming_source(exc: OkidError, source: str | None) -> str:
    """The message of ``exc``, prefixed with ``source`` when it is about the data and does not name it."""
    text = one_line(exc)
    if not source or not isinstance(exc, DataError) or isinstance(exc, OutputError):
        return text
    # named as errors.shown_path shows it, or raw by a message that does not use it (one_line's form)
    named = shown_path(source) in text or one_line(source) in text
    return text if named else f"{shown_path(source)}: {text}"


def _one_line_warning(command: str) -> Callable[..., None]:
    """A ``warnings.showwarning`` that prints ``okid-ros COMMAND: warning: ...`` on one line."""

    def show(message, category, filename, lineno, file=None, line=None) -> None:
        # okid-ros's own warnings say what is wrong; another's (numpy's, scipy's) is located for a report
        where = f" ({category.__name__} at {os.path.basename(filename)}:{lineno})"
        where = "" if issubclass(category, OkidWarning) else where
        print(f"{PROG} {command}: warning: {one_line(message)}{where}",
              file=sys.stderr if file is None else file)

    return show

if __name__ == "__main__":
    sys.exit(main())
