"""Replanning off the event loop: stitching, ROTA and serialisation run in a
separate worker process, so the setpoint stream keeps its rate whatever the
solver does (the solver holds the GIL while it runs; a thread would stall the
stream). The worker keeps the current map, so it is sent once per map, not with
every re-time."""

from __future__ import annotations

import asyncio
import json
import time
from dataclasses import dataclass

import numpy as np

from companion.flight.stitch import StitchError, join
from companion.recording.foxglove import PlanView, plan_view
from companion.ros2.encode import retimed_cdr
from companion.ros2.settings import Ros2Settings
from companion.worker import Worker
from rota import warm_up
from rota.braking import BrakingParams
from rota.chance import ChanceParams, UncertaintyModel
from rota.heading import heading_speed_limits
from rota.problem import Limits, RetimeInput, SolverSettings, make_grid
from rota.result import RetimeResult
from rota.retime import retime
from rota.robust import Safety
from rota.schema import Heading, TrajectoryMessage, result_to_dict
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
    take_acceleration: np.ndarray | None = None  # imposed (along the path) when jerk-limited
    stitch_tolerance: float = 1.0
    solver_max_iter: int = 200
    ros2: Ros2Settings | None = None  # also build the ROS 2 message of the result
    view: bool = False  # also make the plan's Foxglove view (companion.recording.foxglove.PlanView)
    yaw_rate_max: float = 0.0  # rad/s: slow where the heading could not keep up; 0: never
    heading: Heading | None = None  # the planner's heading (ENU degrees), if it sent one


@dataclass(frozen=True)
class ReplanOutcome:
    result: RetimeResult | None
    seconds: float
    payload: bytes  # the rota/result message, b"" when rejected before re-timing
    rejected: str = ""  # why the trajectory cannot take over (stitching)
    ros2_payload: bytes = b""  # the result as a ROS 2 message (CDR), if asked for
    view: PlanView | None = None  # the plan drawn for Foxglove, if asked for


_MAP: VoxelMap | None = None  # the worker's current map
#: Compiling every kernel with an empty cache takes 52-57 s on a quiet 2-core machine
#: (docs/benchmarks.md); with a warm cache, under a second.
WARM_UP_TIMEOUT_S = 300.0


def _start(vmap: VoxelMap | None) -> float:
    """A new worker: compile (or load from the cache) every solver kernel and run
    it once, so the first replan is as fast as the next; take the map. Returns
    the seconds the warm-up took."""
    seconds = warm_up()
    _set_map(vmap)
    return seconds


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
    # Jerk-limited: the new plan starts on the commanded acceleration too (its part
    # along the path), so the acceleration does not step at the takeover.
    a0 = (job.take_acceleration if job.limits.j_max is not None
          and job.take_position is not None else None)
    # the heading keeps up: the path's direction, or the planner's heading (rota.heading)
    yaw_limits = (heading_speed_limits(traj, make_grid(traj, min(job.dtau, traj.duration)),
                                       job.yaw_rate_max, job.heading)
                  if job.yaw_rate_max > 0 else None)
    result = retime(RetimeInput(trajectory=traj, limits=job.limits, smoothness=job.smoothness,
                                dtau=job.dtau, start_velocity=v0, start_acceleration=a0,
                                safety=safety, speed_limits=yaw_limits,
                                solver=SolverSettings(max_iter=job.solver_max_iter)))
    seconds = time.perf_counter() - start
    msg = TrajectoryMessage(traj, id=job.id, frame="ENU", stamp=job.stamp)
    message = result_to_dict(result, msg)
    payload = json.dumps(message, allow_nan=False).encode()
    ros2 = b""
    if job.ros2 is not None:  # here, not on the service's loop: it takes ~10 ms
        try:
            ros2 = retimed_cdr(result, job.ros2)
        except Exception:  # noqa: BLE001, S110 - the service goes on without the ROS copy
            pass
    # (here too: 1-2 ms in this process, and the flight record's process need not
    # load rota to draw the plan)
    view = plan_view(result, message) if job.view and result.status != "rejected" else None
    return ReplanOutcome(result, seconds, payload, ros2_payload=ros2, view=view)


class Retimer:
    """The re-time worker. ``await retimer.replan(job, timeout_s)``."""

    def __init__(self) -> None:
        self._map: VoxelMap | None = None
        self.worker = Worker("re-time", on_spawn=self._give_map)
        self._warm: object = None  # the process pool that was warmed
        self._warming = asyncio.Lock()

    @property
    def map(self) -> VoxelMap | None:
        """The map jobs are re-timed against (None: no map yet)."""
        return self._map

    def _give_map(self, pool) -> None:  # noqa: ANN001 - a fresh process gets the current map
        if self._map is not None:
            pool.submit(_set_map, self._map)

    async def start(self) -> float:
        """Start (or refresh) the worker, warm; the warm-up's seconds. The numba
        cache lives in ``$ROTA_CACHE_DIR``, systemd's ``$CACHE_DIRECTORY`` or
        ``~/.cache/rota`` (:func:`rota.warm_up`)."""
        async with self._warming:
            seconds = await self.worker.call(WARM_UP_TIMEOUT_S, _start, self._map)
            self._warm = self.worker.pool()
            return seconds

    async def set_map(self, vmap: VoxelMap | None) -> None:
        """Hand the worker a new map (jobs after this one use it)."""
        self._map = vmap
        await self.worker.call(60.0, _set_map, vmap)

    async def replan(self, job: ReplanJob, timeout_s: float) -> ReplanOutcome:
        """Raises TimeoutError after ``timeout_s``, WorkerDied if the worker dies
        (either way it is restarted, so a runaway solve cannot block the next). A
        restarted worker is warmed first: its compile-and-import time never counts
        against ``timeout_s`` (it would time out, be restarted, and so on)."""
        if self.worker._pool is None or self.worker._pool is not self._warm:
            await self.start()
        return await self.worker.call(timeout_s, _replan, job)

    def close(self) -> None:
        self.worker.close()
