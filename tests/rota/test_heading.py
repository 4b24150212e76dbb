"""Speed limits that let the heading keep up (rota.heading), measured from the outside:
the yaw rate of the re-timed flight, by finite differences of the direction of its
sampled velocity (or of the planner's heading at its sampled trajectory time)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rota import InputError, Limits, RetimeInput, retime
from rota.heading import FLOOR_M_S, heading_speed_limits
from rota.problem import make_grid
from rota.schema import Heading
from rota.trajectory import BSplineTrajectory
from tests.helpers.kinematics import corner

OMEGA = math.radians(45.0)  # the flight service's default yaw-rate limit
LIMITS = Limits(2.0, 2.0)
DTAU = 0.05
RATE = 200.0  # Hz, the finite differences
#: The limit is imposed at the grid nodes; measured on these paths at dtau 0.05, the
#: flown peaks are 44.998-45.000 deg/s against 45: 1 % (the jerk bound's tolerance) is
#: slack for the 5 ms finite differences alone.
TOL = 0.01


def path_yaw_rate(result, floor: float = FLOOR_M_S) -> float:
    """The fastest the direction of the flown velocity turns (rad/s), where the
    horizontal speed is over ``floor`` (below it the heading is not followed)."""
    t = np.arange(0.0, result.duration, 1 / RATE)
    v = result.sample(t).velocity
    keep = np.hypot(v[:, 0], v[:, 1]) > floor
    yaw = np.unwrap(np.arctan2(v[:, 1], v[:, 0]))
    rate = np.abs(np.diff(yaw)) * RATE
    return float(rate[keep[:-1] & keep[1:]].max())


def retimed(traj, limits=None) -> object:
    result = retime(RetimeInput(traj, LIMITS, dtau=DTAU, speed_limits=limits))
    assert result.ok, result.message
    return result


@pytest.mark.parametrize("radius", [1.0, 2.0])
def test_the_path_direction_turns_within_the_limit_when_slowed(radius):
    traj = corner(radius)
    free = retimed(traj)
    assert path_yaw_rate(free) > 1.2 * OMEGA  # the test case needs the limit
    lim = heading_speed_limits(traj, make_grid(traj, DTAU), OMEGA)
    slowed = retimed(traj, lim)
    print(f"radius {radius} m: yaw rate {math.degrees(path_yaw_rate(free)):.0f} deg/s free, "
          f"{math.degrees(path_yaw_rate(slowed)):.3f} slowed; duration {free.duration:.2f} -> "
          f"{slowed.duration:.2f} s")
    assert path_yaw_rate(slowed) <= OMEGA * (1 + TOL)
    assert slowed.duration > free.duration
    # on the straights nothing is limited
    assert np.isinf(lim[:10]).all() and np.isinf(lim[-10:]).all()


def test_a_planners_heading_turns_within_the_limit_when_slowed():
    """A straight path (1 m per s of trajectory time), the planner's heading turning 180
    degrees in 2 s of trajectory time half-way (samples every 0.1 s): 0.5 m/s lets it
    keep up, over the floor."""
    xy = np.stack([np.linspace(0.0, 10.0, 101), np.zeros(101)], 1)
    traj = BSplineTrajectory(np.column_stack([xy, np.full(101, 2.0)]), 3, 0.1)
    t0, t1 = traj.domain
    samples = np.arange(t0, t1, 0.1)
    yaw = np.clip((samples - (t0 + t1) / 2) * 90.0, 0.0, 180.0)
    heading = Heading(tuple(yaw), 0.1, t0)
    tau = make_grid(traj, DTAU)

    def rate(result) -> float:
        t = np.arange(0.0, result.duration, 1 / RATE)
        tau_t = result.timemap.evaluate(t)[0]
        flown = np.unwrap(np.radians([heading.at(x) for x in tau_t]))
        return float(np.abs(np.diff(flown)).max() * RATE)

    free = retimed(traj)
    slowed = retimed(traj, heading_speed_limits(traj, tau, OMEGA, heading))
    print(f"planner's heading: {math.degrees(rate(free)):.0f} deg/s free, "
          f"{math.degrees(rate(slowed)):.3f} slowed")
    assert rate(free) > 1.5 * OMEGA
    assert rate(slowed) <= OMEGA * (1 + TOL)


def test_no_limit_up_a_vertical_path_and_the_floor_in_a_tight_corner():
    up = BSplineTrajectory(np.column_stack([np.zeros(20), np.zeros(20),
                                            np.linspace(1.0, 5.0, 20)]), 3, 0.2)
    assert np.isinf(heading_speed_limits(up, make_grid(up, DTAU), OMEGA)).all()
    tight = corner(0.2)
    lim = heading_speed_limits(tight, make_grid(tight, DTAU), OMEGA)
    assert np.nanmin(lim) >= FLOOR_M_S * (1 - 1e-9)


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, math.inf])
def test_a_bad_rate_is_refused_in_words(bad):
    traj = corner(1.0)
    with pytest.raises(InputError, match="yaw_rate_max"):
        heading_speed_limits(traj, make_grid(traj, DTAU), bad)
