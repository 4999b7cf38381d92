"""The one-screen summary printed at the end of `okid-ros batch`."""

from __future__ import annotations

from collections.abc import Callable

from okid_ros.errors import shown_path
from okid_ros.tools.campaign.runner import CampaignOptions, CampaignReport

__all__ = ["print_summary"]

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
    emit(f"wrote {', '.join(shown_path(p) for p in report.written)}; per-bag outputs in "
         f"{shown_path(options.out_dir / 'bags')}")
