"""Running `okid-ros` in-process in tests: its status and output, and the one-line error rule."""

from __future__ import annotations

from okid_ros.cli import main


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    """``okid-ros ARGV`` in this process: (status, stdout, stderr) of this call only."""
    capsys.readouterr()
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def assert_one_line_error(code: int, err: str, *fragments: str) -> None:
    """Status 2 and one line on stderr, no traceback, holding every fragment."""
    assert code == 2, err
    assert "Traceback" not in err and err.strip().count("\n") == 0, err
    for fragment in fragments:
        assert fragment in err, err
