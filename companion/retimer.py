"""Replanning off the event loop: stitching, ROTA and serialisation run in a
separate worker process, so the setpoint stream keeps its rate whatever the
solver does (the solver holds the GIL while it runs; a thread would stall the
stream). The worker keeps the current map, so it is sent once per map, not with
every re-time."""

from __future__ import annotations

import asyncio
import json
import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass

import numpy as np

from companion.stitch import StitchError, join
from rota.braking import BrakingParams
from rota.chance import ChanceParams, UncertaintyModel
from rota.problem import Limits, RetimeInput
from rota.result import RetimeResult
from rota.retime import retime
from rota.robust import Safety
from rota.schema import TrajectoryMessage, result_to_dict
from rota.trajectory import Trajectory
from rota.voxelmap import VoxelMap


@dataclass(frozen=True)
class ReplanJob:
    """Everything the worker needs for one replan (all ENU)."""

    id: str
    stamp: float | None
    trajectory: Trajectory
    limits: Limits
    smoothness: float
    dtau: float
    uncertainty: UncertaintyModel
    chance: ChanceParams
    braking: BrakingParams
    take_position: np.ndarray | None = None  # commanded state at takeover; None: from rest
    take_velocity: np.ndarray | None = None
    stitch_tolerance: float = 0.5


@dataclass(frozen=True)
class ReplanOutcome:
    result: RetimeResult | None
    seconds: float
    payload: bytes  # the rota/result message, b"" when rejected before re-timing
    rejected: str = ""  # why the trajectory cannot take over (stitching)


_MAP: VoxelMap | None = None  # the worker's current map
WORKER_NICE = 10  # the worker runs at a lower CPU priority than the stream


def _set_map(vmap: VoxelMap | None) -> bool:
    global _MAP
    _MAP = vmap
    return True


def _replan(job: ReplanJob) -> ReplanOutcome:
    start = time.perf_counter()
    traj, v0 = job.trajectory, np.zeros(3)
    if job.take_position is not None:
        try:
            traj, v0 = join(traj, job.take_position, job.take_velocity, job.stitch_tolerance,
                            job.limits.v_max)
        except StitchError as exc:
            return ReplanOutcome(None, time.perf_counter() - start, b"", str(exc))
    safety = None if _MAP is None else Safety(map=_MAP, uncertainty=job.uncertainty,
                                              chance=job.chance, braking=job.braking)
    result = retime(RetimeInput(trajectory=traj, limits=job.limits, smoothness=job.smoothness,
                                dtau=job.dtau, start_velocity=v0, safety=safety))
    seconds = time.perf_counter() - start
    msg = TrajectoryMessage(traj, id=job.id, frame="ENU", stamp=job.stamp)
    payload = json.dumps(result_to_dict(result, msg), allow_nan=False).encode()
    return ReplanOutcome(result, seconds, payload)


class Retimer:
    """One worker process. ``await retimer.replan(job, timeout_s)``."""

    def __init__(self) -> None:
        self._pool: ProcessPoolExecutor | None = None
        self._map: VoxelMap | None = None

    def _ensure(self) -> ProcessPoolExecutor:
        if self._pool is None:
            # spawn: the parent runs Zenoh and MAVSDK threads, which fork would copy badly
            # nice 10: the setpoint stream is time-critical, the solve is not
            self._pool = ProcessPoolExecutor(max_workers=1,
                                             mp_context=multiprocessing.get_context("spawn"),
                                             initializer=os.nice, initargs=(WORKER_NICE,))
            if self._map is not None:
                self._pool.submit(_set_map, self._map)
        return self._pool

    async def start(self) -> None:
        loop = asyncio.get_running_loop()
        await loop.run_in_executor(self._ensure(), _set_map, self._map)

    async def set_map(self, vmap: VoxelMap | None) -> None:
        """Hand the worker a new map (jobs after this one use it)."""
        self._map = vmap
        loop = asyncio.get_running_loop()
        await loop.run_in_executor(self._ensure(), _set_map, vmap)

    async def replan(self, job: ReplanJob, timeout_s: float) -> ReplanOutcome:
        """Raises TimeoutError after ``timeout_s`` (the worker is then restarted, so
        a runaway solve cannot block the next one)."""
        loop = asyncio.get_running_loop()
        future = loop.run_in_executor(self._ensure(), _replan, job)
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
