"""The code passes the linter, as the rclpy packages lint themselves in their tests.

ruff, configured in ruff.toml: pyflakes, pycodestyle, import order, numpy-style docstrings.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _ruff() -> list[str]:
    """The ruff of this environment (installed by `make setup` from requirements/test.txt)."""
    exe = Path(sys.executable).with_name("ruff")
    if exe.is_file():
        return [str(exe)]
    found = shutil.which("ruff")
    if found is None:
        pytest.fail("ruff is not installed: run `make setup` (requirements/test.txt)")
    return [found]


def test_ruff_finds_nothing():
    result = subprocess.run(
        [*_ruff(), "check", "--no-cache", "--output-format", "concise", "okid_ros", "bench", "test"],
        cwd=ROOT, capture_output=True, text=True, timeout=120,
    )
    assert result.returncode == 0, f"ruff findings:\n{result.stdout}{result.stderr}"


def test_ruff_reads_the_project_configuration():
    """The rules above are those of ruff.toml (a missing file would lint with ruff's defaults)."""
    result = subprocess.run(
        [*_ruff(), "check", "--show-settings", "okid_ros/core/recursive.py"],
        cwd=ROOT, capture_output=True, text=True, timeout=60,
    )
    assert result.returncode == 0, result.stderr
    assert str(ROOT / "ruff.toml") in result.stdout
    assert "line_length = 120" in result.stdout.replace("linter.line_length", "line_length")
