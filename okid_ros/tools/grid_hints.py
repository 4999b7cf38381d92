"""The likely cause when a bag's messages do not fit the sample grid: one rule for every command.

`export`, `identify` and `track` (:class:`okid_ros.tools.bag_record.BagRecord`) and `process`
(:class:`okid_ros.tools.offline.ProcessSummary`) count what the grid refused and how the samples
lie; these functions turn the counts into the hint they print after them:

- most messages refused as duplicates, between sample times or off the stamps' timeline: the
  grid's ``sample_time_s`` is not the stamps' spacing;
- most samples alone between empty sample times: a sample time finer than the stamps' spacing
  (nothing refused), or messages refused for their values (NaN every other message), which
  ``sample_time_s`` does not explain.
"""

from __future__ import annotations

from collections.abc import Mapping

__all__ = ["LOSS_NOTE_FRACTION", "loss_worth_saying", "rejection_hint", "stand_alone_hint"]

#: Samples lost (dropped incomplete, or their messages refused) worth a note even when models came:
#: a stray duplicate or a dropped packet in a long bag is not, a topic that stopped half-way is.
LOSS_NOTE_FRACTION = 0.01


def loss_worth_saying(lost: int, total: int) -> bool:
    """Whether ``lost`` of ``total`` (samples, or messages) is worth a note though models came."""
    return lost > 0 and lost >= LOSS_NOTE_FRACTION * max(total, 1)

#: Refusals a wrong sample_time_s causes, when they are most of them: where those messages fell.
_WHERE = {"duplicate": "in a sample time already taken", "off_grid": "between sample times",
          "off_timeline": "more than the time-jump threshold from the stamps before them"}
#: Refusals for a message's values: the sample times they leave empty are the data's doing.
_VALUES = {"nonfinite": "with NaN or Inf values", "wrong_size": "of the wrong size",
           "no_data": "declaring no data (REP 145)"}


def _question(sample_time_s: float) -> str:
    return f"is sample_time_s {sample_time_s:g} s right?"


def rejection_hint(rejected: Mapping[str, int], sample_time_s: float, *, messages: int) -> str:
    """``"most fell between sample times: is sample_time_s 0.016 s right?"``, or "".

    Said when one of these reasons holds most of the refusals and a quarter of the messages at
    least (a stray duplicate or a loop's few stamps off the timeline are no sign of it). An
    ``inputs.time_jump_s`` at or below the sample time is no cause: the grid's threshold is at
    least ``inputs.latency_samples + 2`` sample times (:func:`~okid_ros.service.stamp_steps.least_time_jump_s`).

    Parameters
    ----------
    rejected : messages the grid refused, by reason (``GridCounters.rejections``).
    sample_time_s : the grid's sample time.
    messages : messages the grid was given.
    """
    total = sum(rejected.values())
    for reason, where in _WHERE.items():
        if rejected.get(reason, 0) > total // 2 and 4 * rejected[reason] >= messages:
            return f"most fell {where}: {_question(sample_time_s)}"
    return ""


def stand_alone_hint(*, samples: int, runs: int, alone: int, present: int, rejected: Mapping[str, int],
                     sample_time_s: float) -> str:
    """The hint when most samples stand alone between empty sample times, or "".

    Parameters
    ----------
    samples : samples the grid made of the whole bag.
    runs : contiguous runs of them.
    alone, present : of the samples looked at (a record's, or all), those with an empty sample
        time on both sides, and all.
    rejected : messages the grid refused, by reason: when those refused for their values
        (NaN/Inf, wrong size) are as many as half the samples, they left the sample times empty.
    sample_time_s : the grid's sample time.
    """
    if samples < 4 or not (runs > samples // 2 or 2 * alone > present):
        return ""
    head = f"most of the {samples} samples stand alone between"
    refused = {reason: rejected.get(reason, 0) for reason in _VALUES if rejected.get(reason, 0)}
    if 2 * sum(refused.values()) >= samples:
        held = ", ".join(f"{count} {_VALUES[reason]}" for reason, count in refused.items())
        return (f"{head} sample times whose messages were rejected ({held}): the values, not sample_time_s, "
                "left them empty")
    return f"{head} empty sample times: {_question(sample_time_s)}"
