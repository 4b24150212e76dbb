"""``rota-companion demo``: a simulated flight through a forest, end to end.

The ``sitl`` vehicle runs in its own process and speaks MAVLink on loopback UDP;
the flight service runs as it would on the drone (MAVSDK, Zenoh on loopback);
a small "planner and ground station" Zenoh client publishes the map and the
reference planner's trajectories, commands arm / takeoff / start, replans on
the way, and watches status. Nothing is mocked; nothing leaves 127.0.0.1.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import socket
import tempfile
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from companion.config import Config, from_dict
from companion.service import Service
from rota.schema import TrajectoryMessage, trajectory_to_dict
from rota.trajectory import BSplineTrajectory
from rota.voxelmap import VoxelMap
from sitl.mavsdk_util import free_udp_port
from sitl.planner import plan
from sitl.process import SimProcess, SimReport
from sitl.world import World, get_world

log = logging.getLogger("rota.demo")


def free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def demo_config(mav_port: int, zenoh_port: int, speed: float, state_dir: str,
                **overrides: dict[str, Any]) -> Config:
    """The service configuration the demo and the end-to-end tests fly with."""
    data: dict[str, Any] = {
        "service": {"vehicle_id": "sim", "state_dir": state_dir},
        "mavlink": {"url": f"udpin://127.0.0.1:{mav_port}", "connect_timeout_s": 20.0},
        "zenoh": {"listen": [f"tcp/127.0.0.1:{zenoh_port}"], "telemetry_rate_hz": 20.0,
                  "status_rate_hz": 5.0},
        "stream": {"takeoff_altitude_m": 1.0},
        "limits": {"v_max": speed, "a_max": [2.0, 2.0, 1.5]},
        "safety": {"geofence_min": [-30.0, -30.0, -1.0], "geofence_max": [30.0, 30.0, 5.0],
                   "max_message_age_s": 5.0},
        "uncertainty": {"semi_axes": [0.2, 0.2, 0.2]},
    }
    for section, values in overrides.items():
        data.setdefault(section, {}).update(values)
    return from_dict(data)


@dataclass
class GroundStation:
    """A Zenoh client playing planner and ground station (loopback only)."""

    cfg: Config
    endpoint: str
    status: dict[str, Any] = field(default_factory=dict)
    telemetry: dict[str, Any] = field(default_factory=dict)
    retimed: list[dict[str, Any]] = field(default_factory=list)
    statuses: list[dict[str, Any]] = field(default_factory=list)
    setpoints: list[tuple[float, list[float]]] = field(default_factory=list)

    def __post_init__(self) -> None:
        z = zenoh.Config()
        z.insert_json5("mode", '"peer"')
        z.insert_json5("scouting/multicast/enabled", "false")
        z.insert_json5("connect/endpoints", json.dumps([self.endpoint]))
        self.session = zenoh.open(z)
        k = self.cfg.key
        self._subs = [
            self.session.declare_subscriber(k("status"), self._on_status),
            self.session.declare_subscriber(k("telemetry"), self._on_telemetry),
            self.session.declare_subscriber(k("retimed"), self._on_retimed),
        ]

    def _on_status(self, sample: zenoh.Sample) -> None:
        self.status = json.loads(sample.payload.to_bytes())
        self.statuses.append(self.status)

    def _on_telemetry(self, sample: zenoh.Sample) -> None:
        self.telemetry = json.loads(sample.payload.to_bytes())
        sp = self.telemetry.get("setpoint")
        if sp is not None:
            self.setpoints.append((time.monotonic(), sp["position"]))

    def _on_retimed(self, sample: zenoh.Sample) -> None:
        self.retimed.append(json.loads(sample.payload.to_bytes()))

    def publish(self, name: str, obj: dict[str, Any]) -> None:
        self.session.put(self.cfg.key(name), json.dumps(obj).encode(),
                         encoding=zenoh.Encoding.APPLICATION_JSON)

    async def command(self, name: str, timeout_s: float = 15.0) -> dict[str, Any]:
        """Send a command (a Zenoh query) and return the reply."""

        def ask() -> dict[str, Any]:
            replies = list(self.session.get(self.cfg.key("cmd", name), timeout=timeout_s))
            if not replies or replies[0].ok is None:
                raise RuntimeError(f"no reply to {name}")
            return json.loads(replies[0].ok.payload.to_bytes())

        return await asyncio.get_running_loop().run_in_executor(None, ask)

    async def wait_for(self, predicate, timeout_s: float, what: str) -> None:  # noqa: ANN001
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if self.status and predicate(self.status):
                return
            await asyncio.sleep(0.05)
        raise TimeoutError(f"timed out waiting for {what}; status: "
                           f"{json.dumps(self.status)[:600]}")

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()
        self.session.close()


@contextlib.asynccontextmanager
async def running(cfg: Config) -> AsyncIterator[tuple[Service, GroundStation]]:
    """The service running in this event loop, and a ground station talking to it."""
    service = Service(cfg)
    stop = asyncio.Event()
    task = asyncio.create_task(service.run(stop))
    gs = GroundStation(cfg, cfg.zenoh.listen[0])
    try:
        yield service, gs
    finally:
        stop.set()
        await task
        gs.close()


async def take_off(gs: GroundStation, world: World | None = None,
                   home: np.ndarray | None = None) -> None:
    """Wait for a healthy vehicle, publish the world's map, arm, take off, settle."""
    await gs.wait_for(lambda s: s["state"] == "ready", 60, "the vehicle to be ready")
    if world is not None and home is not None:
        gs.publish("map", map_message(world, home))
        await gs.wait_for(lambda s: s.get("map_voxels"), 10, "the map to arrive")
    for name in ("arm", "takeoff"):
        reply = await gs.command(name)
        if not reply["ok"]:
            raise RuntimeError(f"{name}: {reply['message']}")
        await asyncio.sleep(0.5)
    await gs.wait_for(lambda s: s["state"] == "airborne", 30, "takeoff")
    await asyncio.sleep(1.0)


def to_local(traj: BSplineTrajectory, home: np.ndarray) -> BSplineTrajectory:
    """World ENU -> the vehicle's local ENU frame (origin at home)."""
    return BSplineTrajectory(control_points=traj.control_points - home, degree=traj.degree,
                             knot_span=traj.knot_span)


def trajectory_message(traj: BSplineTrajectory, ident: str) -> dict[str, Any]:
    return trajectory_to_dict(TrajectoryMessage(traj, id=ident, frame="ENU", stamp=time.time()))


def map_message(world: World, home: np.ndarray, resolution: float = 0.1) -> dict[str, Any]:
    pts = world.voxel_points(resolution) - home
    return VoxelMap.from_points(pts, resolution, origin=-home).to_dict() | {"stamp": time.time()}


async def fly_to_goal(gs: GroundStation, world: World, home: np.ndarray, speed: float,
                      a_max: float, replans: int, timeout_s: float = 120.0) -> dict[str, Any]:
    """Take off, fly the planner's trajectory with ``replans`` replans on the way."""
    await take_off(gs, world, home)
    first = plan(world, v_max=speed, a_max=a_max)
    gs.publish("trajectory", trajectory_message(to_local(first, home), "plan-0"))
    reply = await gs.command("start")
    if not reply["ok"]:
        raise RuntimeError(f"start: {reply['message']}")
    await gs.wait_for(lambda s: s.get("command") == "plan", 10, "the plan to begin")
    t_start = time.monotonic()
    planned = [first.duration]
    for k in range(1, replans + 1):
        share = k / (replans + 1)
        await gs.wait_for(lambda s, share=share: (s.get("progress") or 0) >= share * 0.9
                          and s.get("trajectory_id") is not None, 60, f"progress {share:.0%}")
        sp = gs.telemetry["setpoint"]
        p = np.asarray(sp["position"]) + home
        v = np.asarray(sp["velocity"])
        # Plan from the commanded state as it was (like EGO-Planner): the vehicle will be a
        # little further along by the time the replan is re-timed, and the service joins
        # the new path where the vehicle is then.
        new = plan(world, v_max=speed, a_max=a_max, start=p, start_velocity=v, strict=False)
        gs.publish("trajectory", trajectory_message(to_local(new, home), f"plan-{k}"))
        planned.append(new.duration)
        await asyncio.sleep(0.5)
    goal_local = np.asarray(world.goal) - home
    await gs.wait_for(
        lambda s: s.get("command") == "hold" and gs.telemetry.get("position") is not None
        and np.linalg.norm(np.asarray(gs.telemetry["position"]) - goal_local) < 0.5,
        timeout_s, "the goal")
    flight_time = time.monotonic() - t_start
    return {"flight_time_s": flight_time, "planned_durations_s": planned}


async def _run(cfg: Config, world: World, home: np.ndarray, speed: float, replans: int,
               land: bool) -> dict[str, Any]:
    async with running(cfg) as (service, gs):
        result = await fly_to_goal(gs, world, home, speed, min(cfg.limits.a_max), replans)
        if land:
            await gs.command("land")
            await gs.wait_for(lambda s: s["state"] == "ready", 40, "landing")
        result.update(retimed=gs.retimed, jitter_p99_ms=service.jitter_p99_ms(),
                      last_status=gs.status)
        return result


def closest_approach(world: World, report: SimReport) -> float:
    """Smallest clearance (m) between the robot's true position and any obstacle,
    while airborne (robot radius subtracted)."""
    pos = report.true_position
    airborne = pos[:, 2] > 0.3
    if not airborne.any():
        return float("inf")
    return float(np.min(world.signed_distance(pos[airborne])) - world.robot_radius)


def run_demo(out_dir: str = "out/demo", seed: int = 3, speed: float = 2.0,
             replans: int = 1) -> dict[str, Any]:
    """Run the demo flight; print and return a summary; write a plot and JSON."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    world = get_world("forest", seed=seed)
    mav_port, zenoh_port = free_udp_port(), free_tcp_port()
    with tempfile.TemporaryDirectory() as state:
        cfg = demo_config(mav_port, zenoh_port, speed, state)
        print(f"demo: forest world seed {seed} ({len(world.obstacles)} trees), speed limit "
              f"{speed} m/s; vehicle on udp 127.0.0.1:{mav_port}, Zenoh tcp/127.0.0.1:"
              f"{zenoh_port}", flush=True)
        with SimProcess(port=mav_port, world="forest", seed=seed) as sim:
            result = asyncio.run(_run(cfg, world, sim.home_enu, speed, replans, land=True))
        report = sim.report
    zones = sum(len(r.get("braking_zones", [])) for r in result["retimed"])
    summary = {
        "seed": seed,
        "reached_goal": True,
        "flight_time_s": round(result["flight_time_s"], 2),
        "planned_duration_s": round(result["planned_durations_s"][0], 2),
        "retimed_durations_s": [round(r["duration"], 2) for r in result["retimed"]],
        "input_durations_s": [round(r["input_duration"], 2) for r in result["retimed"]],
        "braking_zones": zones,
        "closest_approach_m": round(closest_approach(world, report), 3),
        "collisions": len(report.collisions),
        "setpoint_jitter_p99_ms": result["jitter_p99_ms"],
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    png = plot_flight(world, report, result["retimed"], out / "flight.png")
    print(f"flight time {summary['flight_time_s']} s from the first plan to the goal "
          f"(the planner's own trajectory: {summary['planned_duration_s']} s)")
    for r in result["retimed"]:
        print(f"  {r['id']}: {r['status']}, {r['input_duration']:.2f} s as planned -> "
              f"{r['duration']:.2f} s re-timed, {len(r['braking_zones'])} braking zone(s), "
              f"solve {1e3 * (r['solver'] or {}).get('wall_time', 0):.0f} ms")
    print(f"closest approach {summary['closest_approach_m']} m, collisions "
          f"{summary['collisions']}, setpoint jitter p99 {summary['setpoint_jitter_p99_ms']} ms")
    print(f"wrote {out / 'summary.json'} and {png}")
    return summary


def plot_flight(world: World, report: SimReport, retimed: list[dict[str, Any]],
                path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from rota.schema import result_from_dict

    fig, (top, spd) = plt.subplots(1, 2, figsize=(14, 6))
    for ob in world.obstacles:
        if hasattr(ob, "radius"):
            top.add_patch(plt.Circle((ob.x, ob.y), ob.radius, color="0.4"))
    home = report.home_enu
    for k, d in enumerate(retimed):
        res, _ = result_from_dict(d)
        t = np.linspace(0, res.duration, 400)
        p = res.sample(t).position + home
        top.plot(p[:, 0], p[:, 1], "--", lw=1, label=f"{d['id']} (re-timed)", color=f"C{k + 1}")
        for a, b in d.get("braking_zones", []):
            tau = np.linspace(a, b, 20)
            q = res.trajectory.position(tau) + home
            top.plot(q[:, 0], q[:, 1], color="C3", lw=4, alpha=0.5)
    air = report.true_position[:, 2] > 0.3
    top.plot(report.true_position[air, 0], report.true_position[air, 1], color="C0",
             label="flown (true position)")
    top.plot(*world.start[:2], "g^", ms=10, label="start")
    top.plot(*world.goal[:2], "r*", ms=12, label="goal")
    for c in report.collisions:
        top.plot(c["position"][0], c["position"][1], "kx", ms=12, mew=3, label="collision")
    top.set(aspect="equal", xlabel="x east (m)", ylabel="y north (m)",
            title="Top view (red: braking zones)")
    top.legend(fontsize=8)
    speed = np.linalg.norm(report.velocity, axis=1)
    spd.plot(report.time_s[air], speed[air])
    spd.set(xlabel="simulation time (s)", ylabel="true speed (m/s)", title="Speed")
    spd.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
