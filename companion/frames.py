"""Coordinate frames. Planners publish ENU (x east, y north, z up; ROS); PX4 works
in NED (x north, y east, z down). Both share the origin of PX4's local frame.
The service works in ENU and converts exactly once, at the MAVLink boundary (a
trajectory given in NED: :func:`companion.messages.trajectory_to_enu`). Numpy only:
the simulator uses these too, without loading the re-timer."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

SWAP = [1, 0, 2]  # x <-> y
SIGN = np.array([1.0, 1.0, -1.0])


def enu_to_ned(v: ArrayLike) -> FloatArray:
    """ENU vectors (..., 3) -> NED: (x, y, z) -> (y, x, -z). Its own inverse."""
    a = np.asarray(v, dtype=float)
    return a[..., SWAP] * SIGN


ned_to_enu = enu_to_ned


def yaw_enu_to_ned_deg(yaw_enu_rad: float) -> float:
    """ENU yaw (from east, counter-clockwise, rad) -> NED yaw (from north, clockwise, deg)."""
    return (math.degrees(math.pi / 2 - yaw_enu_rad) + 180.0) % 360.0 - 180.0


def yaw_ned_to_enu_deg(yaw_ned_deg: float) -> float:
    """NED yaw (from north, clockwise, deg) -> ENU yaw (from east, counter-clockwise,
    deg), -180 to 180. The same map takes ENU to NED (90 - yaw both ways)."""
    return (90.0 - yaw_ned_deg + 180.0) % 360.0 - 180.0


def heading_ned_deg(velocity_enu: ArrayLike) -> float:
    """NED yaw (deg) that faces along an ENU velocity."""
    v = np.asarray(velocity_enu, dtype=float)
    return math.degrees(math.atan2(v[0], v[1]))  # atan2(east, north)
