"""A campaign given one recording twice says so (forty-seventh session); no bag is processed here."""

from __future__ import annotations

from pathlib import Path

import pytest

from okid_ros.tools.campaign.runner import CampaignOptions, CampaignReport
from okid_ros.tools.campaign.summary import print_summary


def _entry(bag: str, start_s: float) -> dict:
    return {"bag": bag, "status": "ok", "models": 1, "samples": 2500, "duration_s": 19.992, "start_s": start_s}


def _rows(bag: str, frequency_hz: float) -> list[dict]:
    return [{"bag": bag, "mode_id": 0, "stamp_s": 5.0, "frequency_hz": frequency_hz, "damping_ratio": 0.01}]


@pytest.mark.parametrize(("start_b", "frequency_b", "said"), [
    (100.0, 5.9, True),  # a copy: same samples and modes
    (106.0, 5.9, False),  # another recording, started later
    (100.0, 6.1, False),  # two rigs recorded at once: same span, other modes
    (100.0, None, False),  # neither bag gave a mode: equal stamps and counts alone are no copy
])
def test_a_recording_given_twice_is_named(tmp_path, capsys, start_b, frequency_b, said):
    """Copies of a bag (another folder, another name) put its modes in the tables twice: named, not refused."""
    entries = [_entry("camp/a/run", 100.0), _entry("camp/d/run", start_b)]
    rows = [] if frequency_b is None else _rows("camp/a/run", 5.9) + _rows("camp/d/run", frequency_b)
    report = CampaignReport(entries=entries, rows=rows,
                            elapsed_s=1.0, written=[tmp_path / "modes.parquet"])
    options = CampaignOptions(paths=["camp"], out_dir=Path(tmp_path), arx_values={}, est_values={})
    print_summary(report, options)
    err = capsys.readouterr().err
    assert ("camp/a/run and camp/d/run: the same samples" in err) is said
    assert ("batch --forget" in err) is said
