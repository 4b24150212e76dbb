"""Coordinate frames. Planners publish ENU (x east, y north, z up; ROS); PX4 works
in NED (x north, y east, z down). Both share the origin of PX4's local frame.
The service works in ENU and converts exactly once, at the MAVLink boundary."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rota.trajectory import (
    BSplineTrajectory,
    PolynomialTrajectory,
    SampledTrajectory,
    Trajectory,
    Window,
)

FloatArray = NDArray[np.float64]

_SWAP = [1, 0, 2]
_SIGN = np.array([1.0, 1.0, -1.0])


def enu_to_ned(v: ArrayLike) -> FloatArray:
    """ENU vectors (..., 3) -> NED: (x, y, z) -> (y, x, -z). Its own inverse."""
    a = np.asarray(v, dtype=float)
    return a[..., _SWAP] * _SIGN


ned_to_enu = enu_to_ned


def yaw_enu_to_ned_deg(yaw_enu_rad: float) -> float:
    """ENU yaw (from east, counter-clockwise, rad) -> NED yaw (from north, clockwise, deg)."""
    return (math.degrees(math.pi / 2 - yaw_enu_rad) + 180.0) % 360.0 - 180.0


def heading_ned_deg(velocity_enu: ArrayLike) -> float:
    """NED yaw (deg) that faces along an ENU velocity."""
    v = np.asarray(velocity_enu, dtype=float)
    return math.degrees(math.atan2(v[0], v[1]))  # atan2(east, north)


def trajectory_to_enu(traj: Trajectory, frame: str) -> Trajectory:
    """The same path expressed in ENU (``frame`` is the one it is given in)."""
    if frame == "ENU":
        return traj
    if frame != "NED":
        raise ValueError(f"unknown frame {frame!r}")
    if isinstance(traj, Window):
        offset = None if traj.offset is None else ned_to_enu(traj.offset)
        return replace(traj, base=trajectory_to_enu(traj.base, frame), offset=offset)
    if isinstance(traj, BSplineTrajectory):
        return replace(traj, control_points=ned_to_enu(traj.control_points))
    if isinstance(traj, PolynomialTrajectory):
        c = traj.coefficients[:, _SWAP, :] * _SIGN[None, :, None]
        return replace(traj, coefficients=c)
    if isinstance(traj, SampledTrajectory):
        v = None if traj.v is None else ned_to_enu(traj.v)
        a = None if traj.a is None else ned_to_enu(traj.a)
        return replace(traj, p=ned_to_enu(traj.p), v=v, a=a)
    raise TypeError(f"cannot convert {type(traj).__name__}")
