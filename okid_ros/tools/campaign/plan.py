"""`okid-ros batch --plan`: the bags of a campaign, their durations, topics and message counts.

Only metadata is read (:func:`okid_ros.tools.campaign.discovery.plan_bag`), so a plan of a
thousand bags takes seconds; a bag whose metadata cannot be read, or that lacks an input topic,
is flagged, since processing it would fail.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from datetime import datetime, timezone
from pathlib import Path

from okid_ros.errors import shown_path
from okid_ros.tools.campaign.discovery import BagPlan, plan_bag

__all__ = ["plan_campaign", "format_plan"]


def plan_campaign(bags: list[Path]) -> tuple[list[BagPlan], float]:
    """Plans of ``bags`` in campaign order (first stamp, then path) and the seconds it took."""
    started = time.perf_counter()
    plans = [plan_bag(bag) for bag in bags]
    plans.sort(key=lambda p: (p.start_s if math.isfinite(p.start_s) else math.inf, str(p.path)))
    return plans, time.perf_counter() - started


def _stamp(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "-"
    return datetime.fromtimestamp(seconds, tz=timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def format_plan(plans: list[BagPlan], input_topics: list[str], elapsed_s: float,
                emit: Callable[[str], None] = print) -> int:
    """Print the plan; returns the number of bags that would fail (metadata or input topics)."""
    width = max([len(shown_path(p.path)) for p in plans] + [3])
    emit(f"{'bag':<{width}}  {'start (UTC)':<20}  {'duration_s':>10}  {'messages':>9}  {'inputs':>9}  note")
    problems = 0
    totals: dict[tuple[str, str], list[int]] = {}
    duration = 0.0
    for plan in plans:
        missing = [t for t in input_topics if t not in plan.topics]
        note = plan.error or (f"no input topic {', '.join(missing)}" if missing else "")
        problems += bool(note)
        for topic, msgtype in plan.topics.items():
            total = totals.setdefault((topic, msgtype), [0, 0])
            total[0] += plan.counts.get(topic, 0)
            total[1] += 1
        if math.isfinite(plan.duration_s):
            duration += plan.duration_s
        emit(f"{shown_path(plan.path):<{width}}  {_stamp(plan.start_s):<20}  "
             f"{plan.duration_s:>10.1f}  {plan.message_count():>9d}  {plan.message_count(input_topics):>9d}  {note}")
    emit("")
    emit(f"topics ({len(totals)}):")
    for (topic, msgtype), (count, n_bags) in sorted(totals.items()):
        flag = "  (input)" if topic in input_topics else ""
        emit(f"  {shown_path(topic)} [{shown_path(msgtype)}]: {count} messages in {n_bags} bag(s){flag}")
    emit("")
    emit(f"{len(plans)} bags, {duration:.1f} s of data, {sum(p.message_count() for p in plans)} messages "
         f"({sum(p.message_count(input_topics) for p in plans)} on the input topics "
         f"{', '.join(input_topics)}); {problems} would fail; planned in {elapsed_s:.2f} s from metadata only")
    return problems
