"""Supervision: the service's long-lived tasks and worker processes, and
systemd's notifications.

Every long-lived task runs under :class:`Supervisor`: when one ends (an
exception, or returning when it never should), the death is reported on the
status channel with its cause and the task is started again. Worker processes
are checked four times a second: a dead one is reported with its exit status
and respawned. systemd's watchdog is fed only while all of them are alive.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Awaitable, Callable, Coroutine
from typing import Any

import sdnotify

from companion.status import Reporter
from companion.worker import Worker

log = logging.getLogger("rota.companion")


class Notifier:
    """sd_notify (READY, STATUS, WATCHDOG, STOPPING) that can never block the
    event loop: the socket is non-blocking (a busy systemd drops a message rather
    than stalling the setpoint stream) and the watchdog is petted at most 4 Hz."""

    def __init__(self, healthy: Callable[[], bool] = lambda: True) -> None:
        self._sd = sdnotify.SystemdNotifier()
        if self._sd.socket is not None:
            self._sd.socket.setblocking(False)
        self._last_watchdog = 0.0
        self._healthy = healthy

    def notify(self, state: str) -> None:
        self._sd.notify(state)  # sdnotify swallows errors (e.g. BlockingIOError)

    async def starting(self, what: str, every_s: float = 5.0, extend_s: float = 30.0,
                       limit_s: float = 900.0) -> None:
        """While cancelled from outside, tell systemd every ``every_s`` that the start
        goes on (``EXTEND_TIMEOUT_USEC``: the first compile of the solver takes
        tens of seconds, minutes on a slow board, beyond the unit's start
        timeout), with ``what`` and the time so far in ``STATUS=``. After
        ``limit_s`` it stops extending: a start that hangs still times out."""
        start = time.monotonic()
        while (spent := time.monotonic() - start) < limit_s:
            self.notify(f"EXTEND_TIMEOUT_USEC={int(extend_s * 1e6)}\n"
                        f"STATUS=starting: {what} ({spent:.0f} s)")
            await asyncio.sleep(every_s)

    def watchdog(self) -> None:
        """Feed systemd's watchdog (at most 4 Hz), only while everything lives."""
        now = time.monotonic()
        if now - self._last_watchdog >= 0.25 and self._healthy():
            self._last_watchdog = now
            self.notify("WATCHDOG=1")


class Supervisor:
    """Runs named coroutines as tasks and restarts any that ends."""

    def __init__(self, report: Reporter) -> None:
        self.report = report
        self.tasks: dict[str, asyncio.Task] = {}
        self._factories: dict[str, Callable[[], Coroutine[Any, Any, None]]] = {}
        self.restarts: dict[str, int] = {}
        self._finite: set[str] = set()
        self._closing = False
        self.workers: list[Worker] = []

    def start(self, name: str, factory: Callable[[], Coroutine[Any, Any, None]],
              forever: bool = True) -> None:
        """Run ``factory()`` as the task ``name``: for the life of the service when
        ``forever``, else until it returns (an exception still restarts it)."""
        self._factories[name] = factory
        if not forever:
            self._finite.add(name)
        task = asyncio.create_task(factory(), name=name)
        task.add_done_callback(self._ended)
        self.tasks[name] = task

    def _ended(self, task: asyncio.Task) -> None:
        name = task.get_name()
        if self._closing or self.tasks.get(name) is not task:
            return
        if task.cancelled():
            cause = "cancelled"
        elif task.exception() is not None:
            exc = task.exception()
            cause = f"{type(exc).__name__}: {exc}"
            log.error("task %s died", name, exc_info=exc)
        elif name in self._finite:
            return  # finished its job
        else:
            cause = "returned"
        self.restarts[name] = self.restarts.get(name, 0) + 1
        self.report.error("supervisor", f"task {name!r} ended ({cause}); restarted")
        self.start(name, self._factories[name])

    def all_alive(self) -> bool:
        """Every task runs (or finished its job) and every watched worker lives."""
        tasks = all(not t.done() or name in self._finite and not t.cancelled()
                    and t.exception() is None for name, t in self.tasks.items())
        return tasks and not any(w.dead() for w in self.workers)

    async def watch(self, workers: list[Worker],
                    respawn: Callable[[Worker], Awaitable[None]]) -> None:
        """Four times a second: a dead worker process is reported, restarted, and
        ``respawn(worker)`` brings the new one up to date (a task)."""
        self.workers = workers
        while True:
            await asyncio.sleep(0.25)
            for worker in workers:
                cause = worker.dead()
                if cause:
                    self.report.error("supervisor", f"{worker.name} worker {cause}; "
                                      "restarting it")
                    worker.restart()
                    try:
                        await respawn(worker)
                    except Exception as exc:  # noqa: BLE001 - the next look tries again
                        self.report.error("supervisor", f"{worker.name} worker did not come "
                                          f"back: {exc}; trying again")
                while worker.deaths:  # seen (and restarted) by a call
                    self.report.error("supervisor", f"{worker.name} worker "
                                      f"{worker.deaths.pop(0)}; restarted")

    async def close(self) -> None:
        self._closing = True
        for task in self.tasks.values():
            task.cancel()
        for task in self.tasks.values():
            try:
                await task
            except (asyncio.CancelledError, Exception):  # noqa: BLE001, S110
                pass
