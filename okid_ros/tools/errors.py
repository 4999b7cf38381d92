"""Errors of the bag tools.

All are :class:`okid_ros.errors.OkidError`, so `okid-ros` prints them as one line
(``okid-ros process: error: ...``) and exits with status 2.
"""

from __future__ import annotations

from okid_ros.errors import DataError, OkidError, OutputError, ParameterError

__all__ = ["BagReadError", "BagWriteError", "OutputExistsError", "ReplayError", "ToolParameterError"]


class BagReadError(DataError):
    """A bag is missing, corrupt, or lacks a topic or type; the message names path and topic."""


class BagWriteError(OutputError):
    """A bag (or another output file) cannot be written."""


class OutputExistsError(BagWriteError):
    """The output path exists and overwriting was not asked for (``--force``)."""


class ReplayError(OkidError):
    """Replay cannot start: ROS is unavailable, or a message type has no Python class."""


class ToolParameterError(ParameterError):
    """An option of a tool is out of range; the message names the option and the range."""
