"""The one-screen summary printed at the end of `okid-ros batch`."""

from __future__ import annotations

import sys
from collections.abc import Callable

from okid_ros.errors import shown_path
from okid_ros.tools.campaign.runner import CampaignOptions, CampaignReport

__all__ = ["print_summary", "same_recordings"]

#: Failed bags listed by name; the rest are counted (summary.csv has them all).
_MAX_LISTED = 10


def print_summary(report: CampaignReport, options: CampaignOptions, emit: Callable[[str], None] = print) -> None:
    """Bags ok/failed/skipped (and reused), models, modes tracked, time, the failures, the outputs."""
    entries = report.entries
    reused = sum(1 for e in entries if e.get("reused"))
    models = sum(int(e.get("models", 0)) for e in entries if e["status"] == "ok")
    samples = sum(int(e.get("samples", 0)) for e in entries if e["status"] == "ok")
    mode_ids = {row["mode_id"] for row in report.rows}
    processed = len(entries) - reused - report.count("skipped")
    started = min(options.workers, processed + report.count("skipped"))  # the pool's processes (engines.run_jobs)
    engine = (f"Dask scheduler {options.scheduler}" if options.scheduler
              else f"{started} local worker(s)" if started > 1 else "serial")
    kept = sum(1 for e in entries if not e.get("given", True))
    emit(f"batch: {len(entries)} bags: {report.count('ok')} ok, {report.count('failed')} failed, "
         f"{report.count('skipped')} skipped; {processed} processed now ({engine}), {reused} unchanged since the "
         f"last run" + (f" ({kept} of them not given this time, kept from the campaign's journal)" if kept else ""))
    emit(f"  {models} model updates over {samples} samples, {len(report.rows)} mode rows, "
         f"{len(mode_ids)} mode ids tracked across the campaign; {report.elapsed_s:.1f} s")
    for mode_id in sorted(mode_ids)[:_MAX_LISTED]:
        rows = [r for r in report.rows if r["mode_id"] == mode_id]
        freqs = sorted(r["frequency_hz"] for r in rows)
        damping = sorted(r["damping_ratio"] for r in rows)
        emit(f"  mode {mode_id:3d}: {len(rows):4d} updates in {len({r['bag'] for r in rows})} bag(s), "
             f"median {freqs[len(freqs) // 2]:9.4f} Hz, damping {100 * damping[len(damping) // 2]:6.3f} %")
    if len(mode_ids) > _MAX_LISTED:
        emit(f"  ... and {len(mode_ids) - _MAX_LISTED} more mode ids (modes.parquet)")
    problems = [e for e in entries if e["status"] != "ok"]
    for entry in problems[:_MAX_LISTED]:
        emit(f"  {entry['status']}: {entry['reason']}")
    if len(problems) > _MAX_LISTED:
        emit(f"  ... and {len(problems) - _MAX_LISTED} more (summary.csv)")
    if twice := same_recordings(entries, report.rows):
        print(f"okid-ros batch: warning: {twice}", file=sys.stderr)
    emit(f"wrote {', '.join(shown_path(p) for p in report.written)}; per-bag outputs in "
         f"{shown_path(options.out_dir / 'bags')}")


def same_recordings(entries: list[dict], rows: list[dict]) -> str:
    """Which bags of the campaign hold one recording twice ('' if none): their mode rows would count twice.

    Two bags whose samples start at the same stamp, span the same time, number the same and give
    the same modes to the last bit are copies (a bag copied to another folder, or under another
    name; two rigs recorded at once differ in their modes; bags with no mode are never named): the
    campaign keeps both, as given, and says so, since its medians and counts then weigh that
    recording twice.
    """
    modes: dict[str, list] = {}
    for row in rows:
        modes.setdefault(str(row["bag"]), []).append((row["stamp_s"], row["frequency_hz"], row["damping_ratio"]))
    groups: dict[tuple, list[str]] = {}
    for entry in entries:
        found = tuple(modes.get(str(entry["bag"]), ()))
        # Without modes, equal stamps and counts say nothing: simulated or rig bags share their start and length.
        if entry["status"] == "ok" and int(entry.get("samples", 0)) > 0 and found:
            key = (entry.get("start_s"), entry.get("duration_s"), int(entry["samples"]), found)
            groups.setdefault(key, []).append(shown_path(entry["bag"]))
    copies = [bags for bags in groups.values() if len(bags) > 1]
    if not copies:
        return ""
    listed = "; ".join(" and ".join(bags) for bags in copies)
    return (f"{listed}: the same samples (first stamp, span and count) and modes, one recording given more than "
            "once? Its modes are in the tables once per copy; take the copies out (okid-ros batch --forget BAG --out "
            "DIR)")
