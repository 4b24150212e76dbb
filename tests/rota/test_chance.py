"""Tests for rota.chance: Eq. 14 probability, closed-form speed limits, Monte-Carlo checks."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.stats import binom, ncx2

from rota.braking import find_braking_zones
from rota.chance import (
    ChanceParams,
    UncertaintyModel,
    collision_probability,
    monte_carlo_collision_probability,
    speed_limits,
)
from rota.errors import InputError
from rota.voxelmap import VoxelMap

PAPER = UncertaintyModel(m=0.2, b=-0.1)


def _line(dists: list[float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Robot at the origin, obstacle on +x at each distance, direction towards it."""
    n = len(dists)
    p = np.zeros((n, 3))
    o = np.column_stack([dists, np.zeros(n), np.zeros(n)])
    u = np.tile([1.0, 0.0, 0.0], (n, 1))
    return p, u, o


# ----------------------------------------------------------- reference values
@pytest.mark.parametrize(
    ("delta", "expected"),
    [(1e-2, (2.65, 1.57, 0.93)), (1e-4, (1.84, 1.17, 0.77))],
)
@pytest.mark.parametrize("semi", [(0.0, 0.0, 0.0), (1e-6, 1e-6, 1e-6)])
def test_reference_numbers(delta: float, expected: tuple, semi: tuple) -> None:
    params = ChanceParams(delta=delta, semi_axes=semi, obstacle_std=(0, 0, 0), v_floor=0.0,
                          v_max=10.0)
    p, u, o = _line([1.0, 0.5, 0.2])
    sl = speed_limits(p, u, o, PAPER, params)
    np.testing.assert_allclose(sl.limit, expected, atol=0.02)
    assert not sl.infeasible.any()
    # the closed-form limit sits exactly on the constraint
    pr = collision_probability(p, u * sl.limit[:, None], o, PAPER, params)
    np.testing.assert_allclose(pr, delta, rtol=1e-6)


def test_default_params_are_the_papers() -> None:
    params = ChanceParams()
    assert params.delta == 1e-4 and params.z == pytest.approx(3.719, abs=1e-3)
    assert PAPER == UncertaintyModel()


def test_uncertainty_model_std() -> None:
    model = UncertaintyModel(m=0.2, b=-0.1, floor=0.02, per_axis=True)
    v = np.array([[0.0, -1.0, 3.0], [0.4, 0.6, -0.6]])
    np.testing.assert_allclose(model.std(v), [[0.02, 0.1, 0.5], [0.02, 0.02, 0.02]])
    paper_axis = UncertaintyModel(per_axis=True)
    np.testing.assert_allclose(paper_axis.std([[-2.0, 0.0, 0.5]]), [[0.3, 0.0, 0.0]])
    # default: the speed on every axis (frame-invariant)
    np.testing.assert_allclose(PAPER.std([[3.0, 4.0, 0.0]]), [[0.9, 0.9, 0.9]])
    np.testing.assert_allclose(PAPER.std([[0.3, 0.0, 0.0]]), [[0.0, 0.0, 0.0]])


def test_default_speed_limit_is_frame_invariant() -> None:
    """Rotating the scene about z does not change the limit (it does per axis)."""
    params = ChanceParams(delta=1e-4, semi_axes=(0.3, 0.3, 0.3), v_floor=0.0, v_max=1e3)
    lims = {}
    for per_axis in (False, True):
        model = UncertaintyModel(per_axis=per_axis)
        out = []
        for angle in (0.0, np.pi / 4):
            rot = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0],
                            [0, 0, 1]])
            p, u, o = np.zeros((1, 3)), rot @ [1.0, 0, 0], rot @ [0.0, 0.8, 0]
            out.append(speed_limits(p, u[None], o[None], model, params).unclamped[0])
        lims[per_axis] = out
    assert lims[False][0] == pytest.approx(lims[False][1], rel=1e-9)
    assert lims[True][0] != pytest.approx(lims[True][1], rel=1e-3)


# ------------------------------------------------- closed form vs bisection
def _bisect_limit(p, u, o, model, params, hi=1e3, iters=80):
    """Largest v in [0, hi] with Pr(v u) <= delta by bisection (nan if none, inf if all)."""
    def ok(v):
        return collision_probability(p, u * v[:, None], o, model, params) <= params.delta

    n = len(p)
    lo_v, hi_v = np.zeros(n), np.full(n, hi)
    feas0, feas_hi = ok(lo_v), ok(hi_v)
    for _ in range(iters):
        mid = 0.5 * (lo_v + hi_v)
        good = ok(mid)
        lo_v = np.where(good, mid, lo_v)
        hi_v = np.where(good, hi_v, mid)
    return np.where(~feas0, np.nan, np.where(feas_hi, np.inf, lo_v))


axes_st = st.one_of(
    st.just((0.0, 0.0, 0.0)),
    st.tuples(*[st.floats(0.05, 0.6)] * 3),
)


@settings(max_examples=150, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    semi=axes_st,
    ostd=st.tuples(*[st.floats(0.0, 0.08)] * 3),
    m=st.one_of(st.just(0.0), st.floats(1e-6, 0.5)),
    b=st.floats(-0.3, 0.2),
    floor=st.floats(0.0, 0.05),
    delta=st.floats(1e-7, 0.45),
)
def test_closed_form_matches_bisection(seed, semi, ostd, m, b, floor, delta) -> None:
    rng = np.random.default_rng(seed)
    n = 16
    model = UncertaintyModel(m=m, b=b, floor=floor, per_axis=bool(seed % 2))
    params = ChanceParams(delta=delta, semi_axes=semi, obstacle_std=ostd, v_floor=0.0,
                          v_max=1e6)
    p = rng.normal(size=(n, 3))
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    o = p + dirs * rng.uniform(0.05, 3.0, (n, 1))
    u = rng.normal(size=(n, 3))
    u[0] = [1.0, 0.0, 0.0]  # axis-aligned: two axes never leave the floor
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    sl = speed_limits(p, u, o, model, params)
    ref = _bisect_limit(p, u, o, model, params)
    np.testing.assert_array_equal(sl.infeasible, np.isnan(ref))
    fin = np.isfinite(ref)
    closed = sl.unclamped
    assert np.all(np.isinf(closed[np.isinf(ref)]) | (closed[np.isinf(ref)] >= 1e3 * (1 - 1e-9)))
    close = np.abs(closed[fin] - ref[fin]) <= 1e-6 * (1 + ref[fin])
    if not close.all():  # flat crossing: accept if both speeds give (almost) the same Pr
        idx = np.flatnonzero(fin)[~close]
        pa = collision_probability(p[idx], u[idx] * closed[idx, None], o[idx], model, params)
        pb = collision_probability(p[idx], u[idx] * ref[idx, None], o[idx], model, params)
        np.testing.assert_allclose(pa, pb, atol=1e-9 + 1e-6 * delta)
    # the limit itself satisfies the constraint (up to rounding)
    feas = ~sl.infeasible & np.isfinite(closed)
    pr = collision_probability(p[feas], u[feas] * closed[feas, None], o[feas], model, params)
    assert np.all(pr <= delta * (1 + 1e-6) + 1e-12)


# -------------------------------------------------------------- monotonicity
def _zone_samples():
    """Braking-zone samples of a path passing 0.6 m from a pillar (0.1 m voxels)."""
    x = np.linspace(0.0, 10.0, 201)
    p = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    v = np.tile([1.0, 0.0, 0.0], (len(x), 1))
    z = np.arange(-1.0, 1.01, 0.1)
    pillar = np.column_stack([np.full_like(z, 5.0), np.full_like(z, 0.6), z])
    vmap = VoxelMap.from_points(pillar, 0.1, origin=[-0.05] * 3)
    d, o = vmap.nearest(p)
    bz = find_braking_zones(x, p, v, d, o)
    k = bz.speed_limit_mask
    assert k.sum() >= 10
    return p[k], v[k], bz.nearest[k]


def test_higher_m_lowers_limits() -> None:
    p, u, o = _zone_samples()
    params = ChanceParams(v_floor=0.0, v_max=1e3)
    lims = [speed_limits(p, u, o, UncertaintyModel(m=m), params).unclamped
            for m in (0.1, 0.2, 0.3, 0.5)]
    for a, b in zip(lims, lims[1:], strict=False):
        assert np.all(b <= a) and np.any(b < a)


def test_larger_delta_raises_limits_and_delta_to_one_is_inactive() -> None:
    p, u, o = _zone_samples()
    lims = [speed_limits(p, u, o, PAPER, ChanceParams(delta=d, v_floor=0.0, v_max=1e3)).unclamped
            for d in (1e-6, 1e-4, 1e-2, 0.1, 0.3)]
    for a, b in zip(lims, lims[1:], strict=False):
        assert np.all(b >= a) and np.any(b > a)
    for d in (0.5, 0.9, 1 - 1e-12):
        sl = speed_limits(p, u, o, PAPER, ChanceParams(delta=d, v_max=2.5))
        np.testing.assert_array_equal(sl.limit, 2.5)
        assert not sl.infeasible.any()


# --------------------------------------------------------- infeasible / clamp
def test_inside_ellipsoid_is_infeasible_and_floored() -> None:
    params = ChanceParams(semi_axes=(0.3, 0.3, 0.2), v_floor=0.4)
    p, u, o = _line([0.25, 0.3, 0.5])
    sl = speed_limits(p, u, o, PAPER, params)
    np.testing.assert_array_equal(sl.infeasible, [True, True, False])
    assert sl.limit[0] == 0.4 and sl.limit[1] == 0.4 and np.isnan(sl.unclamped[0])
    # too much obstacle uncertainty: even hovering violates Delta
    big = ChanceParams(obstacle_std=(0.2, 0.2, 0.2))
    sl = speed_limits(*_line([0.5]), PAPER, big)
    assert sl.infeasible[0] and sl.limit[0] == big.v_floor and sl.violated[0]


def test_clamp_and_floored_and_no_obstacle() -> None:
    # b = 0: uncertainty from the first m/s, so a close obstacle allows less than v_floor
    model = UncertaintyModel(m=0.2, b=0.0)
    params = ChanceParams(v_floor=0.5, v_max=2.0, obstacle_std=(0, 0, 0))
    p, u, o = _line([0.32, 1.0, 5.0])
    o[2] = np.nan  # no obstacle
    sl = speed_limits(p, u, o, model, params)
    assert sl.limit[2] == 2.0 and np.isinf(sl.unclamped[2]) and not sl.infeasible[2]
    assert sl.limit[0] == 0.5 and sl.floored[0] and sl.unclamped[0] < 0.5
    assert 0.5 < sl.limit[1] < 2.0 and not sl.violated[1]


def test_zero_direction_means_speed_independent() -> None:
    params = ChanceParams(v_floor=0.0, v_max=3.0)
    p, _, o = _line([0.5, 0.25])
    sl = speed_limits(p, np.zeros((2, 3)), o, PAPER, params)
    assert sl.limit[0] == 3.0 and sl.infeasible[1]


def test_collision_probability_edge_cases() -> None:
    params = ChanceParams(semi_axes=(0.3, 0.3, 0.3), obstacle_std=(0, 0, 0))
    p, _, o = _line([0.5, 0.2, 0.0])
    pr = collision_probability(p, np.zeros((3, 3)), o, PAPER, params)  # zero variance
    np.testing.assert_array_equal(pr, [0.0, 1.0, 1.0])
    o[0] = np.nan
    assert collision_probability(p, np.ones((3, 3)), o, PAPER, params)[0] == 0.0
    # inside the ellipsoid with noise: at least 1/2
    pr = collision_probability(p[1:2], [[3.0, 3.0, 3.0]], o[1:2], PAPER, params)
    assert 0.5 < pr[0] < 1.0


# --------------------------------------------------------------- Monte Carlo
def test_monte_carlo_matches_exact_sphere_probability() -> None:
    """Isotropic case: Pr(|x| <= r), x ~ N(d, s^2 I), is a noncentral chi-square CDF."""
    r, so = 0.3, 0.03
    params = ChanceParams(delta=0.01, semi_axes=(r, r, r), obstacle_std=(so, so, so))
    cases = [(0.5, 2.0), (0.4, 1.5), (0.35, 1.0)]
    p, _, o = _line([c[0] for c in cases])
    vel = np.array([[c[1]] * 3 for c in cases])
    n = 40_000
    mc = monte_carlo_collision_probability(p, vel, o, PAPER, params, n, np.random.default_rng(7))
    s = np.hypot(PAPER.std(vel)[:, 0], so)
    exact = ncx2.cdf((r / s) ** 2, 3, (o[:, 0] / s) ** 2)
    tol = 5 * np.sqrt(exact * (1 - exact) / n)
    np.testing.assert_array_less(np.abs(mc - exact), tol)


def test_limits_hold_under_monte_carlo_in_a_braking_zone() -> None:
    """At the computed limit each braking sample's true probability is <= Delta."""
    delta = 0.01
    params = ChanceParams(delta=delta, v_floor=0.0, v_max=1e3)
    p, u, o = _zone_samples()
    sl = speed_limits(p, u, o, PAPER, params)
    assert not sl.violated.any()
    vel = u * sl.limit[:, None]
    n = 20_000
    mc = monte_carlo_collision_probability(p, vel, o, PAPER, params, n, np.random.default_rng(11))
    # one-sided binomial bound with a family-wise false-alarm rate of 1e-6
    bound = binom.ppf(1 - 1e-6 / len(p), n, delta)
    assert np.all(mc * n <= bound), (mc, bound / n)
    lin = collision_probability(p, vel, o, PAPER, params)
    bound_by_delta = sl.unclamped < params.v_max
    assert bound_by_delta.sum() >= 10
    np.testing.assert_allclose(lin[bound_by_delta], delta, rtol=1e-6)
    # at the closest approach the obstacle is abeam: with per-axis std (Eq. 15) motion
    # along x adds no uncertainty towards it, so the speed is not limited there
    assert np.all(lin[~bound_by_delta] <= delta)


@settings(max_examples=15, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    semi=st.tuples(*[st.floats(0.15, 0.5)] * 3),
    spd=st.floats(0.6, 4.0),
)
def test_linearisation_is_conservative(seed: int, semi: tuple, spd: float) -> None:
    """MC (true ellipsoid) <= linearised Eq. 14 probability, within sampling error."""
    rng = np.random.default_rng(seed)
    params = ChanceParams(delta=0.01, semi_axes=semi, obstacle_std=(0.03, 0.02, 0.04))
    n = 8
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    # nominal position 1.05-1.6 ellipsoid "radii" away along a random direction
    scale = rng.uniform(1.05, 1.6, (n, 1)) * np.asarray(semi)
    p = rng.normal(size=(n, 3))
    o = p + dirs * scale
    vel = rng.normal(size=(n, 3))
    vel *= spd / np.linalg.norm(vel, axis=1, keepdims=True)
    lin = collision_probability(p, vel, o, PAPER, params)
    assume(np.any(lin > 1e-3))
    n_mc = 20_000
    mc = monte_carlo_collision_probability(p, vel, o, PAPER, params, n_mc, rng)
    bound = binom.ppf(1 - 1e-7, n_mc, lin) / n_mc
    assert np.all(mc <= bound + 1e-12), (mc, lin)


def test_linearisation_tight_for_small_noise_strictly_conservative_for_large() -> None:
    params = ChanceParams(delta=0.01, semi_axes=(2.0, 2.0, 2.0), obstacle_std=(0, 0, 0))
    p, _, o = _line([2.2, 2.4])
    vel = np.array([[1.3, 0.0, 0.0], [6.0, 6.0, 6.0]])
    lin = collision_probability(p, vel, o, PAPER, params)
    mc = monte_carlo_collision_probability(p, vel, o, PAPER, params, 200_000,
                                           np.random.default_rng(3))
    # small std vs the radius: the tangent plane is a good approximation
    assert 0.8 * lin[0] <= mc[0] <= lin[0] * 1.05
    # large isotropic std: the half-space over-counts a lot
    assert mc[1] < 0.75 * lin[1]


def test_monte_carlo_point_robot_and_errors() -> None:
    p, u, o = _line([0.5])
    point = ChanceParams(semi_axes=(0, 0, 0))
    assert monte_carlo_collision_probability(p, u, o, PAPER, point, 10, 0)[0] == 0.0
    with pytest.raises(InputError) as e:
        monte_carlo_collision_probability(p, u, o, PAPER, point, 0, 0)
    assert e.value.field == "n_samples"


# ------------------------------------------------------------------- inputs
@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"delta": 0.0}, "delta"),
        ({"delta": 1.0}, "delta"),
        ({"delta": math.nan}, "delta"),
        ({"semi_axes": (0.3, 0.0, 0.3)}, "semi_axes"),
        ({"semi_axes": (0.3, 0.3)}, "semi_axes"),
        ({"semi_axes": (0.3, -0.3, 0.3)}, "semi_axes[1]"),
        ({"obstacle_std": (0.0, -0.1, 0.0)}, "obstacle_std[1]"),
        ({"v_floor": -0.1}, "v_floor"),
        ({"v_max": 0.2, "v_floor": 0.5}, "v_max"),
        ({"v_max": math.inf}, "v_max"),
    ],
)
def test_bad_chance_params(kwargs: dict, field: str) -> None:
    with pytest.raises(InputError) as e:
        ChanceParams(**kwargs)
    assert e.value.field == field


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [({"m": -0.1}, "m"), ({"b": math.inf}, "b"), ({"floor": -0.01}, "floor"), ({"m": "1"}, "m")],
)
def test_bad_model(kwargs: dict, field: str) -> None:
    with pytest.raises(InputError) as e:
        UncertaintyModel(**kwargs)
    assert e.value.field == field


def test_bad_arrays_name_field() -> None:
    p, u, o = _line([1.0, 2.0])
    with pytest.raises(InputError) as e:
        speed_limits(p, u[:1], o)
    assert e.value.field == "direction"
    with pytest.raises(InputError) as e:
        speed_limits(p, u, np.array([[1.0, 0, 0], [np.inf, 0, 0]]))
    assert e.value.field == "obstacle[1][0]"
    with pytest.raises(InputError) as e:
        collision_probability(np.array([[0.0, np.nan, 0.0]] * 2), u, o)
    assert e.value.field == "p_mean[0][1]"
