"""Regression tests at the edges, found by an independent reference solve: exact
boundary states, check points on every input piece, paths shorter than dtau,
infeasibility in words, and warnings with true figures."""

from __future__ import annotations

import numpy as np
import pytest

from rota import (
    BSplineTrajectory,
    Limits,
    PolynomialTrajectory,
    RetimeInput,
    SampledTrajectory,
    SolverSettings,
    retime,
)
from tests.helpers.kinematics import measured_kinematics

METHODS = ["fast", "clarabel"]


def line(length: float, duration: float, n: int = 11) -> SampledTrajectory:
    """A straight line along x, moving at both ends (so beta is fixed there)."""
    t = np.linspace(0, duration, n)
    return SampledTrajectory(t=t, p=np.column_stack([t * length / duration, 0 * t, 0 * t]))


def fine_speed(result, n: int = 200_001):
    t = np.linspace(0, result.duration, n)
    p = result.sample(t).position
    return p, np.linalg.norm(np.diff(p, axis=0), axis=1) / np.diff(t)


@pytest.mark.parametrize("method", METHODS)
def test_end_at_rest_is_exact_and_holds_after_the_end(method):
    result = retime(RetimeInput(trajectory=line(3.0, 3.0), limits=Limits(1.0, 1.0),
                                solver=SolverSettings(method=method)))
    assert result.ok, result.message
    assert result.beta[-1] == 0.0 and result.ends_at_rest
    after = result.sample([result.duration, result.duration + 0.5, result.duration + 9.0])
    assert np.all(after.velocity == 0.0) and np.all(after.acceleration == 0.0)
    assert np.allclose(after.position, after.position[0])


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("v_max", [0.05, 0.5])
def test_start_at_rest_under_tight_limits(method, v_max):
    """A start requested at rest starts at rest whatever the limits (it came out
    at up to 11.8 % of v_max = 0.05 m/s)."""
    result = retime(RetimeInput(trajectory=line(2.0, 2.0), limits=Limits(v_max, 0.05),
                                solver=SolverSettings(method=method)))
    assert result.ok, result.message
    assert result.beta[0] == 0.0 and result.beta[-1] == 0.0
    ends = result.sample([0.0, result.duration])
    assert np.all(ends.velocity == 0.0)
    _, speed = fine_speed(result, 20_001)
    assert speed[0] <= 0.01 * v_max and speed[-1] <= 0.01 * v_max
    assert speed.max() <= v_max * 1.01


def test_short_stiff_sample_piece_is_checked_inside():
    """Two stamps 1 ms apart with velocities: the interpolating piece between them
    is fast inside (finite differences gave 111 m/s against v_max 2)."""
    t = np.array([0.0, 1.0, 1.001, 2.0, 3.0])
    p = np.zeros((5, 3))
    p[:, 0] = [0.0, 1.0, 1.05, 2.0, 3.0]
    v = np.zeros((5, 3))
    v[:, 0] = [0.0, 1.0, 1.0, 1.0, 0.0]
    result = retime(RetimeInput(trajectory=SampledTrajectory(t=t, p=p, v=v),
                                limits=Limits(2.0, 3.0)))
    assert result.ok, result.message
    _, speed = fine_speed(result)
    assert speed.max() <= 2.0 * 1.01
    _, speed, acc = measured_kinematics(result, refine=20)
    assert speed.max() <= 2.0 * 1.01 and np.abs(acc).max() <= 3.0 * 1.01


def test_short_stiff_polynomial_segment_at_coarse_dtau():
    """A 0.05 s segment between two long ones, re-timed at dtau = 0.2 s (it
    overshot a_max by 2.8 %)."""
    durs = np.array([1.0, 0.05, 1.0])
    coefs = np.zeros((3, 3, 6))
    # x: 0 -> 1 (rest to 1 m/s), then a stiff wiggle in y, then 1 m/s -> rest
    coefs[0, 0, :] = [0.0, 0.0, 0.0, 2.0, -1.5, 0.3]
    x1 = float(np.polyval(coefs[0, 0, ::-1], 1.0))
    v1 = float(np.polyval(np.polyder(coefs[0, 0, ::-1]), 1.0))
    coefs[1, 0, :2] = [x1, v1]
    coefs[1, 1, 2:4] = [40.0, -800.0]  # y = 40 s^2 - 800 s^3: back to y' = 0 at 0.05 s
    y2 = 40 * 0.05**2 - 800 * 0.05**3
    coefs[2, 0, :2] = [x1 + v1 * 0.05, v1]
    coefs[2, 0, 2:4] = [-1.0 * v1, 0.0]
    coefs[2, 1, 0] = y2
    coefs[2, 1, 1] = 80 * 0.05 - 2400 * 0.05**2
    traj = PolynomialTrajectory(durations=durs, coefficients=coefs)
    lim = Limits(1.0, 1.0)
    result = retime(RetimeInput(trajectory=traj, limits=lim, dtau=0.2))
    assert result.ok, result.message
    _, speed, acc = measured_kinematics(result, refine=50)
    assert speed.max() <= 1.0 * 1.01
    assert np.abs(acc).max() <= 1.0 * 1.01


def test_path_shorter_than_dtau_is_retimed_on_a_finer_grid():
    """Rest to rest over 0.11 m in 0.15 s of trajectory time, dtau 0.5 s: it was
    reported as not moving."""
    cps = np.array([[0, 0, 0]] * 3 + [[0.11, 0, 0]] * 3, dtype=float)
    traj = BSplineTrajectory(control_points=cps, knot_span=0.05)
    result = retime(RetimeInput(trajectory=traj, limits=Limits(1.0, 2.0), dtau=0.5))
    assert result.ok, result.message
    assert len(result.tau) > 2
    p, speed = fine_speed(result, 20_001)
    assert p[-1, 0] == pytest.approx(0.11)
    assert speed.max() <= 1.0 * 1.01


@pytest.mark.parametrize("method", METHODS)
def test_infeasible_start_is_explained_in_words(method):
    """1.9 m/s at the start, 1 m of path, a_max 0.2: stopping needs 9 m."""
    result = retime(RetimeInput(trajectory=line(1.0, 1.0), limits=Limits(2.0, 0.2),
                                start_velocity=np.array([1.9, 0, 0]),
                                solver=SolverSettings(method=method)))
    assert result.status == "fallback"
    msg = result.message
    assert "infeasible" in msg and "come to rest by the end of the path (1.00 m)" in msg
    # v^2 = 1.9^2 - 2 * 0.2 * 1.0: the slowest it can arrive is 1.79 m/s
    assert "arrives at 1.79 m/s" in msg


def test_infeasible_speed_limit_ahead_is_located():
    """Too fast for a low per-node speed limit half-way along the path."""
    traj = line(4.0, 4.0, n=41)
    lim = np.full(41, 2.0)
    lim[20:] = 0.5  # from 2 m on
    result = retime(RetimeInput(trajectory=traj, limits=Limits(2.0, 0.5), dtau=0.1,
                                start_velocity=np.array([2.0, 0, 0]),
                                end_velocity=np.array([0.5, 0, 0]), speed_limits=lim))
    assert result.status == "fallback"
    assert "2.00 m along the path" in result.message
    assert "above the speed limit 0.50 m/s" in result.message


def test_start_too_fast_warning_reports_the_true_distance():
    """The distance over which the speed exceeds the limit is measured on the
    result (it said 0.00 m while the speed stayed above v_max for 0.22 m)."""
    traj = line(20.0, 10.0)
    result = retime(RetimeInput(trajectory=traj, limits=Limits(2.0, 2.0),
                                start_velocity=np.array([3.0, 0, 0])))
    assert result.ok, result.message
    (note,) = result.warnings
    said = float(note.split("for the first ")[1].split(" m")[0])
    sp = result.sample(np.linspace(0, result.duration, 40_001))
    speed = np.linalg.norm(sp.velocity, axis=1)
    measured = float(sp.position[speed > 2.0 * (1 + 1e-6), 0].max())
    assert said == pytest.approx(measured, abs=0.02)


def test_start_slightly_too_fast_warning_is_not_zero():
    traj = line(20.0, 10.0)
    result = retime(RetimeInput(trajectory=traj, limits=Limits(2.0, 2.0), dtau=0.5,
                                start_velocity=np.array([2.2, 0, 0])))
    assert result.ok, result.message
    said = float(result.warnings[0].split("for the first ")[1].split(" m")[0])
    sp = result.sample(np.linspace(0, result.duration, 40_001))
    speed = np.linalg.norm(sp.velocity, axis=1)
    measured = float(sp.position[speed > 2.0 * (1 + 1e-6), 0].max())
    assert measured > 0.1 and said == pytest.approx(measured, abs=0.02)
