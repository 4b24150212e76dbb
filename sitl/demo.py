"""``rota-sitl demo``: a simulated flight through a forest, end to end.

The ``sitl`` vehicle runs in its own process and speaks MAVLink on loopback UDP;
the flight service runs as it would on the drone (MAVSDK, Zenoh on loopback);
a small "planner and ground station" Zenoh client publishes the map and the
reference planner's trajectories, commands arm / takeoff / start, replans on
the way, and watches status. Nothing is mocked; nothing leaves 127.0.0.1.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import json
import logging
import multiprocessing
import socket
import time
from collections.abc import AsyncIterator
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from companion.frames import ned_to_enu
from companion.gs import GroundStation, replay
from companion.service import Service
from companion.settings.config import Config, from_dict
from rota.schema import TrajectoryMessage, trajectory_to_dict
from rota.trajectory import BSplineTrajectory
from rota.voxelmap import VoxelMap
from sitl.mavsdk_util import free_udp_port
from sitl.planner import plan
from sitl.process import SimProcess, SimReport
from sitl.world import World, get_world

log = logging.getLogger("rota.demo")
#: How long the demo waits for the service to be ready: a first run compiles the solver
#: (52-57 s on a quiet 2-core x86 machine, 2026-11-27; minutes on a slow board or a busy one).
READY_S = 600.0
#: When the demo began (run_demo sets it): its progress lines say the time since.
_PROGRESS: dict[str, float | None] = {"t0": None}


def say(text: str) -> None:
    """A progress line of the demo on stdout (only while :func:`run_demo` runs: the
    end-to-end tests that fly the same steps stay quiet)."""
    t0 = _PROGRESS["t0"]
    if t0 is not None:
        print(f"demo [{time.monotonic() - t0:5.1f} s] {text}", flush=True)


async def _ticking(what: str, every_s: float = 10.0) -> None:
    """Say ``what`` every ``every_s`` with the time spent: a long wait is not silence."""
    start = time.monotonic()
    while True:
        await asyncio.sleep(every_s)
        say(f"{what} ({time.monotonic() - start:.0f} s so far)")


def free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


#: Takeoff altitude of the demo and the end-to-end tests (m): high enough that PX4's
#: takeoff (which ends 0.1-0.5 m short) and its hover noise stay well clear of the ground.
DEMO_ALTITUDE_M = 2.0


def demo_config(mav_port: int, zenoh_port: int, speed: float, state_dir: str,
                **overrides: dict[str, Any]) -> Config:
    """The service configuration the demo and the end-to-end tests fly with."""
    data: dict[str, Any] = {
        "service": {"vehicle_id": "sim", "state_dir": state_dir},
        "mavlink": {"url": f"udpin://127.0.0.1:{mav_port}", "connect_timeout_s": 20.0},
        "zenoh": {"listen": [f"tcp/127.0.0.1:{zenoh_port}"], "telemetry_rate_hz": 20.0,
                  "status_rate_hz": 5.0},
        "stream": {"takeoff_altitude_m": DEMO_ALTITUDE_M},
        "limits": {"v_max": speed, "a_max": [2.0, 2.0, 1.5]},
        "safety": {"geofence_min": [-30.0, -30.0, -1.0], "geofence_max": [30.0, 30.0, 5.0],
                   "max_message_age_s": 5.0},
        "uncertainty": {"semi_axes": [0.2, 0.2, 0.2]},
    }
    for section, values in overrides.items():
        data.setdefault(section, {}).update(values)
    return from_dict(data)


@contextlib.asynccontextmanager
async def running(cfg: Config) -> AsyncIterator[tuple[Service, GroundStation]]:
    """The service running in this event loop, and a ground station talking to it."""
    service = Service(cfg)
    stop = asyncio.Event()
    task = asyncio.create_task(service.run(stop))
    while service.session is None and not task.done():  # Zenoh open: it listens
        await asyncio.sleep(0.01)
    if task.done():
        await task  # it failed to start: raise why
    gs = GroundStation.for_service(cfg, cfg.zenoh.listen[0])
    try:
        yield service, gs
    finally:
        stop.set()
        await task
        gs.close()


async def take_off(gs: GroundStation, world: World | None = None,
                   home: np.ndarray | None = None, ready_s: float = 60.0) -> None:
    """Wait for a healthy vehicle, publish the world's map, arm, take off and wait
    until the vehicle hovers; every step waits for the state to confirm it."""
    say("flight service starting: compiling or loading the solver (a first run compiles "
        "for about a minute; later runs load it in a second)")
    tick = asyncio.create_task(_ticking("still starting"))
    try:
        await gs.wait_for(lambda s: s["state"] == "ready", ready_s, "the vehicle to be ready")
    finally:
        tick.cancel()
    say("service ready, vehicle healthy: sending the map, arming, taking off")
    if world is not None and home is not None:
        # Encoded in the demo's worker process and sent from a thread: the message is
        # about 1 MB of JSON (50 ms of work that holds the GIL), and in the demo this
        # event loop also runs the service's setpoint stream.
        payload = await in_worker(map_payload, world, home)
        await asyncio.to_thread(gs.publish, "map", payload)
        await gs.wait_for(lambda s: s.get("map_voxels"), 10, "the map to arrive")
    await gs.command_confirmed("arm")
    await gs.command_confirmed("takeoff")
    await hovering(gs)
    say("hovering: starting offboard and planning through the forest")


async def hovering(gs: GroundStation, speed: float = 0.5, timeout_s: float = 20.0) -> None:
    """Wait until the reported speed stays under ``speed`` for 0.5 s: the takeoff's climb is
    over. (PX4 with GPS wanders 0.2-0.3 m in hover at up to 0.4 m/s, docs/sitl.md: a
    tighter test may wait for a calm that never comes.)"""
    end = time.monotonic() + timeout_s
    calm_since = None
    while time.monotonic() < end:
        v = gs.telemetry.get("velocity")
        if v is not None and float(np.linalg.norm(v)) < speed:
            calm_since = calm_since or time.monotonic()
            if time.monotonic() - calm_since >= 0.5:
                return
        else:
            calm_since = None
        await asyncio.sleep(0.05)
    raise TimeoutError(f"the vehicle did not settle under {speed} m/s within {timeout_s} s")


async def start_holding(gs: GroundStation, timeout_s: float = 10.0) -> np.ndarray:
    """Start offboard with nothing to fly yet: the service holds where the vehicle
    is. Returns the position it commands (local ENU), where a planner starts the
    first trajectory: a plan from a position read before the start (and perhaps
    stale) may begin farther from the hold than the service lets a plan join."""
    await gs.command_confirmed("start")
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        tel = gs.telemetry
        if tel.get("state") == "offboard" and tel.get("setpoint"):
            return np.asarray(tel["setpoint"]["position"], dtype=float)
        await asyncio.sleep(0.02)
    raise TimeoutError(f"no setpoint in telemetry within {timeout_s:g} s of the start")


def to_local(traj: BSplineTrajectory, home: np.ndarray) -> BSplineTrajectory:
    """World ENU -> the vehicle's local ENU frame (origin at home)."""
    return BSplineTrajectory(control_points=traj.control_points - home, degree=traj.degree,
                             knot_span=traj.knot_span)


def trajectory_message(traj: BSplineTrajectory, ident: str) -> dict[str, Any]:
    return trajectory_to_dict(TrajectoryMessage(traj, id=ident, frame="ENU", stamp=time.time()))


def map_message(world: World, home: np.ndarray, resolution: float = 0.1) -> dict[str, Any]:
    pts = world.voxel_points(resolution) - home
    return VoxelMap.from_points(pts, resolution, origin=-home).to_dict() | {"stamp": time.time()}


def map_payload(world: World, home: np.ndarray) -> bytes:
    """:func:`map_message` encoded as JSON."""
    return json.dumps(map_message(world, home), allow_nan=False).encode()


#: Clearance (m, beyond the robot's radius) the demo's planner keeps from trees. PX4 with GPS
#: strays 0.3-0.6 m per axis off its path at any speed, and its height estimate drifts by
#: about 0.45 m (docs/sitl.md, docs/estimator.md); a planner for such a vehicle inflates
#: obstacles by as much. Flown 240 times each on the calibrated vehicle (forest seeds 0-7,
#: 2 m/s, re-timed by ROTA): 0.6 m collided in 13, 0.9 m in 2, 1.0 m in 1 (a height dip).
PLANNER_CLEARANCE_M = 1.0

_WORKER: ProcessPoolExecutor | None = None


async def in_worker(fn: Any, *args: Any, **kwargs: Any) -> Any:
    """``fn(*args, **kwargs)`` in the demo's worker process: the demo's service shares
    this event loop, and CPU work here or in a thread (which holds the GIL) would
    stall the setpoint stream, which the service then reports and brakes for, as it
    must."""
    global _WORKER
    if _WORKER is None:
        _WORKER = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"))
    return await asyncio.get_running_loop().run_in_executor(
        _WORKER, functools.partial(fn, *args, **kwargs))


async def plan_async(world: World, **kwargs: Any) -> BSplineTrajectory:
    """:func:`sitl.planner.plan` in the demo's worker process (planning takes up to
    a second of CPU: :func:`in_worker`)."""
    kwargs.setdefault("clearance", PLANNER_CLEARANCE_M)
    return await in_worker(plan, world, **kwargs)


#: Times :func:`fly_to_goal` plans a replan that the service refused (each takes up to a
#: second of CPU; on a busy computer the vehicle turns further meanwhile, and three in a
#: row were seen refused).
REPLAN_ATTEMPTS = 10


async def fly_to_goal(gs: GroundStation, world: World, home: np.ndarray, speed: float,
                      a_max: float, replans: int, timeout_s: float = 120.0) -> dict[str, Any]:
    """Take off, fly the planner's trajectory with ``replans`` replans on the way."""
    # a first run compiles the solver: minutes on a slow board (the demo says so)
    await take_off(gs, world, home, ready_s=READY_S)
    here = await start_holding(gs) + home
    goal = np.array([world.goal[0], world.goal[1], here[2]])
    first = await plan_async(world, v_max=speed, a_max=a_max, start=here, goal=goal)
    gs.publish("trajectory", trajectory_message(to_local(first, home), "plan-0"))
    await gs.wait_for(lambda s: s.get("command") == "plan", 10, "the plan to begin")
    say(f"flying plan-0 ({first.duration:.1f} s as planned; re-timed by the service)")
    t_start = time.monotonic()
    planned = [first.duration]
    published = 1
    for k in range(1, replans + 1):
        share = k / (replans + 1)
        await gs.wait_for(lambda s, share=share: (s.get("progress") or 0) >= share * 0.9
                          and s.get("trajectory_id") is not None, 60, f"progress {share:.0%}")
        for _attempt in range(REPLAN_ATTEMPTS):
            sp = gs.telemetry["setpoint"]
            p = np.asarray(sp["position"]) + home
            v = np.asarray(sp["velocity"])
            # Plan from the commanded state as it was (like EGO-Planner): the vehicle will
            # be a little further along by the time the replan is re-timed, and the
            # service joins the new path where the vehicle is then.
            new = await plan_async(world, v_max=speed, a_max=a_max, start=p, goal=goal,
                                   start_velocity=v, strict=False)
            sent = time.time()
            say(f"replanning on the way: plan-{k}")
            gs.publish("trajectory", trajectory_message(to_local(new, home), f"plan-{k}"))
            published += 1

            def settled(s: dict[str, Any], k: int = k, sent: float = sent) -> bool:
                err = s.get("last_error") or {}
                return (s.get("last_retime") or {}).get("id") == f"plan-{k}" or (
                    f"'plan-{k}'" in err.get("message", "") and err.get("stamp", 0) >= sent)

            seen = await gs.wait_for(settled, 10, f"plan-{k} to be re-timed or refused")
            if (seen.get("last_retime") or {}).get("id") == f"plan-{k}":
                break
            # Refused (on a busy machine the vehicle may have turned further than the
            # service allows while this was planned): plan again from where it is now,
            # as a planner that replans continuously would.
        planned.append(new.duration)
    goal_local = goal - home
    await gs.wait_for(
        lambda s: s.get("command") == "hold" and gs.telemetry.get("position") is not None
        and np.linalg.norm(np.asarray(gs.telemetry["position"]) - goal_local) < 0.5,
        timeout_s, "the goal")
    flight_time = time.monotonic() - t_start
    say(f"goal reached after {flight_time:.1f} s")
    return {"flight_time_s": flight_time, "planned_durations_s": planned,
            "trajectories_published": published}


async def _run(cfg: Config, world: World, home: np.ndarray, speed: float, replans: int,
               land: bool, hold_s: float = 0.0) -> dict[str, Any]:
    async with running(cfg) as (service, gs):
        result = await fly_to_goal(gs, world, home, speed, min(cfg.limits.a_max), replans)
        if hold_s > 0:
            say(f"holding at the goal for {hold_s:g} s")
            await asyncio.sleep(hold_s)  # the window recorded, not a wait for a state
        if land:
            say("landing")
            await gs.command_confirmed("land")
        result.update(retimed=gs.retimed, jitter_p99_ms=service.jitter_p99_ms(),
                      last_status=gs.status)
    result["record"] = list(getattr(service.recorder, "files", []))
    return result


def clearance(world: World, positions: np.ndarray) -> float:
    """Smallest clearance (m) between ``positions`` (world ENU) and any obstacle,
    while airborne (robot radius subtracted)."""
    airborne = positions[:, 2] > 0.3
    if not airborne.any():
        return float("inf")
    return float(np.min(world.signed_distance(positions[airborne])) - world.robot_radius)


def closest_approach(world: World, report: SimReport) -> float:
    """Smallest clearance (m) of the sitl vehicle's true position while airborne."""
    return clearance(world, report.true_position)


def run_demo(out_dir: str = "out/demo", seed: int = 3, speed: float = 2.0,
             replans: int = 1, px4_build: str | None = None, hold_s: float = 0.0,
             vehicle_seed: int | None = None) -> dict[str, Any]:
    """Run the demo flight; print and return a summary; write the flight record,
    its plot and a JSON summary. With ``px4_build`` the vehicle is real PX4 SITL
    (the SIH quadrotor of that build) instead of the ``sitl`` vehicle. ``hold_s``:
    how long it holds at the goal before it lands (the record then shows how it
    settles there: ``rota-sitl parity``). ``vehicle_seed``: the `sitl` vehicle's noise
    (estimation error, wander), if not ``seed``'s."""
    _PROGRESS["t0"] = time.monotonic()
    try:
        return _demo(out_dir, seed, speed, replans, px4_build, hold_s, vehicle_seed)
    finally:
        _PROGRESS["t0"] = None


def _demo(out_dir: str, seed: int, speed: float, replans: int,
          px4_build: str | None, hold_s: float, vehicle_seed: int | None) -> dict[str, Any]:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    world = get_world("forest", seed=seed)
    say("booting PX4 SITL (SIH)" if px4_build else "starting the simulated vehicle (sitl)")
    zenoh_port = free_tcp_port()
    # The service's persisted state (the in-flight estimate) lives under the output folder
    # and is kept: a second and third demo in a row fly with what the first one learned.
    state = str(out / "state")
    with _vehicle(px4_build, world, seed, vehicle_seed) as vehicle:
        mav_port, home, sim = vehicle
        cfg = demo_config(mav_port, zenoh_port, speed, state, record={"dir": str(out / "records")})
        print(f"demo: forest world seed {seed} ({len(world.obstacles)} trees), speed limit "
              f"{speed} m/s; vehicle ({'PX4 SITL' if px4_build else 'sitl'}) on udp "
              f"127.0.0.1:{mav_port}, Zenoh tcp/127.0.0.1:{zenoh_port}", flush=True)
        result = asyncio.run(_run(cfg, world, home, speed, replans, land=True,
                                  hold_s=hold_s))
    say("landed: writing the summary and the plot")
    flight = replay.load(result["record"])
    if isinstance(sim, SimProcess):
        report = sim.report
        closest, collisions = closest_approach(world, report), len(report.collisions)
    else:  # PX4: SIH's ground truth (HIL_STATE_QUATERNION on its GCS link), not its estimate
        truth = sim.truth()
        closest = clearance(world, ned_to_enu(truth) + home if len(truth)
                            else flight.position + home)
        collisions = int(closest < 0)
    figures = replay.stats(flight)
    zones = sum(len(r.get("braking_zones", [])) for r in result["retimed"])
    braking = braking_model(result.get("last_status", {}), cfg)
    summary = {
        "seed": seed,
        "vehicle": "px4" if px4_build else "sitl",
        "reached_goal": True,
        "flight_time_s": round(result["flight_time_s"], 2),
        "planned_duration_s": round(result["planned_durations_s"][0], 2),
        "retimed_durations_s": [round(r["duration"], 2) for r in result["retimed"]],
        "input_durations_s": [round(r["input_duration"], 2) for r in result["retimed"]],
        "braking_zones": zones,
        "braking_model": braking,
        "v_max_m_s": speed,
        "max_speed_m_s": figures["max_speed_m_s"],
        "max_commanded_speed_m_s": figures["max_commanded_speed_m_s"],
        "max_acceleration_m_s2": figures["max_acceleration_m_s2"],
        "max_acceleration_per_axis_m_s2": figures["max_acceleration_per_axis_m_s2"],
        "a_max_m_s2": list(cfg.limits.a_max),
        "max_tracking_error_m": figures["max_tracking_error_m"],
        "closest_approach_m": round(closest, 3),
        "collisions": collisions,
        "setpoint_jitter_p99_ms": result["jitter_p99_ms"],
        "record": [str(p) for p in result["record"]],
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    png = replay.plot(flight, out / "flight.png",
                      title=f"Demo: forest seed {seed}, v_max {speed} m/s ({summary['vehicle']})")
    print(f"flight time {summary['flight_time_s']} s from the first plan to the goal "
          f"(the planner's own trajectory: {summary['planned_duration_s']} s)")
    print(f"braking model: {braking['text']}")
    for r in result["retimed"]:
        print(f"  {r['id']}: {r['status']}, {r['input_duration']:.2f} s as planned -> "
              f"{r['duration']:.2f} s re-timed, {len(r['braking_zones'])} braking zone(s), "
              f"solve {1e3 * (r['solver'] or {}).get('wall_time', 0):.0f} ms")
    print(f"max speed {summary['max_speed_m_s']} m/s flown, "
          f"{summary['max_commanded_speed_m_s']} m/s commanded (limit {speed}); max commanded "
          f"acceleration per axis {summary['max_acceleration_per_axis_m_s2']} m/s^2 (limits "
          f"{summary['a_max_m_s2']}); max tracking error {summary['max_tracking_error_m']} m")
    print(f"closest approach {summary['closest_approach_m']} m, collisions "
          f"{summary['collisions']}, setpoint jitter p99 {summary['setpoint_jitter_p99_ms']} ms")
    print(f"wrote {out / 'summary.json'}, {png} and the flight record "
          f"{', '.join(summary['record'])}")
    return summary


def braking_model(status: dict[str, Any], cfg: Config) -> dict[str, Any]:
    """Which braking model the re-times used: ROTA as in the paper or with error memory
    (its memory time, and whether the in-flight estimator's or the configuration's)."""
    u = status.get("uncertainty") or {}
    memory = float(u.get("memory_s", cfg.uncertainty.memory_s))
    source = "in-flight estimate" if u.get("in_use") == "estimate" else "configured"
    name = "error memory" if memory > 0 else "paper"
    text = (f"ROTA with error memory, T = {memory:g} s ({source})" if memory > 0
            else f"ROTA as in the paper, no error memory ({source})")
    return {"name": name, "memory_s": memory, "source": source, "text": text}


@contextlib.contextmanager
def _vehicle(px4_build: str | None, world: World, seed: int,  # noqa: ANN202
             vehicle_seed: int | None = None):
    """(MAVLink port, home in world ENU, the SimProcess or, for PX4, an observer of its
    GCS link that reads SIH's ground truth) of the demo's vehicle."""
    if px4_build is None:
        port = free_udp_port()
        with SimProcess(port=port, world="forest", seed=seed, noise_seed=vehicle_seed) as sim:
            yield port, sim.home_enu, sim
        return
    from sitl.observer import Observer
    from sitl.px4 import Px4Sitl

    # PX4's SIH starts at its local origin: put that at the world's start
    home = np.array([world.start[0], world.start[1], 0.0])
    with Px4Sitl(Path(px4_build)) as px4, Observer.px4(px4.instance) as observer:
        yield px4.port, home, observer
