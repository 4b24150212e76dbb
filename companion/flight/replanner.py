"""Replanning: the newest accepted trajectory is joined onto the commanded state
at the predicted takeover time, re-timed in the worker, published, and offered
to the stream. One re-time at a time; older trajectories are superseded, and
one stamped older than the newest accepted is refused (arrival order never
wins over stamp order). A death of the worker during a re-time is reported and
the trajectory re-timed once more in the respawned worker."""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from companion import messages as msgs
from companion.flight.plan import Plan
from companion.flight.retimer import ReplanJob, Retimer
from companion.flight.stream import SetpointStream
from companion.settings.config import Config
from companion.status import Reporter
from companion.uncertainty.source import UncertaintySource, origin
from companion.worker import WorkerDied
from rota.chance import risk_reach
from rota.result import FALLBACK, REJECTED, RetimeResult

log = logging.getLogger("rota.companion")


class Replanner:
    def __init__(self, cfg: Callable[[], Config], retimer: Retimer, stream: SetpointStream,
                 uncertainty: Callable[[], UncertaintySource], report: Reporter,
                 publish: Callable[[bytes, bytes, Any], None],
                 flying: Callable[[], bool] = lambda: False) -> None:
        self._cfg = cfg
        self.retimer = retimer
        self.stream = stream
        self._uncertainty = uncertainty
        self.report = report
        self._publish = publish
        self._said: set[tuple[str, str]] = set()  # zone reports made (once per model)
        self.flying = flying  # plans may take over (the commander's word)
        self.latest: msgs.Incoming | None = None  # newest accepted trajectory
        self.newest_stamp: float | None = None  # stamp of the newest accepted trajectory
        self.newest_id = ""
        self.last_trajectory_time = 0.0
        self.last_result_summary: dict[str, Any] = {}
        self.retiming: str | None = None  # the trajectory being re-timed now
        self.solve_latency = 0.25  # s, running estimate used to pick the takeover time
        self._wake = asyncio.Event()

    # ------------------------------------------------------------ interface
    def offer(self, incoming: msgs.Incoming) -> None:
        """A new trajectory: re-time it (superseding older ones). Raises Rejected if
        it is stamped no later than the newest accepted one."""
        if incoming.stamp is not None:
            if self.newest_stamp is not None and incoming.stamp <= self.newest_stamp:
                raise msgs.Rejected(
                    f"trajectory {incoming.id!r}: stamped {self.newest_stamp - incoming.stamp:.3f}"
                    f" s before (or with the same stamp as) trajectory {self.newest_id!r}, "
                    "already accepted; out of order or repeated")
            self.newest_stamp, self.newest_id = incoming.stamp, incoming.id
        self.latest = incoming
        self.last_trajectory_time = time.monotonic()
        self._wake.set()

    def kick(self) -> None:
        """Re-time the newest trajectory now (offboard began); restarts the
        planner-silence clock."""
        self.last_trajectory_time = time.monotonic()
        self._wake.set()

    def drop(self) -> None:
        """Forget the newest trajectory (it must never be flown later)."""
        self.latest = None

    def silence(self) -> float:
        """Seconds since the last accepted trajectory."""
        return time.monotonic() - self.last_trajectory_time

    # ------------------------------------------------------------ the loop
    async def run(self) -> None:
        while True:
            await self._wake.wait()
            self._wake.clear()
            incoming = self.latest
            if incoming is None:
                continue
            for attempt in (1, 2):
                try:
                    await self._retime_and_stitch(incoming)
                except msgs.Rejected as exc:
                    self.report.error("trajectory", str(exc))
                except TimeoutError as exc:
                    self.report.error("retime", f"{incoming.id}: {exc}; keeping the current "
                                      "command")
                except WorkerDied as exc:
                    again = attempt == 1 and incoming is self.latest
                    self.report.error("retime", f"{incoming.id}: {exc}; " + (
                        "re-timing it again" if again else "keeping the current command"))
                    if again:
                        continue
                except Exception as exc:  # noqa: BLE001 - report, keep replanning
                    log.exception("replanning %s", incoming.id)
                    self.report.error("retime", f"{incoming.id}: {type(exc).__name__}: {exc}")
                break

    def _report_zones(self, ident: str, result: RetimeResult, job: ReplanJob) -> None:
        """A model that makes every point of a path a braking point, or whose risk band
        around an obstacle is thinner than one voxel (it can never brake before one),
        is said on status, once per model: flown, but not silently."""
        vmap = self.retimer.map
        if vmap is None:
            return
        u, c = job.uncertainty, job.chance
        model = (f"m={u.m:.3g} s, b={u.b:.3g} m, floor={u.floor:.3g} m, memory "
                 f"{u.memory_s:g} s, Delta={c.delta:g}")
        mask = result.diagnostics.braking_mask
        if mask is not None and len(mask) > 2 and bool(np.all(mask)):
            self._say_once(("all", model), lambda said: (
                f"every point of trajectory {ident!r} is a braking point with the model "
                f"{said}: it flies at the chance-constrained limit all the way; check the "
                "model, Delta and the planner's clearance"))
        band = risk_reach(u, c) - max(c.semi_axes)
        if band < vmap.resolution:
            self._say_once(("none", model), lambda said: (
                f"the model {said} puts the risk band {band:.3f} m around an obstacle, under "
                f"one voxel ({vmap.resolution:g} m): no braking zone can come before the path "
                "meets an obstacle"))

    def _say_once(self, key: tuple[str, str], message: Callable[[str], str]) -> None:
        """``message(the model and its origin)`` on status, once per ``key`` (the origin
        is looked up only then)."""
        if key not in self._said and len(self._said) < 100:
            self._said.add(key)
            self.report.warn(message(f"{key[1]} ({origin(self._uncertainty().describe())})"))

    async def _retime_and_stitch(self, incoming: msgs.Incoming) -> None:
        """Replan in the worker: join the trajectory onto the commanded state at the
        predicted takeover time, re-time it; then schedule the takeover."""
        cfg = self._cfg()
        flying = self.flying()
        started = time.monotonic()
        t_take = started + self.solve_latency
        take = self.stream.commanded(t_take) if flying else None
        job = ReplanJob(
            id=incoming.id, stamp=incoming.stamp, trajectory=incoming.trajectory,
            limits=cfg.rota_limits(), smoothness=cfg.limits.smoothness, dtau=cfg.limits.dtau,
            uncertainty=self._uncertainty().model(), chance=cfg.chance_params(),
            braking=cfg.braking_params(), stitch_tolerance=cfg.safety.stitch_tolerance_m,
            solver_max_iter=cfg.limits.solver_max_iter,
            ros2=cfg.ros2 if cfg.ros2.enabled and cfg.ros2.retimed_topic else None,
            view=cfg.record.enabled and cfg.record.foxglove,
            yaw_rate_max=cfg.yaw_slowdown_rad_s(), heading=incoming.heading,
            take_position=None if take is None else take.position,
            take_velocity=None if take is None else take.velocity,
            take_acceleration=None if take is None else take.acceleration)
        self.retiming = incoming.id
        try:
            out = await self.retimer.replan(job, cfg.limits.max_solve_s)
            retimed = time.monotonic()
        finally:
            self.retiming = None
        if out.rejected:
            raise msgs.Rejected(f"trajectory {incoming.id!r}: {out.rejected}")
        result, seconds = out.result, out.seconds
        self.solve_latency = 0.7 * self.solve_latency + 0.3 * (1.5 * seconds + 0.05)
        self.last_result_summary = {
            "id": incoming.id, "status": result.status, "message": result.message,
            "duration": round(result.duration, 3),
            "input_duration": round(result.trajectory.duration, 3),
            "solve_time": round(seconds, 4),
            "braking_zones": [[round(a, 3), round(b, 3)]
                              for a, b in result.diagnostics.intervals],
        }
        self._publish(out.payload, out.ros2_payload, out.view)
        for w in result.warnings:
            self.report.warn(f"{incoming.id}: {w}")
        self._report_zones(incoming.id, result, job)
        if result.status == REJECTED:
            said = self._uncertainty().describe()
            raise msgs.Rejected(f"trajectory {incoming.id!r}: {result.message} (the model is "
                                f"{origin(said)})")
        if result.status == FALLBACK:
            self.report.warn(f"{incoming.id}: re-time failed ({result.message}); flying the "
                             f"uniformly slowed fallback")
        if incoming is not self.latest or not self.flying():
            return  # superseded, or not flying: the result was published, nothing to fly
        if take is None:  # offboard began while we solved: join it onto the hold first
            self._wake.set()
            return
        # The plan's time 0 is the predicted takeover time even when the solve came in
        # later: the new path was joined where the old command is at t_take, so both
        # have moved on alike since (the stream refuses a takeover whose gap is too big)
        timing = incoming.timing and replace(incoming.timing, started=started, retimed=retimed,
                                             offered=time.monotonic())
        self.stream.offer(Plan(incoming.id, result, t_take, timing=timing,
                               heading=incoming.heading))
