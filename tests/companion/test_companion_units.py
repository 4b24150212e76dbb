"""The flight service's pieces that need no vehicle: configuration, frames,
message validation, plans and stitching."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from companion.flight.plan import Hold, Plan, blend_time, brake_along
from companion.flight.stitch import nearest_tau
from companion.frames import (
    enu_to_ned,
    heading_ned_deg,
    ned_to_enu,
    yaw_enu_to_ned_deg,
)
from companion.messages import Rejected, parse_map, parse_trajectory, trajectory_to_enu
from companion.settings.config import Config, ConfigError, from_dict, load
from rota import Limits, RetimeInput, retime
from rota.schema import TrajectoryMessage, trajectory_to_dict
from rota.voxelmap import VoxelMap
from tests.helpers.strategies import bspline, polynomial, sampled

CFG = from_dict({"safety": {"geofence_min": [-50.0, -50.0, -5.0]}})


def payload(traj, **kw) -> bytes:
    d = trajectory_to_dict(TrajectoryMessage(traj, id="t1", stamp=time.time()))
    d.update(kw)
    return json.dumps(d).encode()


# ------------------------------------------------------------------ config
def test_shipped_config_is_the_default():
    assert load("configs/companion.toml") == Config()


@pytest.mark.parametrize(("data", "words"), [
    ({"limits": {"v_max": -1.0}}, "[limits] v_max: must be positive"),
    ({"limits": {"v_maxx": 1.0}}, "[limits] v_maxx: unknown setting"),
    ({"limit": {}}, "[limit]: unknown section"),
    ({"limits": {"a_max": [1.0, 2.0]}}, "[limits] a_max: must be 3 numbers"),
    ({"stream": {"rate_hz": 1.0}}, "[stream] rate_hz: PX4 needs"),
    ({"stream": {"prestream_s": 0.1}}, "[stream] prestream_s"),
    ({"stream": {"yaw": "north"}}, "[stream] yaw"),
    ({"stream": {"auto_start": "yes"}}, "[stream] auto_start: must be true or false"),
    ({"safety": {"input_frame": "NWU"}}, "[safety] input_frame"),
    ({"safety": {"geofence_min": [0, 0, 20]}}, "[safety] geofence_min"),
    ({"service": {"vehicle_id": "a/b"}}, "[service] vehicle_id"),
    ({"uncertainty": {"delta": 2.0}}, "[uncertainty] delta"),
    ({"uncertainty": {"m": -0.1}}, "[uncertainty] m"),
    ({"zenoh": {"mode": "mesh"}}, "[zenoh] mode"),
])
def test_config_errors_name_the_setting(data, words):
    with pytest.raises(ConfigError) as err:
        from_dict(data)
    assert words in str(err.value)


def test_config_file_errors(tmp_path):
    bad = tmp_path / "c.toml"
    bad.write_text("[limits\nv_max = 1")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load(bad)
    with pytest.raises(ConfigError, match="cannot read"):
        load(tmp_path / "missing.toml")


# ------------------------------------------------------------------ frames
def test_enu_ned_conversion():
    v = np.array([[1.0, 2.0, 3.0]])
    assert np.allclose(enu_to_ned(v), [[2.0, 1.0, -3.0]])
    assert np.allclose(ned_to_enu(enu_to_ned(v)), v)
    assert yaw_enu_to_ned_deg(0.0) == pytest.approx(90.0)  # facing east
    assert yaw_enu_to_ned_deg(np.pi / 2) == pytest.approx(0.0)  # facing north
    assert heading_ned_deg([0.0, 1.0, 0.0]) == pytest.approx(0.0)  # north
    assert heading_ned_deg([1.0, 0.0, 0.0]) == pytest.approx(90.0)  # east


def _joined(base):
    from rota.trajectory import Window

    t0, t1 = base.domain
    return Window(base=base, start=t0 + 0.2 * (t1 - t0), offset=[0.3, -0.2, 0.5],
                  blend=0.3 * (t1 - t0))


@pytest.mark.parametrize("traj", [bspline(1, 5, 1.0), polynomial(1, 5, 1.0),
                                  sampled(1, 5, 1.0, True), _joined(bspline(2, 6, 1.0))])
def test_trajectory_frame_conversion(traj):
    ned = trajectory_to_enu(traj, "NED")  # the same numbers read as NED
    tau = np.linspace(*traj.domain, 30)
    for a, b in zip(traj.evaluate(tau), ned.evaluate(tau), strict=True):
        assert np.allclose(ned_to_enu(a), b)


# ---------------------------------------------------------------- messages
def test_valid_trajectory_is_accepted_in_enu():
    traj = bspline(2, 6, 1.0)
    inc = parse_trajectory(payload(traj), CFG)
    assert inc.id == "t1" and inc.frame == "ENU"
    # NED input arrives converted
    inc = parse_trajectory(payload(traj, frame="NED"), CFG)
    assert np.allclose(inc.trajectory.position(1.0), ned_to_enu(traj.position(1.0)))


def test_unstamped_trajectories_need_a_planner_without_a_clock():
    d = trajectory_to_dict(TrajectoryMessage(bspline(2, 6, 1.0), id="t"))
    with pytest.raises(Rejected, match="no stamp"):
        parse_trajectory(json.dumps(d).encode(), CFG)
    cfg = from_dict({"safety": {"require_stamp": False, "geofence_min": [-50.0, -50.0, -5.0]}})
    assert parse_trajectory(json.dumps(d).encode(), cfg).stamp is None


def test_missing_frame_uses_the_configured_input_frame():
    d = trajectory_to_dict(TrajectoryMessage(bspline(2, 6, 1.0), stamp=time.time()))
    del d["frame"]
    cfg = from_dict({"safety": {"input_frame": "NED", "geofence_min": [-50.0, -50.0, -5.0]}})
    assert parse_trajectory(json.dumps(d).encode(), cfg).frame == "NED"


@pytest.mark.parametrize(("make", "words"), [
    (lambda t: b"{not json", "not valid JSON"),
    (lambda t: payload(t, schema="rota/map"), "schema"),
    (lambda t: payload(t, stamp=time.time() - 10), "stale"),
    (lambda t: payload(t, stamp=time.time() + 10), "future"),
    (lambda t: payload(t, control_points=(t.control_points + [60, 0, 0]).tolist()), "geofence"),
    (lambda t: payload(t, knot_span=0.001), "planned speed"),
    (lambda t: payload(t, control_points=[[0, 0, float("nan")]] * 6), "control_points"),
])
def test_bad_trajectories_are_rejected_with_reason(make, words):
    traj = bspline(2, 6, 1.0)
    with pytest.raises(Rejected) as err:
        parse_trajectory(make(traj), CFG)
    assert words in str(err.value)


def test_map_message():
    vmap = VoxelMap.from_points(np.array([[1.0, 1.0, 1.0]]), 0.1)
    got = parse_map(json.dumps(vmap.to_dict() | {"stamp": time.time()}).encode(), CFG)
    assert len(got) == 1
    with pytest.raises(Rejected, match="stale"):
        parse_map(json.dumps(vmap.to_dict() | {"stamp": 1.0}).encode(), CFG)
    with pytest.raises(Rejected, match="resolution"):
        parse_map(json.dumps(vmap.to_dict() | {"resolution": -1}).encode(), CFG)


# ------------------------------------------------------------------- plans
def _plan(t0=10.0):
    traj = bspline(4, 7, 1.0)
    return Plan("p", retime(RetimeInput(trajectory=traj, limits=Limits(2.0, 2.0))), t0)


def test_plan_follows_the_result_and_holds_the_end():
    plan = _plan()
    r = plan.result
    mid = plan.command(10.0 + r.duration / 2)
    assert np.allclose(mid.position, r.sample(r.duration / 2).position[0])
    end = plan.command(10.0 + r.duration + 5)
    assert np.allclose(end.velocity, 0) and plan.finished(10.0 + r.duration + 5)


def test_takeover_offset_blends_out_without_jumps():
    plan = _plan()
    gap = np.array([0.3, -0.2, 0.1])
    blended = Plan(plan.id, plan.result, plan.t0, offset=gap,
                   blend_s=blend_time(float(np.linalg.norm(gap))))
    t = 10.0 + np.arange(0, 4.0, 0.02)
    p = np.array([blended.command(x).position for x in t])
    a = np.array([blended.command(x).acceleration for x in t])
    a0 = np.array([plan.command(x).acceleration for x in t])
    assert np.allclose(p[0] - plan.command(10.0).position, gap)
    assert np.allclose(p[-1], plan.command(t[-1]).position)
    assert np.abs(a - a0).max() <= 0.5 + 1e-6  # the blend's acceleration budget
    assert np.linalg.norm(np.diff(p, axis=0), axis=1).max() <= 2.0 * 0.02 + 1e-6 + 0.5 * 0.02


def test_a_late_takeover_starts_from_the_full_gap():
    """Regression: the blend faded from the plan's t0, so a takeover on a tick well
    after t0 (a busy machine, a start from a hold) began with the gap partly faded:
    the stream refused a 0.11 m step in 22 ms and braked. Faded from the takeover,
    the first setpoint is the last one commanded."""
    from dataclasses import replace

    plan = _plan()
    gap = np.array([0.3, -0.2, 0.1])
    late = plan.t0 + 0.8  # (the blend takes 2.1 s here)
    old = plan.command(late).position + gap  # what was commanded at the takeover
    blend = blend_time(float(np.linalg.norm(gap)))
    then = replace(plan, offset=gap, blend_s=blend)  # faded from t0, as before
    now = replace(plan, offset=gap, blend_s=blend, blend_t0=late)
    assert np.linalg.norm(then.command(late).position - old) > 0.05
    assert np.allclose(now.command(late).position, old)
    t = late + np.arange(0, 3.0, 0.02)
    p = np.array([now.command(x).position for x in t])
    assert np.linalg.norm(np.diff(p, axis=0), axis=1).max() <= 2.0 * 0.02 + 0.5 * 0.02
    assert np.allclose(p[-1], plan.command(t[-1]).position)


def test_brake_along_the_path_stops_within_the_braking_distance():
    plan = _plan()
    now = 10.0 + plan.result.duration / 2
    v0 = float(np.linalg.norm(plan.command(now).velocity))
    brake = brake_along(plan, now, decel=1.0)
    assert np.allclose(brake.command(now).position, plan.command(now).position)
    t = np.linspace(now, now + v0 + 1, 200)
    speeds = [np.linalg.norm(brake.command(x).velocity) for x in t]
    assert np.all(np.diff(speeds) <= 1e-9) and speeds[-1] == 0.0
    travelled = np.linalg.norm(brake.command(t[-1]).position - brake.command(now).position)
    assert travelled <= v0 * v0 / 2 + 1e-6
    assert Hold(np.zeros(3)).finished(0.0)


def test_nearest_tau_joins_the_first_pass():
    """A path that comes back past the vehicle is joined at its first pass."""
    t = np.linspace(0, 10, 11)
    x = np.array([0, 1, 2, 3, 4, 5, 4, 3, 2, 1, 0.0])
    from rota import SampledTrajectory

    traj = SampledTrajectory(t=t, p=np.column_stack([x, 0.05 * t, 0 * t]))
    tau = nearest_tau(traj, np.array([1.0, 0.0, 0.0]), tolerance=0.5)
    assert tau == pytest.approx(1.0, abs=0.05)


def test_a_joined_replan_starts_at_the_command_and_keeps_the_speed_limit():
    """A replan that passes 0.6 m beside the commanded position of a vehicle
    cruising at v_max: the joined path starts exactly at the command, so nothing is
    left for the stream to blend in, and its re-time holds v_max and a_max for the
    path as flown (a blend added on top of a plan at v_max would exceed it)."""
    from companion.flight.stitch import join
    from rota import BSplineTrajectory

    x = np.arange(-2.0, 60.0) * 0.2  # a straight line along x, 2 m/s as planned
    traj = BSplineTrajectory(control_points=np.column_stack([x, 0 * x, 0 * x + 2]),
                             knot_span=0.1)
    here, v = np.array([3.0, 0.6, 2.0]), np.array([2.0, 0.0, 0.0])
    joined, v0 = join(traj, here, v, tolerance=1.0, v_max=2.0)
    np.testing.assert_allclose(joined.position(joined.domain[0])[0], here, atol=1e-12)
    limits = Limits(v_max=2.0, a_max=np.array([2.0, 2.0, 1.5]))
    result = retime(RetimeInput(trajectory=joined, limits=limits, dtau=0.05,
                                start_velocity=v0))
    assert result.status == "optimal", result.message
    plan = Plan("p", result, t0=0.0)
    t = np.arange(0.0, result.duration, 0.002)
    cmds = [plan.command(x) for x in t]
    np.testing.assert_allclose(cmds[0].position, here, atol=1e-9)
    speed = np.linalg.norm([c.velocity for c in cmds], axis=1)
    acc = np.abs([c.acceleration for c in cmds]).max(axis=0)
    assert speed.max() <= 2.0 * 1.001, speed.max()
    assert np.all(acc <= np.array(limits.a_max) * 1.01), acc
    lateral = np.array([c.position[1] for c in cmds])
    assert lateral[0] == pytest.approx(0.6) and abs(lateral[-1]) < 1e-9  # back on the path


def test_sd_notify_never_blocks_when_nobody_reads(tmp_path, monkeypatch):
    """A full notification socket (a hung systemd) must not stall the service."""
    import socket
    import time as _time

    from companion.supervisor import Notifier

    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(tmp_path / "n"))  # bound, never read
    monkeypatch.setenv("NOTIFY_SOCKET", str(tmp_path / "n"))
    notifier = Notifier()
    start = _time.monotonic()
    for _ in range(5000):
        notifier.notify("STATUS=x" * 50)
    assert _time.monotonic() - start < 2.0
    sock.close()


def test_status_and_telemetry_follow_a_setpoint():
    """The publisher waits for the stream's beat and publishes right after it (its
    work then falls in the stream's idle time); without beats it still publishes."""
    import asyncio

    from companion.status import Publisher

    log: list[str] = []

    class Pub:
        def __init__(self, name: str) -> None:
            self.name = name

        def put(self, payload: bytes) -> None:
            log.append(self.name)

    pubs = {name: Pub(name) for name in ("status", "telemetry")}
    publisher = Publisher(pubs, lambda: {"s": 1}, lambda: {"t": 1})

    async def beats(beat: asyncio.Event) -> None:
        while True:
            await asyncio.sleep(0.002)
            log.append("beat")
            beat.set()

    async def run(with_beats: bool) -> None:
        beat = asyncio.Event()
        tasks = [asyncio.create_task(publisher.run(20.0, 5.0, beat))]
        if with_beats:
            tasks.append(asyncio.create_task(beats(beat)))
        while log.count("telemetry") < 8:
            await asyncio.sleep(0.01)
        for t in tasks:
            t.cancel()

    asyncio.run(run(True))
    first = [i for i, what in enumerate(log) if what == "telemetry"]
    assert all(log[i - 1] == "beat" for i in first), log  # right after a setpoint
    assert log.count("status") >= 1
    log.clear()
    asyncio.run(run(False))  # a stream being restarted: status goes on
    assert log.count("telemetry") >= 8 and "beat" not in log


def test_the_publisher_stops_when_cancelled_as_a_beat_arrives():
    """Regression: with asyncio.wait_for (Python 3.11) a cancellation that came with
    the beat was swallowed; the publisher went on and the service could not stop
    (SIGTERM, 30 s, on a busy machine)."""
    import asyncio

    from companion.status import Publisher

    class Pub:
        def put(self, payload: bytes) -> None:
            pass

    publisher = Publisher({"status": Pub(), "telemetry": Pub()}, dict, dict)

    async def run() -> None:
        beat = asyncio.Event()
        task = asyncio.create_task(publisher.run(10.0, 5.0, beat))
        await asyncio.sleep(0.15)  # past its due time: waiting for the beat
        beat.set()
        await asyncio.sleep(0)  # the beat's waiter is done ...
        task.cancel()  # ... as the cancellation comes
        done, _ = await asyncio.wait({task}, timeout=1.0)
        assert task in done and task.cancelled()

    asyncio.run(run())
