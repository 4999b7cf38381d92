"""`okid-ros batch`: find the bags, skip what is done, run the rest, gather, write the tables.

The order of a run: the bags are found and fingerprinted; a bag whose manifest entry matches
(same path, size, modification time and parameters' hash) is taken as it is (``reused``), as is one
journaled at another path it was moved from (:mod:`~okid_ros.tools.campaign.moved`), the
others become jobs for the engine; each finished bag is journaled at once; then campaign mode
ids are given over every ok bag and ``modes.parquet`` and ``summary.csv`` are written (both
atomically, rebuilt from the per-bag results each run, so a run killed before this point is
completed by the next one). The tables hold every bag of the journal, given this run or not: a
campaign grows run by run, and nothing identified before leaves its tables.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

from okid_ros.errors import OkidError, OutputError, shown_path
from okid_ros.tools.campaign import SCHEDULER_TIMEOUT_S
from okid_ros.tools.campaign.discovery import bag_fingerprint, bag_label, find_bags, plan_bag
from okid_ros.tools.campaign.engines import run_jobs
from okid_ros.tools.campaign.forget import forget_entries, journaled_entries
from okid_ros.tools.campaign.lock import LEFTOVER_PREFIXES, campaign_lock, remove_leftovers
from okid_ros.tools.campaign.manifest import MANIFEST_NAME, Manifest, parameters_hash
from okid_ros.tools.campaign.moved import drop_replaced, journaled_elsewhere, take_moved
from okid_ros.tools.campaign.stored import stored_result
from okid_ros.tools.campaign.table import campaign_order, mode_rows, write_modes, write_summary
from okid_ros.tools.campaign.worker import BagJob
from okid_ros.tools.output_paths import check_output_paths

__all__ = ["CampaignOptions", "CampaignReport", "input_topics", "is_campaign_dir", "run_campaign"]


@dataclass
class CampaignOptions:
    """What `okid-ros batch` was asked to do (see its --help)."""

    paths: list[str]
    out_dir: Path
    arx_values: dict
    est_values: dict
    namespace: str | None = None
    storage: str = "mcap"
    workers: int = 1
    scheduler: str | None = None
    scheduler_timeout_s: float = SCHEDULER_TIMEOUT_S
    force: bool = False
    retry_failed: bool = False
    max_failures: int | None = None
    csv: bool = False
    progress: bool | None = None
    provenance: dict = field(default_factory=dict)
    #: Bags to take out of the campaign (``--forget``): none processed, the tables rebuilt without them.
    forget: list[str] = field(default_factory=list)


@dataclass
class CampaignReport:
    """What a run did: one summary entry per bag (campaign order) and the mode rows."""

    entries: list[dict]
    rows: list[dict]
    elapsed_s: float
    written: list[Path]

    def count(self, status: str) -> int:
        return sum(1 for e in self.entries if e["status"] == status)

    @property
    def exit_status(self) -> int:
        """0 when every bag given is ok, 1 otherwise (failed or not run); bags kept from the journal do not count."""
        return 0 if all(e["status"] == "ok" for e in self.entries if e.get("given", True)) else 1


def is_campaign_dir(path: Path) -> bool:
    """True for a directory written by `okid-ros batch` (False for a path that cannot be looked at)."""
    try:
        return Path(path).is_dir() and (Path(path) / MANIFEST_NAME).is_file()
    except OSError:  # a name too long: not a campaign; the command reading it says what is wrong
        return False


def input_topics(arx_values: dict, est_values: dict, namespace: str | None) -> list[str]:
    """Input topics of both nodes, as `process` reads them."""
    from okid_ros.service.inputs import sources_and_grid

    topics: list[str] = []
    for values in (arx_values, est_values):
        specs, _ = sources_and_grid(values, namespace)
        topics += [spec.topic for spec in specs if spec.topic not in topics]
    return topics


def _check_out_dir(out_dir: Path) -> None:
    """Refuse an --out that is not a new, empty or campaign directory, or cannot be created; create it.

    A file there is `batch`'s refusal (``output_paths.check_folder_option``, before the work); one made
    since fails the mkdir below.
    """
    try:
        if out_dir.is_dir() and any(out_dir.iterdir()) and not is_campaign_dir(out_dir):
            raise OutputError(f"--out {shown_path(out_dir)}: a non-empty directory that is not a campaign of "
                              "okid-ros batch "
                              f"(no {MANIFEST_NAME}); give a new or empty directory")
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:  # a read-only place, /proc, a name too long, no permission
        raise OutputError(f"--out {shown_path(out_dir)}: cannot create the campaign directory "
                          f"({exc.strerror or exc})") from None


def _job(options: CampaignOptions, bag: Path, state_space_topic: str) -> BagJob:
    return BagJob(bag=str(bag.resolve()), display=str(bag), label=bag_label(bag),
                  out_dir=str(options.out_dir.resolve()), arx_values=options.arx_values,
                  est_values=options.est_values, namespace=options.namespace,
                  storage=options.storage, state_space_topic=state_space_topic,
                  provenance={**options.provenance, "campaign": str(options.out_dir.resolve())})


def _reused(entry: dict, out_dir: Path, retry_failed: bool, bag: Path) -> dict | None:
    """The result kept for an unchanged bag, or None when it must run again (a spoilt one: with a warning)."""
    result, problem = stored_result(entry, out_dir, retry_failed)
    if problem:
        print(f"okid-ros batch: warning: {problem}; processing {shown_path(bag)} again", file=sys.stderr)
    return result


def run_campaign(options: CampaignOptions) -> CampaignReport:
    """Run a campaign (see the module docstring); returns its report.

    Raises
    ------
    OkidError
        a usage error: a path missing, no bags found, an --out that is not a campaign directory, or
        one another batch is running on (campaign/lock.py).
    """
    started = time.perf_counter()
    out_dir = options.out_dir
    if options.forget:
        return _forget(options, started)
    bags = find_bags(options.paths, exclude=out_dir)
    if not bags:
        raise OkidError(f"no bags found in {', '.join(map(shown_path, options.paths))}")
    for bag in bags:  # a campaign inside a bag would fail every bag and spoil it as a bag
        check_output_paths(bag, "input bag", [(out_dir, "campaign folder")])
    _check_out_dir(out_dir)
    with campaign_lock(out_dir) as locked:  # from the journal read to the tables written
        _start_campaign(out_dir, locked=locked)
        return _run_locked(options, bags, started)


def _forget(options: CampaignOptions, started: float) -> CampaignReport:
    """Take ``options.forget`` out of the campaign (campaign/forget.py) and rebuild its tables, under its lock."""
    out_dir = options.out_dir
    if not is_campaign_dir(out_dir):
        raise OutputError(f"--out {shown_path(out_dir)}: not a campaign of okid-ros batch (no {MANIFEST_NAME}): no "
                          "bag to forget")
    params_hash = parameters_hash(options.arx_values, options.est_values, namespace=options.namespace,
                                  storage=options.storage)
    with campaign_lock(out_dir) as locked:
        _start_campaign(out_dir, locked=locked)
        manifest = _read_journal(out_dir)
        forget_entries(manifest, journaled_entries(manifest, options.forget, out_dir), out_dir, remove=options.force)
        return _finish(options, manifest, _kept_from_journal(manifest, [], {}, out_dir, params_hash), started)


def _read_journal(out_dir: Path) -> Manifest:
    """The campaign's journal, its unreadable lines said (the journal is rewritten without them)."""
    manifest = Manifest(out_dir)
    if manifest.unreadable:
        print(f"okid-ros batch: warning: {shown_path(manifest.path)}: {manifest.unreadable} unreadable line(s) "
              f"ignored (not JSON text): their bags are left out of the tables, and processed again when given",
              file=sys.stderr)
    return manifest


def _start_campaign(out_dir: Path, *, locked: bool) -> None:
    """Remove what a killed run left under ``DIR/bags`` when ``locked`` (saying so); mark ``DIR`` a campaign.

    The journal is made, empty, at the start: a first run killed before any bag was done left a
    folder that the next run refused as "not a campaign".
    """
    removed = remove_leftovers(out_dir) if locked else 0
    if removed:
        print(f"okid-ros batch: removed {removed} unfinished folder(s) under {shown_path(out_dir / 'bags')} left by "
              f"a run that was killed ({', '.join(prefix + '*' for prefix in LEFTOVER_PREFIXES)})", file=sys.stderr)
    try:
        (out_dir / MANIFEST_NAME).touch()
    except OSError as exc:
        raise OutputError(f"--out {shown_path(out_dir)}: cannot write the campaign's journal "
                          f"({exc.strerror or exc})") from None


def _run_locked(options: CampaignOptions, bags: list[Path], started: float) -> CampaignReport:
    """The rest of :func:`run_campaign`, under the campaign's lock."""
    from okid_ros.service.topics import resolve_topic

    out_dir = options.out_dir
    params_hash = parameters_hash(options.arx_values, options.est_values, namespace=options.namespace,
                                  storage=options.storage)
    manifest = _read_journal(out_dir)
    ss_topic = resolve_topic(options.est_values["state_space_model_topic"], options.namespace)
    results: dict[str, dict] = {}
    jobs: list[BagJob] = []
    fingerprints: dict[str, tuple[int, int]] = {}
    given, replaced = {Manifest.key(bag) for bag in bags}, {}  # replaced: the entries of moved bags run again
    for bag in bags:
        fingerprints[str(bag)] = fingerprint = bag_fingerprint(bag)
        entry = None if options.force else manifest.lookup(bag, *fingerprint, params_hash)
        kept = None if entry is None else _reused(entry, out_dir, options.retry_failed, bag)
        moved = None if entry is not None else journaled_elsewhere(manifest, bag, fingerprint, given)
        if moved is not None and not options.force and moved.get("params_hash") == params_hash:
            stored = _reused(moved, out_dir, options.retry_failed, bag)
            kept = None if stored is None else take_moved(manifest, moved, stored, bag, fingerprint, out_dir)
        if kept is not None:
            results[str(bag)] = {**kept, "bag": str(bag), "reused": True}
        else:
            replaced[str(bag)] = moved
            jobs.append(_job(options, bag, ss_topic))
    topics = input_topics(options.arx_values, options.est_values, options.namespace)
    bar = CampaignBar(jobs, topics, options.progress)
    failures = 0

    def on_result(job: BagJob, result: dict) -> bool:
        nonlocal failures
        if not result.get("transient"):
            manifest.record(Path(job.bag), *fingerprints[job.display], params_hash, result)
            if replaced.get(job.display) is not None:
                drop_replaced(manifest, replaced[job.display], out_dir, result)
        results[job.display] = {**result, "reused": False}
        failures += result["status"] == "failed"
        bar.done(job, result)
        return options.max_failures is not None and failures >= options.max_failures

    try:
        not_run = run_jobs(jobs, on_result, workers=options.workers, scheduler=options.scheduler,
                           scheduler_timeout_s=options.scheduler_timeout_s)
    finally:
        bar.close()
        manifest.close()
    for job in not_run:
        results[job.display] = {"bag": job.display, "label": job.label, "status": "skipped",
                                "reason": f"not run: --max-failures {options.max_failures} reached", "models": 0,
                                "samples": 0, "duration_s": math.nan, "start_s": math.nan, "seconds": 0.0,
                                "reused": False, "updates": []}
    for result in results.values():
        result["given"] = True
    kept = _kept_from_journal(manifest, bags, fingerprints, out_dir, params_hash)
    return _finish(options, manifest, list(results.values()) + kept, started)


def _kept_from_journal(manifest: Manifest, bags: list[Path], fingerprints: dict[str, tuple[int, int]],
                       out_dir: Path, params_hash: str) -> list[dict]:
    """The journaled bags not given this run, as their earlier runs left them (the tables keep them).

    A campaign grows run by run (``batch DIR/new_bag.mcap --out DIR``): rewriting the tables with the
    bags given this time only dropped the rows of every bag identified before, in silence. A bag is
    known by its absolute path; one journaled or given at another path with the same name, size and
    modification time (the input folder moved) is that bag, not kept twice. A journaled bag whose stored result
    is gone or spoilt is left out with a warning (give it again to process it).
    """
    given = {Manifest.key(bag) for bag in bags}
    seen = {(bag.resolve().name, *fingerprints[str(bag)]) for bag in bags}
    kept, other_parameters = [], 0
    for key, entry in reversed(manifest.entries.items()):  # the newest path of a moved bag first
        same = (Path(key).name, entry.get("size"), entry.get("mtime_ns"))
        if key in given or same in seen:
            continue
        seen.add(same)
        result, problem = stored_result(entry, out_dir, retry_failed=False)
        if result is None:
            why = problem or f"{shown_path(key)}: its outputs under {shown_path(out_dir / 'bags')} are gone"
            print(f"okid-ros batch: warning: {why}; the bag is not given this time: left out of the tables (give "
                  "it again to process it)", file=sys.stderr)
            continue
        other_parameters += entry.get("params_hash") != params_hash
        kept.append({**result, "bag": str(result.get("bag") or key), "reused": True, "given": False})
    if other_parameters:
        print(f"okid-ros batch: warning: {other_parameters} bag(s) of the campaign not given this time were "
              "identified with other parameters; the tables keep them as they are (give them again to redo "
              "them with these)", file=sys.stderr)
    return kept


def _finish(options: CampaignOptions, manifest: Manifest, results: list[dict], started: float) -> CampaignReport:
    ordered = campaign_order(results)
    rows = mode_rows(ordered, options.est_values)
    written = write_modes(rows, options.out_dir, csv_too=options.csv)
    entries = [{**{k: v for k, v in r.items() if k != "updates"},
                "outputs": f"bags/{r['label']}" if r["status"] == "ok" else ""} for r in ordered]
    written.append(write_summary(entries, options.out_dir))
    manifest.compact()
    return CampaignReport(entries=entries, rows=rows, elapsed_s=time.perf_counter() - started, written=written)


class CampaignBar:
    """One progress bar over the campaign: input messages done (ETA from them), bags and samples."""

    def __init__(self, jobs: list[BagJob], topics: list[str], enabled: bool | None,
                 stream: TextIO | None = None) -> None:
        self.stream = stream or sys.stderr
        if enabled is None:
            enabled = bool(getattr(self.stream, "isatty", lambda: False)())
        self.bags, self.done_bags, self.failed, self.samples = len(jobs), 0, 0, 0
        self._bar = None
        self._counts = {}
        if not enabled or not jobs:
            return
        for job in jobs:
            plan = plan_bag(Path(job.bag))
            self._counts[job.display] = plan.message_count(topics)
        try:
            from tqdm import tqdm
        except ImportError:
            return
        tqdm.monitor_interval = 0  # no monitor thread: the local pool forks this process
        self._bar = tqdm(total=sum(self._counts.values()), file=self.stream, unit="msg", unit_scale=True,
                         desc="batch", dynamic_ncols=True, mininterval=0.5)
        self._bar.set_postfix_str(f"bags 0/{self.bags}")

    def done(self, job: BagJob, result: dict) -> None:
        self.done_bags += 1
        self.failed += result["status"] == "failed"
        self.samples += int(result.get("samples", 0))
        if self._bar is None:
            return
        self._bar.update(self._counts.get(job.display, 0))
        failed = f", {self.failed} failed" if self.failed else ""
        self._bar.set_postfix_str(f"bags {self.done_bags}/{self.bags}{failed}, samples {self.samples}")

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
