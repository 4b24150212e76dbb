"""Braking zones follow the risk (docs/safety-model.md, section 2): checked against a
brute-force evaluation of the chance limit along random paths."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rota import SampledTrajectory
from rota.braking import BrakingParams, find_braking_zones
from rota.chance import (
    MIN_SEMI_AXIS_M,
    ChanceParams,
    UncertaintyModel,
    collision_probability,
    risk_reach,
)
from rota.errors import InputError
from rota.robust import Safety, assess
from rota.voxelmap import VoxelMap

RES = 0.1


def _world(rng: np.random.Generator) -> tuple[SampledTrajectory, VoxelMap]:
    """A wiggly path through 8 x 8 x 2 m with 30 random pillars and loose voxels."""
    n = 12
    x = np.linspace(0.0, 8.0, n)
    p = np.column_stack([x, rng.uniform(-1.0, 1.0, n), rng.uniform(0.8, 1.2, n)])
    t = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    traj = SampledTrajectory(t=t, p=p)
    pts = []
    for cx, cy in rng.uniform([0.0, -3.0], [8.0, 3.0], (30, 2)):
        z = np.arange(0.0, 2.5, RES)
        pts.append(np.column_stack([np.full_like(z, cx), np.full_like(z, cy), z]))
    pts.append(rng.uniform([0.0, -3.0, 0.0], [8.0, 3.0, 2.5], (40, 3)))
    return traj, VoxelMap.from_points(np.concatenate(pts), RES)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), m=st.floats(0.0, 0.6), b=st.floats(-0.3, 0.2),
       floor=st.floats(0.0, 0.15), log_delta=st.floats(-6.0, -1.0),
       radius=st.just(0.0) | st.floats(MIN_SEMI_AXIS_M, 0.4), v_max=st.floats(0.8, 4.0),
       memory=st.sampled_from([0.0, 1.0, 2.5]))
def test_zones_are_where_the_chance_limit_falls_below_v_max(
        seed: int, m: float, b: float, floor: float, log_delta: float, radius: float,
        v_max: float, memory: float) -> None:
    rng = np.random.default_rng(seed)
    traj, vmap = _world(rng)
    model = UncertaintyModel(m=m, b=b, floor=floor, memory_s=memory)
    chance = ChanceParams(delta=10.0 ** log_delta, semi_axes=(radius,) * 3,
                          obstacle_std=(0.03,) * 3, v_floor=min(0.3, v_max / 2), v_max=v_max)
    tau = np.linspace(*traj.domain, 400)
    pos, vel, _ = traj.evaluate(tau)
    seen = assess(traj, tau, Safety(map=vmap, uncertainty=model, chance=chance), pos, vel)

    # brute force: every voxel against every node, no k-d tree, no search radius
    occ = vmap.occupied
    dist_all = np.linalg.norm(pos[:, None, :] - occ[None, :, :], axis=2)
    near = np.argmin(dist_all, axis=1)
    o = occ[near]
    u = vel / np.linalg.norm(vel, axis=1, keepdims=True)
    pr = collision_probability(pos, v_max * u, o, model, chance)
    ahead = np.einsum("ij,ij->i", o - pos, vel) >= 0.0
    want = ahead & (pr > chance.delta)
    # nodes within a hair of the bound can go either way in floating point
    sure = np.abs(pr - chance.delta) > 1e-9 * chance.delta
    np.testing.assert_array_equal(seen.zones.mask[sure], want[sure])
    # the nearest obstacle is the riskiest one (isotropic robot and model), so no other
    # obstacle could have made a braking point
    for i in np.flatnonzero(sure & ~want & ahead)[:20]:
        others = collision_probability(np.repeat(pos[i:i + 1], len(occ), 0),
                                       np.repeat(v_max * u[i:i + 1], len(occ), 0), occ,
                                       model, chance)
        assert others.max() <= chance.delta * (1 + 1e-9)
    # every braking point lies within the reach, and the reach is tight (isotropic)
    reach = risk_reach(model, chance)
    assert np.all(seen.zones.distance[seen.zones.mask] <= reach + 1e-9)
    # outside braking points (and their memory windows) nothing limits the speed
    free = ~seen.zones.mask & ~seen.approach & ~seen.outside
    assert np.all(np.isinf(seen.speed_limits[free]))
    assert np.all(seen.speed_limits[seen.zones.mask] < v_max) or seen.chance.infeasible.any()


@pytest.mark.parametrize("radius", [0.0, 0.3])
def test_reach_is_where_the_limit_reaches_v_max(radius: float) -> None:
    """Just inside the reach the limit is below v_max, just outside it is not."""
    model = UncertaintyModel(m=0.3, b=0.05)
    chance = ChanceParams(delta=1e-4, semi_axes=(radius,) * 3, v_max=2.0)
    reach = risk_reach(model, chance)
    p = np.zeros((2, 3))
    o = np.array([[0.0, reach * (1 - 1e-6), 0.0], [0.0, reach * (1 + 1e-6), 0.0]])
    u = np.tile([1.0, 0.0, 0.0], (2, 1))
    pr = collision_probability(p, 2.0 * u, o, model, chance)
    assert pr[0] > chance.delta > pr[1]
    # obstacle abeam (ahead . v = 0 counts as ahead): zones exactly at the inner point
    bz = find_braking_zones([0.0, 1.0], p, u, np.linalg.norm(o, axis=1), o, None, model,
                            chance)
    assert bz.mask.tolist() == [True, False]


def test_d_th_only_adds_and_paper_mode_is_eq6() -> None:
    rng = np.random.default_rng(7)
    traj, vmap = _world(rng)
    tau = np.linspace(*traj.domain, 300)
    pos, vel, _ = traj.evaluate(tau)
    d, o = vmap.nearest(pos, bbox_margin=np.inf)
    risk = find_braking_zones(tau, pos, vel, d, o).mask
    both = find_braking_zones(tau, pos, vel, d, o, BrakingParams(d_th=2.5)).mask
    paper = find_braking_zones(tau, pos, vel, d, o, BrakingParams(d_th=1.0, risk=False)).mask
    ahead = np.einsum("ij,ij->i", o - pos, vel) >= 0.0
    assert np.all(both >= risk) and np.array_equal(both, risk | ((d <= 2.5) & ahead))
    np.testing.assert_array_equal(paper, (d <= 1.0) & ahead)


def test_a_robot_smaller_than_the_smallest_semi_axis_is_refused_in_words():
    """(hypothesis found 5e-324 m: 1 / a overflowed and the risk came out NaN)"""
    with pytest.raises(InputError, match="semi_axes.*at least"):
        ChanceParams(semi_axes=(5e-324,) * 3)
    assert ChanceParams(semi_axes=(0.0,) * 3).point_robot
