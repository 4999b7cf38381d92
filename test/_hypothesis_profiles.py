"""Hypothesis profiles of the property-based tests (test_property_*.py import this module).

``ci`` (default): few examples and no deadline, so the whole property set stays under about a
minute on a loaded 2-core machine. ``bench``: many more examples, for a longer robustness run::

    HYPOTHESIS_PROFILE=bench pytest test/test_property_*.py

See docs/robustness.md.
"""

from __future__ import annotations

import os

from hypothesis import HealthCheck, settings

settings.register_profile(
    "ci", max_examples=25, deadline=None, derandomize=True, print_blob=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
settings.register_profile(
    "bench", max_examples=400, deadline=None, print_blob=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

#: Fewer examples for the properties whose example runs a whole command (identify, track).
SLOW = settings(max_examples=max(4, settings().max_examples // 5))
