"""Independent measurement of a re-timed trajectory: finite differences of the
positions it produces, never the velocities it reports; and a minimum-jerk move
for the flight tests."""

from __future__ import annotations

import math

import numpy as np

from rota import RetimeResult
from rota.trajectory import BSplineTrajectory


def fine_times(result: RetimeResult, refine: int = 10) -> np.ndarray:
    """Real times of a trajectory-time grid ``refine`` times finer than the solver's."""
    tau = result.tau
    fine = np.linspace(tau[0], tau[-1], refine * (len(tau) - 1) + 1)
    return np.unique(result.timemap.real_time(fine))


def measured_kinematics(result: RetimeResult, refine: int = 10):
    """Speed and per-axis acceleration from finite differences of positions.

    Velocity: first differences (at interval midpoints). Acceleration: the
    three-point formula for non-uniform steps.
    """
    t = fine_times(result, refine)
    t = t[np.concatenate([[True], np.diff(t) > 1e-9])]
    p = result.sample(t).position
    dt = np.diff(t)
    v = np.diff(p, axis=0) / dt[:, None]
    a = 2 * (v[1:] - v[:-1]) / (dt[1:] + dt[:-1])[:, None]
    return t, np.linalg.norm(v, axis=1), a


def min_jerk(t: float, duration: float, dist: float) -> tuple[float, float, float]:
    """Position, velocity, acceleration of a rest-to-rest minimum-jerk move of ``dist``
    metres in ``duration`` seconds at time ``t`` (held before and after)."""
    s = min(max(t / duration, 0.0), 1.0)
    p = dist * (10 * s**3 - 15 * s**4 + 6 * s**5)
    v = dist / duration * (30 * s**2 - 60 * s**3 + 30 * s**4)
    a = dist / duration**2 * (60 * s - 180 * s**2 + 120 * s**3)
    return p, v, a


def corner(radius: float) -> BSplineTrajectory:
    """4 m east, a quarter circle of ``radius`` to the north, 4 m north (z = 2 m), as
    a cubic B-spline through dense control points (0.1 m apart)."""
    east = np.stack([np.linspace(-4.0, 0.0, 41), np.zeros(41)], 1)
    turn = np.linspace(0.0, math.pi / 2, max(8, int(radius * 16)))[1:]
    arc = np.stack([radius * np.sin(turn), radius * (1 - np.cos(turn))], 1)
    north = np.stack([np.full(40, radius), radius + np.linspace(0.1, 4.0, 40)], 1)
    xy = np.concatenate([np.repeat(east[:1], 3, 0), east, arc, north,
                         np.repeat(north[-1:], 3, 0)])
    return BSplineTrajectory(np.column_stack([xy, np.full(len(xy), 2.0)]), 3, 0.1)
