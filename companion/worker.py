"""A supervised worker process: CPU-heavy work (decoding network input,
re-timing) runs here, never on the event loop or in a thread of the service's
process (the work holds the GIL; a thread would stall the setpoint stream).

:meth:`Worker.call` runs a function in the process with a timeout; a runaway
call or a death of the process restarts it, and the caller learns which of the
two happened. :meth:`Worker.dead` tells whether an idle process died, so the
supervisor can report and respawn it within a second.

Workers are forked from a fork server (:func:`start_fork_server`): a process of its
own, started from a fresh interpreter before the service opens Zenoh or MAVSDK (so
no thread of theirs is forked), that imports the workers' code once
(:data:`PRELOAD`), at the same time as the service imports its own. A worker then
starts with numpy, scipy and ``rota`` already loaded (a decode worker is ready in
milliseconds, not the second of imports a fresh interpreter takes) and shares those
pages with the other workers.
"""

from __future__ import annotations

import asyncio
import contextlib
import multiprocessing
import os
import signal
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import forkserver
from typing import Any, TypeVar

from companion import memory

T = TypeVar("T")

#: Worker processes run this many nice levels below the service (the setpoint
#: stream is time-critical, they are not) ...
WORKER_NICE_STEP = 5
#: ... but never below ordinary work (nice 0): a re-time or decode starved by an
#: unrelated busy process runs into its time budget and is refused. Measured on a
#: busy 2-core machine: at nice +5 beside two busy loops, a small map took over
#: 10 s to decode and load.
WORKER_NICE_FLOOR = 0


class WorkerDied(RuntimeError):
    """The worker process died during a call; the message says how and when."""


def worker_nice(parent: int) -> int:
    """The nice level of a worker of a process at nice ``parent``."""
    return max(parent + WORKER_NICE_STEP, WORKER_NICE_FLOOR)


#: What every worker imports (numpy, scipy, ``rota``): by the fork server, before it forks
#: the first worker. (Not the re-timer's own code: it draws plans with Foxglove's schemas,
#: which a decode worker has no use for; it imports them in its own process, 0.2 s.)
PRELOAD = ("companion.network.decoder", "companion.messages")


def start_fork_server() -> None:
    """Start the fork server the workers are forked from (if it does not run), importing
    :data:`PRELOAD` while the service goes on with its own start: the service's ``run``
    calls it first thing. Started from a fresh interpreter (not forked from the service);
    restarted by the next worker's start if it died."""
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(list(PRELOAD))
    forkserver.ensure_running()


def _init(service_nice: int) -> None:
    here = os.getpriority(os.PRIO_PROCESS, 0)  # the fork server's
    with contextlib.suppress(OSError):  # (only a raise needs a privilege)
        os.nice(worker_nice(service_nice) - here)
    # Ctrl-C in a terminal goes to the whole process group: the service decides
    # when its workers stop, a KeyboardInterrupt traceback in one helps nobody
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    memory.fix_mmap_threshold()  # (a large input's memory goes back when it is freed)


def describe_exit(code: int | None) -> str:
    """A process exit code in words (negative: killed by a signal)."""
    if code is None:
        return "still running"
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"


#: The exit code Python gives a forked worker whose status its fork server can no longer
#: tell (the server died: every pool then counts its workers dead)
_SERVER_LOST = 255


def _exit_of(code: int | None) -> str:
    """A worker's exit code in words (:func:`describe_exit`)."""
    return "lost with its fork server" if code == _SERVER_LOST else describe_exit(code)


class Worker:
    """One worker process (``workers`` > 1: a small pool), spawned on first use.

    ``on_spawn(pool)`` runs after every (re)spawn, e.g. to hand a new process the
    state the old one had.
    """

    def __init__(self, name: str, workers: int = 1,
                 on_spawn: Callable[[ProcessPoolExecutor], None] = lambda pool: None) -> None:
        self.name = name
        self.workers = workers
        self._on_spawn = on_spawn
        self._pool: ProcessPoolExecutor | None = None
        self._procs: list[Any] = []  # the current pool's processes, as last seen
        self.restarts = 0
        self.deaths: list[str] = []  # deaths seen by calls, not yet reported

    def pool(self) -> ProcessPoolExecutor:
        if self._pool is None:
            # forked from the fork server, not from here: this process runs Zenoh and
            # MAVSDK threads
            start_fork_server()
            self._pool = ProcessPoolExecutor(
                max_workers=self.workers, mp_context=multiprocessing.get_context("forkserver"),
                initializer=_init, initargs=(os.getpriority(os.PRIO_PROCESS, 0),))
            self._on_spawn(self._pool)
        return self._pool

    def _processes(self, pool: ProcessPoolExecutor) -> list[Any]:
        """The pool's processes (the executor forgets them once it breaks)."""
        procs = list(pool._processes.values())
        if pool is self._pool and procs:
            self._procs = procs
        return procs or (self._procs if pool is self._pool else [])

    def pids(self) -> list[int]:
        pool = self._pool
        return [] if pool is None else [p.pid for p in self._processes(pool)]

    async def call(self, timeout_s: float, fn: Callable[..., T], *args: Any) -> T:
        """``fn(*args)`` in the worker. Raises TimeoutError after ``timeout_s`` and
        WorkerDied if the process dies; either way the process is restarted."""
        loop = asyncio.get_running_loop()
        start = time.monotonic()
        pool = self.pool()
        procs: list[Any] = []
        try:
            # (asyncio.timeout, not wait_for: in Python 3.11 wait_for can swallow a
            # cancellation that comes as the result arrives, and the task that
            # called it then outlives the supervisor's close)
            async with asyncio.timeout(timeout_s):
                # submitted from a thread: a submit to a fresh pool starts its process
                # (the fork server's fork and hand-over; a fresh interpreter's took 1-10 ms
                # beside two busy loops), which would hold up the setpoint stream at every
                # respawn
                try:
                    submitted = await loop.run_in_executor(None, pool.submit, fn, *args)
                except (OSError, EOFError) as exc:  # (the fork server died as it was asked)
                    if self._pool is pool:
                        self.restart()
                    raise WorkerDied(f"{self.name} worker could not start ({exc!r}); "
                                     "tried again at the next call") from None
                procs = self._processes(pool)
                return await asyncio.wrap_future(submitted)
        except TimeoutError:
            if self._pool is pool:  # (the supervisor may have restarted it already)
                self.restart()
            raise TimeoutError(f"{self.name} did not finish within {timeout_s:.2f} s; "
                               "worker restarted") from None
        except BrokenProcessPool:
            procs = procs or self._processes(pool)
            for _ in range(10):  # the exit status shows a moment after the pipes close
                cause = next((_exit_of(p.exitcode) for p in procs
                              if p.exitcode is not None), "died")
                if cause != "died":
                    break
                await asyncio.sleep(0.02)
            if self._pool is pool:
                self.deaths.append(f"{cause} during a call")
                self.restart()
            raise WorkerDied(f"{self.name} worker {cause} after "
                             f"{time.monotonic() - start:.2f} s; restarted") from None

    def dead(self, pool: ProcessPoolExecutor | None = None) -> str | None:
        """How the worker process died (None while it lives or was not started)."""
        pool = pool or self._pool
        if pool is None:
            return None
        for proc in self._processes(pool):
            if proc.exitcode is not None:
                return _exit_of(proc.exitcode)
        return None  # (a broken pool whose process shows no exit status yet: next look)

    @property
    def cold(self) -> bool:
        """No process yet (never started, or restarted): the next call spawns one and
        waits for its imports."""
        return self._pool is None

    def restart(self) -> None:
        """Kill the process(es); the next call spawns fresh ones."""
        pool = self._pool
        if pool is None:
            return
        procs = self._processes(pool)
        self._pool, self._procs = None, []
        self.restarts += 1
        for proc in procs:
            if proc.exitcode is None:
                proc.kill()
        pool.shutdown(wait=False, cancel_futures=True)

    def close(self) -> None:
        pool, self._pool = self._pool, None
        if pool is not None:
            for proc in list(pool._processes.values()):
                if proc.exitcode is None:
                    proc.terminate()
            pool.shutdown(wait=False, cancel_futures=True)
