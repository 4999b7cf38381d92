"""``okid-ros replay --wait-for-subscribers``: the wait says now and then that it still waits."""

from __future__ import annotations

import threading
import time

from okid_ros.tools import replay


class _Publisher:
    """A publisher whose subscriptions match ``after_s`` seconds from its creation."""

    def __init__(self, topic_name: str, after_s: float):
        self.topic_name, self._ready = topic_name, time.monotonic() + after_s

    def get_subscription_count(self) -> int:
        return 1 if time.monotonic() >= self._ready else 0


def _player(lines: list[str]) -> replay.BagPlayer:
    player = replay.BagPlayer.__new__(replay.BagPlayer)  # the wait alone: no bag, no ROS
    player.wait_for_subscribers, player.log, player._stop = 1, lines.append, threading.Event()
    return player


def test_a_long_wait_for_subscribers_is_reminded_of_and_ends_when_they_match(monkeypatch):
    # Before, one line at the start and then silence for as long as no node came (without end).
    monkeypatch.setattr(replay, "WAIT_REMINDER_S", 0.1)
    lines: list[str] = []
    _player(lines)._wait_for_subscriptions([_Publisher("/imu", 0.0), _Publisher("/okid/io_sample", 0.45)])
    assert lines[0] == "replay: waiting for 1 subscription on /okid/io_sample (0 matched)", lines
    reminders = [line for line in lines[1:] if line.startswith("replay: still waiting after")]
    assert 2 <= len(reminders) <= 6 and all("/okid/io_sample (0 matched)" in line and "/imu" not in line
                                            for line in reminders), lines


def test_no_reminder_when_the_subscribers_are_there():
    lines: list[str] = []
    _player(lines)._wait_for_subscriptions([_Publisher("/imu", 0.0)])
    assert lines == []
