"""Assembly of the ROTA second-order cone program (paper Sec. III-D).

Decision variables on the grid ``tau_0 .. tau_N`` (step ``h``):

* ``beta_i = tau_dot^2`` at the nodes (Eq. 18), piecewise linear in tau;
* ``alpha_i = tau_ddot`` on interval i. With the correct kinematics
  ``d beta / d tau = 2 tau_ddot`` (the paper's Eq. 20 drops the 2), so
  ``alpha_i = (beta_{i+1} - beta_i) / (2 h)`` and alpha is eliminated;
* ``zeta_i <= sqrt(beta_i)`` (rotated cone, Eq. 22) and
  ``gamma_i >= 1 / (zeta_i + zeta_{i+1})`` (rotated cone, Eq. 24).

Objective (Eqs. 21, 25 with the notes' errata): total time
``sum 2 h gamma_i`` plus ``lambda * sum alpha_i^2 h`` (the smoothness integral
of Eq. 9, a quadratic term; the paper's printed linear ``lambda alpha_i`` is a
typo).

Constraints: speed ``|sigma'|^2 beta <= v^2`` (Eq. 23; an upper bound on beta at
the nodes), acceleration per axis ``|sigma'_k alpha_i + sigma''_k beta| <= a_max_k``
(Eq. 26) at both ends of every interval (alpha jumps at nodes), both also at
interior check points (see :class:`PathSamples`), and boundary equalities for
stitching onto a moving vehicle.

The result is Clarabel's standard form ``min 1/2 x'Px + q'x, Ax + s = b,
s in K``, built with vectorised sparse assembly (no loops over samples).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import clarabel
import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from rota.trajectory import Trajectory

FloatArray = NDArray[np.float64]


#: Below this |sigma'| (m per second of trajectory time) the path is standing still.
STILL = 1e-6
#: beta may exceed the median speed-limited beta by at most this factor (tau_dot x 100).
BETA_CAP_FACTOR = 1e4
#: Candidate check points per interval (the interior of a uniform subdivision).
DENSE = 8
#: ... and at most this far apart (s of trajectory time), so coarse grids get more.
DENSE_SPACING = 0.025
#: Intervals over which |sigma'| changes by more than this ratio start fully checked.
REFINE_RATIO = 1.2
#: Start constraint generation with the interval midpoints constrained too. Off:
#: the nodes (both ends of every interval) and breakpoints suffice almost
#: everywhere, and a violated midpoint activates its interval (measured in
#: docs/benchmarks.md: fewer rows beat the occasional extra round).
INITIAL_MIDPOINTS = False
#: Leave out rows that no beta within its bounds can violate (exact presolve).
PRUNE_ROWS = True


@dataclass(frozen=True)
class PathSamples:
    """The path and its limits on the grid: what the SOCP needs, nothing more.

    Beyond the nodes, the limits are imposed at *check points* inside the
    intervals. Candidates are the interior points of a uniform subdivision of
    every interval into ``DENSE`` parts (more on coarse grids, so they are at most
    ``DENSE_SPACING`` apart), both of its ends (alpha jumps at nodes) and
    the path's own breakpoints; ``active`` says which are constrained. The nodes
    (both ends of every interval) and breakpoints always are (the midpoints too
    with :data:`INITIAL_MIDPOINTS`), and every candidate of an interval over
    which the path's speed ``|sigma'|`` changes fast (near a stop, such as a
    clamped B-spline end). The re-timer activates more where a solution violates
    a limit at a candidate
    (constraint generation, see :func:`rota.retime.retime`). Beta is linear in tau
    inside an interval: at fraction ``f`` of interval ``i``,
    ``beta = (1 - f) beta_i + f beta_{i+1}``.
    """

    tau: FloatArray  # (N+1,)
    d1: FloatArray  # (N+1, 3) sigma' at the nodes
    d2: FloatArray  # (N+1, 3) sigma'' at the nodes
    beta_max: FloatArray  # (N+1,) bound on beta from the node speed limits and the cap
    vlim: FloatArray  # (N+1,) speed limit per node (m/s)
    a_max: FloatArray  # (3,)
    pt_interval: NDArray[np.int64]  # (M,) interval of each candidate check point
    pt_fraction: FloatArray  # (M,) its fraction in [0, 1] of the interval
    pt_d1: FloatArray  # (M, 3) sigma' there
    pt_d2: FloatArray  # (M, 3) sigma'' there
    active: NDArray[np.bool_]  # (M,) constrained in the SOCP

    @property
    def n_intervals(self) -> int:
        return len(self.tau) - 1

    @property
    def h(self) -> float:
        return float(self.tau[1] - self.tau[0])

    def activate(self, intervals: NDArray[np.int64]) -> PathSamples:
        """The same path with every candidate of ``intervals`` constrained."""
        more = self.active | np.isin(self.pt_interval, intervals)
        return replace(self, active=more)

    def vlim2_between(self, i: NDArray[np.int64], f: FloatArray) -> FloatArray:
        """Squared speed limit at fraction ``f`` of interval ``i``: interpolated
        linearly between the nodes' squared limits (exact for a braking profile
        ``v^2 = v0^2 - 2 a s`` on a path of constant ``|sigma'|``)."""
        return (1 - f) * self.vlim[i] ** 2 + f * self.vlim[i + 1] ** 2

    def ratios(self, beta: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Speed and acceleration of ``beta`` at every candidate, as fractions of
        their limits (speed: squared ratio; acceleration: worst axis)."""
        i, f = self.pt_interval, self.pt_fraction
        b = (1 - f) * beta[i] + f * beta[i + 1]
        alpha = np.diff(beta) / (2 * self.h)
        lim2 = self.vlim2_between(i, f)
        v2 = np.einsum("ij,ij->i", self.pt_d1, self.pt_d1) * b / lim2
        acc = self.pt_d1 * alpha[i, None] + self.pt_d2 * b[:, None]
        return v2, np.max(np.abs(acc) / self.a_max, axis=1)


def sample_path(trajectory: Trajectory, tau: FloatArray, vlim: FloatArray,
                a_max: FloatArray, midpoints: bool | None = None) -> PathSamples:
    """Evaluate the path on the grid and at the candidate check points.

    ``beta_max`` is the speed bound ``v_i^2 / |sigma'_i|^2`` (Eq. 23); where the path
    stands still (``|sigma'| = 0``, e.g. a B-spline's clamped end) beta is capped at
    :data:`BETA_CAP_FACTOR` times the median speed bound, so the problem stays
    bounded and well scaled.
    """
    n = len(tau) - 1
    h = np.diff(tau)
    _, d1, d2 = trajectory.evaluate(tau)
    parts = max(DENSE, int(np.ceil(float(h.max()) / DENSE_SPACING)))
    inner = np.arange(1, parts) / parts
    # The path's own breakpoints are candidates too: its acceleration peaks there.
    bp = trajectory.breakpoints
    bp_idx = np.clip(np.searchsorted(tau, bp, side="right") - 1, 0, n - 1)
    bp_frac = (bp - tau[bp_idx]) / h[bp_idx]
    keep = (bp_frac > 1e-9) & (bp_frac < 1 - 1e-9)
    idx = np.concatenate([np.repeat(np.arange(n), len(inner)), bp_idx[keep]])
    frac = np.concatenate([np.tile(inner, n), bp_frac[keep]])
    _, c1, c2 = trajectory.evaluate(tau[idx] + frac * h[idx])
    ends = np.arange(n)
    idx = np.concatenate([ends, ends, idx])
    frac = np.concatenate([np.zeros(n), np.ones(n), frac])
    c1 = np.concatenate([d1[:-1], d1[1:], c1])
    c2 = np.concatenate([d2[:-1], d2[1:], c2])
    speed = np.linalg.norm(d1, axis=1)
    lo = np.minimum(speed[:-1], speed[1:])
    hi = np.maximum(speed[:-1], speed[1:])
    refine = np.flatnonzero(hi > REFINE_RATIO * np.maximum(lo, STILL))
    if midpoints is None:
        midpoints = INITIAL_MIDPOINTS
    active = (frac == 0) | (frac == 1) | np.isin(idx, refine)
    if midpoints:
        active |= np.abs(frac - 0.5) < 1e-12
    active[2 * n + n * len(inner):] = True  # breakpoints
    moving = speed > STILL
    with np.errstate(divide="ignore"):
        beta_v = np.where(moving, vlim**2 / np.maximum(speed, STILL) ** 2, np.inf)
    cap = BETA_CAP_FACTOR * float(np.median(beta_v[moving])) if moving.any() else 1.0
    return PathSamples(tau=tau, d1=d1, d2=d2, beta_max=np.minimum(beta_v, cap), vlim=vlim,
                       a_max=a_max, pt_interval=idx, pt_fraction=frac, pt_d1=c1, pt_d2=c2,
                       active=active)


@dataclass(frozen=True)
class Boundary:
    """Equality constraints at the ends; None leaves the quantity free."""

    beta_start: float | None = 0.0
    alpha_start: float | None = None
    beta_end: float | None = 0.0


@dataclass(frozen=True)
class Socp:
    """A problem in Clarabel's standard form plus the variable layout."""

    P: sp.csc_matrix
    q: FloatArray
    A: sp.csc_matrix
    b: FloatArray
    cones: list
    n_nodes: int

    def beta(self, x: FloatArray) -> FloatArray:
        return np.asarray(x[: self.n_nodes])


def assemble(path: PathSamples, smoothness: float, boundary: Boundary) -> Socp:
    """Build the SOCP of paper Eqs. 21-26 for ``path`` (vectorised, sparse)."""
    n = path.n_intervals
    nb = n + 1
    h = path.h
    ib = np.arange(nb)  # beta indices
    iz = nb + np.arange(nb)  # zeta indices
    ig = 2 * nb + np.arange(n)  # gamma indices
    nx = 2 * nb + n

    # Objective: 2h * sum(gamma) + lambda/(4h) * sum((beta_{i+1}-beta_i)^2).
    q = np.zeros(nx)
    q[ig] = 2.0 * h
    w = smoothness / (2.0 * h)  # 1/2 x'Px form: P = (lambda / 2h) D'D
    if w > 0:
        diag = np.full(nb, 2.0 * w)
        diag[[0, -1]] = w
        upper = np.full(n, -w)
        pb = sp.diags([diag, upper], [0, 1], shape=(nb, nb), format="coo")
        P = sp.coo_matrix((pb.data, (pb.row, pb.col)), shape=(nx, nx)).tocsc()
    else:
        P = sp.csc_matrix((nx, nx))

    rows: list[np.ndarray] = []
    cols: list[np.ndarray] = []
    vals: list[np.ndarray] = []
    rhs: list[np.ndarray] = []
    cones: list = []
    offset = 0

    def block(r: np.ndarray, c: np.ndarray, v: np.ndarray, b: np.ndarray) -> None:
        nonlocal offset
        rows.append(r + offset)
        cols.append(c)
        vals.append(v)
        rhs.append(b)
        offset += len(b)

    # Zero cone: boundary equalities.
    eq_r, eq_c, eq_v, eq_b = [], [], [], []
    k = 0
    if boundary.beta_start is not None:
        eq_r.append([k]), eq_c.append([ib[0]]), eq_v.append([1.0]), eq_b.append(boundary.beta_start)
        k += 1
    if boundary.beta_end is not None:
        eq_r.append([k]), eq_c.append([ib[-1]]), eq_v.append([1.0]), eq_b.append(boundary.beta_end)
        k += 1
    if boundary.alpha_start is not None:
        eq_r.append([k, k]), eq_c.append([ib[0], ib[1]])
        eq_v.append([-1.0 / (2 * h), 1.0 / (2 * h)]), eq_b.append(boundary.alpha_start)
        k += 1
    if k:
        block(np.concatenate(eq_r), np.concatenate(eq_c), np.concatenate(eq_v).astype(float),
              np.asarray(eq_b, dtype=float))
        cones.append(clarabel.ZeroConeT(k))

    # Nonnegative cone: beta_i <= beta_max_i (speed limits at the nodes, Eq. 23).
    block(ib.copy(), ib.copy(), np.ones(nb), path.beta_max.astype(float))
    n_nonneg = nb

    # Speed (Eq. 23) and acceleration (Eq. 26) at every check point. At fraction f
    # of interval i, with beta(f) = (1 - f) beta_i + f beta_{i+1}:
    #   |sigma'(f)|^2 beta(f) <= v^2       (interior points; the nodes are bounds)
    #   |sigma'_k(f) (beta_{i+1} - beta_i) / 2h + sigma''_k(f) beta(f)| <= a_max_k
    # Rows are scaled by their limit so every right-hand side is 1.
    act = path.active
    ci, f = path.pt_interval[act], path.pt_fraction[act]
    pd1, pd2 = path.pt_d1[act], path.pt_d2[act]
    # With PRUNE_ROWS a row is left out when no beta in [0, beta_max] can break it
    # (its largest value over that box is at most 1): an exact presolve that drops,
    # e.g., every z row of a flat path and the speed rows away from the limit.
    bmax = path.beta_max
    inner = (f > 0) & (f < 1)
    ci_in, f_in = ci[inner], f[inner]
    lim2 = path.vlim2_between(ci_in, f_in)
    w = np.einsum("ij,ij->i", pd1[inner], pd1[inner]) / lim2
    w_lo, w_hi = (1 - f_in) * w, f_in * w
    if PRUNE_ROWS:
        keep = w_lo * bmax[ci_in] + w_hi * bmax[ci_in + 1] > 1.0
        ci_in, w_lo, w_hi = ci_in[keep], w_lo[keep], w_hi[keep]
    m = len(ci_in)
    r = np.arange(m)
    block(np.concatenate([r, r]), np.concatenate([ib[ci_in], ib[ci_in + 1]]),
          np.concatenate([w_lo, w_hi]), np.ones(m))
    n_nonneg += m
    d1 = pd1 / path.a_max
    d2 = pd2 / path.a_max
    c_lo = (-d1 / (2 * h) + (1 - f)[:, None] * d2).ravel()  # coefficient on beta_i
    c_hi = (d1 / (2 * h) + f[:, None] * d2).ravel()  # coefficient on beta_{i+1}
    j_lo, j_hi = np.repeat(ib[ci], 3), np.repeat(ib[ci + 1], 3)  # row per (point, axis)
    for sign in (1.0, -1.0):
        a_lo, a_hi, k_lo, k_hi = sign * c_lo, sign * c_hi, j_lo, j_hi
        if PRUNE_ROWS:
            keep = (np.maximum(a_lo, 0.0) * bmax[k_lo] + np.maximum(a_hi, 0.0) * bmax[k_hi]
                    > 1.0)
            a_lo, a_hi, k_lo, k_hi = a_lo[keep], a_hi[keep], k_lo[keep], k_hi[keep]
        r = np.arange(len(a_lo))
        block(np.concatenate([r, r]), np.concatenate([k_lo, k_hi]),
              np.concatenate([a_lo, a_hi]), np.ones(len(r)))
        n_nonneg += len(r)
    cones.append(clarabel.NonnegativeConeT(n_nonneg))

    # SOC: beta_i * 1 >= zeta_i^2  <=>  ||(2 zeta_i, beta_i - 1)|| <= beta_i + 1.
    r3 = 3 * ib
    block(np.concatenate([r3, r3 + 1, r3 + 2]),
          np.concatenate([ib, iz, ib]),
          np.concatenate([-np.ones(nb), -2.0 * np.ones(nb), -np.ones(nb)]),
          np.tile([1.0, 0.0, -1.0], nb))
    # SOC: gamma_i (zeta_i + zeta_{i+1}) >= 1
    #   <=>  ||(2, gamma_i - zeta_i - zeta_{i+1})|| <= gamma_i + zeta_i + zeta_{i+1}.
    i = np.arange(n)
    r3 = 3 * i
    block(np.concatenate([r3, r3, r3, r3 + 2, r3 + 2, r3 + 2]),
          np.concatenate([ig, iz[i], iz[i + 1], ig, iz[i], iz[i + 1]]),
          np.concatenate([-np.ones(n), -np.ones(n), -np.ones(n),
                          -np.ones(n), np.ones(n), np.ones(n)]),
          np.tile([0.0, 2.0, 0.0], n))
    cones.extend([clarabel.SecondOrderConeT(3)] * (nb + n))

    A = sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(offset, nx))
    return Socp(P=sp.triu(P, format="csc"), q=q, A=A, b=np.concatenate(rhs), cones=cones,
                n_nodes=nb)
