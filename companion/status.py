"""What the service tells the world: errors, warnings and events (logged and
kept for the status channel), and the periodic ``status`` and ``telemetry``
publications on Zenoh.

Status goes out at ``zenoh.status_rate_hz`` and never faster, whatever
happens: a burst of errors (a flood of refused commands) is coalesced into the
next status, which carries the newest entries of the event log with sequence
numbers (a subscriber sees what it missed) and counts of everything. The log
itself says a repeated message once and then how often it repeated.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from typing import Any

from companion import messages as msgs
from companion.network.outbox import Send, send_now

log = logging.getLogger("rota.companion")

#: Entries of the event log carried by every status message.
STATUS_EVENTS = 10
#: A message repeated within this many seconds is logged once, then counted.
REPEAT_WINDOW_S = 1.0


async def after_setpoint(beat: asyncio.Event, timeout_s: float) -> None:
    """Wait for the stream's next setpoint (``beat``), at most ``timeout_s``: periodic
    work that waits here runs just after a setpoint, in the stream's idle time,
    not across its next deadline. (Not asyncio.wait_for, which in Python 3.11 can
    swallow a cancellation that comes with the beat; then the service cannot stop.)"""
    beat.clear()
    with contextlib.suppress(TimeoutError):
        async with asyncio.timeout(timeout_s):
            await beat.wait()


class Reporter:
    """Errors, warnings and events in words. An error is logged and kept as
    ``last_error``; everything goes into the event log that status carries.
    Thread-safe (the setpoint stream reports from its own thread)."""

    def __init__(self) -> None:
        self.last_error: dict[str, Any] | None = None
        self.warnings: deque[str] = deque(maxlen=5)
        self.events: deque[dict[str, Any]] = deque(maxlen=200)
        self.seq = 0
        self.counts: Counter[str] = Counter()  # errors / warnings / events
        self._last_log: tuple[int, str] = (0, "")
        self._last_log_t = 0.0
        self._repeats = 0
        self._lock = threading.Lock()

    def _log(self, level: int, text: str) -> None:
        with self._lock:
            now = time.monotonic()
            if (level, text) == self._last_log and now - self._last_log_t < REPEAT_WINDOW_S:
                self._repeats += 1
                return
            repeats, last = self._repeats, self._last_log[0]
            self._last_log, self._last_log_t, self._repeats = (level, text), now, 0
        if repeats:
            log.log(last, "(the message above repeated %d more times)", repeats)
        log.log(level, "%s", text)

    def _keep(self, level: str, source: str, message: str) -> None:
        with self._lock:
            self.seq += 1
            self.counts[level] += 1
            self.events.append({"seq": self.seq, "stamp": time.time(), "level": level,
                                "source": source, "message": message})

    def recent(self, n: int = STATUS_EVENTS) -> list[dict[str, Any]]:
        with self._lock:
            return list(self.events)[-n:]

    def snapshot(self) -> dict[str, Any]:
        """What status carries of it, copied at one instant."""
        with self._lock:
            return {"last_error": self.last_error, "warnings": list(self.warnings),
                    "events": list(self.events)[-STATUS_EVENTS:], "counts": dict(self.counts)}

    def error(self, source: str, message: str) -> None:
        self._log(logging.ERROR, f"{source}: {message}")
        self.last_error = {"stamp": time.time(), "source": source, "message": message}
        self._keep("error", source, message)

    def warn(self, message: str, source: str = "service") -> None:
        self._log(logging.WARNING, message)
        with self._lock:
            self.warnings.append(message)
        self._keep("warning", source, message)

    def event(self, message: str, source: str = "service") -> None:
        self._log(logging.INFO, message)
        self._keep("event", source, message)

    def audit(self, message: str, peer: str) -> None:
        """A change made at run time, by ``peer``: logged at WARNING, kept as an
        ``audit`` event."""
        self._log(logging.WARNING, f"audit: {message} (requested by Zenoh peer {peer})")
        self._keep("audit", peer, message)



def _put(publisher: Any, name: str, payload: bytes, source: Any = None) -> None:
    try:
        publisher.put(payload, **({} if source is None else {"source_info": source}))
    except Exception as exc:  # noqa: BLE001 - never let publishing take the service down
        log.warning("publishing %s failed: %s", name, exc)


class Publisher:
    """Puts JSON on the service's Zenoh publishers; publishes telemetry at
    ``telemetry_rate_hz`` and status at ``status_rate_hz``."""

    def __init__(self, publishers: dict[str, Any], status: Callable[[], dict[str, Any]],
                 telemetry: Callable[[], dict[str, Any]],
                 on_status: Callable[[dict[str, Any]], None] = lambda s: None,
                 send: Send = send_now, source: Callable[[], Any] | None = None) -> None:
        self._pub = publishers
        self._source = source  # the source info of each put: who speaks (the ground station checks)
        self._send = send
        self._status = status
        self._telemetry = telemetry
        self._on_status = on_status
        self.status_count = 0

    def put(self, name: str, obj: dict[str, Any]) -> None:
        self.put_bytes(name, msgs.dumps(obj))

    def put_bytes(self, name: str, payload: bytes) -> None:
        source = None if self._source is None else self._source()
        self._send(_put, self._pub[name], name, payload, source)

    def publish_status(self) -> None:
        status = self._status()
        self.put("status", status)
        self.status_count += 1
        self._on_status(status)

    def close(self) -> None:
        for pub in self._pub.values():
            try:
                pub.undeclare()
            except Exception:  # noqa: BLE001, S110 - closing anyway
                pass

    async def run(self, telemetry_rate_hz: float, status_rate_hz: float,
                  beat: asyncio.Event | None = None) -> None:
        """Publish until cancelled. With ``beat`` (the setpoint stream's, set after
        each setpoint) every publication waits for the next setpoint and follows it
        at once: building and encoding status takes a millisecond or more, and
        done then it delays no setpoint (measured on a loaded 2-core machine,
        the publication was the event loop's longest callback)."""
        period = 1.0 / telemetry_rate_hz
        status_every = max(1, round(telemetry_rate_hz / status_rate_hz))
        k = 0
        due = time.monotonic()
        while True:
            due = max(due + period, time.monotonic() - period)  # no burst after a stall
            await asyncio.sleep(max(due - time.monotonic(), 0.0))
            if beat is not None:  # (bounded: a stream being restarted does not stop status)
                await after_setpoint(beat, period)
            self.put("telemetry", self._telemetry())
            k += 1
            if k % status_every == 0:
                self.publish_status()


class Retimed:
    """Where each re-timed plan goes (the replanner hands it here): the flight record
    at once; Zenoh and ROS 2 from the moment they are open (:meth:`open`)."""

    def __init__(self, recorder: Any) -> None:
        self._recorder = recorder
        self._publisher: Publisher | None = None
        self._ros2: Any = None

    def open(self, publisher: Publisher, ros2: Any = None) -> None:
        """Zenoh is up: publish on ``publisher`` (and ``ros2``'s link, if any) too."""
        self._publisher, self._ros2 = publisher, ros2

    def put(self, payload: bytes, ros2: bytes = b"", view: Any = None) -> None:
        """A re-time's result as JSON and (built in the worker) as a ROS 2 message and
        the plan's Foxglove view (:class:`companion.recording.foxglove.PlanView`)."""
        self._recorder.put("retimed", payload)
        if view is not None:
            self._recorder.show("plan", view)
        if self._publisher is not None:
            self._publisher.put_bytes("retimed", payload)
        if self._ros2 is not None and ros2:
            self._ros2.put("retimed", ros2)
