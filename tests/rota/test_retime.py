"""The re-timing entry point: boundary states, shorter/longer, fallback."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rota import BSplineTrajectory, Limits, RetimeInput, SampledTrajectory, retime
from rota.cli import example_path
from rota.schema import trajectory_from_dict
from tests.helpers.kinematics import measured_kinematics
from tests.helpers.strategies import bspline


def example():
    return trajectory_from_dict(json.loads(example_path().read_text())).trajectory


def straight(length: float = 10.0, duration: float = 10.0) -> SampledTrajectory:
    """A straight line along x at constant speed (not at rest at its ends)."""
    t = np.linspace(0, duration, 11)
    return SampledTrajectory(t=t, p=np.column_stack([t * length / duration, 0 * t, 0 * t]))


def test_slow_input_comes_out_shorter_within_limits():
    """Paper sample trajectory 1: planned at 1 m/s and 3 m/s^2, re-timed faster."""
    traj = example()
    _, v, a = traj.evaluate(np.linspace(*traj.domain, 5000))
    assert np.linalg.norm(v, axis=1).max() <= 1.0 + 1e-3  # the planner's own limits
    result = retime(RetimeInput(trajectory=traj, limits=Limits(1.0, 3.0)))
    assert result.ok, result.message
    assert result.duration < 0.9 * traj.duration
    _, speed, acc = measured_kinematics(result)
    assert speed.max() <= 1.0 * 1.01 and np.abs(acc).max() <= 3.0 * 1.01


def test_input_breaking_limits_comes_out_longer_and_feasible():
    traj = example()
    result = retime(RetimeInput(trajectory=traj, limits=Limits(0.5, 0.5)))
    assert result.ok, result.message
    assert result.duration > traj.duration
    _, speed, acc = measured_kinematics(result)
    assert speed.max() <= 0.5 * 1.01 and np.abs(acc).max() <= 0.5 * 1.01


@pytest.mark.parametrize("v0", [0.3, 1.0, 1.9])
def test_start_velocity_is_reproduced(v0):
    traj = straight()
    result = retime(RetimeInput(trajectory=traj, limits=Limits(2.0, 2.0),
                                start_velocity=np.array([v0, 0.0, 0.0])))
    assert result.ok, result.message
    start = result.sample(0.0)
    assert np.allclose(start.velocity[0], [v0, 0, 0], atol=1e-4)
    # and the positions say the same: a forward difference over 1 ms
    fd = (result.sample(1e-3).position[0] - start.position[0]) / 1e-3
    assert abs(fd[0] - v0) < 2e-3 + 1e-3 * 2.0


def test_start_acceleration_is_reproduced():
    traj = straight()
    result = retime(RetimeInput(trajectory=traj, limits=Limits(2.0, 2.0),
                                start_velocity=np.array([1.0, 0, 0]),
                                start_acceleration=np.array([-0.5, 0, 0])))
    assert result.ok, result.message
    assert np.allclose(result.sample(0.0).acceleration[0], [-0.5, 0, 0], atol=1e-6)


def test_end_velocity_is_reproduced():
    traj = straight()
    result = retime(RetimeInput(trajectory=traj, limits=Limits(2.0, 2.0),
                                end_velocity=np.array([1.5, 0, 0])))
    assert result.ok, result.message
    assert np.allclose(result.sample(result.duration).velocity[0], [1.5, 0, 0], atol=1e-4)


def test_start_faster_than_limit_brakes_as_hard_as_allowed():
    traj = straight(length=20.0)
    result = retime(RetimeInput(trajectory=traj, limits=Limits(2.0, 2.0),
                                start_velocity=np.array([3.0, 0, 0])))
    assert result.ok, result.message
    assert any("exceeds the speed limit" in w for w in result.warnings)
    sp = result.sample(np.linspace(0, result.duration, 2000))
    speed = np.linalg.norm(sp.velocity, axis=1)
    assert speed[0] == pytest.approx(3.0, abs=1e-3)
    # brakes at (at most) half the acceleration limit until under the limit
    s = sp.position[:, 0]
    # 1 m/s^2 = half of a_max; limits hold at grid nodes 0.2 m apart, linear in v^2
    # between them, so the profile may be met one node late.
    profile = np.sqrt(np.maximum(9.0 - 2 * 1.0 * (s - 0.2), 0))
    assert np.all(speed <= np.maximum(profile, 2.0) * 1.001)
    assert np.all(speed[s > 2.7] <= 2.0 * 1.001)
    assert speed[s < 2.0].min() > 2.0  # it is braking, not stopping dead


@pytest.mark.parametrize(("v0", "words"), [
    ([0, 1.0, 0], "not along the path"),
    ([-1.0, 0, 0], "backwards"),
])
def test_inconsistent_start_state_gives_fallback_in_words(v0, words):
    traj = straight()
    result = retime(RetimeInput(trajectory=traj, limits=Limits(2.0, 2.0),
                                start_velocity=np.array(v0, dtype=float)))
    assert result.status == "fallback" and words in result.message
    assert np.isfinite(result.duration)
    _, speed, acc = measured_kinematics(result)
    assert speed.max() <= 2.0 * 1.01 and np.abs(acc).max() <= 2.0 * 1.01


def test_cannot_brake_in_time_gives_fallback_not_exception():
    """Start fast with a tiny acceleration limit and a short path: infeasible."""
    traj = straight(length=1.0, duration=1.0)
    result = retime(RetimeInput(trajectory=traj, limits=Limits(2.0, 0.2),
                                start_velocity=np.array([1.9, 0, 0])))
    assert result.status == "fallback"
    assert "infeasible" in result.message or "cannot be met" in result.message
    assert np.all(np.isfinite(result.sample(np.linspace(0, result.duration, 50)).velocity))


def test_degenerate_path_that_does_not_move():
    traj = BSplineTrajectory(control_points=np.ones((6, 3)), knot_span=0.5)
    result = retime(RetimeInput(trajectory=traj, limits=Limits(1.0, 1.0)))
    assert result.status == "fallback" and "does not move" in result.message
    sp = result.sample(np.linspace(0, result.duration, 20))
    assert np.all(np.isfinite(sp.position)) and np.allclose(sp.velocity, 0)


def test_smoothness_trades_time_for_smaller_alpha_jumps():
    traj = bspline(7, 8, 1.0)
    fast = retime(RetimeInput(trajectory=traj, limits=Limits(2.0, 2.0), smoothness=0.0))
    smooth = retime(RetimeInput(trajectory=traj, limits=Limits(2.0, 2.0), smoothness=5.0))
    assert fast.ok and smooth.ok
    assert fast.duration <= smooth.duration + 1e-6
    assert np.sum(smooth.alpha**2) < np.sum(fast.alpha**2)


def test_sample_rate_is_ready_to_stream():
    result = retime(RetimeInput(trajectory=example(), limits=Limits(1.0, 3.0)))
    sp = result.sample_rate(50.0)
    assert np.allclose(np.diff(sp.t)[:-1], 0.02)
    assert sp.t[-1] == pytest.approx(result.duration)
    assert np.allclose(sp.velocity[-1], 0, atol=1e-6)
    after = result.sample(result.duration + 5.0)  # beyond the end: hold the end
    assert np.allclose(after.position, sp.position[-1]) and np.allclose(after.velocity, 0)
