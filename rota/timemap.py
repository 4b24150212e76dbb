"""The time mapping tau = h(t) reconstructed from beta (paper Eqs. 2, 18-20).

Between grid nodes beta is linear in tau, i.e. the trajectory time has constant
acceleration ``alpha_i = (beta_{i+1} - beta_i) / (2 h)`` on interval i. So, exactly:

* interval duration ``dt_i = 2 h / (sqrt(beta_i) + sqrt(beta_{i+1}))``;
* inside it, ``tau(t) = tau_i + sqrt(beta_i) s + alpha_i s^2 / 2`` with ``s = t - t_i``,
  ``tau_dot = sqrt(beta_i) + alpha_i s``, ``tau_ddot = alpha_i``.

The mapping is monotone by construction (beta >= 0) and reaches ``tau_{i+1}``
exactly at ``t_{i+1}``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class TimeMap:
    """Time mapping on the grid: trajectory times ``tau`` and ``beta = tau_dot^2``."""

    tau: FloatArray
    beta: FloatArray
    t: FloatArray = field(init=False)
    alpha: FloatArray = field(init=False)

    def __post_init__(self) -> None:
        from rota.jit import kernels  # noqa: PLC0415 - the kernels load lazily

        tau = np.ascontiguousarray(self.tau, dtype=float)
        beta, t, alpha = kernels().time_map(tau, np.ascontiguousarray(self.beta, dtype=float))
        object.__setattr__(self, "tau", tau)
        object.__setattr__(self, "beta", beta)
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "alpha", alpha)

    @property
    def duration(self) -> float:
        """Total real time of the re-timed trajectory (paper Eq. 8)."""
        return float(self.t[-1])

    def evaluate(self, t: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(tau, tau_dot, tau_ddot)`` at real times ``t`` (clamped to [0, duration])."""
        tq = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), 0.0, self.duration)
        i = np.clip(np.searchsorted(self.t, tq, side="right") - 1, 0, len(self.alpha) - 1)
        s = tq - self.t[i]
        r0 = np.sqrt(self.beta[i])
        a = self.alpha[i]
        tau = np.minimum(self.tau[i] + r0 * s + 0.5 * a * s * s, self.tau[i + 1])
        tau_dot = np.maximum(r0 + a * s, 0.0)
        return tau, tau_dot, a.copy()

    def real_time(self, tau: ArrayLike) -> FloatArray:
        """Inverse mapping: real time at which trajectory time ``tau`` is reached."""
        x = np.clip(np.atleast_1d(np.asarray(tau, dtype=float)), self.tau[0], self.tau[-1])
        i = np.clip(np.searchsorted(self.tau, x, side="right") - 1, 0, len(self.alpha) - 1)
        d = x - self.tau[i]
        r0 = np.sqrt(self.beta[i])
        r = np.sqrt(np.maximum(self.beta[i] + 2.0 * self.alpha[i] * d, 0.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(r0 + r > 0, 2.0 * d / (r0 + r), 0.0)
        return self.t[i] + s
