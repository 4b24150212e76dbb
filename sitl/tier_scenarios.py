"""The PX4 tier's scenarios: each flies one promise of the service on a
:class:`~sitl.tier.TierFlight` (either backend) and returns what it measured, a frozen
dataclass. tests/e2e/test_px4_tier.py asserts on them; ``rota-sitl parity --tier`` flies
them on both backends and puts their figures side by side (docs/sitl.md).

Each scenario first brings the vehicle back to "airborne, OFFBOARD, holding" whatever the
one before left (:meth:`~sitl.tier.TierFlight.ready_to_fly`), so none depends on another's
order. Times are ``time.monotonic()`` seconds, positions world ENU metres.
"""

from __future__ import annotations

import asyncio
import os
import signal
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from sitl.proving import statuses_errors
from sitl.tier import TierFlight

#: Stall shorter than PX4's offboard-loss timeout (1 s) minus the stream's margin
SHORT_STALL_S = 0.6
#: Stall past PX4's offboard-loss timeout
LONG_STALL_S = 1.5
#: The window of a rest point: PX4 (SIH) does not come to rest at a hold; its estimate
#: wanders around the setpoint by up to 0.65 m at 0.3-0.5 m/s with a period of about 10 s
#: (docs/sitl.md), so a shorter mean stops at a random phase of it
REST_WINDOW_S = 10.0
#: How long PX4 is watched after the service reports the end of its stream: PX4 would be
#: back in OFFBOARD within 30 ms of resumed setpoints (docs/sitl.md)
WATCH_AFTER_LOSS_S = 2.0


async def rest_point(f: TierFlight) -> np.ndarray:
    """Where the vehicle holds (world ENU): the mean reported position over REST_WINDOW_S
    once it hovers (the window of the measurement, not a wait for a state)."""
    await f.at_rest()
    t0 = time.monotonic()
    await asyncio.sleep(REST_WINDOW_S)
    return f.reported_world(t0).mean(axis=0)


def failsafes(f: TierFlight, since: float) -> list[str]:
    """PX4's STATUSTEXTs since ``since`` that name a failsafe."""
    return [t for t in f.observer.texts(since) if "ailsafe" in t]


@dataclass(frozen=True)
class ForestFlight:
    """Start to goal through the forest, replanned half-way (the demo's flight)."""

    t0: float
    t1: float  #: at the goal, holding
    goal: np.ndarray
    rest: np.ndarray  #: rest point (:func:`rest_point`) after it
    clearance_m: float  #: closest approach to a trunk from t0 to t1 (truth)

    @property
    def miss_m(self) -> float:
        return float(np.linalg.norm(self.rest - self.goal))


async def forest_flight(f: TierFlight) -> ForestFlight:
    await f.ready_to_fly()
    t0 = time.monotonic()
    goal = await f.fly_toward("forest-0")
    await f.under_way(0.4)
    await f.fly_toward("forest-1", goal)
    local = goal - f.home
    for attempt in range(3):
        s = await f.gs.wait_for(
            lambda s: s.get("halted") or s.get("command") == "hold"
            and s.get("trajectory_id") is None
            and np.linalg.norm(np.asarray(f.gs.telemetry["position"]) - local) < 0.5, 60,
            "the goal")
        if not s.get("halted"):
            break
        # a stall of the busy machine halted the flight, as it must (in OFFBOARD): a
        # planner starts again from the hold
        f.retries.append(f"forest: {s['halted']}")
        await f.gs.command_confirmed("start")
        await f.fly_toward(f"forest-{attempt + 2}", goal)
    t1 = time.monotonic()
    rest = await rest_point(f)
    return ForestFlight(t0, t1, goal, rest, f.true_clearance(t0, t1))


@dataclass(frozen=True)
class Hold:
    """``hold`` under way: where the setpoint braked to, where the vehicle came to rest."""

    t0: float  #: the command sent
    speed: float  #: commanded speed then (m/s)
    age_s: float  #: age of the telemetry sample the commanded position is from
    replied_s: float  #: the reply's round trip
    here: np.ndarray  #: the vehicle (reported) at the command
    commanded: np.ndarray  #: the setpoint at the command
    held: np.ndarray  #: the hold setpoint
    rest: np.ndarray  #: the vehicle at rest
    reply: dict[str, Any]
    status: dict[str, Any]

    @property
    def brake_m(self) -> float:
        return float(np.linalg.norm(self.held - self.commanded))

    @property
    def settle_m(self) -> float:
        return float(np.linalg.norm(self.rest - self.held))

    @property
    def lag_m(self) -> float:
        return float(np.linalg.norm(self.commanded - self.here))

    @property
    def travel_m(self) -> float:
        return float(np.linalg.norm(self.rest - self.here))


async def hold(f: TierFlight) -> Hold:
    await f.ready_to_fly()
    await f.fly_toward("hold-0")
    await f.under_way(0.2)
    t0 = time.monotonic()
    here = f.reported_world(t0 - 0.1)[-1]
    tel = f.gs.telemetry
    age = max(time.time() - float(tel["stamp"]), 0.0)
    speed = float(np.linalg.norm(tel["setpoint"]["velocity"]))
    commanded = f.position_world()
    reply = await f.gs.command("hold")
    replied = time.monotonic() - t0
    await f.at_rest()
    rest = f.reported_world(time.monotonic() - 0.3).mean(axis=0)
    return Hold(t0, speed, age, replied, here, commanded, f.position_world(), rest, reply,
                f.gs.status)


@dataclass(frozen=True)
class ShortStall:
    """Frozen for SHORT_STALL_S, a trajectory sent meanwhile, then a new ``start``."""

    t_fly: float
    t0: float  #: frozen
    t1: float  #: resumed
    halted: dict[str, Any]  #: the status that reported the halt
    not_flown: dict[str, Any]  #: the status after the trajectory sent while halted
    reply: dict[str, Any]  #: to the new ``start``
    status: dict[str, Any]


async def short_stall(f: TierFlight) -> ShortStall:
    await f.ready_to_fly()
    t_fly = time.monotonic()
    goal = await f.fly_toward("stall-0")
    await f.under_way(0.2)
    t0, t1 = f.stall(SHORT_STALL_S)
    halted = await f.gs.wait_for(lambda s: s.get("halted"), 10, "the halt")
    await f.send_plan("stall-1", goal)
    await f.gs.wait_for(lambda s: (s.get("last_retime") or {}).get("id") == "stall-1",
                        30, "stall-1 re-timed")
    not_flown = await f.gs.wait_for(lambda s: s.get("command") == "hold", 10, "the hold")
    reply = await f.gs.command("start")
    await f.gs.wait_for(lambda s: not s.get("halted"), 10, "the start", fresh=True)
    await f.fly_toward("stall-2", goal)
    return ShortStall(t_fly, t0, t1, halted, not_flown, reply, f.gs.status)


@dataclass(frozen=True)
class WorkerKilled:
    t0: float  #: the re-time worker killed
    status: dict[str, Any]  #: after the next trajectory flies


async def worker_killed(f: TierFlight) -> WorkerKilled:
    await f.ready_to_fly()
    await f.fly_toward("worker-0")
    await f.under_way(0.1)
    t0 = time.monotonic()
    pid = f.gs.status["supervision"]["worker_pids"]["re-time"][0]
    os.kill(pid, signal.SIGKILL)
    await f.gs.wait_for(lambda s: any("re-time worker killed by SIGKILL" in e["message"]
                                      for e in s.get("events", ())), 5, "the report")
    await f.gs.wait_for(lambda s: s["supervision"]["worker_pids"]["re-time"]
                        and s["supervision"]["worker_pids"]["re-time"][0] != pid, 20,
                        "a new worker")
    # (the new worker's first re-time loads its compiled kernels: 5-40 s when busy)
    await f.fly_toward("worker-1", timeout_s=90)
    return WorkerKilled(t0, f.gs.status)


@dataclass(frozen=True)
class Sigterm:
    t0: float  #: SIGTERM sent
    code: int  #: the service's exit code
    t_hold: float  #: PX4 reports Hold (AUTO_LOITER)


async def sigterm(f: TierFlight) -> Sigterm:
    await f.ready_to_fly()
    await f.fly_toward("term-0")
    await f.under_way(0.1)
    t0 = time.monotonic()
    code = f.stop_service()
    t_hold = await f.until_px4(lambda o: o.mode()[0] == "AUTO_LOITER", 10, "Hold")
    return Sigterm(t0, code, t_hold)


@dataclass(frozen=True)
class OffboardLoss:
    """Frozen for LONG_STALL_S (past PX4's offboard-loss timeout), then a new ``start``."""

    t_fly: float
    t0: float  #: frozen (the last setpoint went out about then)
    t1: float  #: resumed
    ended: list[str]  #: the errors the service reported
    t_start: float  #: the new ``start`` sent
    t_back: float  #: PX4 reports OFFBOARD again
    status: dict[str, Any]
    failsafe: tuple[float, str] | None  #: PX4's first mode after OFFBOARD (time, name)

    @property
    def failsafe_after_s(self) -> float:
        """From the freeze to PX4's failsafe mode (its offboard-loss timeout at work)."""
        return self.failsafe[0] - self.t0 if self.failsafe else float("nan")


async def offboard_loss(f: TierFlight) -> OffboardLoss:
    await f.ready_to_fly()
    t_fly = time.monotonic()
    goal = await f.fly_toward("loss-0")
    await f.under_way(0.1)
    t0, t1 = f.stall(LONG_STALL_S)
    await f.gs.wait_for(lambda s: not s.get("streaming") and s["state"] == "airborne",
                        10, "the end of the stream")
    ended = statuses_errors(f.gs.statuses)
    await asyncio.sleep(WATCH_AFTER_LOSS_S)  # the window watched, not a wait for a state
    t_start = time.monotonic()
    await f.gs.command_confirmed("start")
    t_back = await f.until_px4(lambda o: o.mode()[0] == "OFFBOARD", 10, "OFFBOARD")
    await f.fly_toward("loss-1", goal)
    left = [(t, m) for t, m, _ in f.observer.mode_changes(t0) if m != "OFFBOARD"]
    return OffboardLoss(t_fly, t0, t1, ended, t_start, t_back, f.gs.status,
                        left[0] if left else None)


@dataclass(frozen=True)
class Landing:
    t0: float  #: ``land`` sent
    t_down: float  #: PX4 reports disarmed
    status: dict[str, Any]


async def land(f: TierFlight) -> Landing:
    await f.ready_to_fly()
    t0 = time.monotonic()
    await f.gs.command_confirmed("land")
    t_down = await f.until_px4(lambda o: not o.mode()[1], 30, "disarmed")
    return Landing(t0, t_down, f.gs.status)


@dataclass(frozen=True)
class KillSwitch:
    t_fly: float
    t0: float  #: the kill switch thrown
    t_seen: float  #: the service out of offboard
    status: dict[str, Any]
    land: dict[str, Any]  #: replies to land, disarm, arm once on the ground
    disarm: dict[str, Any]
    arm: dict[str, Any]


async def kill_switch(f: TierFlight) -> KillSwitch:
    await f.ready_to_fly()
    t_fly = time.monotonic()
    await f.fly_toward("kill-0")
    await f.under_way(0.1)
    t0 = time.monotonic()
    f.observer.kill()
    s = await f.gs.wait_for(lambda s: s["state"] in ("ready", "not_ready"), 10, "the service")
    t_seen = time.monotonic()
    await f.until_px4(lambda o: o.seen.landed and o.seen.landed[-1][1] == 1, 20,
                      "the vehicle on the ground")
    land_reply, disarm, arm = (await f.gs.command("land"), await f.gs.command("disarm"),
                               await f.gs.command("arm"))
    return KillSwitch(t_fly, t0, t_seen, s, land_reply, disarm, arm)
