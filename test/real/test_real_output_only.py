"""The steel subframe's 28 accelerations alone, against its 15 input-output reference modes (issue 18's goal).

The shaker forces are not used. Found: an identified mode within 0.5 % of a reference frequency
(nearest first, one each); spurious: a listed mode within 2 % of no reference mode and of none of
the poles its README names uncertain; the damping against the reference's (itself an
input-output estimate).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from real_helpers import RECORD_DIR

from okid_ros.core.output_only import identify_output_only


def _reference() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    reference = json.loads((RECORD_DIR / "truth.json").read_text())["reference_estimates_not_published"]
    frequency_hz = np.array([m["f_Hz"] for m in reference["modes"]])
    damping = np.array([m["zeta_pct"] / 100 for m in reference["modes"]])
    uncertain_hz = np.array([m["f_Hz"] for m in reference["uncertain_near_band_edge_or_unstable"]])
    return frequency_hz, damping, uncertain_hz


@pytest.mark.parametrize("method", ["ssi-cva"])
def test_the_subframe_outputs_alone_give_its_reference_modes(method: str) -> None:
    record = np.load(RECORD_DIR / "steel_subframe.npz")
    model = identify_output_only(record["y"], float(record["sample_time_s"]), method=method)
    reference_hz, reference_damping, uncertain_hz = _reference()
    listed_hz = np.array([m.frequency_hz for m in model.modes])
    listed_damping = np.array([m.damping_ratio for m in model.modes])
    found, free = {}, set(range(listed_hz.size))
    for k in np.argsort([np.min(np.abs(listed_hz / f - 1)) for f in reference_hz]):
        j = min(free, key=lambda i: abs(listed_hz[i] / reference_hz[k] - 1), default=None)
        if j is not None and abs(listed_hz[j] / reference_hz[k] - 1) <= 0.005:
            found[k] = j
            free.discard(j)
    near = np.concatenate([reference_hz, uncertain_hz])
    spurious = [listed_hz[j] for j in free if np.min(np.abs(listed_hz[j] / near - 1)) > 0.02]
    within = [abs(listed_damping[j] / reference_damping[k] - 1) <= 0.3 for k, j in found.items()]
    assert len(found) >= 14, (sorted(listed_hz), reference_hz)
    assert len(spurious) <= 1, spurious
    # measured 14 of 15 within 30 % (forty-second session); at the record's capped 71 block rows 6 of 14;
    # 12 of 15 with the correlations' taper off the poles (forty-fourth: 119, 229.5, 417.5 Hz at -31 to -34 %
    # against input-output reference estimates of the same 8.3 s, docs/benchmarks-output-only.md)
    assert np.mean(within) >= 0.8, dict(zip(reference_hz[list(found)], listed_damping[list(found.values())]))
