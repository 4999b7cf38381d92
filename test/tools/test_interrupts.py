"""Ctrl-C and SIGTERM held back while a bag record is written (okid_ros/tools/interrupts.py).

`process` terminated at the wrong instant left a truncated record that made its whole output bag
unreadable (test_process_interrupt failed so in a CI run under load).
"""

from __future__ import annotations

import signal
import threading

import pytest

from okid_ros.tools import interrupts


def test_an_interrupt_in_a_held_section_is_raised_when_it_ends():
    done = []
    with pytest.raises(KeyboardInterrupt):
        with interrupts.deferred():
            interrupts.interrupt(signal.SIGTERM, None)  # as the handler is called mid-write
            done.append("the write finished")
    assert done == ["the write finished"]
    with interrupts.deferred():  # nothing left pending
        pass


def test_outside_a_held_section_an_interrupt_is_raised_at_once():
    with pytest.raises(KeyboardInterrupt):
        interrupts.interrupt(signal.SIGINT, None)


def test_a_section_in_another_thread_holds_nothing():
    raised = []

    def write():
        with interrupts.deferred():
            try:
                interrupts.interrupt(signal.SIGTERM, None)
            except KeyboardInterrupt:
                raised.append(True)

    worker = threading.Thread(target=write)
    worker.start()
    worker.join()
    assert raised == [True]
