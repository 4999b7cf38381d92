"""Column names of a record's CSV header that name one column twice (record_csv.py refuses them)."""

from __future__ import annotations

from collections.abc import Sequence

__all__ = ["repeated_column_names"]


def repeated_column_names(header: Sequence[str], read: Sequence[int]) -> str:
    """The names the ``read`` columns of ``header`` give more than once, worded ('' when none is).

    Names are compared without their case, as the reader takes a channel by its first letter in
    either case: ``y1`` and ``Y1`` are two outputs of one name (``2 columns 'y1' and 'Y1', one
    name but for its case``), as ``y1`` twice is (``2 columns 'y1'``).
    """
    spellings: dict[str, list[str]] = {}
    for column in read:
        spellings.setdefault(header[column].lower(), []).append(header[column])
    worded = []
    for names in spellings.values():
        if len(names) > 1:
            distinct = list(dict.fromkeys(names))
            if len(distinct) == 1:
                worded.append(f"{len(names)} columns {distinct[0]!r}")
            else:
                shown = ", ".join(map(repr, distinct[:-1])) + f" and {distinct[-1]!r}"
                worded.append(f"{len(names)} columns {shown}, one name but for its case")
    return "; ".join(worded)
