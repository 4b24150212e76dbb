"""State-estimation error and hover wander of the simulated vehicle.

The simulated autopilot flies on an *estimated* position ``p_est = p_true + e``. Per NED axis
the error has two independent parts, ``e = e_v + e_0``:

* the **speed-dependent** part of the paper's model (Eq. 15), with the standard deviation
  ``sigma(s) = max(m * s + b, sigma_min)`` (times ``vertical_scale`` on the vertical axis),
  where ``s`` is the 3-D speed (or ``|v_i|`` with ``speed_mode="axis"``). Where the speed
  enters makes the two error models (``kind``):

  - ``"correlated"`` (default): ``e_v(t) = sigma(|v(t)|) z(t)``, ``z`` a unit-variance
    first-order Gauss-Markov process with correlation time ``tau``::

        z[k+1] = phi z[k] + sqrt(1 - phi^2) w[k],   phi = exp(-dt / tau),   w ~ N(0, 1);

    ``z`` starts from its stationary distribution, so the std of ``e_v`` is exactly
    ``sigma(|v|)`` at every instant (it **shrinks the instant the vehicle slows down**) and
    its autocorrelation at a constant speed is ``exp(-|lag| / tau)``;
  - ``"drift"``: the error accumulates; the speed drives its *increments*::

        e_v[k+1] = phi e_v[k] + sigma(|v[k+1]|) sqrt(1 - phi^2) w[k].

    Over short times the variance grows like a random walk, by ``2 sigma^2 / tau`` per
    second, i.e. with the distance flown and faster at higher speed; after the vehicle slows
    down the error stays and only fades with ``tau``, the time over which the estimate is
    re-anchored to the obstacles it measures them against (docs/table1.md, "Error models").
    At a constant speed its std is ``sigma(|v|)``, as the correlated model's, so the two
    differ only in their memory. The std reported is the exact running value,
    ``P[k+1] = phi^2 P[k] + sigma^2 (1 - phi^2)``;
* a **speed-independent** part ``e_0 = s_0 * y`` that reproduces PX4's EKF in SIH (GPS-driven,
  0.1-0.3 m horizontally, a slowly varying height offset): ``y`` is a smooth unit-variance
  process, the second of two cascaded first-order filters with time constant ``T_0``::

      u[k+1] = phi u[k] + sqrt(1 - phi^2) w'[k],   y'[k+1] = phi y'[k] + (1 - phi) u[k],
      y = y' (1 + phi) / sqrt(1 + phi^2)            (Var y = 1; phi = exp(-dt / T_0)).

Besides the estimate, PX4's vehicle **wanders** in hover (it is never still: sensor noise, the
estimator's yaw error): a disturbance acceleration ``d = s_d * q`` acts on the *true* vehicle,
``q`` a unit-variance first-order Gauss-Markov process with time constant ``T_d``. The values
of ``PX4_SIH_ESTIMATION`` were fitted to the hover and tracking recordings of PX4's SIH quadrotor
(docs/sitl.md, "Calibration"); the dataclass defaults are the paper's model alone.

Random numbers: one generator per vehicle; at start three normals for ``z``, then (when the
part is on) three for ``u``, three for ``y'``, three for ``q``; each step three for ``z``,
then three for ``u`` and three for ``q`` (:attr:`PositionErrorModel.draws_per_step`), so
:mod:`sitl.batch` reproduces a vehicle draw for draw.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

SpeedMode = Literal["norm", "axis"]
ErrorKind = Literal["correlated", "drift"]
Vec3 = tuple[float, float, float]
#: The speed-dependent error models, by name.
KINDS: tuple[ErrorKind, ...] = ("correlated", "drift")


@dataclass(frozen=True)
class EstimationErrorParams:
    """Parameters of the estimation error and of the hover wander (see module docstring).

    Attributes:
        slope_s: ``m`` in ``sigma = m * |v| + b`` (seconds: metres of error per m/s of speed).
        offset_m: ``b`` in ``sigma = m * |v| + b`` (metres; may be negative).
        min_std_m: floor of ``sigma`` (metres), used at low speed where ``m*|v|+b`` is small.
        correlation_time_s: correlation time ``tau`` of the Gauss-Markov process (seconds).
        speed_mode: ``"norm"``: |v| is the 3-D speed, the same sigma for all three axes;
            ``"axis"``: axis i uses ``|v_i|``.
        base_std_m: per-axis std ``s_0`` of the speed-independent error (NED, m).
        base_time_constant_s: per-axis ``T_0`` of its smooth process (s).
        reported_base_std_m: what the autopilot *reports* for that part in its covariance
            (PX4's EKF states about 0.2 m whatever its real error).
        wander_acc_std_m_s2: per-axis std ``s_d`` of the disturbance acceleration (m/s^2).
        wander_time_constant_s: per-axis ``T_d`` of the disturbance (s).
        enabled: if False there is no noise at all: the estimate equals the true state and
            nothing disturbs the vehicle (an idealised vehicle).
        kind: the speed-dependent part's model: ``"correlated"`` (its amplitude follows the
            speed) or ``"drift"`` (the speed drives its increments; it fades with ``tau``).
        vertical_scale: its vertical (NED z) std is this share of the horizontal one.
            Default 0.5: height is held by a barometer or rangefinder and is free of the
            heading error that spreads horizontal drift (docs/table1.md, "Error models").
    """

    slope_s: float = 0.2
    offset_m: float = -0.1
    min_std_m: float = 0.02
    correlation_time_s: float = 1.0
    speed_mode: SpeedMode = "norm"
    base_std_m: Vec3 = (0.0, 0.0, 0.0)
    base_time_constant_s: Vec3 = (1.8, 1.8, 30.0)
    reported_base_std_m: Vec3 = (0.0, 0.0, 0.0)
    wander_acc_std_m_s2: Vec3 = (0.0, 0.0, 0.0)
    wander_time_constant_s: Vec3 = (7.5, 7.5, 2.8)
    enabled: bool = True
    kind: ErrorKind = "correlated"
    vertical_scale: float = 0.5

    def __post_init__(self) -> None:
        if self.min_std_m < 0.0:
            raise ValueError("min_std_m must be >= 0")
        if self.correlation_time_s <= 0.0:
            raise ValueError("correlation_time_s must be > 0")
        if self.speed_mode not in ("norm", "axis"):
            raise ValueError("speed_mode must be 'norm' or 'axis'")
        if self.kind not in KINDS:
            raise ValueError(f"kind must be one of {KINDS}")
        if not 0.0 <= self.vertical_scale <= 10.0:
            raise ValueError("vertical_scale must be in [0, 10]")
        for name in ("base_std_m", "reported_base_std_m", "wander_acc_std_m_s2"):
            if len(getattr(self, name)) != 3 or min(getattr(self, name)) < 0.0:
                raise ValueError(f"{name} must be three values >= 0")
        for name in ("base_time_constant_s", "wander_time_constant_s"):
            if len(getattr(self, name)) != 3 or min(getattr(self, name)) <= 0.0:
                raise ValueError(f"{name} must be three values > 0")

    @property
    def has_base(self) -> bool:
        """The speed-independent error part is on."""
        return self.enabled and max(self.base_std_m) > 0.0

    @property
    def has_wander(self) -> bool:
        """The hover-wander disturbance is on."""
        return self.enabled and max(self.wander_acc_std_m_s2) > 0.0

    @property
    def axis_scale(self) -> np.ndarray:
        """Per-axis factor of sigma (NED): ``(1, 1, vertical_scale)``."""
        return np.array([1.0, 1.0, self.vertical_scale])


#: PX4's EKF and hover wander in SIH (quadrotor x, PX4 defaults), fitted to the recordings in
#: docs/sitl.md: estimate - truth 0.18 m per horizontal axis (T_0 1.8 s) and 0.45 m in height
#: (T_0 30 s: a slowly varying offset), reported as 0.2 m; no measurable dependence on speed.
PX4_SIH_ESTIMATION = EstimationErrorParams(
    slope_s=0.0, offset_m=0.0, min_std_m=0.0,
    base_std_m=(0.18, 0.18, 0.45), base_time_constant_s=(1.8, 1.8, 30.0),
    reported_base_std_m=(0.2, 0.2, 0.2),
    wander_acc_std_m_s2=(0.73, 0.73, 0.6), wander_time_constant_s=(7.5, 7.5, 2.8))

#: No noise at all: the estimate is the truth and nothing disturbs the vehicle.
IDEAL = EstimationErrorParams(enabled=False)

#: The drift model with the correlated model's sigma and a 3 s re-anchoring time.
DRIFT = EstimationErrorParams(kind="drift", correlation_time_s=3.0)


def error_std(params: EstimationErrorParams, velocity: np.ndarray) -> np.ndarray:
    """Per-axis std of the speed-dependent error part for the given velocities.

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
        s = max(params.slope_s * speed + params.offset_m, params.min_std_m)
        return np.array([s, s, s * params.vertical_scale])
    if params.speed_mode == "norm":
        speed = np.linalg.norm(v, axis=-1, keepdims=True)
        speed = np.broadcast_to(speed, v.shape)
    else:
        speed = np.abs(v)
    return np.maximum(params.slope_s * speed + params.offset_m, params.min_std_m) \
        * params.axis_scale


def std_for_speed(params: EstimationErrorParams, speed: float | np.ndarray) -> np.ndarray:
    """``max(m * speed + b, sigma_min)`` for scalar or array speeds (m/s) -> metres."""
    s = np.asarray(speed, dtype=float)
    if not params.enabled:
        return np.zeros_like(s)
    return np.maximum(params.slope_s * s + params.offset_m, params.min_std_m)


def smooth_coefficients(params: EstimationErrorParams, dt: float
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-axis step coefficients for ``dt``: ``phi_0`` and the output scale of the smooth
    part, ``phi_d`` and ``sqrt(1 - phi_d^2)`` of the wander."""
    phi0 = np.exp(-dt / np.asarray(params.base_time_constant_s, dtype=float))
    scale0 = np.asarray(params.base_std_m, dtype=float) * (1.0 + phi0) / np.sqrt(1.0 + phi0**2)
    phid = np.exp(-dt / np.asarray(params.wander_time_constant_s, dtype=float))
    return phi0, scale0, phid, np.sqrt(1.0 - phid**2)


class PositionErrorModel:
    """Seeded generator of the estimation error and the wander (one instance per vehicle).

    Call :meth:`step` once per simulation step with the step length and the *true* velocity.
    :attr:`error` is the current error ``e`` (NED m, added to the true position),
    :attr:`std` its per-axis standard deviation, :attr:`reported_std` what the vehicle reports
    as its position uncertainty, :attr:`disturbance` the wander acceleration (NED m/s^2).

    Args:
        params: model parameters.
        rng: the vehicle's generator.
        dt: the physics step, used to start the smooth part in its stationary distribution.
    """

    def __init__(self, params: EstimationErrorParams, rng: np.random.Generator,
                 dt: float = 0.004) -> None:
        self.params = params
        self._rng = rng
        self._base0 = np.asarray(params.base_std_m, dtype=float) if params.has_base else None
        self._rep0 = np.asarray(params.reported_base_std_m, dtype=float) ** 2
        self._wander = params.has_wander
        #: normals drawn per step (the batch simulator draws the same)
        self.draws_per_step = 3 + 3 * (self._base0 is not None) + 3 * self._wander
        self._coef_dt = dt
        self._coef = smooth_coefficients(params, dt)
        # Start from the stationary distribution so that Var(z) = 1 from t = 0 onward; the
        # drift model carries its error itself (stationary at hover) and its variance.
        self._drift = params.kind == "drift"
        self._z = rng.standard_normal(3)
        self._var = error_std(params, np.zeros(3)) ** 2
        if self._drift:
            self._z = np.sqrt(self._var) * self._z
        self._u = np.zeros(3)
        self._y = np.zeros(3)
        if self._base0 is not None:
            phi0 = self._coef[0]
            self._u = rng.standard_normal(3)
            # stationary (u, y'): Cov = phi / (1 + phi), Var y' = (1 + phi^2) / (1 + phi)^2
            self._y = (phi0 * self._u + rng.standard_normal(3)) / (1.0 + phi0)
        self._q = rng.standard_normal(3) if self._wander else np.zeros(3)
        self._update(error_std(params, np.zeros(3)))

    @property
    def unit_state(self) -> np.ndarray:
        """The carried state of the speed-dependent part (copy): the unit-variance ``z``
        (correlated), or the error itself (drift)."""
        return self._z.copy()

    def state(self) -> dict[str, np.ndarray]:
        """The processes' states ``z``, ``u``, ``y`` (``y'``) and ``q``, and ``var`` (the drift
        model's running variance) (copies)."""
        return {"z": self._z.copy(), "u": self._u.copy(), "y": self._y.copy(),
                "q": self._q.copy(), "var": self._var.copy()}

    def _update(self, speed_std: np.ndarray) -> None:
        p = self.params
        if self._drift:
            e = self._z.copy() if p.enabled else np.zeros(3)
            std2 = self._var.copy()
        else:
            e = speed_std * self._z if p.enabled else np.zeros(3)
            std2 = speed_std**2
        rep2 = std2
        if self._base0 is not None:
            e = e + self._coef[1] * self._y
            std2 = std2 + self._base0**2
            rep2 = rep2 + self._rep0
        self.error = e
        self.std = np.sqrt(std2)
        self.reported_std = np.sqrt(rep2)
        wander = np.asarray(p.wander_acc_std_m_s2, dtype=float)
        self.disturbance = wander * self._q if self._wander else np.zeros(3)

    def step(self, dt: float, velocity: np.ndarray) -> np.ndarray:
        """Advance the processes by ``dt`` seconds and return the new error (copy)."""
        if dt <= 0.0:
            return self.error.copy()
        if dt != self._coef_dt:
            self._coef, self._coef_dt = smooth_coefficients(self.params, dt), dt
        w = self._rng.standard_normal(self.draws_per_step)
        phi = math.exp(-dt / self.params.correlation_time_s)
        gain = math.sqrt(1.0 - phi * phi)
        sigma = error_std(self.params, velocity)
        if self._drift:
            self._z = phi * self._z + gain * sigma * w[:3]
            self._var = phi * phi * self._var + (gain * sigma) ** 2
        else:
            self._z = phi * self._z + gain * w[:3]
        k = 3
        phi0, _, phid, gaind = self._coef
        if self._base0 is not None:
            self._y = phi0 * self._y + (1.0 - phi0) * self._u
            self._u = phi0 * self._u + np.sqrt(1.0 - phi0**2) * w[k:k + 3]
            k += 3
        if self._wander:
            self._q = phid * self._q + gaind * w[k:k + 3]
        self._update(sigma)
        return self.error.copy()
