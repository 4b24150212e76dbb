"""Braking zones and chance-constrained speed limits in the re-time."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import binom

from rota.chance import (
    collision_probability,
    monte_carlo_collision_probability,
)
from rota.voxelmap import VoxelMap
from tests.helpers.scenes import RES, line, node_speed, pillar, run, safety


def test_pillar_ahead_brakes_then_reaccelerates():
    traj = line(0.0, 10.0)
    free = run(traj)
    robust = run(traj, safety(pillar()))
    assert free.ok and robust.ok, robust.message
    mask = robust.diagnostics.braking_mask
    assert mask.any() and robust.diagnostics.intervals
    x = traj.position(robust.tau)[:, 0]
    # braking points: ahead of the pillar only (x <= 5), within d_th
    assert np.all(x[mask] <= 5.0 + 0.1) and np.all(x[mask] >= 5.0 - 1.1)  # pillar r = 0.1
    speed = node_speed(robust)
    limit = robust.speed_limits
    assert np.all(speed[mask] <= limit[mask] * 1.001)
    assert limit[mask].min() < 1.5  # a real slow-down, well under v_max = 3
    # slower inside the zone than the unconstrained re-time, then fast again after it
    assert speed[mask].max() < node_speed(free)[mask].min()
    after = (x > 6.5) & (x < 8.0)
    assert speed[after].min() > 2.5
    assert robust.duration > free.duration


def test_same_pillar_behind_changes_nothing():
    traj = line(5.05, 15.0)  # starts beside the pillar and flies away from it
    free = run(traj)
    robust = run(traj, safety(pillar()))
    assert robust.ok and not robust.diagnostics.braking_mask.any()
    assert robust.duration == pytest.approx(free.duration, rel=1e-6)
    assert np.allclose(robust.beta, free.beta, rtol=1e-5, atol=1e-8)


def test_monte_carlo_collision_probability_within_delta_in_braking_zone():
    """At the re-timed speed of every braking-zone node, the true collision
    probability (Monte Carlo against the real ellipsoid) is at most Delta."""
    delta = 1e-3
    safe = safety(pillar(), delta=delta)
    result = run(line(0.0, 10.0), safe)
    assert result.ok
    mask = result.diagnostics.braking_mask
    p, d1, _ = result.trajectory.evaluate(result.tau[mask])
    vel = d1 * np.sqrt(result.beta[mask])[:, None]
    _, obstacle = safe.map.nearest(p)
    n = 200_000
    mc = monte_carlo_collision_probability(p, vel, obstacle, safe.uncertainty, safe.chance,
                                           n_samples=n, rng=7)
    # one-sided 99.9 % binomial bound: hits beyond it would contradict Pr <= delta
    assert np.all(mc * n <= binom.ppf(0.999, n, delta)), mc.max()
    lin = collision_probability(p, vel, obstacle, safe.uncertainty, safe.chance)
    assert np.all(lin <= delta * (1 + 1e-3))  # the linearised constraint holds
    assert np.all(mc <= lin + 3 * np.sqrt(lin / n))  # and it is conservative


def test_more_uncertainty_means_slower_and_longer():
    traj = line(0.0, 10.0)
    low = run(traj, safety(pillar(), m=0.1))
    high = run(traj, safety(pillar(), m=0.4))
    assert low.ok and high.ok
    mask = high.diagnostics.braking_mask
    assert np.all(high.speed_limits[mask] <= low.speed_limits[mask] + 1e-12)
    assert node_speed(high)[mask].max() < node_speed(low)[mask].max()
    assert high.duration > low.duration


def test_delta_near_one_makes_the_chance_constraint_inactive():
    traj = line(0.0, 10.0)
    free = run(traj)
    loose = run(traj, safety(pillar(), delta=0.999999))
    assert loose.ok and loose.diagnostics.braking_mask.any()
    assert loose.duration == pytest.approx(free.duration, rel=1e-6)


def test_empty_map_changes_nothing():
    traj = line(0.0, 10.0)
    empty = VoxelMap(RES, np.zeros((0, 3)))
    result = run(traj, safety(empty))
    assert result.ok and result.duration == pytest.approx(run(traj).duration, rel=1e-9)


def test_obstacles_everywhere_rejects_the_path():
    g = np.arange(-1, 11, 0.1)
    xx, yy, zz = np.meshgrid(g, np.arange(-1, 1, 0.1), np.arange(0, 2, 0.1), indexing="ij")
    full = VoxelMap.from_points(np.column_stack([xx.ravel(), yy.ravel(), zz.ravel()]), 0.1)
    result = run(line(0.0, 10.0), safety(full))
    assert result.status == "rejected" and not result.ok
    assert "unsafe" in result.message and "obstacle" in result.message


def test_trajectory_leaving_the_map_is_slowed_and_warned():
    vmap = pillar()
    bounds = np.array([[-1.0, -3.0, 0.0], [7.0, 3.0, 3.0]])
    result = run(line(0.0, 10.0), safety(vmap, bounds=bounds))
    assert result.ok
    assert any("leaves the map" in w for w in result.warnings)
    x = result.trajectory.position(result.tau)[:, 0]
    assert np.all(node_speed(result)[x > 7.0] <= 0.3 * 1.001)  # v_floor where unknown
    # the map's own bounds work the same way
    bounded = VoxelMap(vmap.resolution, vmap.occupied, bounds=bounds)
    again = run(line(0.0, 10.0), safety(bounded))
    assert again.duration == pytest.approx(result.duration, rel=1e-9)


def test_start_too_fast_for_the_braking_zone_brakes_and_warns():
    traj = line(4.2, 10.0)  # starts 0.8 m before the pillar
    result = run(traj, safety(pillar()), start_velocity=np.array([2.5, 0, 0]))
    assert result.ok, result.message
    assert any("exceeds the speed limit" in w for w in result.warnings)
    assert np.linalg.norm(result.sample(0.0).velocity) == pytest.approx(2.5, abs=1e-3)
    speed = node_speed(result)
    assert speed[5] < speed[0]  # braking from the first node on


def test_cli_with_map_shades_braking_zones(tmp_path):
    import json

    from rota.cli import main
    from rota.schema import TrajectoryMessage, dump, trajectory_to_dict

    src, mp = tmp_path / "traj.json", tmp_path / "map.json"
    dump(trajectory_to_dict(TrajectoryMessage(line(0.0, 10.0), id="line")), src)
    dump(pillar().to_dict(), mp)
    out, png = tmp_path / "out.json", tmp_path / "out.png"
    code = main(["retime", str(src), "-o", str(out), "--map", str(mp), "--v-max", "3",
                 "--a-max", "3", "--semi-axes", "0.15", "--plot", str(png)])
    assert code == 0
    d = json.loads(out.read_text())
    assert d["braking_zones"] and d["status"] == "optimal"
    assert min(x for x in d["speed_limits"] if x is not None) < 2.0
    assert png.stat().st_size > 10_000
    # a map the path runs through: rejected, exit status 4
    dump(pillar(gap=-0.1).to_dict(), mp)
    assert main(["retime", str(src), "-o", str(out), "--map", str(mp)]) == 4
    assert json.loads(out.read_text())["status"] == "rejected"


def test_the_outcome_is_an_enum_whose_json_keeps_its_word_and_diagnostics_are_typed():
    import json

    from rota.errors import InputError
    from rota.result import Diagnostics, Outcome
    from rota.schema import TrajectoryMessage, result_from_dict, result_to_dict

    traj = line(0.0, 10.0)
    robust = run(traj, safety(pillar()))
    assert robust.status is Outcome.OPTIMAL and robust.status == "optimal"
    assert isinstance(robust.diagnostics, Diagnostics) and robust.diagnostics.solve_rounds >= 1
    d = json.loads(json.dumps(result_to_dict(robust, TrajectoryMessage(traj, id="p"))))
    assert d["status"] == "optimal" and d["braking_zones"]
    back, _ = result_from_dict(d)
    assert back.status is Outcome.OPTIMAL
    assert [list(z) for z in back.diagnostics.intervals] == d["braking_zones"]
    with pytest.raises(InputError, match="status"):
        result_from_dict({**d, "status": "fine"})
