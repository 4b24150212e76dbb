"""The time mapping of a jerk-limited re-time (:mod:`rota.jerk`), and the path's
first three derivatives.

The paper's mapping has ``beta = tau_dot^2`` linear in tau between nodes, so
``tau_ddot`` is constant there and jumps at every node: the commanded
acceleration jumps, the jerk is unbounded. Here ``tau_ddot`` is *continuous*
and linear in tau between nodes (node values ``acc_i``), so beta is quadratic:

    beta(u) = beta_i + 2 acc_i u + kappa_i u^2,   kappa_i = (acc_{i+1} - acc_i) / h,

with ``beta_{i+1} = beta_i + h (acc_i + acc_{i+1})``. In real time ``tau_ddot =
acc_i + kappa_i u`` is a linear ODE, solved exactly (``u = acc_i C + sqrt(beta_i)
S`` with the hyperbolic or trigonometric functions of ``kappa_i``), and

    jerk = sigma''' tau_dot^3 + 3 sigma'' tau_dot tau_ddot + sigma' tau_dddot,
    tau_dddot = kappa_i tau_dot.

A vehicle at rest on a path that moves cannot leave with that form in finite
time (beta and its slope both 0), so an end at rest is a *rest interval*:
``beta = c r^{4/3}`` with ``r`` the fraction of the interval from the rest end,
which is ``tau = g t^3 / 6`` in real time (``g = 2 c^{3/2} / 9 h^2``, constant
``tau_dddot``): the jerk-limited start (and, mirrored, stop) from rest.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rota.trajectory import Trajectory

FloatArray = NDArray[np.float64]

#: Below this |kappa s^2| the series of C, S and cosh is used (error < 1e-16).
SERIES = 1e-3
#: Newton steps for an interval's duration (quadratic convergence from the
#: linear-beta duration; measured: 4-6 steps reach 1e-15).
NEWTON_STEPS = 30


#: Relative distance (to the duration) within which a point is on a breakpoint.
SNAP = 1e-11


def derivatives(traj: Trajectory, tau: ArrayLike, left: bool = False
                ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``(sigma', sigma'', sigma''')`` at ``tau`` (clamped to the domain), each
    ``(n, 3)``. At a breakpoint (within :data:`SNAP`) the piece after it
    (``left``: before it)."""
    breaks, coefs = traj.pieces
    t0, t1 = traj.domain
    x = np.clip(np.atleast_1d(np.asarray(tau, dtype=float)), t0, t1)
    m = coefs.shape[0]
    # Within SNAP of a breakpoint counts as on it: a grid node computed as
    # t0 + i h may round past a breakpoint it coincides with.
    snap = SNAP * max(t1 - t0, 1.0)
    j = (np.searchsorted(breaks, x - snap, side="left") if left
         else np.searchsorted(breaks, x + snap, side="right")) - 1
    j = np.clip(j, 0, m - 1)
    s = (x - breaks[j])[:, None]
    c = coefs[j]  # (n, k + 1, 3)
    k = c.shape[1] - 1
    d1 = np.zeros((len(x), 3))
    d2 = np.zeros((len(x), 3))
    d3 = np.zeros((len(x), 3))
    for r in range(k, 0, -1):  # Horner on the derivatives' coefficients
        d1 = d1 * s + r * c[:, r]
        if r >= 2:
            d2 = d2 * s + r * (r - 1) * c[:, r]
        if r >= 3:
            d3 = d3 * s + r * (r - 1) * (r - 2) * c[:, r]
    return d1, d2, d3


def _funcs(kappa: FloatArray, s: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``C = (cosh(sqrt(k) s) - 1) / k``, ``S = sinh(sqrt(k) s) / sqrt(k)`` and
    ``cosh(sqrt(k) s)`` (trigonometric for k < 0), series near k s^2 = 0."""
    x = kappa * s * s
    small = np.abs(x) < SERIES
    w = np.sqrt(np.abs(kappa))
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        ws = w * s
        ch = np.where(kappa > 0, np.cosh(ws), np.cos(ws))
        sh = np.where(kappa > 0, np.sinh(ws), np.sin(ws)) / w
        cc = (ch - 1.0) / kappa
    ch = np.where(small, 1.0 + x / 2 + x * x / 24, ch)
    sh = np.where(small, s * (1.0 + x / 6 + x * x / 120), sh)
    cc = np.where(small, s * s * (0.5 + x / 24 + x * x / 720), cc)
    return cc, sh, ch


def _advance(acc: FloatArray, root: FloatArray, kappa: FloatArray, s: FloatArray
             ) -> tuple[FloatArray, FloatArray]:
    """``(u, u')`` after real time ``s`` from ``u = 0`` with ``u' = root``."""
    cc, sh, ch = _funcs(kappa, s)
    return acc * cc + root * sh, acc * sh + root * ch


def _time_to(acc: FloatArray, beta0: FloatArray, beta1: FloatArray, kappa: FloatArray,
             dist: FloatArray) -> FloatArray:
    """Real time to advance ``dist`` in tau from a node (Newton from the
    linear-beta time, on a solution that only moves forward)."""
    r0 = np.sqrt(beta0)
    s = 2.0 * dist / (r0 + np.sqrt(np.maximum(beta1, 0.0)))
    s = np.where(np.isfinite(s), s, np.inf)
    ok = np.isfinite(s)
    for _ in range(NEWTON_STEPS):
        u, du = _advance(acc, r0, kappa, np.where(ok, s, 0.0))
        step = np.where(ok & (du > 0), (u - dist) / np.where(du > 0, du, 1.0), 0.0)
        s = np.where(ok, np.maximum(s - step, 0.5 * s), s)
        if np.all(np.abs(step) <= 1e-15 * np.maximum(s, 1e-300)):
            break
    return s


@dataclass(frozen=True)
class JerkTimeMap:
    """Time mapping with continuous ``tau_ddot`` (see the module text): node
    trajectory times ``tau``, ``beta = tau_dot^2`` and ``acc = tau_ddot`` at the
    nodes; ``rest_start`` / ``rest_end``: the first / last interval is a rest
    interval. Same interface as :class:`rota.timemap.TimeMap` (``alpha``: the mean
    ``tau_ddot`` of every interval)."""

    tau: FloatArray
    beta: FloatArray
    acc: FloatArray
    rest_start: bool = False
    rest_end: bool = False
    t: FloatArray = field(init=False)
    alpha: FloatArray = field(init=False)
    kappa: FloatArray = field(init=False)

    def __post_init__(self) -> None:
        tau = np.ascontiguousarray(self.tau, dtype=float)
        beta = np.maximum(np.asarray(self.beta, dtype=float), 0.0)
        acc = np.asarray(self.acc, dtype=float).copy()
        h = float(tau[1] - tau[0])
        n = len(tau) - 1
        if self.rest_start:
            beta[0], acc[0] = 0.0, 0.0
        if self.rest_end:
            beta[-1], acc[-1] = 0.0, 0.0
        # The end of every interval reaches beta_{i+1} exactly (the solver's
        # equalities hold to its tolerance only): kappa from beta, so tau_dot is
        # continuous at the nodes; tau_ddot there is continuous to that tolerance.
        kappa = (np.diff(beta) - 2.0 * h * acc[:-1]) / (h * h)
        with np.errstate(divide="ignore"):
            dt = _time_to(acc[:-1], beta[:-1], beta[1:], kappa, np.full(n, h))
            if self.rest_start:
                dt[0] = 3.0 * h / np.sqrt(beta[1])
            if self.rest_end:
                dt[-1] = 3.0 * h / np.sqrt(beta[-2])
        object.__setattr__(self, "tau", tau)
        object.__setattr__(self, "beta", beta)
        object.__setattr__(self, "acc", acc)
        object.__setattr__(self, "rest_start", bool(self.rest_start))
        object.__setattr__(self, "rest_end", bool(self.rest_end))
        object.__setattr__(self, "kappa", kappa)
        object.__setattr__(self, "t", np.concatenate([[0.0], np.cumsum(dt)]))
        object.__setattr__(self, "alpha", np.diff(beta) / (2 * h))

    @property
    def h(self) -> float:
        return float(self.tau[1] - self.tau[0])

    @property
    def duration(self) -> float:
        return float(self.t[-1])

    def _rest_g(self, node: int) -> float:
        """``tau_dddot`` of a rest interval whose inner node is ``node``."""
        return 2.0 * float(self.beta[node]) ** 1.5 / (9.0 * self.h**2)

    def evaluate(self, t: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(tau, tau_dot, tau_ddot)`` at real times ``t`` (clamped to [0, duration])."""
        tq = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), 0.0, self.duration)
        n = len(self.tau) - 1
        i = np.clip(np.searchsorted(self.t, tq, side="right") - 1, 0, n - 1)
        s = tq - self.t[i]
        h = self.h
        a0 = self.acc[i]
        kappa = self.kappa[i]
        u, du = _advance(a0, np.sqrt(self.beta[i]), kappa, s)
        u = np.clip(u, 0.0, h)
        du = np.maximum(du, 0.0)
        dd = a0 + kappa * u
        if self.rest_start:
            at = i == 0
            g = self._rest_g(1)
            u = np.where(at, np.minimum(g * s**3 / 6, h), u)
            du = np.where(at, g * s**2 / 2, du)
            dd = np.where(at, g * s, dd)
        if self.rest_end:
            at = i == n - 1
            g = self._rest_g(n - 1)
            r = np.maximum(self.t[-1] - tq, 0.0)
            u = np.where(at, np.maximum(h - g * r**3 / 6, 0.0), u)
            du = np.where(at, g * r**2 / 2, du)
            dd = np.where(at, -g * r, dd)
        return self.tau[i] + u, du, dd

    def real_time(self, tau: ArrayLike) -> FloatArray:
        """Inverse mapping: real time at which trajectory time ``tau`` is reached."""
        x = np.clip(np.atleast_1d(np.asarray(tau, dtype=float)), self.tau[0], self.tau[-1])
        n = len(self.tau) - 1
        h = self.h
        i = np.clip(np.searchsorted(self.tau, x, side="right") - 1, 0, n - 1)
        d = x - self.tau[i]
        a0 = self.acc[i]
        kappa = self.kappa[i]
        b_at = self.beta[i] + 2 * a0 * d + kappa * d * d
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(d > 0, _time_to(a0, self.beta[i], b_at, kappa, d), 0.0)
            if self.rest_start:
                s = np.where(i == 0, np.cbrt(6 * d / self._rest_g(1)), s)
            if self.rest_end:
                s = np.where(i == n - 1,
                             self.t[-1] - self.t[i] - np.cbrt(6 * (h - d) / self._rest_g(n - 1)),
                             s)
        return self.t[i] + s


__all__ = ["JerkTimeMap", "derivatives"]
