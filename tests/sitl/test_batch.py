"""Validation of the batched simulator (``sitl.batch``) against the single-vehicle sitl.

The reference is :class:`sitl.vehicle.SimVehicle` itself (which composes ``sitl.dynamics`` and
``sitl.estimation``): a vehicle takes off, hovers in OFFBOARD, and then flies a trajectory with
setpoints streamed at 50 Hz. The batch simulator starts from the same state (read from the
vehicle) with the same random stream and must reproduce the true and the estimated path, and
the collision, to within ``PATH_TOL`` (only floating-point rounding differs). Both models are
checked: the idealised one of the collision-rate experiment (the dataclass defaults: light drag,
the paper's error model) and the vehicle's default, PX4's SIH quadrotor with its EKF error and
hover wander.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from rota.trajectory import BSplineTrajectory
from sitl.batch import (
    BatchWorlds,
    NoiseStreams,
    SetpointTable,
    enu_to_ned,
    ned_to_enu,
    simulate,
)
from sitl.dynamics import PX4_SIH_QUAD, QuadrotorParams, Setpoint
from sitl.estimation import PX4_SIH_ESTIMATION, EstimationErrorParams
from sitl.planner import plan, straight_line
from sitl.vehicle import Px4Mode, SimVehicle, VehicleParams
from sitl.world import Box, Cylinder, World, forest, pillar_world

#: Largest allowed difference (m) between batch and single-vehicle paths.
PATH_TOL = 1e-9
RATE = 50.0
#: (quad, estimation) of the experiment's idealised vehicle and of the PX4-like one
IDEAL_MODEL = (QuadrotorParams(), EstimationErrorParams())
PX4_MODEL = (PX4_SIH_QUAD, PX4_SIH_ESTIMATION)


def _table(traj: BSplineTrajectory, duration: float) -> SetpointTable:
    t = np.arange(int(math.floor(duration * RATE)) + 1) / RATE
    p, v, a = traj.evaluate(np.minimum(t, traj.duration))
    after = t >= traj.duration
    v[after], a[after] = 0.0, 0.0
    return SetpointTable.from_lists(RATE, [(p, v, a)])


def _fly_single(world: World, traj: BSplineTrajectory, seed: int, duration: float,
                estimation: EstimationErrorParams, quad: QuadrotorParams):
    """SimVehicle: take off at the trajectory's start, hover in OFFBOARD, then fly ``traj``.

    Returns the vehicle, the state at the start of the trajectory (batch-NED, home at the ENU
    origin) and its random generator at that instant, and the history index where it starts.
    """
    start = traj.position(np.array([0.0]))[0]
    home = (float(start[0]), float(start[1]), 0.0)
    params = VehicleParams(home_enu_m=home)
    sim = SimVehicle(params, world=world, seed=seed, record_history=True,
                     estimation=estimation, quad=quad)
    assert sim.arm() == 0
    assert sim.takeoff(float(start[2])) == 0
    sim.run_for(14.0)
    home_arr = np.array(home)

    def to_ned(p_enu: np.ndarray) -> np.ndarray:
        return enu_to_ned(p_enu - home_arr)

    hold = Setpoint.hold(to_ned(start))
    sim.set_position_target(hold)
    assert sim.set_mode(Px4Mode.OFFBOARD) == 0
    sim.run_for(3.0, lambda t: hold, RATE)
    s = sim._model.state  # private: the validation needs the exact state
    initial = {
        "pos": enu_to_ned(ned_to_enu(s.position[None]) + home_arr),
        "vel": s.velocity[None].copy(), "acc": s.acceleration[None].copy(),
        "thrust": s.thrust[None].copy(), "integral": sim._ctrl.integral[None].copy(),
        "on_ground": np.array([s.on_ground]),
        **{k: v[None] for k, v in sim._err.state().items()},
    }
    rng = np.random.default_rng()
    rng.bit_generator.state = sim._err._rng.bit_generator.state
    n0 = len(sim.history.time_s)
    t0 = sim.time_s

    def sp_fn(t: float) -> Setpoint:
        tt = min(t - t0, traj.duration)
        p, v, a = (x[0] for x in traj.evaluate(np.array([tt])))
        if t - t0 >= traj.duration:
            v, a = np.zeros(3), np.zeros(3)
        return Setpoint(to_ned(p), enu_to_ned(v), enu_to_ned(a))

    sim.run_for(duration, sp_fn, RATE)
    return sim, initial, rng, n0, home_arr


def _compare(world: World, traj: BSplineTrajectory, seed: int, duration: float,
             model: tuple[QuadrotorParams, EstimationErrorParams] = IDEAL_MODEL):
    quad, estimation = model
    sim, initial, rng, n0, home = _fly_single(world, traj, seed, duration, estimation, quad)
    res = simulate(_table(traj, duration), BatchWorlds.from_worlds([world]),
                   np.array([duration]), NoiseStreams.from_generators([rng]),
                   initial=initial, estimation=estimation, quad=quad, record=True)
    h = sim.history.arrays()
    true_single = ned_to_enu(h["true_position_ned"][n0:]) + home
    est_single = ned_to_enu(h["estimated_position_ned"][n0:]) + home
    return sim, res, true_single, est_single


@pytest.mark.parametrize("model", [IDEAL_MODEL, PX4_MODEL], ids=["ideal", "px4"])
def test_batch_reproduces_single_vehicle_forest_flight(model):
    """3 m/s planned flight through a dense forest: same true and estimated path."""
    world = forest(0.063, 4)
    traj = plan(world, 3.0, 3.0)
    duration = traj.duration + 1.0
    sim, res, true_single, est_single = _compare(world, traj, 11, duration, model)
    k = min(len(true_single), res.history["true_position"].shape[0])
    if not sim.collisions:
        assert k == len(true_single) == res.history["true_position"].shape[0]
    dev_true = np.abs(res.history["true_position"][:k, 0] - true_single[:k]).max()
    dev_est = np.abs(res.history["estimated_position"][:k, 0] - est_single[:k]).max()
    assert dev_true < PATH_TOL and dev_est < PATH_TOL
    # The flight really exercised the noise: the estimate was off by decimetres.
    assert res.max_estimation_error[0] > 0.2
    assert bool(res.collided[0]) == bool(sim.collisions)


@pytest.mark.parametrize("model", [IDEAL_MODEL, PX4_MODEL], ids=["ideal", "px4"])
def test_batch_reproduces_single_vehicle_collision(model):
    """A straight line through a pillar: same collision step, position and distance."""
    world = World((Cylinder(10.0, 10.35, 0.2),), start=(1.0, 10.0, 2.0), goal=(19.0, 10.0, 2.0))
    traj = straight_line(np.array(world.start), np.array(world.goal), 2.0, 2.0)
    sim, res, true_single, _ = _compare(world, traj, 5, traj.duration + 1.0, model)
    assert len(sim.collisions) == 1 and res.collided[0]
    col = sim.collisions[0]
    assert res.collision_position[0] == pytest.approx(col.position_enu, abs=PATH_TOL)
    assert res.min_distance[0] == pytest.approx(col.signed_distance_m, abs=PATH_TOL)
    # Collision time: same number of steps after the start of the trajectory.
    n_steps = round(res.collision_time[0] / 0.004)
    assert res.history["true_position"].shape[0] == n_steps
    assert np.abs(res.history["true_position"][:, 0] - true_single[:n_steps]).max() < PATH_TOL


def test_batch_reproduces_single_vehicle_axis_mode_and_short_tau():
    """Other estimation settings (per-axis speed, tau = 0.3 s) on the pillar world."""
    est = EstimationErrorParams(slope_s=0.3, offset_m=-0.05, correlation_time_s=0.3,
                                speed_mode="axis")
    world = pillar_world()
    traj = plan(world, 2.0, 2.0)
    sim, res, true_single, est_single = _compare(world, traj, 2, traj.duration + 0.5,
                                                 (QuadrotorParams(), est))
    k = res.history["true_position"].shape[0]
    assert np.abs(res.history["true_position"][:, 0] - true_single[:k]).max() < PATH_TOL
    assert np.abs(res.history["estimated_position"][:, 0] - est_single[:k]).max() < PATH_TOL


def test_batch_reproduces_single_vehicle_drift_model():
    """The drift model (error carried over, increments scaled by sigma), another vertical
    scale, on the calibrated vehicle with PX4's base error and wander: same true and
    estimated path, same reported std, as SimVehicle."""
    est = replace(PX4_SIH_ESTIMATION, kind="drift", slope_s=0.2, offset_m=-0.1, min_std_m=0.02,
                  correlation_time_s=3.0, vertical_scale=0.3)  # with PX4's base error, wander
    world = forest(0.043, 2)
    traj = plan(world, 3.0, 3.0)
    sim, res, true_single, est_single = _compare(world, traj, 9, traj.duration + 1.0,
                                                 (PX4_SIH_QUAD, est))
    k = res.history["true_position"].shape[0]
    assert np.abs(res.history["true_position"][:, 0] - true_single[:k]).max() < PATH_TOL
    assert np.abs(res.history["estimated_position"][:, 0] - est_single[:k]).max() < PATH_TOL
    h = sim.history.arrays()
    n0 = len(h["error_std_m"]) - len(true_single)
    std_single = h["error_std_m"][n0:n0 + k][:, [1, 0, 2]]
    assert np.abs(res.history["error_std"][:, 0] - std_single).max() < PATH_TOL
    assert res.max_estimation_error[0] > 0.2


def test_drift_error_persists_after_slowing_down():
    """3 m/s for 6 s, then hover: the correlated model's error std drops to its hover value
    at once; the drift model's decays with its tau (3 s), from the same stationary value at
    3 m/s (sigma = 0.5 m per horizontal axis)."""
    n, dur = 300, 12.0
    t = np.arange(int(dur * RATE) + 1) / RATE
    x = np.where(t < 6.0, 3.0 * t, 18.0)
    p = np.column_stack([x, np.zeros_like(t), np.ones_like(t)])
    v = np.column_stack([np.where(t < 6.0, 3.0, 0.0), 0 * t, 0 * t])
    tab = SetpointTable.from_lists(RATE, [(p, v, np.zeros_like(p))] * n)
    out = {}
    for kind, tau in (("correlated", 1.0), ("drift", 3.0)):
        est = EstimationErrorParams(kind=kind, correlation_time_s=tau)
        res = simulate(tab, None, np.full(n, dur), np.arange(n), estimation=est, record=True)
        h = res.history
        err = h["estimated_position"] - h["true_position"]
        out[kind] = (h["time"], np.sqrt(np.mean(err[..., 1] ** 2, axis=1)),
                     h["error_std"][:, 0, 1])
    tt, rms_c, std_c = out["correlated"]
    _, rms_d, std_d = out["drift"]
    cruise = (tt > 4.5) & (tt < 5.5)
    assert std_d[cruise].mean() == pytest.approx(0.5, rel=0.05)
    assert rms_d[cruise].mean() == pytest.approx(0.5, rel=0.2)
    after = (tt > 9.0) & (tt < 9.5)  # 3 s after the stop (the vehicle settles in ~2.5 s)
    assert std_c[after].max() < 0.05  # the correlated error is gone at hover speed
    assert std_d[after].min() > 0.5 * math.exp(-3.5 / 3.0) * 0.9  # decays with tau only
    assert rms_d[after].mean() > 4 * rms_c[after].mean()


def test_equal_seeds_equal_draws_and_independent_of_batch():
    """Vehicles with the same seed see the same noise; a vehicle's path does not depend on
    which other vehicles share its batch; the start state matches PositionErrorModel's."""
    world = pillar_world()
    traj = straight_line(np.array(world.start), np.array(world.goal), 2.0, 2.0)
    tab = _table(traj, traj.duration)
    both = SetpointTable.from_lists(RATE, [(tab.position[0], tab.velocity[0],
                                            tab.acceleration[0])] * 3)
    worlds = BatchWorlds.from_worlds([world] * 3)
    res = simulate(both, worlds, np.full(3, 3.0), [7, 7, 8], record=True)
    hist = res.history["estimated_position"]
    assert np.array_equal(hist[:, 0], hist[:, 1])
    assert not np.allclose(hist[:, 0], hist[:, 2])
    alone = simulate(tab, BatchWorlds.from_worlds([world]), np.array([3.0]), [8], record=True)
    assert np.array_equal(alone.history["estimated_position"][:, 0], hist[:, 2])


def test_error_statistics_match_model():
    """400 vehicles at 2.5 m/s: sigma = 0.2 |v| - 0.1 at every step, the per-axis RMS of
    (estimate - truth) equals the model's RMS sigma (3 %), the autocorrelation of z at lags
    0.25 / 0.5 / 1 s is exp(-lag / tau) (0.03), z has zero mean."""
    n, speed, dur = 400, 2.5, 12.0
    t = np.arange(int(dur * RATE) + 1) / RATE
    p = np.column_stack([speed * t, np.zeros_like(t), np.ones_like(t)])
    v = np.tile([speed, 0.0, 0.0], (len(t), 1))
    tab = SetpointTable.from_lists(RATE, [(p, v, np.zeros_like(p))] * n)
    start = np.zeros((n, 3)) + [0.0, 0.0, 1.0]
    # Start already moving so the speed is constant from the first step.
    initial = {"pos": enu_to_ned(start), "vel": enu_to_ned(np.tile([speed, 0.0, 0.0], (n, 1))),
               "acc": np.zeros((n, 3)),
               "thrust": np.tile([0.0, 0.0, -9.80665], (n, 1)),
               "integral": enu_to_ned(np.tile([0.05 * speed, 0.0, 0.0], (n, 1))),
               "z": np.random.default_rng(0).standard_normal((n, 3)),
               "on_ground": np.zeros(n, dtype=bool)}
    res = simulate(tab, None, np.full(n, dur), np.arange(n) + 100, initial=initial,
                   record=True)
    h = res.history
    sl = slice(int(2.0 / 0.004), None)  # after the initial transient
    err = (h["estimated_position"] - h["true_position"])[sl]
    speeds = np.linalg.norm(h["velocity"][sl], axis=2)
    assert speeds.mean() == pytest.approx(speed, rel=0.02)
    # sigma follows the true speed of every step (the vehicle chases its noisy estimate, so
    # the speed itself fluctuates), per axis and exactly the model's formula; the vertical
    # std is half the horizontal one (the default vertical_scale).
    want_std = np.maximum(0.2 * speeds - 0.1, 0.02)[..., None] * [1.0, 1.0, 0.5]
    assert np.abs(h["error_std"][sl] - want_std).max() < 1e-12
    rms_model = np.sqrt(np.mean(h["error_std"][sl] ** 2, axis=(0, 1)))
    assert np.sqrt(np.mean(err**2, axis=(0, 1))) == pytest.approx(rms_model, rel=0.03)
    z = err / h["error_std"][sl]
    # z is zero-mean; e itself is not quite along the flight direction (a positive e_x makes
    # the vehicle slow down, hence a smaller sigma: a genuine property of the model).
    assert np.abs(z.reshape(-1, 3).mean(axis=0)).max() < 0.05
    for lag_s in (0.25, 0.5, 1.0):
        lag = int(lag_s / 0.004)
        rho = np.mean(z[lag:] * z[:-lag]) / np.mean(z * z)
        assert rho == pytest.approx(math.exp(-lag_s / 1.0), abs=0.03)


def test_worlds_signed_distance_matches_world():
    rng = np.random.default_rng(1)
    worlds = [forest(0.043, 1), forest(0.025, 2),
              World((Box((5, 5, 0), (6, 7, 2)), Cylinder(2, 2, 0.3)))]
    bw = BatchWorlds.from_worlds(worlds)
    for _ in range(20):
        pts = rng.uniform([0, 0, 0], [20, 20, 3], (3, 3))
        want = np.array([w.signed_distance(p[None])[0] for w, p in zip(worlds, pts,
                                                                          strict=True)])
        assert bw.signed_distance(pts) == pytest.approx(want, abs=1e-12)


def test_ground_contact_and_collision_altitude_rule():
    """A setpoint below the ground: the vehicle lands (no collision counted below the robot
    radius altitude), ground contact is reported."""
    t = np.arange(201) / RATE
    p = np.column_stack([np.full_like(t, 5.0), np.full_like(t, 5.0), np.full_like(t, -1.0)])
    tab = SetpointTable.from_lists(RATE, [(p, np.zeros_like(p), np.zeros_like(p))])
    world = World((Cylinder(5.0, 5.5, 0.1),))  # 0.4 m away: a collision if it counted
    res = simulate(tab, BatchWorlds.from_worlds([world]), np.array([4.0]), [0],
                   start_enu=np.array([[5.0, 5.0, 0.5]]), record=True)
    assert res.ground_contact[0]
    assert not res.collided[0]
    assert res.history["true_position"][-1, 0, 2] == 0.0


def test_collisions_at_any_altitude_and_ground_ends_flight():
    """The experiment's crash rules: a trunk touched below the robot-radius altitude counts,
    and the first ground contact ends the flight at its time."""
    t = np.arange(201) / RATE
    p = np.column_stack([np.full_like(t, 5.0), np.full_like(t, 5.0), np.full_like(t, -1.0)])
    tab = SetpointTable.from_lists(RATE, [(p, np.zeros_like(p), np.zeros_like(p))])
    # A stump 0.25 m from the vehicle's axis, 0.1 m tall: out of reach at or above
    # the robot-radius altitude (0.3 m), in reach below it.
    world = BatchWorlds.from_worlds([World((Cylinder(5.0, 5.35, 0.1, 0.0, 0.1),))])
    start = np.array([[5.0, 5.0, 0.5]])
    low = simulate(tab, world, np.array([4.0]), [0], start_enu=start,
                   collide_at_any_altitude=True)
    assert low.collided[0] and low.collision_position[0, 2] < 0.3
    assert not simulate(tab, world, np.array([4.0]), [0], start_enu=start).collided[0]
    ground = simulate(tab, None, np.array([4.0]), [0], start_enu=start, ground_ends_flight=True)
    assert ground.ground_contact[0] and ground.end_time[0] == ground.ground_time[0] < 4.0
    assert ground.final_position[0, 2] == 0.0
    free = simulate(tab, None, np.array([4.0]), [0], start_enu=start)
    assert free.ground_time[0] == ground.ground_time[0] and free.end_time[0] == 4.0
