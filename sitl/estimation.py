"""Speed-dependent state-estimation error for the simulated vehicle.

The simulated autopilot flies on an *estimated* position ``p_est = p_true + e``. The error ``e``
(metres, per NED axis) is

    e(t) = sigma(|v(t)|) * z(t),    sigma(s) = max(m * s + b, sigma_min),

where ``|v|`` is the **3-D speed** (Euclidean norm of the true velocity, m/s) by default, or the
per-axis absolute velocity ``|v_i|`` when ``speed_mode="axis"``, and ``z`` is a zero-mean,
unit-variance, first-order Gauss-Markov process per axis with correlation time ``tau``:

    z[k+1] = phi * z[k] + sqrt(1 - phi**2) * w[k],   phi = exp(-dt / tau),   w ~ N(0, 1).

Because ``z`` has unit variance at every instant (it starts from its stationary distribution and
the exact discretisation keeps it there for any ``dt``), the per-axis standard deviation of ``e``
is exactly ``sigma(|v|)`` at every instant, and its autocorrelation at a constant speed is
``exp(-|lag| / tau)``. See docs/sitl.md for the rationale.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

SpeedMode = Literal["norm", "axis"]


@dataclass(frozen=True)
class EstimationErrorParams:
    """Parameters of the speed-dependent position-estimation error.

    Attributes:
        slope_s: ``m`` in ``sigma = m * |v| + b`` (seconds: metres of error per m/s of speed).
        offset_m: ``b`` in ``sigma = m * |v| + b`` (metres; may be negative).
        min_std_m: floor of ``sigma`` (metres), used at low speed where ``m*|v|+b`` is small.
        correlation_time_s: correlation time ``tau`` of the Gauss-Markov process (seconds).
        speed_mode: ``"norm"``: |v| is the 3-D speed, the same sigma for all three axes;
            ``"axis"``: axis i uses ``|v_i|``.
        enabled: if False the estimate equals the true state (error identically zero).
    """

    slope_s: float = 0.2
    offset_m: float = -0.1
    min_std_m: float = 0.02
    correlation_time_s: float = 1.0
    speed_mode: SpeedMode = "norm"
    enabled: bool = True

    def __post_init__(self) -> None:
        if self.min_std_m < 0.0:
            raise ValueError("min_std_m must be >= 0")
        if self.correlation_time_s <= 0.0:
            raise ValueError("correlation_time_s must be > 0")
        if self.speed_mode not in ("norm", "axis"):
            raise ValueError("speed_mode must be 'norm' or 'axis'")


def error_std(params: EstimationErrorParams, velocity: np.ndarray) -> np.ndarray:
    """Per-axis standard deviation of the position error for the given velocities.

    Args:
        params: error model parameters.
        velocity: true velocity, shape ``(3,)`` or ``(n, 3)`` (m/s, any orthonormal frame).

    Returns:
        Standard deviations in metres with the same shape as ``velocity``.
    """
    v = np.asarray(velocity, dtype=float)
    if not params.enabled:
        return np.zeros_like(v)
    if params.speed_mode == "norm" and v.shape == (3,):  # fast path for a single vector
        speed = math.sqrt(float(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]))
        return np.full(3, max(params.slope_s * speed + params.offset_m, params.min_std_m))
    if params.speed_mode == "norm":
        speed = np.linalg.norm(v, axis=-1, keepdims=True)
        speed = np.broadcast_to(speed, v.shape)
    else:
        speed = np.abs(v)
    return np.maximum(params.slope_s * speed + params.offset_m, params.min_std_m)


def std_for_speed(params: EstimationErrorParams, speed: float | np.ndarray) -> np.ndarray:
    """``max(m * speed + b, sigma_min)`` for scalar or array speeds (m/s) -> metres."""
    s = np.asarray(speed, dtype=float)
    if not params.enabled:
        return np.zeros_like(s)
    return np.maximum(params.slope_s * s + params.offset_m, params.min_std_m)


class PositionErrorModel:
    """Seeded, time-correlated position-error generator (one instance per vehicle).

    Call :meth:`step` once per simulation step with the step length and the *true* velocity;
    it returns the current error ``e`` (NED metres, shape ``(3,)``) to be added to the true
    position. :attr:`std` holds the per-axis standard deviation used for that sample, which the
    vehicle reports as its position covariance.
    """

    def __init__(self, params: EstimationErrorParams, rng: np.random.Generator) -> None:
        self.params = params
        self._rng = rng
        # Start from the stationary distribution so that Var(z) = 1 from t = 0 onward.
        self._z = rng.standard_normal(3)
        self.std = error_std(params, np.zeros(3))
        self.error = self.std * self._z if params.enabled else np.zeros(3)

    @property
    def unit_state(self) -> np.ndarray:
        """The unit-variance Gauss-Markov state ``z`` (copy)."""
        return self._z.copy()

    def step(self, dt: float, velocity: np.ndarray) -> np.ndarray:
        """Advance the Gauss-Markov state by ``dt`` seconds and return the new error (copy)."""
        if dt <= 0.0:
            return self.error.copy()
        phi = math.exp(-dt / self.params.correlation_time_s)
        self._z = phi * self._z + math.sqrt(1.0 - phi * phi) * self._rng.standard_normal(3)
        self.std = error_std(self.params, velocity)
        self.error = self.std * self._z if self.params.enabled else np.zeros(3)
        return self.error.copy()
