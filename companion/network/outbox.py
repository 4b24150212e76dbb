"""What the service sends on Zenoh (status, telemetry, re-timed results, query
replies, ROS messages) leaves from one thread of its own, never from the event
loop.

A Zenoh send can wait: a query's reply waits for room on the asker's link (its
congestion control is *block*), and a publication waits behind it in the same
pipeline. Measured under a flood of 1,000 queries a second from a peer on a
busy machine, replies sent from the event loop held it for up to 80 ms, and the
setpoint stream with it. The loop only queues here; the order of what is queued
is kept.
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable
from typing import Any

log = logging.getLogger("rota.companion")


def send_now(fn: Callable[..., Any], *args: Any) -> None:
    """Send at once, in the calling thread (tools and tests without a loop to spare)."""
    fn(*args)


#: How the modules that send get their sends done: ``Outbox.send`` or :func:`send_now`.
Send = Callable[..., None]


class Outbox:
    """Runs ``send(fn, *args)`` calls one at a time, in order, in a thread."""

    def __init__(self, name: str = "zenoh-out") -> None:
        self._queue: queue.SimpleQueue[tuple[Callable[..., Any], tuple[Any, ...]] | None] = \
            queue.SimpleQueue()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def send(self, fn: Callable[..., Any], *args: Any) -> None:
        """Queue ``fn(*args)`` (any thread; returns at once)."""
        self._queue.put((fn, args))

    def _run(self) -> None:
        while (item := self._queue.get()) is not None:
            fn, args = item
            try:
                fn(*args)
            except Exception as exc:  # noqa: BLE001 - a failed send must not end the others
                log.warning("zenoh send failed: %s", exc)

    def close(self, timeout_s: float = 3.0) -> None:
        """Send what is queued (for at most ``timeout_s``), then stop."""
        self._queue.put(None)
        self._thread.join(timeout_s)
