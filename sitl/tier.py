"""The PX4 tier: one flight through the demo's forest on either vehicle backend (the
``sitl`` vehicle, or real PX4 SITL's SIH quadrotor), with the flight service in its own
process (as systemd runs it: it can be stopped, frozen and killed) and a ground station on
Zenoh, shared by a sequence of scenarios (PX4 runs in real time: one boot, one flight).

What the autopilot did is read from what it reports itself, through a passive MAVLink
observer on its GCS link (:mod:`sitl.observer`: modes, arming, landed state, position), and
true clearance from the simulator's ground truth (``HIL_STATE_QUATERNION``), the same way on
both backends. Used by tests/e2e/test_px4_tier.py.
"""

from __future__ import annotations

import asyncio
import contextlib
import signal
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from companion.frames import ned_to_enu
from companion.gs import GroundStation
from companion.gs.client import GroundStationError
from sitl.demo import (
    PLANNER_CLEARANCE_M,
    clearance,
    demo_config,
    free_tcp_port,
    hovering,
    plan_async,
    start_holding,
    take_off,
    to_local,
    trajectory_message,
)
from sitl.mavsdk_util import free_udp_port
from sitl.observer import Observer
from sitl.planner import PlanningError
from sitl.process import SimProcess
from sitl.proving import Notes, ServiceProcess, stream_figures, until
from sitl.stream_checks import StreamFigures
from sitl.world import get_world

BACKENDS = ("sitl", "px4")
#: The demo's forest (``rota-sitl demo`` flies seed 3)
TIER_SEED = 3
SPEED = 2.0
A_MAX = 1.5
#: The most clearance the tier's planner keeps after refusals (the forest's gaps allow it)
MAX_CLEARANCE_M = 1.9


class TierFlight:
    """``with TierFlight("px4", build) as f:`` boots the vehicle, starts the service and
    a ground station; coroutines then fly scenarios with :meth:`ready_to_fly`,
    :meth:`fly_toward` and :meth:`stall`."""

    def __init__(self, backend: str, build: Path | None = None, seed: int = TIER_SEED,
                 px4_params: dict[str, float] | None = None, defect: str | None = None,
                 noise_seed: int | None = None, **overrides: dict[str, Any]) -> None:
        if backend not in BACKENDS:
            raise ValueError(f"backend {backend!r}: one of {BACKENDS}")
        self.backend, self.build, self.seed = backend, build, seed
        self.noise_seed = noise_seed  # the `sitl` vehicle's noise, if not ``seed``'s
        self.defect = defect  # a deliberate defect built into the service (sitl.proving)
        self.px4_params = px4_params or {}
        # PX4's Return (its offboard-loss failsafe) climbs to 30 m before it flies home: a
        # fence ceiling under that would refuse the 'start' that takes the vehicle back
        self.overrides = {"safety": {"geofence_max": [30.0, 30.0, 35.0]}} | overrides
        self.world = get_world("forest", seed=seed)
        self.home = np.zeros(3)
        self.observer: Observer | None = None
        self.sim: SimProcess | None = None  # the `sitl` vehicle: its record of every setpoint
        self.pauses: list[tuple[float, float]] = []  # the service was frozen on purpose
        self.service: ServiceProcess | None = None
        self.gs: GroundStation | None = None
        self.logs: list[str] = []  # outputs of the services that ended
        self.retries: list[str] = []  # trajectories sent again, and why
        self.phases: list[tuple[str, float]] = []  # how long take-offs took
        #: the planner's clearance (m): more after the service refuses a path as unsafe
        self.clearance = PLANNER_CLEARANCE_M
        self._stack = contextlib.ExitStack()
        self._tmp = tempfile.TemporaryDirectory(prefix=f"rota-tier-{backend}-")
        self.workdir = Path(self._tmp.name)
        self.notes = Notes(self.workdir / "notify")  # systemd's notification socket

    # ------------------------------------------------------------ life
    def __enter__(self) -> TierFlight:
        try:
            self._stack.enter_context(self.notes)
            if self.backend == "sitl":
                port = free_udp_port()
                self.sim = self._stack.enter_context(SimProcess(port=port, world="forest",
                                                                seed=self.seed,
                                                                noise_seed=self.noise_seed))
                self.home = self.sim.home_enu
                self.observer = self._stack.enter_context(Observer(self.sim.gcs_port))
            else:
                from sitl.px4 import Px4Sitl

                px4 = self._stack.enter_context(Px4Sitl(self.build, self.px4_params))
                port = px4.port
                # PX4's SIH starts at its local origin: put that at the world's start
                self.home = np.array([self.world.start[0], self.world.start[1], 0.0])
                self.observer = self._stack.enter_context(Observer.px4(px4.instance))
            self.cfg = demo_config(port, free_tcp_port(), SPEED, str(self.workdir),
                                   **self.overrides)
            self.start_service()
        except BaseException:
            self.__exit__()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop_service()
        self._stack.close()
        self._tmp.cleanup()

    def start_service(self) -> None:
        """(Re)start the service and a ground station for it."""
        self.notes.clear()
        self.service = ServiceProcess(self.cfg, self.workdir, self.notes.path,
                                      self.defect).start()
        try:
            # (the service's start-up imports take 5-40 s on a busy 2-core machine)
            self.gs = GroundStation.for_service(self.cfg, self.cfg.zenoh.listen[0],
                                                wait_s=90.0)
        except Exception as exc:
            raise RuntimeError(f"{exc}\nservice log:\n{self.service.output()[-3000:]}") \
                from None

    def stop_service(self) -> int:
        """SIGTERM the service (as systemd stops it); its exit code."""
        if self.gs is not None:
            self.gs.close()
            self.gs = None
        code = 0
        if self.service is not None:
            code = self.service.stop()
            self.logs.append(self.service.output())
            self.service = None
        return code

    @property
    def log(self) -> str:
        """Every service's output so far."""
        now = self.service.output() if self.service is not None else ""
        return "\n".join([*self.logs, now])

    # ------------------------------------------------------------ flying
    async def ready_to_fly(self) -> np.ndarray:
        """Whatever the last scenario left: the service running, the vehicle airborne and
        in OFFBOARD, holding; returns the held position (local ENU)."""
        if self.service is None or not self.service.alive():
            self.stop_service()
            self.start_service()
        gs = self.gs
        t0 = time.monotonic()
        # PX4's own word on arming (a service just started may not know yet)
        states = ("airborne", "offboard") if self.armed() else ("ready", "airborne",
                                                                "offboard")
        s = await gs.wait_for(lambda s: s["state"] in states, 90, "the vehicle to be ready")
        if s["state"] == "ready":
            self.phases.append(("ready", round(time.monotonic() - t0, 1)))
            await take_off(gs, self.world, self.home)
            self.phases.append(("took off", round(time.monotonic() - t0, 1)))
        elif not s.get("map_voxels"):
            await self._send_map()
        if gs.status["state"] == "offboard" and not gs.status.get("halted") \
                and gs.status.get("streaming"):
            if gs.status.get("command") != "hold":  # the last scenario left it flying
                await gs.command_confirmed("hold")  # (confirmed: the brake is over)
                await self.at_rest()
            return np.asarray(gs.telemetry["setpoint"]["position"], dtype=float)
        for attempt in range(3):
            try:
                return await start_holding(gs)
            except GroundStationError as exc:
                # the start's pre-stream was cut short (on a busy machine: a stall of the
                # service long enough to end the stream): PX4 keeps its mode; again
                if "interrupted" not in str(exc) or attempt == 2:
                    raise
                self.retries.append(f"start: {exc}")
                await gs.wait_for(lambda s: s["state"] in ("airborne", "offboard"), 30,
                                  "the vehicle airborne")
        raise AssertionError("unreachable")

    async def _send_map(self) -> None:
        from sitl.demo import in_worker, map_payload

        payload = await in_worker(map_payload, self.world, self.home)
        self.gs.publish("map", payload)
        await self.gs.wait_for(lambda s: s.get("map_voxels"), 10, "the map to arrive")

    def target(self) -> np.ndarray:
        """The farther of the forest's start and goal from the vehicle (world ENU)."""
        here = self.position_world()
        ends = [np.array([*self.world.start[:2], here[2]]),
                np.array([*self.world.goal[:2], here[2]])]
        return max(ends, key=lambda e: float(np.linalg.norm(e[:2] - here[:2])))

    def position_world(self) -> np.ndarray:
        """The commanded position (else the reported one), world ENU."""
        tel = self.gs.telemetry
        p = (tel.get("setpoint") or {}).get("position") or tel.get("position")
        return np.asarray(p, dtype=float) + self.home

    async def plan(self, goal: np.ndarray) -> Any:
        """The reference planner's trajectory from the commanded state to ``goal`` (from
        rest if it cannot continue along the commanded velocity)."""
        sp = self.gs.telemetry.get("setpoint") or {}
        start = np.asarray(sp.get("position", self.gs.telemetry["position"])) + self.home
        v = np.asarray(sp.get("velocity", [0.0, 0.0, 0.0]))
        moving = self.gs.status.get("command") == "plan"
        kwargs = {"v_max": SPEED, "a_max": A_MAX, "start": start, "goal": goal,
                  "clearance": self.clearance}
        try:
            return await asyncio.wait_for(plan_async(
                self.world, start_velocity=v if moving else None, strict=False, **kwargs), 60)
        except PlanningError:
            if not moving:
                raise
        return await asyncio.wait_for(plan_async(self.world, **kwargs), 60)

    async def send_plan(self, ident: str, goal: np.ndarray) -> float:
        """Plan to ``goal`` (:meth:`plan`) and publish it as trajectory ``ident``; when
        (wall clock, as the service's error stamps)."""
        traj = await self.plan(goal)
        sent = time.time()
        self.gs.publish("trajectory", trajectory_message(to_local(traj, self.home), ident))
        return sent

    async def fly_toward(self, ident: str, goal: np.ndarray | None = None,
                         timeout_s: float = 30.0) -> np.ndarray:
        """Plan to ``goal`` (default :meth:`target`) from where the service commands, fly
        it; returns the goal (world ENU)."""
        goal = self.target() if goal is None else goal
        for attempt in range(3):
            sent = await self.send_plan(ident, goal)

            def refused(s: dict[str, Any], sent: float = sent) -> bool:
                err = s.get("last_error") or {}
                return f"'{ident}'" in err.get("message", "") and err.get("stamp", 0) >= sent

            s = await self.gs.wait_for(lambda s: s.get("trajectory_id") == ident
                                       or s.get("halted") or refused(s), timeout_s,
                                       f"{ident} to fly")
            if s.get("trajectory_id") == ident:
                return goal
            # A stall of the busy machine halted the flight (or the vehicle moved on while
            # this was planned): start again and plan from where it holds, as a planner would.
            why = s.get("halted") or s.get("last_error")
            self.retries.append(f"{ident} (attempt {attempt}): {why}")
            if not s.get("halted") and "unsafe" in str(why):
                # the model the service learned in flight needs more room than the planner
                # kept: a planner that reads the refusal keeps more
                self.clearance = min(self.clearance + 0.3, MAX_CLEARANCE_M)
            if s.get("halted"):
                await start_holding(self.gs)
        raise TimeoutError(f"{ident} not flown: {self.retries[-3:]}")

    async def under_way(self, share: float = 0.15) -> None:
        """Wait until the trajectory flown is ``share`` done; a flight halted on the way by
        a stall of the busy machine (as it must be) starts again and flies on."""
        for attempt in range(3):
            s = await self.gs.wait_for(lambda s: (s.get("progress") or 0) >= share
                                       or s.get("halted") or s.get("trajectory_id") is None,
                                       30, "speed")
            if s.get("trajectory_id") is None and not s.get("halted"):
                # the service gave the plan up (a tracking error, a refusal): say why
                raise AssertionError(f"the plan was given up before {share:.0%} of it: "
                                     f"{s.get('hold_reason') or s.get('last_error')}")
            if not s.get("halted"):
                return
            self.retries.append(f"under way: {s['halted']}")
            await start_holding(self.gs)
            await self.fly_toward(f"again-{attempt}")
        raise TimeoutError(f"not under way: {self.retries[-3:]}")

    def stall(self, seconds: float) -> tuple[float, float]:
        """Freeze the service (SIGSTOP) for ``seconds``: the fault itself, so a timed wait."""
        t0 = time.monotonic()
        self.service.signal(signal.SIGSTOP)
        time.sleep(seconds)
        self.service.signal(signal.SIGCONT)
        self.pauses.append((t0, time.monotonic()))
        return self.pauses[-1]

    async def at_rest(self) -> None:
        await hovering(self.gs)

    # ------------------------------------------------------------ what the vehicle says
    def modes(self, t0: float, t1: float = float("inf")) -> list[str]:
        """PX4's modes (as it reported them) from ``t0`` to ``t1``, in order, repeats
        collapsed."""
        seen = self.observer.modes_between(t0, t1)
        return [m for i, m in enumerate(seen) if i == 0 or m != seen[i - 1]]

    def armed(self) -> bool:
        return self.observer.mode()[1]

    def truth_world(self, t0: float = 0.0, t1: float = float("inf")) -> np.ndarray:
        """The simulator's true positions (world ENU) from ``t0`` to ``t1``."""
        ned = self.observer.truth(t0, t1)
        return ned_to_enu(ned) + self.home if len(ned) else ned

    def true_clearance(self, t0: float = 0.0, t1: float = float("inf")) -> float:
        """Closest approach to a trunk (robot radius subtracted), ground truth, airborne."""
        return clearance(self.world, self.truth_world(t0, t1))

    def wire(self, t0: float = 0.0, t1: float = float("inf")) -> dict[str, np.ndarray] | None:
        """The setpoints the `sitl` vehicle received from ``t0`` to ``t1`` (monotonic; world
        ENU; as :attr:`sitl.process.SimReport.setpoints`); None on PX4, which does not say."""
        if self.sim is None:
            return None
        sp = self.sim.setpoints()
        keep = (sp["wall_time"] >= t0) & (sp["wall_time"] <= t1)
        return {k: v[keep] for k, v in sp.items()}

    def stream(self, t0: float, t1: float = float("inf")) -> StreamFigures | None:
        """Gaps, jumps, limits and the geofence of what the `sitl` vehicle received from
        ``t0`` to ``t1`` (the freezes of :meth:`stall` left out); None on PX4."""
        if self.sim is None:
            return None
        return stream_figures(self.cfg, self.sim, (t0, t1), pauses=self.pauses)

    def reported_world(self, t0: float = 0.0, t1: float = float("inf")) -> np.ndarray:
        ned = self.observer.positions(t0, t1)
        return ned_to_enu(ned) + self.home if len(ned) else ned

    async def until_px4(self, predicate, timeout_s: float, what: str) -> float:  # noqa: ANN001
        """Wait until ``predicate(observer)``; when (monotonic)."""
        await until(lambda: predicate(self.observer), timeout_s, f"PX4 to report {what}",
                    period_s=0.02)
        return time.monotonic()
