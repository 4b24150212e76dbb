"""Re-timing off the event loop: ROTA runs in a separate worker process, so the
setpoint stream keeps its rate whatever the solver does (the solver holds the
GIL while it runs; a thread would stall the stream)."""

from __future__ import annotations

import asyncio
import multiprocessing
import time
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool

from rota.problem import RetimeInput
from rota.result import RetimeResult
from rota.retime import retime


def _timed_retime(inp: RetimeInput) -> tuple[RetimeResult, float]:
    start = time.perf_counter()
    result = retime(inp)
    return result, time.perf_counter() - start


def _warm_up() -> bool:
    import rota.retime  # noqa: F401 - imports numpy, scipy, clarabel once

    return True


class Retimer:
    """One worker process; ``await retimer.retime(inp)`` returns ``(result, seconds)``."""

    def __init__(self) -> None:
        self._pool: ProcessPoolExecutor | None = None

    def _ensure(self) -> ProcessPoolExecutor:
        if self._pool is None:
            # spawn: the parent runs Zenoh and MAVSDK threads, which fork would copy badly
            self._pool = ProcessPoolExecutor(max_workers=1,
                                             mp_context=multiprocessing.get_context("spawn"))
        return self._pool

    async def start(self) -> None:
        loop = asyncio.get_running_loop()
        await loop.run_in_executor(self._ensure(), _warm_up)

    async def retime(self, inp: RetimeInput, timeout_s: float) -> tuple[RetimeResult, float]:
        """Re-time in the worker. Raises TimeoutError after ``timeout_s`` (the worker
        is then restarted, so a runaway solve cannot block the next one)."""
        loop = asyncio.get_running_loop()
        future = loop.run_in_executor(self._ensure(), _timed_retime, inp)
        try:
            return await asyncio.wait_for(future, timeout_s)
        except (TimeoutError, BrokenProcessPool):
            self._restart()
            raise TimeoutError(f"re-time did not finish within {timeout_s:.2f} s") from None

    def _restart(self) -> None:
        pool, self._pool = self._pool, None
        if pool is not None:
            for proc in list(getattr(pool, "_processes", {}).values()):
                proc.kill()
            pool.shutdown(wait=False, cancel_futures=True)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None
