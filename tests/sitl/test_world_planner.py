"""Tests for sitl.world (obstacles, signed distance, forests, JSON) and sitl.planner."""

from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest
from scipy.spatial import cKDTree

from rota.errors import InputError
from rota.trajectory import BSplineTrajectory
from sitl.planner import PlanningError, plan, plan_detailed, straight_line
from sitl.world import (
    DENSITIES,
    WORLD_NAMES,
    Box,
    Cylinder,
    World,
    forest,
    get_world,
)

TOL = 1e-6  # relative tolerance on v_max and a_max (the planner meets them up to rounding)


# ------------------------------------------------------------------- helpers
def _cylinder_surface(c: Cylinder, h: float) -> np.ndarray:
    """Points on the surface of a finite cylinder, spaced about ``h``."""
    n_phi = int(math.ceil(2 * math.pi * c.radius / h))
    phi = np.linspace(0, 2 * math.pi, n_phi, endpoint=False)
    z = np.linspace(c.z_min, c.z_max, int(math.ceil((c.z_max - c.z_min) / h)) + 1)
    pp, zz = np.meshgrid(phi, z)
    side = np.stack([c.x + c.radius * np.cos(pp).ravel(), c.y + c.radius * np.sin(pp).ravel(),
                     zz.ravel()], axis=1)
    g = np.arange(-c.radius, c.radius + h, h)
    gx, gy = np.meshgrid(g, g)
    disc = np.stack([gx.ravel(), gy.ravel()], axis=1)
    disc = disc[np.hypot(disc[:, 0], disc[:, 1]) <= c.radius]
    caps = [np.column_stack([disc + [c.x, c.y], np.full(len(disc), zc)]) for zc in
            (c.z_min, c.z_max)]
    return np.vstack([side, *caps])


def _box_surface(b: Box, h: float) -> np.ndarray:
    lo, hi = np.array(b.lo), np.array(b.hi)
    axes = [np.linspace(lo[k], hi[k], int(math.ceil((hi[k] - lo[k]) / h)) + 1) for k in range(3)]
    faces = []
    for k in range(3):
        o = [j for j in range(3) if j != k]
        u, v = np.meshgrid(axes[o[0]], axes[o[1]])
        for val in (lo[k], hi[k]):
            f = np.empty((u.size, 3))
            f[:, k], f[:, o[0]], f[:, o[1]] = val, u.ravel(), v.ravel()
            faces.append(f)
    return np.vstack(faces)


def _dense_samples(traj: BSplineTrajectory, step: float) -> tuple[np.ndarray, ...]:
    """Samples at most ``step`` metres of arc length apart (speed bound from control points)."""
    t0, t1 = traj.domain
    vmax = np.max(np.linalg.norm(np.diff(traj.control_points, axis=0), axis=1)) / traj.knot_span
    n = int(math.ceil((t1 - t0) * vmax / step)) + 2
    return traj.evaluate(np.linspace(t0, t1, n))


def _check_plan(world: World, traj: BSplineTrajectory, v_max: float, a_max: float,
                start=None, goal=None, v0=None) -> None:
    p, v, a = _dense_samples(traj, 0.01)  # every 1 cm of arc length
    sd = world.signed_distance(p)
    assert np.all(sd >= world.robot_radius), f"clips an obstacle: clearance {sd.min():.4f} m"
    start = np.array(world.start if start is None else start)
    goal = np.array(world.goal if goal is None else goal)
    v0 = np.zeros(3) if v0 is None else np.asarray(v0)
    np.testing.assert_allclose(p[0], start, atol=1e-9)
    np.testing.assert_allclose(p[-1], goal, atol=1e-9)
    np.testing.assert_allclose(v[0], v0, atol=1e-9)
    np.testing.assert_allclose(v[-1], 0.0, atol=1e-9)
    np.testing.assert_allclose(a[-1], 0.0, atol=1e-9)
    speed_cap = max(v_max, float(np.linalg.norm(v0)))
    assert np.linalg.norm(v, axis=1).max() <= speed_cap * (1 + TOL)
    assert np.linalg.norm(a, axis=1).max() <= a_max * (1 + TOL)
    # exact acceleration maximum: the cubic B-spline's acceleration is piecewise linear
    acc_cp = np.diff(traj.control_points, 2, axis=0) / traj.knot_span**2
    assert np.linalg.norm(acc_cp, axis=1).max() <= a_max * (1 + TOL)


# ------------------------------------------------------------ signed distance
@pytest.mark.parametrize("seed", range(3))
def test_cylinder_signed_distance_matches_brute_force(seed: int) -> None:
    rng = np.random.default_rng(seed)
    cyl = Cylinder(rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(0.2, 0.6),
                   rng.uniform(0, 0.5), rng.uniform(1.0, 2.0))
    world = World((cyl,), ((-5, -5, -5), (5, 5, 5)), start=(-4, -4, 0), goal=(4, 4, 0))
    h = 0.01
    tree = cKDTree(_cylinder_surface(cyl, h))
    q = np.column_stack([rng.uniform(cyl.x - 1.5, cyl.x + 1.5, 400),
                         rng.uniform(cyl.y - 1.5, cyl.y + 1.5, 400),
                         rng.uniform(cyl.z_min - 1, cyl.z_max + 1, 400)])
    sd = world.signed_distance(q)
    brute, _ = tree.query(q)
    inside = (np.hypot(q[:, 0] - cyl.x, q[:, 1] - cyl.y) < cyl.radius) & \
        (q[:, 2] > cyl.z_min) & (q[:, 2] < cyl.z_max)
    assert inside.any() and (~inside).any()
    np.testing.assert_array_equal(sd < 0, inside)
    assert np.all(np.abs(sd) <= brute + 1e-9)  # sampled surface distance is an upper bound
    assert np.all(brute <= np.abs(sd) + h)  # ... within the sampling spacing


@pytest.mark.parametrize("seed", range(3))
def test_box_signed_distance_matches_brute_force(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    lo = rng.uniform(-1, 0, 3)
    box = Box(tuple(lo), tuple(lo + rng.uniform(0.3, 1.2, 3)))
    world = World((box,), ((-5, -5, -5), (5, 5, 5)), start=(-4, -4, 0), goal=(4, 4, 0))
    h = 0.01
    tree = cKDTree(_box_surface(box, h))
    q = rng.uniform(lo - 1, np.array(box.hi) + 1, (400, 3))
    sd = world.signed_distance(q)
    brute, _ = tree.query(q)
    inside = np.all((q > box.lo) & (q < box.hi), axis=1)
    assert inside.any() and (~inside).any()
    np.testing.assert_array_equal(sd < 0, inside)
    assert np.all(np.abs(sd) <= brute + 1e-9)
    assert np.all(brute <= np.abs(sd) + h)


def test_signed_distance_exact_values_and_union() -> None:
    cyl = Cylinder(0.0, 0.0, 1.0, 0.0, 2.0)
    box = Box((3.0, 3.0, 0.0), (4.0, 5.0, 1.0))
    world = World((cyl, box), ((-10, -10, -10), (10, 10, 10)), start=(-9, 0, 0), goal=(9, 0, 0))
    pts = np.array([[2.0, 0.0, 1.0],  # beside the cylinder: radial gap 1
                    [1.3, 0.0, 2.4],  # past the rim: hypot(0.3, 0.4) = 0.5
                    [0.0, 0.0, 1.5],  # inside, 0.5 below the top cap
                    [3.5, 4.0, 3.0],  # above the box: 2
                    [2.0, 2.0, 0.5]])  # nearest: box edge (1, 1) vs cylinder 2*sqrt2 - 1
    expected = [1.0, 0.5, -0.5, 2.0, min(math.sqrt(2.0), 2 * math.sqrt(2.0) - 1.0)]
    np.testing.assert_allclose(world.signed_distance(pts), expected, atol=1e-12)
    singles = [World((o,), world.bounds, start=world.start, goal=world.goal) for o in (cyl, box)]
    rng = np.random.default_rng(7)
    q = rng.uniform(-6, 6, (5000, 3))
    np.testing.assert_allclose(world.signed_distance(q),
                               np.minimum(*(w.signed_distance(q) for w in singles)))
    np.testing.assert_array_equal(world.collides(q), world.signed_distance(q) < 0.3)
    np.testing.assert_array_equal(world.collides(q, radius=0.0), world.signed_distance(q) < 0)
    assert np.all(np.isinf(get_world("empty").signed_distance(q)))


# ------------------------------------------------------------------- forests
@pytest.mark.parametrize(("level", "count"), [("low", 10), ("mid", 17), ("high", 25)])
def test_forest_counts_and_determinism(level: str, count: int) -> None:
    density = DENSITIES[level]
    for seed in range(20):
        w = forest(density, seed)
        assert len(w.obstacles) == count == round(density * 400)
        assert w == forest(density, seed)
        for c in w.obstacles:
            assert isinstance(c, Cylinder)
            assert 0.15 <= c.radius <= 0.4
            assert c.radius <= c.x <= 20 - c.radius and c.radius <= c.y <= 20 - c.radius
        xy = np.array([(c.x, c.y) for c in w.obstacles])
        r = np.array([c.radius for c in w.obstacles])
        gaps = np.linalg.norm(xy[:, None] - xy[None], axis=2) - r[:, None] - r[None]
        assert np.all(gaps[~np.eye(len(r), dtype=bool)] >= 0.3)
        for end in (w.start, w.goal):
            assert np.all(np.hypot(*(xy - end[:2]).T) - r >= 1.5)
        assert w.start[0] == 1.0 and w.goal[0] == 19.0
    assert forest(density, 1) != forest(density, 2)


def test_named_worlds() -> None:
    for name in WORLD_NAMES:
        w = get_world(name, seed=3)
        assert not w.collides(np.array([w.start, w.goal])).any()
    assert get_world("forest", 4) == get_world("forest-mid", 4)
    assert len(get_world("forest-high", 0).obstacles) == 25
    assert get_world("empty").obstacles == ()
    pillar = get_world("pillar")
    line = np.linspace(pillar.start, pillar.goal, 2001)
    d = pillar.signed_distance(line)
    assert np.all(d >= pillar.robot_radius) and d.min() < 1.0  # clear, but in braking range
    with pytest.raises(InputError) as err:
        get_world("moon")
    assert err.value.field == "name"


# -------------------------------------------------------------------- voxels
@pytest.mark.parametrize("res", [0.1, 0.25])
def test_voxel_points_cover_obstacles(res: float) -> None:
    world = World((Cylinder(2.0, 2.0, 0.3, 0.0, 1.5), Box((3.1, 0.4, 0.2), (3.9, 1.0, 0.9))),
                  ((0, 0, 0), (5, 4, 2)), start=(0.5, 0.5, 1), goal=(4.5, 3.5, 1))
    vox = world.voxel_points(res)
    lo = np.array(world.bounds[0])
    occupied = {tuple(i) for i in np.floor((vox - lo) / res).astype(int)}
    assert len(occupied) == len(vox)
    np.testing.assert_allclose((vox - lo) / res % 1.0, 0.5)  # voxel centres
    rng = np.random.default_rng(0)
    q = rng.uniform(lo, world.bounds[1], (200_000, 3))
    q = q[world.signed_distance(q) <= 0]
    assert len(q) > 1000
    assert all(tuple(i) in occupied for i in np.floor((q - lo) / res).astype(int))
    assert np.all(world.signed_distance(vox) <= 0.5 * math.sqrt(3) * res + 1e-12)
    volume = math.pi * 0.3**2 * 1.5 + 0.8 * 0.6 * 0.7
    assert volume / res**3 <= len(vox) <= 6 * volume / res**3
    assert get_world("empty").voxel_points(0.2).shape == (0, 3)


# ---------------------------------------------------------------------- JSON
def test_json_round_trip_and_validation() -> None:
    w = World((Cylinder(1.0, 2.0, 0.3, 0.0, 3.0), Box((5, 5, 0), (6, 7, 2))),
              ((0, 0, 0), (10, 10, 3)), 0.25, (0.5, 0.5, 1.0), (9.5, 9.5, 1.5), "mixed")
    data = json.loads(json.dumps(w.to_dict()))
    assert data["schema"] == "rota/world" and data["version"] == 1
    assert World.from_dict(data) == w
    f = forest(0.063, 11)
    assert World.from_dict(json.loads(json.dumps(f.to_dict()))) == f

    def field_of(mutate) -> str:
        d = json.loads(json.dumps(w.to_dict()))
        mutate(d)
        with pytest.raises(InputError) as err:
            World.from_dict(d)
        return err.value.field

    assert field_of(lambda d: d.update(schema="other")) == "schema"
    assert field_of(lambda d: d.update(version=2)) == "version"
    assert field_of(lambda d: d.pop("goal")) == "goal"
    assert field_of(lambda d: d["obstacles"][0].update(radius=-1)) == "obstacles[0].radius"
    assert field_of(lambda d: d["obstacles"][0].update(center=[1])) == "obstacles[0].center"
    assert field_of(lambda d: d["obstacles"][1].update(max=[4, 8, 3])) == "obstacles[1].max"
    assert field_of(lambda d: d["obstacles"][1].update(type="cone")) == "obstacles[1].type"
    assert field_of(lambda d: d.update(start=[-1, 0, 0])) == "start"
    assert field_of(lambda d: d["bounds"].update(max=[0, 10, 3])) == "bounds.max"
    assert field_of(lambda d: d.update(robot_radius="big")) == "robot_radius"


# ------------------------------------------------------------------- planner
def test_straight_line_rest_to_rest() -> None:
    for length, v_max, a_max in [(10.0, 2.0, 2.0), (0.5, 2.0, 2.0), (7.0, 3.0, 9.0)]:
        p0, p1 = np.array([1.0, 2.0, 1.0]), np.array([1.0 + length, 2.0, 1.0])
        traj = straight_line(p0, p1, v_max, a_max)
        world = get_world("empty")
        _check_plan(world, traj, v_max, a_max, start=p0, goal=p1)
        v_peak = min(v_max, math.sqrt(a_max * length))  # trapezoid or triangle
        ideal = length / v_peak + v_peak / a_max
        _, v, _ = _dense_samples(traj, 0.01)
        # a trapezoid cruises at v_max; a triangle's peak is rounded over one knot span
        floor = 0.999 * v_max if v_peak == v_max else v_peak - 0.6 * a_max * traj.knot_span
        assert np.linalg.norm(v, axis=1).max() >= floor
        assert ideal <= traj.duration <= ideal + 4 * traj.knot_span
        p, _, _ = _dense_samples(traj, 0.01)
        assert np.abs(p[:, 1:] - p0[1:]).max() < 1e-9  # stays on the line


@pytest.mark.parametrize("density", [0.025, 0.043, 0.063])
def test_planner_collision_free_in_100_forests(density: float) -> None:
    v_max, a_max = 2.0, 2.0
    times, repaired = [], 0
    for seed in range(100):
        world = forest(density, seed)
        t = time.perf_counter()
        result = plan_detailed(world, v_max, a_max)
        times.append(time.perf_counter() - t)
        repaired += result.attempts > 1
        _check_plan(world, result.trajectory, v_max, a_max)
        _, v, _ = _dense_samples(result.trajectory, 0.05)
        assert np.linalg.norm(v, axis=1).max() >= 0.95 * v_max  # open stretches at v_max
    assert np.median(times) < 0.5, f"median planning time {np.median(times):.3f} s"
    assert repaired <= 10


@pytest.mark.parametrize(("v_max", "a_max"), [(1.0, 3.0), (3.0, 9.0), (3.0, 2.0)])
def test_planner_other_limits(v_max: float, a_max: float) -> None:
    for seed in range(10):
        world = forest(0.063, 1000 + seed)
        _check_plan(world, plan(world, v_max, a_max), v_max, a_max)


def test_replanning_from_moving_state() -> None:
    v_max, a_max = 2.0, 2.0
    for seed in range(20):
        world = forest(0.043, 500 + seed)
        first = plan(world, v_max, a_max)
        tau = np.random.default_rng(seed).uniform(0.2, 0.8) * first.duration
        p, v, _ = first.evaluate([tau])
        traj = plan(world, v_max, a_max, start=p[0], start_velocity=v[0])
        _check_plan(world, traj, v_max, a_max, start=p[0], v0=v[0])
        if seed < 5:  # faster than v_max (a re-timed trajectory may be): brake down to it
            traj = plan(world, v_max, a_max, start=p[0], start_velocity=1.5 * v[0])
            _check_plan(world, traj, v_max, a_max, start=p[0], v0=1.5 * v[0])


def test_replanning_that_cannot_brake_in_time() -> None:
    world = World((Cylinder(5.0, 5.0, 0.3, 0.0, 3.0),), ((0, 0, 0), (10, 10, 3)),
                  start=(4.0, 5.0, 1.0), goal=(9.0, 9.0, 1.0))
    v0 = np.array([3.0, 0.0, 0.0])  # 0.4 m from the trunk's reach, heading straight at it
    with pytest.raises(PlanningError, match="start velocity"):
        plan(world, 2.0, 2.0, start_velocity=v0)
    result = plan_detailed(world, 2.0, 2.0, start_velocity=v0, strict=False)
    assert result.max_acceleration > 2.0
    p, v, _ = _dense_samples(result.trajectory, 0.01)
    assert np.all(world.signed_distance(p) >= world.robot_radius)  # over-limit, never colliding
    np.testing.assert_allclose(v[0], v0, atol=1e-9)


def test_planner_errors() -> None:
    world = get_world("pillar")
    with pytest.raises(PlanningError, match="goal"):
        plan(world, 2.0, 2.0, goal=(10.0, 10.75, 1.0))  # inside the pillar's reach
    walls = (Box((15, 15, 0), (20, 15.5, 3)), Box((15, 15, 0), (15.5, 20, 3)))
    boxed = World(walls, ((0, 0, 0), (20, 20, 3)), start=(1, 1, 1), goal=(18, 18, 1))
    with pytest.raises(PlanningError, match="no"):
        plan(boxed, 2.0, 2.0)
    for kwargs, field in [({"v_max": 0.0}, "v_max"), ({"a_max": -1.0}, "a_max"),
                          ({"start": (1, 2)}, "start"), ({"resolution": float("nan")},
                                                          "resolution")]:
        args = {"v_max": 2.0, "a_max": 2.0, **kwargs}
        with pytest.raises(InputError) as err:
            plan(world, **args)
        assert err.value.field == field


def test_planner_simple_worlds_and_altitude_change() -> None:
    for name in ("empty", "pillar"):
        world = get_world(name)
        result = plan_detailed(world, 2.0, 2.0)
        assert len(result.waypoints) == 2  # straight: no detour needed
        _check_plan(world, result.trajectory, 2.0, 2.0)
    # a wall with a window, start and goal at different altitudes: a 3-D search
    wall = (Box((3.0, 0.0, 0.0), (3.4, 6.0, 1.0)), Box((3.0, 0.0, 2.6), (3.4, 6.0, 3.0)),
            Box((3.0, 0.0, 1.0), (3.4, 2.2, 2.6)), Box((3.0, 3.8, 1.0), (3.4, 6.0, 2.6)))
    world = World(wall, ((0, 0, 0), (6, 6, 3)), start=(0.5, 1.0, 0.8), goal=(5.5, 5.0, 2.4))
    result = plan_detailed(world, 2.0, 2.0)
    _check_plan(world, result.trajectory, 2.0, 2.0)
    p, _, _ = _dense_samples(result.trajectory, 0.01)
    crossing = p[np.argmin(np.abs(p[:, 0] - 3.2))]
    assert 1.0 < crossing[2] < 2.6 and 2.2 < crossing[1] < 3.8  # through the window


def test_repair_keeps_trajectories_collision_free() -> None:
    # without clearance the fitted spline often grazes an obstacle; the check must catch
    # every case and the repaired plan must be clean
    attempts = []
    for seed in range(30):
        world = forest(0.063, seed)
        result = plan_detailed(world, 3.0, 2.0, clearance=0.0)
        attempts.append(result.attempts)
        _check_plan(world, result.trajectory, 3.0, 2.0)
        assert result.min_clearance > 0
    assert max(attempts) > 1  # the repair path was exercised
