"""The `okid-ros` entry point: subcommand registration, errors as one line, no ROS for --help."""

from __future__ import annotations

import argparse
import subprocess
import sys
import types
from importlib import metadata

import pytest

import okid_ros
from okid_ros import cli
from okid_ros.errors import DataError, OkidError, ParameterError


def test_help_lists_every_command(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    for module in cli.COMMAND_MODULES:
        assert f"    {module.rsplit('.', 1)[-1]} " in out


def test_no_command_prints_help_and_exits_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main([]) == 2
    assert "usage: okid-ros" in capsys.readouterr().err


def test_version(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        cli.main(["--version"])
    assert capsys.readouterr().out.strip() == f"okid-ros {okid_ros.__version__}"


@pytest.fixture
def fake_command(monkeypatch: pytest.MonkeyPatch) -> types.ModuleType:
    """A command module `fake` whose run() raises what the test puts in `module.error`."""
    module = types.ModuleType("okid_ros_test_fake_command")
    module.error = None

    def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
        parser = subparsers.add_parser("fake", help="test command")
        parser.set_defaults(func=run)
        return parser

    def run(args: argparse.Namespace) -> int:
        if module.error is not None:
            raise module.error
        return 7

    module.add_parser, module.run = add_parser, run
    monkeypatch.setitem(sys.modules, module.__name__, module)
    monkeypatch.setattr(cli, "COMMAND_MODULES", (*cli.COMMAND_MODULES, module.__name__))
    return module


def test_command_exit_status_is_returned(fake_command: types.ModuleType) -> None:
    assert cli.main(["fake"]) == 7


@pytest.mark.parametrize("error", [OkidError("plain"), DataError("no topic /imu in bag.mcap"),
                                   ParameterError("window_length must be in [10, 100000]")])
def test_okid_error_is_one_line_and_status_2(fake_command: types.ModuleType, error: OkidError,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    fake_command.error = error
    assert cli.main(["fake"]) == 2
    captured = capsys.readouterr()
    assert captured.err == f"okid-ros fake: error: {error}\n"
    assert captured.out == ""


def test_other_exceptions_are_not_hidden(fake_command: types.ModuleType, monkeypatch: pytest.MonkeyPatch,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    # A bug is one line naming the exception (status 70), its traceback on request.
    fake_command.error = ZeroDivisionError("a bug")
    monkeypatch.delenv("OKID_ROS_TRACEBACK", raising=False)
    assert cli.main(["fake"]) == 70
    assert "ZeroDivisionError: a bug" in capsys.readouterr().err
    monkeypatch.setenv("OKID_ROS_TRACEBACK", "1")
    with pytest.raises(ZeroDivisionError):
        cli.main(["fake"])


def test_unimportable_command_does_not_break_the_others(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    missing = "okid_ros.commands.not_written_yet"
    monkeypatch.setattr(cli, "COMMAND_MODULES", (*cli.COMMAND_MODULES, missing))
    assert "not_written_yet" in cli.build_parser().format_help()
    assert cli.main(["not_written_yet", "--some", "args"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("okid-ros not_written_yet: error: this command is unavailable: ")
    assert err.count("\n") == 1


def test_command_modules_follow_the_contract() -> None:
    """Each module has add_parser and run, and the parser is built without ROS, plotting or numpy.

    (`track`'s parser took 1.2 s of every command's start importing the numerical modules for two
    defaults; they are read from the parameter table when used now.)

    Run in a fresh interpreter: this one has imported rclpy already.
    """
    code = (
        "import sys; from okid_ros import cli; cli.build_parser()\n"
        "heavy = sorted(m for m in ('rclpy', 'okid_msgs', 'matplotlib', 'rosbags', 'numpy', 'scipy')"
        " if m in sys.modules)\n"
        "assert not heavy, f'imported while building the parser: {heavy}'\n"
        "import importlib\n"
        "for name in cli.COMMAND_MODULES:\n"
        "    module = importlib.import_module(name)\n"
        "    assert callable(module.add_parser) and callable(module.run), name\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 0, result.stderr


def test_console_scripts_are_declared() -> None:
    scripts = {ep.name: ep.value for ep in metadata.entry_points(group="console_scripts")
               if ep.value.startswith("okid_ros.")}
    assert scripts["okid-ros"] == "okid_ros.cli:main"
    assert scripts["arx_identifier"] == "okid_ros.nodes.arx_identifier_node:main"
    assert scripts["modal_estimator"] == "okid_ros.nodes.modal_estimator_node:main"


def test_info_selftest_over_dds(ros_env: dict[str, str]) -> None:
    """`make demo`'s current command: okid_msgs through Fast DDS in a separate process."""
    result = subprocess.run(
        [sys.executable, "-m", "okid_ros.cli", "info", "--selftest", "--count", "50"],
        env=ros_env, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "selftest: 50/50 okid_msgs/IoSample delivered over rmw_fastrtps_cpp" in result.stdout
    assert f"ROS_DOMAIN_ID={ros_env['ROS_DOMAIN_ID']}" in result.stdout


def test_an_option_that_defaults_to_a_node_parameter_reads_the_parameter_table() -> None:
    from okid_ros.core.change_detection import DEFAULT_FALSE_ALARM_SAMPLES
    from okid_ros.service.identification import ArxIdentificationParams

    args = cli.build_parser().parse_args(["track", "data.npz", "--jsonl", "out.jsonl"])
    assert float(args.false_alarm_samples) == DEFAULT_FALSE_ALARM_SAMPLES
    assert float(args.restart_min_fill) == ArxIdentificationParams.restart_min_fill
    assert str(args.false_alarm_samples) == "1e+07"  # as `track --help` shows it
    given = cli.build_parser().parse_args(["track", "d.npz", "--jsonl", "o", "--false-alarm-samples", "1e5"])
    assert given.false_alarm_samples == 1e5


@pytest.mark.parametrize("argv, words", [
    (["track", "x.npz", "--every", "0", "--jsonl", "x.jsonl"],
     "okid-ros track: error: argument --every: expected a positive"),
    (["identify"], "okid-ros identify: error: the following arguments are required: data, --json"),
    (["bogus"], "okid-ros: error: argument COMMAND: invalid choice: 'bogus'"),
])
def test_a_usage_error_is_one_line_as_every_other_error(capsys: pytest.CaptureFixture[str], argv, words) -> None:
    # argparse printed its usage (three lines) before the error line.
    with pytest.raises(SystemExit) as exited:
        cli.main(argv)
    err = capsys.readouterr().err
    assert exited.value.code == 2 and err.count("\n") == 1 and err.startswith(words), err
    assert err.rstrip().endswith(f"(see {words.split(': error')[0]} --help)")


def test_a_reader_that_goes_away_ends_the_command_as_a_piped_tool(tmp_path) -> None:
    # `okid-ros identify ... | head -1` was "internal error ... BrokenPipeError", exit 70, after the JSON.
    import numpy as np

    from okid_ros.sim.inputs import lowpass_input
    from okid_ros.sim.paper_model import paper_model
    from okid_ros.sim.simulators import simulate_innovation

    truth = paper_model()
    u = lowpass_input(1500, 2, 15.0, truth.sample_time_s, seed=3)
    y, _ = simulate_innovation(truth, u, seed=4)
    np.savez(tmp_path / "run.npz", u=u, y=y, sample_time_s=truth.sample_time_s)
    command = [sys.executable, "-m", "okid_ros.cli", "identify", str(tmp_path / "run.npz"), "--order", "20",
               "--json", str(tmp_path / "model.json")]
    child = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    child.stdout.close()  # the reader is gone before the report is printed
    _, err = child.communicate(timeout=120)
    assert child.returncode == 141, err.decode()  # 128 + SIGPIPE, as `yes | head -1` leaves `yes`
    assert err.decode() == ""
    assert (tmp_path / "model.json").is_file()
