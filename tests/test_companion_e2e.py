"""End-to-end: the flight service over real Zenoh sessions and MAVSDK (UDP on
loopback) against the ``sitl`` vehicle in its own process (issue #6)."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np
import pytest

from companion.demo import (
    GroundStation,
    closest_approach,
    demo_config,
    fly_to_goal,
    free_tcp_port,
    running,
    take_off,
    to_local,
    trajectory_message,
)
from sitl.mavsdk_util import free_udp_port
from sitl.planner import plan
from sitl.process import SimProcess
from sitl.world import get_world

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(240)]
SPEED = 2.0


def run_flight(scenario, seed: int = 3, world_name: str = "forest", **overrides):
    """Start vehicle + service + ground station, run ``scenario(gs, service, sim,
    world)``, return its result and the vehicle's report."""
    world = get_world(world_name, seed=seed)
    mav, zport = free_udp_port(), free_tcp_port()
    with tempfile.TemporaryDirectory() as state:
        cfg = demo_config(mav, zport, SPEED, state, **overrides)

        async def main():
            async with running(cfg) as (service, gs):
                return await scenario(gs, service, sim, world)

        with SimProcess(port=mav, world=world_name, seed=seed) as sim:
            out = asyncio.run(main())
    return out, sim.report


async def start_flight(gs, sim, world, ident: str, progress: float = 0.0):
    """Take off, publish the planner's trajectory, start; wait for ``progress``."""
    home = sim.home_enu
    await take_off(gs, world, home)
    traj = plan(world, v_max=SPEED, a_max=2.0)
    gs.publish("trajectory", trajectory_message(to_local(traj, home), ident))
    assert (await gs.command("start"))["ok"]
    if progress:
        await gs.wait_for(lambda s: (s.get("progress") or 0) > progress, 30, "progress")
    return traj


def test_three_replans_reach_the_goal_without_collision_or_jumps():
    async def scenario(gs, service, sim, world):
        result = await fly_to_goal(gs, world, sim.home_enu, SPEED, 2.0, replans=3)
        return result, list(service.sent), list(gs.statuses)

    (result, sent, statuses), report = run_flight(scenario)
    assert not report.collisions
    t = np.array([s[0] for s in sent])
    p = np.array([s[1] for s in sent])
    step = np.linalg.norm(np.diff(p, axis=0), axis=1)
    dt = np.diff(t)
    # consecutive setpoints never jump: at most the speed limit times the period
    # (plus the takeover blend's own small velocity, at most 0.4 m/s)
    assert np.all(step <= (SPEED + 0.4) * dt + 1e-3), step.max()
    ids = {s.get("trajectory_id") for s in statuses} - {None}
    assert {"plan-0", "plan-1", "plan-2", "plan-3"} <= ids
    # offboard only after a pre-stream: the state sequence and the vehicle agree
    states = [s["state"] for s in statuses]
    assert "prestream" in states and states.index("prestream") < states.index("offboard")
    assert any("OFFBOARD" in e for _, e in report.events)


def test_malformed_trajectory_mid_flight_is_rejected_and_flight_continues():
    async def scenario(gs, service, sim, world):
        home = sim.home_enu
        traj = await start_flight(gs, sim, world, "good", 0.3)
        bad = trajectory_message(to_local(traj, home), "bad")
        bad["control_points"][4][1] = "NaN"
        gs.publish("trajectory", bad)
        bad2 = trajectory_message(to_local(traj, home), "far")
        bad2["control_points"] = (np.asarray(bad2["control_points"]) + [0, 0, 40]).tolist()
        gs.publish("trajectory", bad2)
        await asyncio.sleep(1.0)
        errors = [s["last_error"]["message"] for s in gs.statuses if s.get("last_error")]
        mid = gs.status
        await gs.wait_for(lambda s: s.get("command") == "hold", 40, "end of trajectory")
        return errors, mid

    (errors, mid), report = run_flight(scenario)
    assert any("control_points[4][1]" in e for e in errors), errors
    assert any("geofence" in e for e in errors), errors
    assert mid["trajectory_id"] == "good" and mid["command"] == "plan"
    assert not report.collisions


def test_planner_silence_ends_in_a_hold():
    async def scenario(gs, service, sim, world):
        await start_flight(gs, sim, world, "only")
        await gs.wait_for(lambda s: s.get("hold_reason") and "no trajectory" in
                          s["hold_reason"], 20, "the planner-silence hold")
        t_hold = time.monotonic()
        await gs.wait_for(lambda s: s.get("command") == "hold", 10, "the stop")
        await asyncio.sleep(1.0)
        state = sim.state()
        return gs.status, time.monotonic() - t_hold, state

    (status, _, state), report = run_flight(
        scenario, safety={"planner_timeout_s": 2.0})
    assert status["command"] == "hold" and status["state"] == "offboard"
    assert np.linalg.norm(state["velocity"]) < 0.5  # stopped, holding
    assert not report.collisions


def test_sigterm_mid_flight_hands_over_to_hold(tmp_path):
    """The service as systemd runs it (a process), killed with SIGTERM in flight."""
    world = get_world("forest", seed=4)
    mav, zport = free_udp_port(), free_tcp_port()
    cfg = demo_config(mav, zport, SPEED, str(tmp_path))
    cfg_file = tmp_path / "companion.toml"
    cfg_file.write_text(_toml(cfg))

    async def scenario(gs, sim):
        await start_flight(gs, sim, world, "t", 0.3)

    # systemd's notification socket, to see READY / WATCHDOG / STOPPING arrive
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(str(tmp_path / "notify"))
    notify.settimeout(0.2)
    notes: set[str] = set()
    done = threading.Event()

    def listen() -> None:  # like systemd: read the socket all the time
        while not done.is_set():
            with contextlib.suppress(TimeoutError):
                notes.update(notify.recv(4096).decode().split("\n"))

    listener = threading.Thread(target=listen, daemon=True)
    listener.start()
    env = dict(os.environ, NOTIFY_SOCKET=str(tmp_path / "notify"))
    with SimProcess(port=mav, world="forest", seed=4) as sim:
        proc = subprocess.Popen([sys.executable, "-m", "companion.cli", "run", "--config",
                                 str(cfg_file)], stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True, env=env)
        gs = GroundStation(cfg, f"tcp/127.0.0.1:{zport}")
        try:
            asyncio.run(scenario(gs, sim))
            proc.send_signal(signal.SIGTERM)
            out, _ = proc.communicate(timeout=20)
            time.sleep(0.5)
            state = sim.state()
        finally:
            gs.close()
            if proc.poll() is None:
                proc.kill()
    done.set()
    listener.join()
    notify.close()
    assert {"READY=1", "WATCHDOG=1", "STOPPING=1"} <= notes, notes
    assert any(n.startswith("STATUS=offboard") for n in notes)
    assert proc.returncode == 0, out
    assert "PX4 Hold" in out
    assert state["mode"] == "AUTO_LOITER" and state["armed"]
    assert not sim.report.collisions


def _toml(cfg) -> str:
    lines = []
    for section, values in cfg.to_dict().items():
        lines.append(f"[{section}]")
        for k, v in values.items():
            lines.append(f"{k} = {json.dumps(list(v) if isinstance(v, tuple) else v)}")
    return "\n".join(lines) + "\n"


def test_closest_approach_helper_measures_clearance():
    world = get_world("pillar", seed=0)
    from sitl.process import SimReport

    rep = SimReport(true_position=np.array([[0.0, 0.0, 1.0], *[list(world.start)]]))
    clearance = closest_approach(world, rep)
    expected = min(float(world.signed_distance(np.array([[0.0, 0.0, 1.0], world.start])).min())
                   - world.robot_radius, np.inf)
    assert clearance == pytest.approx(expected)


def test_link_loss_stops_the_stream_and_never_resumes_without_start():
    async def scenario(gs, service, sim, world):
        await start_flight(gs, sim, world, "t", 0.2)
        sim.block_link(True)
        await gs.wait_for(lambda s: s["state"] == "link_lost", 10, "link loss detected")
        lost = dict(gs.status)
        await asyncio.sleep(2.0)
        sim.block_link(False)
        await gs.wait_for(lambda s: s["state"] not in ("link_lost",), 15, "reconnection")
        await asyncio.sleep(2.0)
        after = dict(gs.status)
        return lost, after, service.streaming, sim.state()

    (lost, after, streaming, state), report = run_flight(scenario)
    assert "link lost" in lost["last_error"]["message"] and not lost["streaming"]
    assert not streaming and not after["streaming"] and after["trajectory_id"] is None
    assert after["command"] is None  # nothing resumed without a new start
    assert state["mode"] != "OFFBOARD"  # PX4 ran its offboard-loss failsafe
    assert not report.collisions


def test_auto_start_flies_without_commands_and_tracking_error_brakes():
    """With stream.auto_start the first trajectory arms, takes off and starts; an
    absurdly tight tracking threshold then makes the service brake to a hold."""

    async def scenario(gs, service, sim, world):
        home = sim.home_enu
        await gs.wait_for(lambda s: s["state"] == "ready", 40, "ready")
        traj = plan(world, v_max=SPEED, a_max=2.0)
        gs.publish("trajectory", trajectory_message(to_local(traj, home), "auto"))
        # the plan may last only a moment before the tight threshold brakes it
        await gs.wait_for(lambda s: s.get("hold_reason") and "tracking error" in
                          s["hold_reason"], 60, "auto start, then the tracking-error hold")
        return [s["state"] for s in gs.statuses]

    states, report = run_flight(scenario, stream={"auto_start": True},
                                safety={"max_tracking_error_m": 0.05})
    assert "prestream" in states and states.index("prestream") < states.index("offboard")
    assert not report.collisions
