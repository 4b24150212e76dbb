"""Tests of the simulated PX4 vehicle.

Fast tests run on the simulated clock without networking. Tests marked ``e2e`` talk MAVLink 2
over UDP loopback: through unmodified MAVSDK 4.x (``mavsdk.asyncio``) and a raw pymavlink
client. Every networked test uses its own free ports, so tests may run in parallel.
"""

from __future__ import annotations

import asyncio
import math
import socket
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from sitl.dynamics import Setpoint
from sitl.estimation import EstimationErrorParams
from sitl.mavsdk_util import connect, free_udp_port, send_command_long, wait_health_ok, wait_until
from sitl.vehicle import Px4Mode, SimVehicle, VehicleParams, enu_to_ned, ned_to_enu

ACCEPTED = mavlink2.MAV_RESULT_ACCEPTED
TEMP_REJECTED = mavlink2.MAV_RESULT_TEMPORARILY_REJECTED
NAN3 = np.full(3, np.nan)


def _hovering(params: VehicleParams | None = None, **kw) -> SimVehicle:
    """A vehicle (simulated clock) hovering in Hold at 5 m above home."""
    sim = SimVehicle(params or VehicleParams(), **kw)
    assert sim.arm() == ACCEPTED
    assert sim.takeoff(5.0) == ACCEPTED
    sim.run_for(6.0)
    assert sim.mode is Px4Mode.AUTO_LOITER
    assert sim.true_state().position_ned[2] == pytest.approx(-5.0, abs=0.3)
    return sim


def _velocity_sp(v_ned: tuple[float, float, float], alt: float = 5.0):
    """Setpoint function: constant horizontal velocity at a fixed altitude."""
    return lambda t: Setpoint(
        np.array([np.nan, np.nan, -alt]), np.array([v_ned[0], v_ned[1], np.nan]), NAN3.copy()
    )


# ------------------------------------------------------------------ simulated clock


def test_px4_custom_mode_encoding():
    assert Px4Mode.OFFBOARD.custom_mode == 6 << 16
    assert Px4Mode.POSCTL.custom_mode == 3 << 16
    assert Px4Mode.AUTO_LAND.custom_mode == (6 << 24) | (4 << 16)
    assert Px4Mode.AUTO_LOITER.custom_mode == (3 << 24) | (4 << 16)
    assert Px4Mode.AUTO_TAKEOFF.custom_mode == (2 << 24) | (4 << 16)
    assert Px4Mode.AUTO_RTL.custom_mode == (5 << 24) | (4 << 16)
    for mode in Px4Mode:
        assert Px4Mode.from_custom_mode(mode.custom_mode) is mode


def test_frame_conversions():
    p_ned = np.array([[1.0, 2.0, -3.0]])
    assert ned_to_enu(p_ned) == pytest.approx(np.array([[2.0, 1.0, 3.0]]))
    assert enu_to_ned(ned_to_enu(p_ned)) == pytest.approx(p_ned)


def test_offboard_refused_without_stream_and_accepted_after_window():
    sim = _hovering()
    assert sim.set_mode(Px4Mode.OFFBOARD) == TEMP_REJECTED  # no setpoint at all
    hold = sim.estimated_state().position_ned
    sp = lambda t: Setpoint.hold(hold)  # noqa: E731
    sim.run_for(0.5, sp, setpoint_rate_hz=20.0)
    assert sim.set_mode(Px4Mode.OFFBOARD) == TEMP_REJECTED  # stream shorter than 1 s
    assert sim.mode is Px4Mode.AUTO_LOITER
    sim.run_for(0.6, sp, setpoint_rate_hz=20.0)
    assert sim.set_mode(Px4Mode.OFFBOARD) == ACCEPTED
    assert sim.mode is Px4Mode.OFFBOARD


def test_offboard_refused_when_stream_too_slow():
    sim = _hovering()
    hold = sim.estimated_state().position_ned
    sim.run_for(3.0, lambda t: Setpoint.hold(hold), setpoint_rate_hz=1.5)  # PX4 needs > 2 Hz
    assert sim.set_mode(Px4Mode.OFFBOARD) == TEMP_REJECTED


def test_offboard_window_is_a_parameter():
    sim = _hovering(VehicleParams(offboard_min_stream_s=0.0))
    sim.set_position_target(Setpoint.hold(sim.estimated_state().position_ned))
    assert sim.set_mode(Px4Mode.OFFBOARD) == ACCEPTED


def test_arming_in_offboard_requires_stream():
    sim = SimVehicle(VehicleParams(offboard_min_stream_s=0.0))
    sim.set_position_target(Setpoint.hold(np.zeros(3)))
    assert sim.set_mode(Px4Mode.OFFBOARD) == ACCEPTED
    sim.run_for(2.0)  # stream stops
    assert sim.arm() == TEMP_REJECTED
    assert not sim.armed


def test_offboard_loss_failsafe_hold_land_disarm_timing():
    params = VehicleParams(com_of_loss_t_s=0.7, failsafe_hold_s=2.0, disarm_land_s=1.0)
    sim = _hovering(params)
    hold = sim.estimated_state().position_ned
    sim.run_for(1.2, lambda t: Setpoint.hold(hold))
    assert sim.set_mode(Px4Mode.OFFBOARD) == ACCEPTED
    sim.run_for(2.0, lambda t: Setpoint.hold(hold + [3.0, 0.0, 0.0]))
    t_last = sim.last_setpoint_time_s
    assert t_last is not None
    sim.run_for(0.65)
    assert sim.mode is Px4Mode.OFFBOARD  # still within COM_OF_LOSS_T
    sim.run_for(0.1)
    assert sim.mode is Px4Mode.AUTO_LOITER and sim.failsafe_active
    t_fs = [t for t, text in sim.events if text.startswith("Failsafe activated")][-1]
    assert 0.7 <= t_fs - t_last <= 0.7 + 2 * params.physics_dt_s
    p_fs = sim.true_state().position_ned
    sim.run_for(1.8)  # hold: stays put
    assert sim.mode is Px4Mode.AUTO_LOITER
    assert np.linalg.norm(sim.true_state().position_ned - p_fs) < 1.0
    sim.run_for(0.3)
    assert sim.mode is Px4Mode.AUTO_LAND
    t_land = [t for t, text in sim.events if text.startswith("Failsafe action: Land")][-1]
    assert t_land - t_fs == pytest.approx(2.0, abs=2 * params.physics_dt_s)
    sim.run_for(12.0)
    assert not sim.armed
    assert sim.landed_state == mavlink2.MAV_LANDED_STATE_ON_GROUND
    t_touch = [t for t, text in sim.events if text == "Landing detected"][-1]
    t_disarm = [t for t, text in sim.events if text == "Disarmed by landing"][-1]
    assert t_disarm - t_touch == pytest.approx(1.0, abs=2 * params.physics_dt_s)
    # Land mode descends at MPC_LAND_SPEED = 0.7 m/s from 5 m: about 7 s.
    assert 6.0 < t_touch - t_land < 9.0


def test_type_mask_velocity_only_and_yaw_via_mavlink_messages():
    sim = _hovering(VehicleParams(offboard_min_stream_s=0.0))
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=195)
    ignore_pos_acc_yaw = 1 | 2 | 4 | 64 | 128 | 256 | 1024 | 2048
    vel_msg = mav.set_position_target_local_ned_encode(
        0, 1, 1, mavlink2.MAV_FRAME_LOCAL_NED, ignore_pos_acc_yaw,
        99.0, 99.0, 99.0, 2.0, 0.0, 0.0, 9.0, 9.0, 9.0, 0.0, 0.0,
    )  # fmt: skip
    sim.inject_message(vel_msg)
    assert sim.set_mode(Px4Mode.OFFBOARD) == ACCEPTED
    for _ in range(60):  # 3 s at 20 Hz
        sim.inject_message(vel_msg)
        sim.step(0.05)
    st = sim.true_state()
    assert st.velocity_ned == pytest.approx([2.0, 0.0, 0.0], abs=0.2)  # positions ignored
    # Position + yaw (velocity/acceleration and yaw rate ignored).
    pos_msg = mav.set_position_target_local_ned_encode(
        0, 1, 1, mavlink2.MAV_FRAME_LOCAL_NED, 8 | 16 | 32 | 64 | 128 | 256 | 2048,
        10.0, 4.0, -3.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, math.pi / 2, 0.0,
    )  # fmt: skip
    for _ in range(200):  # 10 s
        sim.inject_message(pos_msg)
        sim.step(0.05)
    est = sim.estimated_state()
    assert est.position_ned == pytest.approx([10.0, 4.0, -3.0], abs=0.3)
    assert est.yaw_rad == pytest.approx(math.pi / 2, abs=0.05)
    # Unsupported frame and other targets are ignored (no proof of life).
    n = sim.setpoints_received
    sim.inject_message(
        mav.set_position_target_local_ned_encode(
            0, 1, 1, mavlink2.MAV_FRAME_GLOBAL, 0, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0, 0
        )
    )
    sim.inject_message(
        mav.set_position_target_local_ned_encode(
            0, 7, 1, mavlink2.MAV_FRAME_LOCAL_NED, 0, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0, 0
        )
    )
    assert sim.setpoints_received == n


def test_takeoff_hold_land_and_auto_disarm_python_api():
    sim = SimVehicle(VehicleParams(disarm_land_s=2.0))
    assert sim.takeoff() == TEMP_REJECTED  # not armed
    assert sim.arm() == ACCEPTED
    assert sim.takeoff() == ACCEPTED  # MIS_TAKEOFF_ALT = 2.5 m
    assert sim.landed_state == mavlink2.MAV_LANDED_STATE_ON_GROUND
    sim.run_for(0.5)
    assert sim.landed_state == mavlink2.MAV_LANDED_STATE_TAKEOFF
    sim.run_for(4.0)
    assert sim.mode is Px4Mode.AUTO_LOITER
    assert sim.landed_state == mavlink2.MAV_LANDED_STATE_IN_AIR
    assert -sim.true_state().position_ned[2] == pytest.approx(2.5, abs=0.25)
    assert sim.disarm() == TEMP_REJECTED  # in the air
    assert sim.land() == ACCEPTED
    sim.run_for(1.0)
    assert sim.landed_state == mavlink2.MAV_LANDED_STATE_LANDING
    sim.run_for(6.0)
    assert sim.true_state().position_ned[2] == pytest.approx(0.0, abs=1e-6)
    assert not sim.armed


def test_return_to_launch_flies_home_and_lands():
    sim = _hovering(VehicleParams(offboard_min_stream_s=0.0, disarm_land_s=1.0))
    target = np.array([12.0, -6.0, -5.0])
    sim.set_position_target(Setpoint.hold(target))
    assert sim.set_mode(Px4Mode.OFFBOARD) == ACCEPTED
    sim.run_for(8.0, lambda t: Setpoint.hold(target))
    assert sim.estimated_state().position_ned == pytest.approx(target, abs=0.3)
    assert sim.handle_command(mavlink2.MAV_CMD_NAV_RETURN_TO_LAUNCH, []) == ACCEPTED
    sim.run_for(8.0)
    st = sim.true_state()
    assert np.hypot(*st.position_ned[:2]) < 0.6
    assert sim.mode is Px4Mode.AUTO_LAND
    sim.run_for(10.0)
    assert not sim.armed and sim.true_state().position_ned[2] == pytest.approx(0.0, abs=1e-6)


def test_auto_disarm_without_takeoff():
    sim = SimVehicle(VehicleParams(disarm_preflight_s=10.0))
    assert sim.arm() == ACCEPTED
    sim.run_for(9.9)
    assert sim.armed
    sim.run_for(0.2)
    assert not sim.armed


class _WallNorth:
    """Stub world: everything north of ENU y = ``y_wall`` is an obstacle."""

    robot_radius = 0.3

    def __init__(self, y_wall: float) -> None:
        self.y_wall = y_wall
        self.calls = 0

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        self.calls += 1
        assert points.ndim == 2 and points.shape[1] == 3
        return self.y_wall - points[:, 1]


def test_collision_with_world_ends_flight():
    world = _WallNorth(8.0)
    sim = _hovering(VehicleParams(offboard_min_stream_s=0.0), world=world, seed=1)
    sp = _velocity_sp((3.0, 0.0, 0.0))  # NED north = ENU +y, into the wall
    sim.set_position_target(sp(0.0))
    assert sim.set_mode(Px4Mode.OFFBOARD) == ACCEPTED
    sim.run_for(6.0, sp)
    assert len(sim.collisions) == 1
    col = sim.collisions[0]
    # First true position (not the estimate) within the robot radius of the wall: at most one
    # physics step (3 m/s * 4 ms) beyond the contact point.
    assert 8.0 - 0.3 < col.position_enu[1] <= 8.0 - 0.3 + 0.02
    assert col.signed_distance_m < 0.3
    assert col.position_ned[0] == pytest.approx(col.position_enu[1])
    assert col.position_enu[2] == pytest.approx(5.0, abs=0.5)
    assert sim.crashed and not sim.armed
    frozen = sim.true_state().position_ned
    sim.run_for(1.0)
    assert np.array_equal(sim.true_state().position_ned, frozen)
    assert sim.arm() == TEMP_REJECTED


def test_no_collision_flying_parallel_and_home_offset():
    world = _WallNorth(8.0)
    sim = _hovering(VehicleParams(offboard_min_stream_s=0.0), world=world)
    sp = _velocity_sp((0.0, 3.0, 0.0))  # NED east = ENU +x, parallel to the wall
    sim.set_position_target(sp(0.0))
    assert sim.set_mode(Px4Mode.OFFBOARD) == ACCEPTED
    sim.run_for(5.0, sp)
    assert sim.collisions == [] and world.calls > 0
    assert sim.true_state().position_enu[0] > 10.0
    # Home 6 m north in the world: the wall is only 2 m away.
    world2 = _WallNorth(8.0)
    params = VehicleParams(offboard_min_stream_s=0.0, home_enu_m=(0.0, 6.0, 0.0))
    sim2 = _hovering(params, world=world2)
    sp2 = _velocity_sp((1.0, 0.0, 0.0))
    sim2.set_position_target(sp2(0.0))
    assert sim2.set_mode(Px4Mode.OFFBOARD) == ACCEPTED
    sim2.run_for(4.0, sp2)
    assert len(sim2.collisions) == 1
    assert sim2.collisions[0].position_ned[0] == pytest.approx(1.7, abs=0.3)


def test_estimation_error_statistics_match_model():
    """Long simulated flights at 2, 4, 6 m/s: std(estimate - truth) = m*|v| + b within 10 %.

    |v| is the 3-D speed of the true velocity. The std pooled over the three axes is checked at
    10 %, each axis at 20 % (sampling error: with 100 s at tau = 0.25 s, 12 other seeds stayed
    within 5 % pooled and 14 % per axis).
    """
    est = EstimationErrorParams(slope_s=0.2, offset_m=-0.1, correlation_time_s=0.25)
    params = VehicleParams(physics_dt_s=0.01, offboard_min_stream_s=0.0)
    for seed, speed in enumerate((2.0, 4.0, 6.0)):
        sim = _hovering(
            params, estimation=est, seed=10 + seed, record_history=True, history_decimation=5
        )
        sp = _velocity_sp((speed, 0.0, 0.0))
        sim.set_position_target(sp(0.0))
        assert sim.set_mode(Px4Mode.OFFBOARD) == ACCEPTED
        sim.run_for(5.0, sp)  # accelerate
        n0 = len(sim.history.time_s)
        sim.run_for(100.0, sp)
        h = sim.history.arrays()
        err = h["estimated_position_ned"][n0:] - h["true_position_ned"][n0:]
        speeds = np.linalg.norm(h["velocity_ned"][n0:], axis=1)
        assert speeds.mean() == pytest.approx(speed, rel=0.03)
        expected = 0.2 * speeds.mean() - 0.1
        assert np.sqrt(np.mean(err**2)) == pytest.approx(expected, rel=0.10)
        assert err.std(axis=0) == pytest.approx(np.full(3, expected), rel=0.20)
        assert h["error_std_m"][n0:].mean() == pytest.approx(expected, rel=0.02)
        assert np.abs(err.mean(axis=0)).max() < 0.35 * expected  # zero mean (3.5 sigma)


def test_hover_error_is_at_floor_and_state_readout():
    sim = _hovering(seed=2)
    sim.run_for(2.0)
    err = sim.estimated_state().position_ned - sim.true_state().position_ned
    assert err == pytest.approx(sim.estimation_error())
    assert sim.estimation_std() == pytest.approx(np.full(3, 0.02), abs=0.01)  # floor
    assert np.abs(err).max() < 0.1


def test_same_seed_is_deterministic():
    def run(seed: int) -> np.ndarray:
        sim = _hovering(VehicleParams(offboard_min_stream_s=0.0), seed=seed)
        sp = _velocity_sp((4.0, 1.0, 0.0))
        sim.set_position_target(sp(0.0))
        sim.set_mode(Px4Mode.OFFBOARD)
        sim.run_for(5.0, sp)
        return np.concatenate((sim.true_state().position_ned, sim.estimation_error()))

    assert np.array_equal(run(3), run(3))
    assert not np.allclose(run(3), run(4))


def test_cli_runs_briefly():
    from sitl.cli import main

    assert main(["--world", "none", "--seed", "3", "--duration", "0.3",
                 "--port", str(free_udp_port())]) == 0  # fmt: skip


# ------------------------------------------------------------------ MAVLink over UDP


def _raw_client(sim_port: int) -> tuple[socket.socket, object]:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", sim_port))
    sock.settimeout(0.2)
    return sock, mavlink2.MAVLink(None, srcSystem=42, srcComponent=191)


def _recv_until(sock: socket.socket, mav, predicate, timeout: float = 3.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            data, _ = sock.recvfrom(65535)
        except TimeoutError:
            continue
        for msg in mav.parse_buffer(data) or []:
            if predicate(msg):
                return msg
    return None


@pytest.mark.e2e
def test_e2e_raw_mavlink_heartbeat_acks_and_requests():
    port = free_udp_port()
    sock, mav = _raw_client(port)
    with sock, SimVehicle(port=port) as sim:
        hb = _recv_until(sock, mav, lambda m: m.get_type() == "HEARTBEAT")
        assert hb is not None
        assert hb.autopilot == mavlink2.MAV_AUTOPILOT_PX4
        assert hb.type == mavlink2.MAV_TYPE_QUADROTOR
        assert hb.base_mode & mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        assert not hb.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
        assert Px4Mode.from_custom_mode(hb.custom_mode) is Px4Mode.AUTO_LOITER
        addr = ("127.0.0.1", sim.local_port)

        def command(cmd: int, *params: float):
            p = list(params) + [0.0] * (7 - len(params))
            sock.sendto(mav.command_long_encode(1, 1, cmd, 0, *p).pack(mav), addr)
            return _recv_until(
                sock, mav, lambda m: m.get_type() == "COMMAND_ACK" and m.command == cmd
            )

        ack = command(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
        assert ack.result == ACCEPTED
        assert (ack.target_system, ack.target_component) == (42, 191)
        hb = _recv_until(
            sock, mav, lambda m: m.get_type() == "HEARTBEAT" and m.base_mode & 128, 2.0
        )
        assert hb is not None  # armed flag shows up in the heartbeat
        assert command(mavlink2.MAV_CMD_DO_SET_MODE, 1, 6, 0).result == TEMP_REJECTED
        assert command(mavlink2.MAV_CMD_DO_SET_MODE, 1, 3, 0).result == TEMP_REJECTED  # no RC
        assert command(mavlink2.MAV_CMD_DO_SET_MODE, 1, 4, 6).result == ACCEPTED  # AUTO.LAND
        land_mode = Px4Mode.AUTO_LAND.custom_mode
        hb = _recv_until(
            sock, mav, lambda m: m.get_type() == "HEARTBEAT" and m.custom_mode == land_mode
        )
        assert hb is not None
        assert command(mavlink2.MAV_CMD_DO_FENCE_ENABLE, 1).result == (
            mavlink2.MAV_RESULT_UNSUPPORTED
        )
        ack = command(mavlink2.MAV_CMD_REQUEST_MESSAGE, mavlink2.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
        assert ack.result == ACCEPTED
        ver = _recv_until(sock, mav, lambda m: m.get_type() == "AUTOPILOT_VERSION")
        assert ver is not None and ver.flight_sw_version >> 24 == 1
        odo = _recv_until(sock, mav, lambda m: m.get_type() == "ODOMETRY")
        assert odo is not None and odo.pose_covariance[0] == pytest.approx(0.02**2, rel=0.01)
        # Other targets are ignored: no ACK.
        sock.sendto(mav.command_long_encode(9, 1, 400, 0, 0, 0, 0, 0, 0, 0, 0).pack(mav), addr)
        assert _recv_until(sock, mav, lambda m: m.get_type() == "COMMAND_ACK", 0.5) is None


def _min_jerk(t: float, duration: float, dist: float) -> tuple[float, float, float]:
    s = min(max(t / duration, 0.0), 1.0)
    p = dist * (10 * s**3 - 15 * s**4 + 6 * s**5)
    v = dist / duration * (30 * s**2 - 60 * s**3 + 30 * s**4)
    a = dist / duration**2 * (60 * s - 180 * s**2 + 120 * s**3)
    return p, v, a


@pytest.mark.e2e
def test_e2e_mavsdk_connect_health_arm_takeoff_land_disarm():
    from mavsdk.asyncio import Autopilot
    from mavsdk.asyncio.plugins.telemetry import FlightMode, LandedState

    port = free_udp_port()

    async def scenario(sim: SimVehicle) -> None:
        async with connect(port) as link:
            assert await link.system.autopilot_type() == Autopilot.PX4
            assert await wait_health_ok(link, 5.0)
            health = await link.telemetry.health()
            assert health.is_armable and health.is_home_position_ok
            assert health.is_local_position_ok and health.is_global_position_ok
            assert await link.telemetry.flight_mode() == FlightMode.HOLD
            home = await link.telemetry.home()
            assert home.latitude_deg == pytest.approx(sim.params.home_lat_deg, abs=1e-6)
            await link.action.arm()
            assert await wait_until(link.telemetry.armed, 2.0)
            await link.action.takeoff()

            async def at_takeoff_alt() -> bool:
                pos = await link.telemetry.position()
                mode = await link.telemetry.flight_mode()
                return mode == FlightMode.HOLD and pos.relative_altitude_m > 2.2

            assert await wait_until(at_takeoff_alt, 6.0)
            assert await link.telemetry.landed_state() == LandedState.IN_AIR
            await link.action.land()

            async def disarmed_on_ground() -> bool:
                landed = await link.telemetry.landed_state()
                return landed == LandedState.ON_GROUND and not await link.telemetry.armed()

            assert await wait_until(disarmed_on_ground, 10.0)
            assert sim.true_state().position_ned[2] == pytest.approx(0.0, abs=1e-6)

    params = VehicleParams(disarm_land_s=0.5)
    with SimVehicle(params, port=port, seed=3) as sim:
        asyncio.run(scenario(sim))
    assert sim.thread_error is None


@pytest.mark.e2e
def test_e2e_mavsdk_offboard_refused_without_stream():
    from mavsdk.asyncio.plugins.offboard import OffboardError, OffboardResult, PositionNedYaw

    port = free_udp_port()

    async def scenario(sim: SimVehicle) -> None:
        async with connect(port) as link:
            assert await wait_health_ok(link, 5.0)
            # Raw DO_SET_MODE(OFFBOARD) with no setpoint stream: PX4 answers TEMPORARILY_REJECTED.
            result = await send_command_long(link, mavlink2.MAV_CMD_DO_SET_MODE, [1, 6, 0])
            assert result == TEMP_REJECTED
            # MAVSDK's offboard.start() right after the first setpoint: stream younger than the
            # 1 s window -> the vehicle refuses (MAVSDK maps it to COMMAND_DENIED).
            await link.offboard.set_position_ned(PositionNedYaw(0.0, 0.0, 0.0, 0.0))
            with pytest.raises(OffboardError) as exc:
                await link.offboard.start()
            assert exc.value.result == OffboardResult.COMMAND_DENIED
            assert sim.mode is not Px4Mode.OFFBOARD
            await asyncio.sleep(1.2)  # MAVSDK keeps streaming at 20 Hz
            await link.offboard.start()
            assert sim.mode is Px4Mode.OFFBOARD

    with SimVehicle(port=port, seed=3) as sim:
        asyncio.run(scenario(sim))


@pytest.mark.e2e
def test_e2e_mavsdk_offboard_trajectory_failsafe_land_disarm():
    """Fly 10 m north (min-jerk, 5 s, peak 3.75 m/s) with pos+vel+acc setpoints at 50 Hz.

    Stated tracking error (estimation error disabled, so truth = estimate): max 0.5 m and RMS
    0.25 m between the true position and the last received setpoint. Then the setpoint stream
    stops: the vehicle must leave OFFBOARD for Hold within COM_OF_LOSS_T + 0.5 s (as seen by
    MAVSDK), land after COM_FAIL_ACT_T and disarm after landing.
    """
    from mavsdk.asyncio.plugins.offboard import AccelerationNed, PositionNedYaw, VelocityNedYaw
    from mavsdk.asyncio.plugins.telemetry import FlightMode, LandedState

    port = free_udp_port()
    params = VehicleParams(com_of_loss_t_s=1.0, failsafe_hold_s=1.0, disarm_land_s=0.5)
    est = EstimationErrorParams(enabled=False)
    loss_latency: list[float] = []

    async def scenario(sim: SimVehicle) -> None:
        async with connect(port) as link:
            assert await wait_health_ok(link, 5.0)
            await link.action.arm()
            await link.action.takeoff()

            async def in_hold_at_alt() -> bool:
                return sim.mode is Px4Mode.AUTO_LOITER and sim.true_state().position_ned[2] < -2.2

            assert await wait_until(in_hold_at_alt, 6.0)
            pv = await link.telemetry.position_velocity_ned()
            n0, e0, d0 = pv.position.north_m, pv.position.east_m, pv.position.down_m
            await link.offboard.set_position_ned(PositionNedYaw(n0, e0, d0, 0.0))
            await asyncio.sleep(1.2)
            await link.offboard.start()

            async def in_offboard() -> bool:
                return await link.telemetry.flight_mode() == FlightMode.OFFBOARD

            assert await wait_until(in_offboard, 1.0)
            loop = asyncio.get_running_loop()
            t0 = loop.time()
            while (t := loop.time() - t0) < 7.0:
                p, v, a = _min_jerk(t, 5.0, 10.0)
                await link.offboard.set_position_velocity_acceleration_ned(
                    PositionNedYaw(n0 + p, e0, d0, 0.0),
                    VelocityNedYaw(v, 0.0, 0.0, 0.0),
                    AccelerationNed(a, 0.0, 0.0),
                )
                await asyncio.sleep(0.02)
            pv = await link.telemetry.position_velocity_ned()
            assert pv.position.north_m == pytest.approx(n0 + 10.0, abs=0.3)
            # Offboard loss: stop the stream (destroying the plugin ends MAVSDK's 20 Hz resend).
            link.offboard.destroy()
            t_stop = loop.time()

            async def left_offboard() -> bool:
                return await link.telemetry.flight_mode() == FlightMode.HOLD

            assert await wait_until(left_offboard, params.com_of_loss_t_s + 2.0, 0.02)
            loss_latency.append(loop.time() - t_stop)

            async def landing() -> bool:
                return await link.telemetry.flight_mode() == FlightMode.LAND

            assert await wait_until(landing, params.failsafe_hold_s + 1.0)

            async def disarmed_on_ground() -> bool:
                landed = await link.telemetry.landed_state()
                return landed == LandedState.ON_GROUND and not await link.telemetry.armed()

            assert await wait_until(disarmed_on_ground, 8.0)

    with SimVehicle(params, estimation=est, port=port, seed=3, record_history=True) as sim:
        asyncio.run(scenario(sim))
    assert loss_latency[0] <= params.com_of_loss_t_s + 0.5
    t_fs = [t for t, text in sim.events if text.startswith("Failsafe activated")]
    assert len(t_fs) == 1
    h = sim.history.arrays()
    in_offboard = h["mode"] == "OFFBOARD"
    # Only the part while setpoints were streaming (the last 1 s is the loss window).
    in_offboard &= h["time_s"] <= t_fs[0] - params.com_of_loss_t_s
    dev = np.linalg.norm(
        h["true_position_ned"][in_offboard] - h["setpoint_position_ned"][in_offboard], axis=1
    )
    assert dev.size > 1000
    print(f"tracking: max {dev.max():.3f} m, rms {math.sqrt(float(np.mean(dev**2))):.3f} m; "
          f"offboard-loss -> Hold seen by MAVSDK after {loss_latency[0]:.2f} s")  # fmt: skip
    assert dev.max() < 0.5
    assert math.sqrt(float(np.mean(dev**2))) < 0.25
    assert h["velocity_ned"][in_offboard][:, 0].max() > 3.0  # the trajectory was really flown
    assert not sim.armed and sim.collisions == []
