"""Worker processes come from the fork server (companion/worker.py): they start with
its imports, at the nice level the service sets for them; a dead fork server is
reported as the loss of its workers and replaced when the next worker starts."""

from __future__ import annotations

import asyncio
import os
import signal
import sys
from multiprocessing import forkserver

import pytest

from companion.worker import PRELOAD, Worker, WorkerDied, worker_nice


def _state() -> tuple[int, int, list[str]]:
    """In the worker: its pid, its nice level, and which of PRELOAD it has loaded."""
    return os.getpid(), os.getpriority(os.PRIO_PROCESS, 0), [m for m in PRELOAD
                                                             if m in sys.modules]


def _die() -> None:
    os.kill(os.getpid(), signal.SIGKILL)


async def _until_dead(pid: int) -> None:
    """Until ``pid`` is a zombie (its parent has not reaped it: the fork server's
    start does)."""
    for _ in range(500):
        with open(f"/proc/{pid}/stat") as f:
            if f.read().rsplit(")", 1)[1].split()[0] == "Z":
                return
        await asyncio.sleep(0.01)
    raise AssertionError(f"{pid} still runs")


def test_a_worker_starts_with_the_preload_and_outlives_a_dead_fork_server():
    async def scenario():
        worker = Worker("test")
        try:
            pid, nice, loaded = await worker.call(60.0, _state)
            server = forkserver._forkserver._forkserver_pid
            assert server and pid != os.getpid()
            assert loaded == list(PRELOAD)  # imported by the server, not by the call
            assert nice == worker_nice(os.getpriority(os.PRIO_PROCESS, 0))
            with pytest.raises(WorkerDied, match="killed by SIGKILL"):
                await worker.call(10.0, _die)  # a worker dies: reported, a new one forked
            new, _, loaded = await worker.call(10.0, _state)
            assert new != pid and loaded == list(PRELOAD)
            os.kill(server, signal.SIGKILL)  # the fork server dies: its workers count as
            await _until_dead(server)        # dead (no exit status can come through it)
            with pytest.raises(WorkerDied, match="lost with its fork server"):
                await worker.call(10.0, _state)
            newer, _, loaded = await worker.call(60.0, _state)
            assert newer not in (pid, new) and loaded == list(PRELOAD)
            assert forkserver._forkserver._forkserver_pid not in (None, server)
        finally:
            worker.close()

    asyncio.run(scenario())
