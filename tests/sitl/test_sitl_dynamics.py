"""Fast unit tests of the quadrotor model, the cascaded controller and the error model."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sitl.dynamics import (
    ControllerParams,
    PositionController,
    QuadrotorModel,
    QuadrotorParams,
    Setpoint,
    euler_from_rotation,
    quaternion_from_rotation,
    rotation_from_thrust_yaw,
)
from sitl.estimation import EstimationErrorParams, PositionErrorModel, error_std, std_for_speed
from tests.helpers.kinematics import min_jerk

DT = 0.004
NAN3 = np.full(3, np.nan)


def _sim(setpoint_fn, seconds, start=None, quad=None, ctrl=None):
    """Closed loop with perfect state; returns (t, pos, vel, thrust) arrays."""
    quad = quad or QuadrotorParams()
    model = QuadrotorModel(quad)
    if start is not None:
        model.state.position = np.asarray(start, dtype=float)
        model.state.on_ground = False
        model.state.thrust = np.array([0.0, 0.0, -quad.gravity_m_s2])
    pc = PositionController(ctrl or ControllerParams(), quad)
    n = int(round(seconds / DT))
    t = np.arange(1, n + 1) * DT
    pos, vel, thr = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))
    for k in range(n):
        s = model.state
        sp = setpoint_fn(k * DT)
        f = pc.update(DT, s.position, s.velocity, s.acceleration, sp)
        model.step(DT, f, pc.yaw_rate_command(s.yaw, sp))
        pos[k], vel[k], thr[k] = s.position, s.velocity, s.thrust
    return t, pos, vel, thr, model


def test_takeoff_and_hover_converges():
    target = np.array([0.0, 0.0, -5.0])
    _, pos, vel, _, model = _sim(lambda t: Setpoint.hold(target), 12.0)
    assert not model.state.on_ground
    assert np.linalg.norm(pos[-1] - target) < 0.05
    assert np.linalg.norm(vel[-1]) < 0.05
    # Climb rate respects MPC_Z_VEL_MAX_UP = 3 m/s (NED: up is negative) up to a small
    # overshoot of the velocity loop.
    assert -3.0 * 1.1 < vel[:, 2].min() < -2.5


def test_idle_on_ground_stays_on_ground():
    quad = QuadrotorParams()
    model = QuadrotorModel(quad)
    for _ in range(500):
        model.step(DT, np.array([0.0, 0.0, -0.3 * quad.gravity_m_s2]), 0.0)
    assert model.state.on_ground
    assert model.state.position[2] == pytest.approx(0.0)
    assert np.all(model.state.velocity == 0.0)


def test_tilt_and_speed_limits_on_large_step():
    ctrl = ControllerParams(tilt_max_deg=30.0, vel_max_xy_m_s=6.0)
    target = np.array([60.0, 0.0, -5.0])
    _, _, vel, thr, _ = _sim(lambda t: Setpoint.hold(target), 8.0, start=[0, 0, -5], ctrl=ctrl)
    tilt = np.degrees(np.arctan2(np.hypot(thr[:, 0], thr[:, 1]), -thr[:, 2]))
    assert tilt.max() <= 30.0 + 0.5
    assert tilt.max() > 25.0  # the limit is actually reached, not trivially satisfied
    speed_xy = np.hypot(vel[:, 0], vel[:, 1])
    assert speed_xy.max() <= 6.0 * 1.05
    assert speed_xy.max() > 5.5
    g = QuadrotorParams().gravity_m_s2
    assert np.linalg.norm(thr, axis=1).max() <= 2.0 * g + 1e-6  # thrust-to-weight 2


def test_feed_forward_tracking_beats_position_only():
    """Min-jerk 10 m in 5 s (peak 3.75 m/s, 2.3 m/s^2).

    With velocity + acceleration feed-forward the tracking error stays below 0.3 m (it is not
    zero: like PX4, the D term acts on the measured acceleration and opposes the feed-forward,
    and there is drag and the attitude lag); with position setpoints only the vehicle lags by
    metres (P gain 0.95 1/s needs ~4 m of error for 3.75 m/s).
    """
    start = np.array([0.0, 0.0, -5.0])

    def full(t):
        p, v, a = min_jerk(t, 5.0, 10.0)
        return Setpoint(start + [p, 0, 0], np.array([v, 0, 0.0]), np.array([a, 0, 0.0]))

    def pos_only(t):
        p, _, _ = min_jerk(t, 5.0, 10.0)
        return Setpoint(start + [p, 0, 0], NAN3.copy(), NAN3.copy())

    t, pos_ff, *_ = _sim(full, 7.0, start=start)
    ref = np.array([start + [min_jerk(tk - DT, 5.0, 10.0)[0], 0, 0] for tk in t])
    err_ff = np.linalg.norm(pos_ff - ref, axis=1).max()
    _, pos_p, *_ = _sim(pos_only, 7.0, start=start)
    err_p = np.linalg.norm(pos_p - ref, axis=1).max()
    assert err_ff < 0.3
    assert err_p > 3.0


def test_velocity_only_setpoint_tracks_velocity():
    sp = Setpoint(
        position=np.array([np.nan, np.nan, -5.0]),
        velocity=np.array([2.0, -1.0, np.nan]),
        acceleration=NAN3.copy(),
    )
    _, pos, vel, _, _ = _sim(lambda t: sp, 10.0, start=[0, 0, -5])
    assert vel[-1] == pytest.approx([2.0, -1.0, 0.0], abs=0.08)
    assert pos[-1, 2] == pytest.approx(-5.0, abs=0.05)


def test_yaw_setpoint_and_yaw_rate():
    target = np.array([0.0, 0.0, -5.0])
    sp = Setpoint.hold(target, yaw=math.radians(90.0))
    *_, model = _sim(lambda t: sp, 4.0, start=target)
    assert math.degrees(model.state.yaw) == pytest.approx(90.0, abs=1.0)
    sp_rate = Setpoint(target, np.zeros(3), np.zeros(3), yaw_rate=0.5)
    *_, model = _sim(lambda t: sp_rate, 2.0, start=target)
    assert model.state.yaw == pytest.approx(1.0, abs=0.02)


def test_attitude_conversions():
    g = 9.80665
    # Accelerating north needs thrust tilted north: nose down (negative pitch) at yaw 0.
    thrust = np.array([3.0, 0.0, -g])
    r = rotation_from_thrust_yaw(thrust, 0.0)
    roll, pitch, yaw = euler_from_rotation(r)
    assert pitch == pytest.approx(-math.atan2(3.0, g), abs=1e-9)
    assert roll == pytest.approx(0.0, abs=1e-9)
    assert yaw == pytest.approx(0.0, abs=1e-9)
    # Accelerating east: right roll (positive) at yaw 0.
    roll_e, _, _ = euler_from_rotation(rotation_from_thrust_yaw(np.array([0.0, 3.0, -g]), 0.0))
    assert roll_e > 0.2
    # Quaternion of a pure yaw.
    q = quaternion_from_rotation(rotation_from_thrust_yaw(np.array([0, 0, -g]), math.pi / 2))
    assert q == pytest.approx([math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4)], abs=1e-9)
    assert np.allclose(r.T @ r, np.eye(3))


# --------------------------------------------------------------------- estimation error


def test_error_std_formula_and_floor():
    p = EstimationErrorParams(slope_s=0.2, offset_m=-0.1, min_std_m=0.05)
    assert std_for_speed(p, [0.0, 0.5, 1.0, 5.0]) == pytest.approx([0.05, 0.05, 0.1, 0.9])
    v = np.array([[3.0, 4.0, 0.0]])  # speed 5
    assert error_std(p, v) == pytest.approx(np.array([[0.9, 0.9, 0.45]]))  # vertical: half
    pa = EstimationErrorParams(speed_mode="axis", vertical_scale=1.0)
    assert error_std(pa, np.array([3.0, 0.0, -1.0])) == pytest.approx([0.5, 0.02, 0.1])
    assert np.all(error_std(EstimationErrorParams(enabled=False), v) == 0.0)


def test_gauss_markov_statistics_and_correlation():
    """At constant speed: per-axis std = sigma and lag-tau autocorrelation = exp(-1)."""
    params = EstimationErrorParams(slope_s=0.2, offset_m=-0.1, correlation_time_s=0.5)
    model = PositionErrorModel(params, np.random.default_rng(11))
    vel = np.array([4.0, 0.0, 0.0])  # sigma = 0.7
    dt = 0.02
    e = np.array([model.step(dt, vel) for _ in range(60_000)])
    assert e.std(axis=0) == pytest.approx([0.7, 0.7, 0.35], rel=0.05)
    assert np.abs(e.mean(axis=0)).max() < 0.05
    lag = int(round(0.5 / dt))
    z = e / [0.7, 0.7, 0.35]
    rho = np.mean(z[:-lag] * z[lag:])
    assert rho == pytest.approx(math.exp(-1.0), abs=0.05)
    assert np.mean(z[:-1] * z[1:]) > 0.9  # strongly correlated from step to step


def test_error_model_is_seeded():
    p = EstimationErrorParams()
    v = np.array([2.0, 0.0, 0.0])
    a = PositionErrorModel(p, np.random.default_rng(3))
    b = PositionErrorModel(p, np.random.default_rng(3))
    c = PositionErrorModel(p, np.random.default_rng(4))
    ea = [a.step(0.01, v) for _ in range(100)]
    eb = [b.step(0.01, v) for _ in range(100)]
    ec = [c.step(0.01, v) for _ in range(100)]
    assert np.array_equal(ea, eb)
    assert not np.allclose(ea, ec)
