"""Tests for rota.braking: braking points (Eq. 6) and interval refinement (Alg. 1)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rota.braking import BrakingParams, find_braking_zones, refine_intervals
from rota.errors import InputError
from rota.voxelmap import VoxelMap

RES = 0.1
#: The paper's Eq. 6 (fixed 1 m threshold, no risk): the mechanics tested below.
PAPER = BrakingParams(d_th=1.0, risk=False)
ORIGIN = np.full(3, -RES / 2)  # voxel centres on multiples of RES


def pillar(x: float, y: float) -> np.ndarray:
    z = np.arange(-1.0, 1.01, RES)
    return np.column_stack([np.full_like(z, x), np.full_like(z, y), z])


def straight_path(x0: float, x1: float, n: int = 201) -> tuple[np.ndarray, ...]:
    x = np.linspace(x0, x1, n)
    p = np.column_stack([x, np.zeros(n), np.zeros(n)])
    v = np.tile([1.0, 0.0, 0.0], (n, 1)) * np.sign(x1 - x0)
    tau = np.abs(x - x0)  # 1 m/s
    return tau, p, v


def zones(obstacles: np.ndarray, tau, p, v, params: BrakingParams = PAPER):
    m = VoxelMap.from_points(obstacles, RES, ORIGIN)
    d, o = m.nearest(p)
    return find_braking_zones(tau, p, v, d, o, params)


def test_pillar_brakes_before_closest_approach_only() -> None:
    tau, p, v = straight_path(0.0, 10.0)
    bz = zones(pillar(5.0, 0.3), tau, p, v)
    x = p[:, 0]
    # nearest voxel is at (5, 0.3, 0): within 1 m for |x - 5| <= sqrt(1 - 0.09)
    expected = (np.abs(x - 5.0) <= math.sqrt(1 - 0.09) + 1e-12) & (x <= 5.0 + 1e-12)
    np.testing.assert_array_equal(bz.mask, expected)
    assert bz.mask.sum() == 20  # x = 4.05 ... 5.0 step 0.05
    assert x[bz.mask].max() == pytest.approx(5.0)  # closest approach: dot == 0 counts
    assert not bz.mask[x > 5.0 + 1e-9].any()  # obstacle behind: never brakes
    np.testing.assert_allclose(bz.distance[bz.mask].min(), 0.3)
    assert bz.intervals == ((pytest.approx(4.05), pytest.approx(5.0)),)
    np.testing.assert_array_equal(bz.speed_limit_mask, bz.mask)
    assert bz.nearest.shape == (201, 3) and bz.distance.shape == (201,)


def test_pillar_behind_the_vehicle_changes_nothing() -> None:
    tau, p, v = straight_path(0.0, 10.0)
    base = zones(pillar(5.0, 0.3), tau, p, v)
    # a second pillar 0.5 m behind the start: close to the first samples, but behind
    both = zones(np.vstack([pillar(5.0, 0.3), pillar(-0.5, 0.3)]), tau, p, v)
    assert both.distance[0] == pytest.approx(math.hypot(0.5, 0.3))
    np.testing.assert_array_equal(both.mask, base.mask)
    assert both.intervals == base.intervals
    # a path that starts just past the pillar and flies away never brakes
    tau2, p2, v2 = straight_path(5.05, 10.0)
    away = zones(pillar(5.0, 0.3), tau2, p2, v2)
    assert (away.distance <= 1.0).sum() > 5
    assert not away.mask.any() and away.intervals == ()
    # the same segment flown towards the pillar brakes
    tau3, p3, v3 = straight_path(10.0, 5.05)
    towards = zones(pillar(5.0, 0.3), tau3, p3, v3)
    assert towards.mask.sum() == (towards.distance <= 1.0).sum()


def test_empty_map_no_braking() -> None:
    tau, p, v = straight_path(0.0, 3.0, 31)
    bz = find_braking_zones(tau, p, v, np.full(31, np.inf), np.full((31, 3), np.nan))
    assert not bz.mask.any()
    bz = find_braking_zones(tau, p, v, np.full(31, np.inf), np.full((31, 3), np.nan), PAPER)
    assert not bz.mask.any() and bz.intervals == () and not bz.refined_mask.any()


def _synthetic(on: list[tuple[float, float]], t_end: float = 10.0, dt: float = 0.1):
    """A path whose braking points are exactly the tau ranges in ``on``."""
    n = int(round(t_end / dt)) + 1
    tau = np.round(np.arange(n) * dt, 9)
    p = np.column_stack([tau, np.zeros(n), np.zeros(n)])
    v = np.tile([1.0, 0, 0], (n, 1))
    close = np.zeros(n, bool)
    for a, b in on:
        close |= (tau >= a - 1e-9) & (tau <= b + 1e-9)
    obstacle = p + np.array([0.5, 0.0, 0.0])  # ahead
    distance = np.where(close, 0.5, 5.0)
    return tau, p, v, distance, obstacle, close


def test_refinement_drops_short_and_merges_gaps() -> None:
    # T = 10: drop <= min(1.0, 0.5) = 0.5, merge gaps <= min(0.5, 0.25) = 0.25
    on = [(1.0, 1.3), (3.0, 4.0), (4.2, 5.0), (7.0, 8.0), (9.0, 9.3), (9.5, 9.8)]
    tau, p, v, d, o, close = _synthetic(on)
    bz = find_braking_zones(tau, p, v, d, o, PAPER)
    np.testing.assert_array_equal(bz.mask, close)  # raw mask keeps everything
    assert len(bz.raw_intervals) == 6
    got = [(round(a, 6), round(b, 6)) for a, b in bz.intervals]
    # (1.0, 1.3) dropped; 3-4 and 4.2-5 merged; 9.0-9.3 + 9.5-9.8 merged, then kept
    assert got == [(3.0, 5.0), (7.0, 8.0), (9.0, 9.8)]
    expected_refined = np.zeros_like(close)
    for a, b in got:
        expected_refined |= (tau >= a - 1e-9) & (tau <= b + 1e-9)
    np.testing.assert_array_equal(bz.refined_mask, expected_refined)
    # the dropped short approach still gets a speed limit
    assert bz.speed_limit_mask[(tau >= 1.0) & (tau <= 1.3)].all()
    assert not bz.refined_mask[(tau >= 1.0) & (tau <= 1.3)].any()


def test_refinement_thresholds_scale_with_short_trajectories() -> None:
    # T = 2: drop <= 0.2, merge <= 0.1
    on = [(0.2, 0.3), (0.6, 0.9), (1.0, 1.2), (1.5, 1.9)]
    tau, p, v, d, o, _ = _synthetic(on, t_end=2.0, dt=0.05)
    bz = find_braking_zones(tau, p, v, d, o, PAPER)
    got = [(round(a, 6), round(b, 6)) for a, b in bz.intervals]
    assert got == [(0.6, 1.2), (1.5, 1.9)]
    # explicit parameters override the defaults
    bz2 = find_braking_zones(tau, p, v, d, o, BrakingParams(d_th=1.0, risk=False, min_interval=0.0,
                                                           merge_gap=0.0))
    assert len(bz2.intervals) == 4


def test_refine_intervals_unit() -> None:
    assert refine_intervals([], 0.5, 0.25) == ()
    assert refine_intervals([(0.0, 0.0)], 0.0, 0.0) == ()  # zero length is "no longer than 0"
    assert refine_intervals([(2.0, 3.0), (0.0, 1.0)], 0.5, 1.0) == ((0.0, 3.0),)


def test_horizon_length_limits_checked_path() -> None:
    tau, p, v, d, o, close = _synthetic([(0.0, 10.0)])
    bz = find_braking_zones(tau, p, v, d, o, BrakingParams(d_th=1.0, risk=False,
                                                                horizon_length=3.0))
    np.testing.assert_array_equal(bz.mask, tau <= 3.0 + 1e-9)
    assert find_braking_zones(tau, p, v, d, o, PAPER).mask.all()


def test_d_th_threshold() -> None:
    tau, p, v = straight_path(0.0, 10.0)
    small = zones(pillar(5.0, 0.3), tau, p, v, BrakingParams(d_th=0.3 + 1e-9, risk=False))
    assert small.mask.sum() == 1  # only the closest approach (distance exactly 0.3)
    none = zones(pillar(5.0, 0.3), tau, p, v, BrakingParams(d_th=0.29, risk=False))
    assert not none.mask.any()


@settings(max_examples=50, deadline=None)
@given(
    st.lists(st.floats(0.0, 3.0), min_size=2, max_size=60),
    st.floats(0.0, 2.0),
    st.integers(0, 2**32 - 1),
)
def test_mask_is_exactly_eq6(dists: list[float], d_th: float, seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = len(dists)
    tau = np.cumsum(rng.uniform(0.01, 0.3, n))
    p = rng.normal(size=(n, 3))
    v = rng.normal(size=(n, 3))
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    d = np.array(dists)
    o = p + d[:, None] * direction
    bz = find_braking_zones(tau, p, v, d, o, BrakingParams(d_th=d_th, risk=False))
    want = (d <= d_th) & (np.einsum("ij,ij->i", o - p, v) >= 0)
    np.testing.assert_array_equal(bz.mask, want)
    # refined intervals are sorted, disjoint, longer than min_interval, gaps > merge_gap
    T = tau[-1] - tau[0]
    min_iv, gap = min(0.1 * T, 0.5), min(0.05 * T, 0.25)
    iv = bz.intervals
    assert all(b - a > min_iv for a, b in iv)
    assert all(iv[k + 1][0] - iv[k][1] > gap for k in range(len(iv) - 1))
    # every refined interval starts and ends at a raw braking point
    for a, b in iv:
        assert bz.mask[np.searchsorted(tau, a)] and bz.mask[np.searchsorted(tau, b)]


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"tau": [0.0, 0.2, 0.1]}, "tau"),
        ({"tau": [[0.0, 0.1, 0.2]]}, "tau"),
        ({"p": np.zeros((2, 3))}, "p"),
        ({"v": np.full((3, 3), np.nan)}, "v[0][0]"),
        ({"distance": [0.1, -1.0, 0.3]}, "distance[1]"),
        ({"distance": [0.1, np.nan, 0.3]}, "distance[1]"),
        ({"obstacle": np.full((3, 3), np.inf)}, "obstacle[0][0]"),
    ],
)
def test_bad_input_names_field(change: dict, field: str) -> None:
    args = {"tau": [0.0, 0.1, 0.2], "p": np.zeros((3, 3)), "v": np.ones((3, 3)),
            "distance": [0.5, 0.5, 0.5], "obstacle": np.ones((3, 3))}
    args.update(change)
    with pytest.raises(InputError) as e:
        find_braking_zones(**args)
    assert e.value.field == field


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [({"d_th": -1.0}, "d_th"), ({"risk": 1}, "risk"), ({"d_th": math.inf}, "d_th"),
     ({"merge_gap": -0.1}, "merge_gap"),
     ({"min_interval": "x"}, "min_interval"), ({"horizon_length": math.nan}, "horizon_length")],
)
def test_bad_params(kwargs: dict, field: str) -> None:
    with pytest.raises(InputError) as e:
        BrakingParams(**kwargs)
    assert e.value.field == field
