"""Expected failures: raised by commands, printed by the CLI as one line without a traceback."""


class OkidError(Exception):
    """A failure the user can fix (bad input, bad option); `okid-ros` exits with status 2."""


class DataError(OkidError):
    """Input data is missing, unreadable or inconsistent (files, bags, topics, array sizes)."""


class ParameterError(OkidError):
    """A parameter or option value is invalid; the message names it and its valid range."""
