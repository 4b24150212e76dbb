"""The heading streamed to PX4 (NED yaw, degrees): toward a target, within a yaw-rate
and a yaw-acceleration limit, and continuous across plans: when a new plan takes over
facing another way, the yaw PX4 receives turns to it, it never steps.

The target is the path's direction (``[stream] yaw = "path"``) or the yaw held at
start (``"hold"``). Each tick the yaw rate moves toward the time-optimal rate of a
double integrator that stops exactly on the target (the rate ``r`` with
``r^2 / 2a + r dt / 2 = |error|``: braking one tick at a time; capped at the rate
limit), by no more than the acceleration limit allows in one tick; the yaw then moves
by that rate. So the yaw PX4 receives changes by at most
``yaw_rate_max * dt`` between setpoints, and its rate by at most ``yaw_accel_max * dt``.
PX4's own auto modes limit yaw the same way (``MPC_YAWRAUTO_MAX``, 45 deg/s by default;
``MPC_YAWRAUTO_ACC``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass


def wrap_deg(angle: float) -> float:
    """``angle`` in [-180, 180) degrees."""
    return (angle + 180.0) % 360.0 - 180.0


@dataclass(frozen=True)
class Heading:
    """The yaw streamed (NED, deg) and its rate (deg/s)."""

    yaw_deg: float
    rate_deg_s: float = 0.0

    def toward(self, target_deg: float, dt: float, rate_max: float,
               accel_max: float) -> Heading:
        """The heading one tick of ``dt`` seconds later (module docstring)."""
        error = wrap_deg(target_deg - self.yaw_deg)
        # the fastest rate from which braking at accel_max, one tick at a time, still
        # stops on the target: r^2 / (2 a) + r dt / 2 <= |error|
        half = 0.5 * accel_max * dt
        stop = math.sqrt(half * half + 2.0 * accel_max * abs(error)) - half
        want = math.copysign(min(rate_max, stop), error)
        if abs(want) * dt > abs(error):  # the last tick lands on the target
            want = error / dt
        step = accel_max * dt
        rate = min(max(want, self.rate_deg_s - step), self.rate_deg_s + step)
        rate = min(max(rate, -rate_max), rate_max)
        return Heading(wrap_deg(self.yaw_deg + rate * dt), rate)
