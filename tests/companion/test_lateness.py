"""The kernel's account of a late tick (companion.flight.lateness), on this machine's /proc."""

from __future__ import annotations

import sys
import threading
import time

import pytest

from companion.flight.lateness import TickClock, _sched, _steal

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux /proc")


def test_counters_are_parsed():
    assert _sched(b"123 4500000 7\n") == (4500000, 7)
    assert _sched(None) is None
    stat = b"cpu  1 2 3 4 5 6 7 30 0 0\ncpu0 1 2 3 4 5 6 7 10 0 0\ncpu1 1 2 3 4 5 6 7 20 0 0\n"
    assert _steal(stat) == [10, 20]


def test_a_thread_kept_from_the_gil_is_reported_blocked():
    """Another thread holds the GIL in a busy Python loop for 0.3 s: this one,
    running Python meanwhile, is switched out and woken again and again."""
    clock = TickClock()
    stop = time.monotonic() + 0.3

    def busy() -> None:
        while time.monotonic() < stop:
            pass

    other = threading.Thread(target=busy)
    other.start()
    clock.tick()
    n = 0
    while time.monotonic() < stop:
        n += 1
    clock.tick()
    other.join()
    words = clock.explain()
    assert "waited" in words and "ms for a CPU" in words
    assert "was woken" in words and "blocked" in words, words


def test_an_idle_tick_says_nothing_alarming():
    clock = TickClock()
    clock.tick()
    time.sleep(0.02)
    clock.tick()
    words = clock.explain()
    assert "waited" in words and "blocked" not in words, words
