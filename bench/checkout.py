"""The root of the checkout on ``sys.path``, after the trees that ``PYTHONPATH`` names.

A bench script runs the ``okid_ros`` of the checkout it lives in, unless ``PYTHONPATH`` names
another tree: an old commit unpacked beside it (``git archive``) to compare with, which must then
be the code that runs. Putting the checkout first (as the scripts did) silently ran the new code
under the old one's name. Imported like ``blas_threads`` (Python puts the script's folder on
``sys.path``): ``import checkout`` then ``checkout.add()``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def add(*parts: str) -> None:
    """Put ``REPO / part`` (the root when no part is given) on ``sys.path`` after PYTHONPATH's entries."""
    named = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    # sys.path starts with the script's folder, then PYTHONPATH's entries in their order.
    position = 1 + len(named) if named else 0
    for part in reversed(parts or ("",)):
        path = str(REPO / part) if part else str(REPO)
        if path not in sys.path[:position]:
            sys.path.insert(position, path)
