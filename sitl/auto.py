"""Setpoints of PX4's automatic modes (takeoff, hold, return, land) for the simulated vehicle.

PX4 does not step its position setpoint in the automatic modes: a trajectory generator moves it
smoothly towards the target within the mode's speed and acceleration limits (PX4 User Guide,
*Flight Modes* and the MPC_* parameters). ``AutoReference`` is a small stand-in for it: a
reference point ``p_r`` with velocity ``v_r`` driven towards a target, its speed towards the
target limited by the mode's maximum, by ``gain * distance`` (the approach near the target) and
by ``sqrt(2 * a_max * distance)`` (braking), its acceleration a first-order chase of that speed
limited by ``a_max``. The position controller tracks ``(p_r, v_r, a_r)`` like an offboard
setpoint. Horizontal and vertical motion are limited separately (NED: up is negative z).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sitl.dynamics import Setpoint


@dataclass(frozen=True)
class AutoLimits:
    """Limits of one automatic mode (PX4 parameter names in brackets).

    Attributes:
        speed_xy: [MPC_XY_CRUISE] horizontal speed (m/s).
        speed_up / speed_down: [MPC_Z_V_AUTO_UP / _DN] vertical speeds (m/s).
        acc_xy: [MPC_ACC_HOR] horizontal acceleration (m/s^2).
        acc_z: [MPC_ACC_UP_MAX] vertical acceleration (m/s^2).
        gain: approach gain near the target (1/s).
        response_s: time constant of the chase of the wanted velocity (s).
    """

    speed_xy: float = 5.0
    speed_up: float = 3.0
    speed_down: float = 1.5
    acc_xy: float = 3.0
    acc_z: float = 4.0
    gain: float = 0.5
    response_s: float = 0.4


def _approach_speed(dist: float, vmax: float, acc: float, gain: float) -> float:
    return min(vmax, gain * dist, math.sqrt(2.0 * acc * dist))


class AutoReference:
    """A smoothly moving setpoint (see module docstring), NED.

    Args:
        position / velocity: start state (usually the vehicle's estimate).
    """

    def __init__(self, position: np.ndarray, velocity: np.ndarray | None = None) -> None:
        self.position = np.asarray(position, dtype=float).copy()
        self.velocity = (np.zeros(3) if velocity is None
                         else np.asarray(velocity, dtype=float).copy())
        self.acceleration = np.zeros(3)

    def stopping_point(self, limits: AutoLimits) -> np.ndarray:
        """Where the reference comes to rest when it brakes now."""
        v = self.velocity
        vh = math.hypot(v[0], v[1])
        out = self.position.copy()
        out[:2] += v[:2] * vh / (2.0 * limits.acc_xy)
        out[2] += v[2] * abs(v[2]) / (2.0 * limits.acc_z)
        return out

    def step(self, dt: float, target: np.ndarray, limits: AutoLimits) -> Setpoint:
        """Move ``dt`` seconds towards ``target`` (NaN z: hold the reference's height) and
        return the setpoint (position, velocity and acceleration feed-forward)."""
        p, v = self.position, self.velocity
        d = np.asarray(target, dtype=float) - p
        if not math.isfinite(d[2]):
            d[2] = 0.0
        want = np.zeros(3)
        dist_h = math.hypot(d[0], d[1])
        if dist_h > 1e-9:
            want[:2] = d[:2] / dist_h * _approach_speed(dist_h, limits.speed_xy, limits.acc_xy,
                                                        limits.gain)
        vmax_z = limits.speed_up if d[2] < 0.0 else limits.speed_down
        want[2] = math.copysign(_approach_speed(abs(d[2]), vmax_z, limits.acc_z, limits.gain),
                                d[2])
        acc = (want - v) / limits.response_s
        ah = math.hypot(acc[0], acc[1])
        if ah > limits.acc_xy:
            acc[:2] *= limits.acc_xy / ah
        acc[2] = min(max(acc[2], -limits.acc_z), limits.acc_z)
        self.velocity = v + acc * dt
        self.position = p + self.velocity * dt
        self.acceleration = acc
        return Setpoint(self.position.copy(), self.velocity.copy(), acc.copy())
