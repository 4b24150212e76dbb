"""The jerk-limited problem (:mod:`rota.jerk`, ``Limits.j_max`` set; beyond the paper).

The time mapping is :class:`rota.jerkmap.JerkTimeMap`: ``beta`` quadratic in tau
between nodes, ``tau_ddot`` (node values ``acc``) continuous, so the commanded
acceleration is continuous and the jerk finite. Unknowns: ``beta_i`` and
``acc_i`` at the nodes, tied by ``beta_{i+1} = beta_i + h (acc_i + acc_{i+1})``.
At a check point (fraction ``f`` of interval ``i``, ``u = f h``)

    beta  = beta_i + acc_i (2u - u^2/h) + acc_{i+1} u^2/h        (linear)
    accel = sigma' tau_ddot + sigma'' beta                       (linear)
    jerk  = sqrt(beta) L,  L = sigma''' beta + 3 sigma'' tau_ddot + sigma' kappa_i

Speed and acceleration limits stay linear. The jerk limit ``|L| <= J / sqrt(beta)``
is not convex; its right-hand side is convex in beta, so the tangent at the
previous iterate ``b`` lies below it: ``|L| <= J (3 b - beta) / (2 b^{3/2})`` is a
linear *inner* approximation (as COPP does). Every iterate that meets it meets
the true bound, and the duration never increases from one iterate to the next
(successive convexification). The first iterate starts from the unlimited
optimum, which need not meet it: the rows have slacks at a large price (an exact
penalty); a solution with slack left is refused, never returned.

A rest interval (:mod:`rota.jerkmap`) has one unknown (its inner node's beta
``c``); its limits are bounds on ``c`` (jerk: ``c^{3/2} |G| <= J``).

Time: ``sum`` over intervals of ``int du / sqrt(beta(u))``, by the quadrature
:data:`GAUSS` (``t >= 1 / z``, ``z <= sqrt(beta)``: two 3-d second-order cones per
node); a rest interval's is exact, ``3 h / sqrt(c)``. The result's duration is
the exact one of the time map.

After convergence an audit evaluates the exact limits on a grid four times
denser than the check points (and at the path's breakpoints, both sides); a limit
broken there adds those points and the problem is solved again.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import clarabel
import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from rota.jerkmap import derivatives
from rota.problem import RetimeInput, SolverSettings
from rota.solver import clarabel_settings

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Check points per interval (uniform), plus the path's breakpoints.
PARTS = 2
#: The audit probes this many times denser than the check points.
AUDIT_FACTOR = 4
#: A limit may be exceeded by this share at most (audit, and the result's check).
LIMIT_TOL = 1e-3
#: Successive convexification stops when the duration changes less than this
#: (relative), or after :data:`MAX_STEPS` solves.
STEP_TOL = 1e-5
MAX_STEPS = 40
#: Rounds of constraint generation after the audit.
MAX_ROUNDS = 4
#: Price of the jerk rows' slack, times the marginal value of beta there.
PENALTY = 100.0
#: Quadrature nodes of the time integral on [0, 1] (the midpoint rule; measured on
#: the 7 m bench row: the same duration to 1e-8 as two-point Gauss, 30 % less CPU).
GAUSS = (0.5,)
NORMAL, REST_START, REST_END = 0, 1, 2


@dataclass(frozen=True)
class Points:
    """Check points: interval, fraction, the path's derivatives, squared speed
    limit; ``left``: derivatives from the piece before (a breakpoint's left side)."""

    interval: IntArray
    frac: FloatArray
    d1: FloatArray
    d2: FloatArray
    d3: FloatArray
    lim2: FloatArray


def make_points(inp: RetimeInput, tau: FloatArray, vlim: FloatArray, parts: int,
                extra: tuple[IntArray, FloatArray] | None = None) -> Points:
    """Uniform fractions ``0, 1/parts, .., 1`` of every interval, the path's
    breakpoints inside intervals (both sides) and ``extra`` points."""
    n = len(tau) - 1
    h = float(tau[1] - tau[0])
    f = np.linspace(0.0, 1.0, parts + 1)
    iv = np.repeat(np.arange(n), parts + 1)
    fr = np.tile(f, n)
    edges = inp.trajectory.edges
    inner = edges[(edges > tau[0]) & (edges < tau[-1])]
    bi = np.clip(np.searchsorted(tau, inner, side="right") - 1, 0, n - 1)
    bf = (inner - tau[bi]) / h
    keep = (bf > 1e-9) & (bf < 1 - 1e-9)  # else it is on a node
    bi, bf = bi[keep], bf[keep]
    left = np.concatenate([fr == 1.0, np.ones(len(bi), bool), np.zeros(len(bi), bool)])
    # Nodes and breakpoints are evaluated at their own numbers (tau_i + f h may
    # round to the other side of a breakpoint, where the third derivative jumps).
    at = np.concatenate([np.where(fr == 1.0, tau[np.minimum(iv + 1, n)], tau[iv] + fr * h),
                         inner[keep], inner[keep]])
    iv = np.concatenate([iv, bi, bi])
    fr = np.concatenate([fr, bf, bf])
    if extra is not None and len(extra[0]):
        iv = np.concatenate([iv, extra[0]])
        fr = np.concatenate([fr, extra[1]])
        left = np.concatenate([left, extra[1] == 1.0])
        at = np.concatenate([at, np.where(extra[1] == 1.0, tau[extra[0] + 1],
                                          tau[extra[0]] + extra[1] * h)])
    r1, r2, r3 = derivatives(inp.trajectory, at, left=False)
    l1, l2, l3 = derivatives(inp.trajectory, at, left=True)
    lf = left[:, None]
    lim2 = (1 - fr) * vlim[iv] ** 2 + fr * vlim[iv + 1] ** 2
    return Points(iv, fr, np.where(lf, l1, r1), np.where(lf, l2, r2), np.where(lf, l3, r3),
                  lim2)


@dataclass(frozen=True)
class Layout:
    """The problem's shape: nodes, interval kinds, the boundary equalities."""

    tau: FloatArray
    kind: IntArray  # per interval
    beta_start: float | None
    acc_start: float | None
    beta_end: float | None
    cap: float

    @property
    def h(self) -> float:
        return float(self.tau[1] - self.tau[0])

    @property
    def nb(self) -> int:
        return len(self.tau)


def _maps(lay: Layout, pts: Points) -> tuple[IntArray, FloatArray, FloatArray, FloatArray]:
    """Per point: the three columns ``(beta_i, acc_i, acc_{i+1})`` and the
    coefficients of beta, tau_ddot and kappa on them (normal intervals; rest
    intervals' points get zero coefficients here)."""
    h = lay.h
    i = pts.interval
    u = pts.frac * h
    cols = np.stack([i, lay.nb + i, lay.nb + i + 1], axis=1)
    cb = np.stack([np.ones_like(u), 2 * u - u * u / h, u * u / h], axis=1)
    ca = np.stack([np.zeros_like(u), 1 - pts.frac, pts.frac], axis=1)
    ck = np.stack([np.zeros_like(u), np.full_like(u, -1 / h), np.full_like(u, 1 / h)], axis=1)
    normal = (lay.kind[i] == NORMAL)[:, None]
    return cols, cb * normal, ca * normal, ck * normal


def _rest(lay: Layout, pts: Points) -> tuple[NDArray[np.bool_], IntArray, FloatArray,
                                                 FloatArray, FloatArray]:
    """Rest-interval points: mask, the column of ``c``, and per unit ``c`` the
    beta, tau_ddot and (per axis) ``G`` with ``jerk = c^{3/2} G``."""
    h = lay.h
    n = lay.nb - 1
    k = lay.kind[pts.interval]
    start = k == REST_START
    end = k == REST_END
    r = np.where(start, pts.frac, 1 - pts.frac)
    col = np.where(start, 1, n - 1)
    sgn = np.where(start, 1.0, -1.0)
    rb = r ** (4 / 3)
    ra = sgn * (2 / 3) * np.cbrt(r) / h
    g = (pts.d3 * (r * r)[:, None] + 2 * sgn[:, None] * pts.d2 * (r / h)[:, None]
         + (2 / 9) * pts.d1 / h**2)
    return start | end, col, rb, ra, g


class _Rows:
    """Sparse rows ``A x <= b`` (or ``= b``) gathered block by block."""

    def __init__(self) -> None:
        self.r: list[FloatArray] = []
        self.c: list[FloatArray] = []
        self.v: list[FloatArray] = []
        self.b: list[FloatArray] = []
        self.count = 0

    def add(self, cols: IntArray, vals: FloatArray, rhs: FloatArray) -> None:
        """One row per line of ``cols`` / ``vals`` (2-D, same shape)."""
        m = len(rhs)
        if m == 0:
            return
        rows = np.repeat(np.arange(m) + self.count, cols.shape[1])
        self.r.append(rows)
        self.c.append(cols.ravel())
        self.v.append(vals.ravel())
        self.b.append(np.asarray(rhs, dtype=float))
        self.count += m


def _assemble(lay: Layout, pts: Points, a_max: FloatArray, j_max: FloatArray,
              bbar: FloatArray, smoothness: float, jrow: NDArray[np.bool_]
              ) -> tuple[sp.csc_matrix, FloatArray, sp.csc_matrix, FloatArray, list, int]:
    """Clarabel's ``(P, q, A, b, cones)`` of one convexified problem, and the
    column of the first slack. ``jrow``: the points with jerk rows (fixed for a
    round, so every step has the same sparsity)."""
    nb = lay.nb
    n = nb - 1
    h = lay.h
    normal_iv = np.flatnonzero(lay.kind == NORMAL)
    rest_iv = np.flatnonzero(lay.kind != NORMAL)
    n_t = len(GAUSS) * len(normal_iv) + len(rest_iv)
    cols, cb, ca, ck = _maps(lay, pts)
    rest_mask, rcol, rb, ra, rg = _rest(lay, pts)
    is_normal = ~rest_mask
    n_s = int(jrow.sum())
    t0 = 2 * nb
    s0 = t0 + n_t
    nx = s0 + n_s

    # Equalities.
    eq = _Rows()
    iv = normal_iv
    eq.add(np.stack([iv + 1, iv, nb + iv, nb + iv + 1], 1),
           np.tile([1.0, -1.0, -h, -h], (len(iv), 1)), np.zeros(len(iv)))
    fixed: list[tuple[int, float]] = []
    if lay.kind[0] == REST_START:
        fixed += [(0, 0.0), (nb, 0.0)]
        eq.add(np.array([[nb + 1, 1]]), np.array([[1.0, -2 / (3 * h)]]), np.zeros(1))
    else:
        if lay.beta_start is not None:
            fixed.append((0, lay.beta_start))
        if lay.acc_start is not None:
            fixed.append((nb, lay.acc_start))
    if lay.kind[-1] == REST_END:
        fixed += [(n, 0.0), (2 * nb - 1, 0.0)]
        eq.add(np.array([[2 * nb - 2, n - 1]]), np.array([[1.0, 2 / (3 * h)]]), np.zeros(1))
    elif lay.beta_end is not None:
        fixed.append((n, lay.beta_end))
    if fixed:
        eq.add(np.array([[c] for c, _ in fixed]), np.ones((len(fixed), 1)),
               np.array([v for _, v in fixed]))

    # Inequalities.
    le = _Rows()
    nodes = np.arange(nb)[:, None]
    le.add(nodes, -np.ones((nb, 1)), np.zeros(nb))  # beta >= 0
    le.add(nodes, np.ones((nb, 1)) / lay.cap, np.ones(nb))  # beta <= cap
    # Speed and acceleration at the end of an interval are those at the start of
    # the next (the path is C2, beta and tau_ddot continuous): one row each.
    m = is_normal & ((pts.frac < 1.0) | (pts.interval == n - 1))
    inner = m & (pts.frac > 0.0) & (pts.frac < 1.0)
    le.add(cols[inner], -cb[inner], np.zeros(int(inner.sum())))  # beta >= 0 between nodes
    c3 = cols[m]
    s2 = np.einsum("ij,ij->i", pts.d1, pts.d1)
    sp_ok = m & np.isfinite(pts.lim2) & (s2 > 0)
    le.add(cols[sp_ok], cb[sp_ok] * (s2[sp_ok] / pts.lim2[sp_ok])[:, None],
           np.ones(int(sp_ok.sum())))
    for ax in range(3):
        acc = (pts.d1[m, ax][:, None] * ca[m] + pts.d2[m, ax][:, None] * cb[m]) / a_max[ax]
        le.add(c3, acc, np.ones(len(c3)))
        le.add(c3, -acc, np.ones(len(c3)))
    # Jerk rows (normal points): sgn L w + beta - e bbar <= 3 bbar, w = 2 bbar^1.5 / J.
    jc = cols[jrow]
    bb = np.maximum(bbar[jrow], 1e-12 * max(float(bbar.max(initial=0.0)), 1e-300))
    slack = (s0 + np.arange(n_s))[:, None]
    for ax in range(3):
        w = 2 * bb**1.5 / j_max[ax]
        L = (pts.d3[jrow, ax][:, None] * cb[jrow] + 3 * pts.d2[jrow, ax][:, None] * ca[jrow]
             + pts.d1[jrow, ax][:, None] * ck[jrow])
        for sgn in (1.0, -1.0):
            vals = sgn * L * w[:, None] + cb[jrow]
            le.add(np.hstack([jc, slack]), np.hstack([vals, -bb[:, None]]),
                   3.0 * bb)
    le.add(slack, -np.ones((n_s, 1)), np.zeros(n_s))  # e >= 0
    # Rest intervals: bounds on c.
    rm = rest_mask
    if rm.any():
        rc = rcol[rm][:, None]
        ok = np.isfinite(pts.lim2[rm])
        le.add(rc[ok], (s2[rm] * rb[rm] / pts.lim2[rm])[ok][:, None], np.ones(int(ok.sum())))
        for ax in range(3):
            acc = (pts.d1[rm, ax] * ra[rm] + pts.d2[rm, ax] * rb[rm]) / a_max[ax]
            le.add(rc, acc[:, None], np.ones(len(rc)))
            le.add(rc, -acc[:, None], np.ones(len(rc)))
            gk = np.abs(rg[rm, ax])
            big = gk > 0
            le.add(rc[big], np.ones((int(big.sum()), 1)), (j_max[ax] / gk[big]) ** (2 / 3))

    # Time: t >= 1 / z, z <= sqrt(beta(u)) (two 3-d second-order cones each, with
    # z in the columns after the slacks): ||(beta - 1, 2 z)|| <= beta + 1 and
    # ||(t - z, 2)|| <= t + z.
    z0 = nx
    nx += n_t
    q = np.zeros(nx)
    cone_r: list[FloatArray] = []
    cone_c: list[FloatArray] = []
    cone_v: list[FloatArray] = []
    cone_b: list[FloatArray] = []

    def cones_for(k: int, bcols: list[int], bvals: list[float], weight: float) -> None:
        tcol, zcol = t0 + k, z0 + k
        q[tcol] = weight
        base = 6 * k
        bc = np.array(bcols)
        bv = np.array(bvals)
        m = len(bc)
        cone_r.append(np.concatenate([np.full(m, base), np.full(m, base + 1),
                                      [base + 2, base + 3, base + 3, base + 5, base + 5]]))
        cone_c.append(np.concatenate([bc, bc, [zcol, tcol, zcol, tcol, zcol]]))
        cone_v.append(np.concatenate([-bv, -bv, [-2.0, -1.0, -1.0, -1.0, 1.0]]))
        cone_b.append(np.array([1.0, -1.0, 0.0, 0.0, 2.0, 0.0]))

    k = 0
    for g in GAUSS:
        u = g * h
        for i in normal_iv:
            cones_for(k, [i, nb + i, nb + i + 1], [1.0, 2 * u - u * u / h, u * u / h],
                      h / len(GAUSS))
            k += 1
    for i in rest_iv:
        cones_for(k, [1 if lay.kind[i] == REST_START else n - 1], [1.0], 3 * h)
        k += 1
    # Slack price: PENALTY times the marginal time of beta (per bbar) at the point.
    q[s0:s0 + n_s] = PENALTY * (h / PARTS) * 0.5 / np.sqrt(bb)
    # Smoothness: lambda * int tau_ddot^2 dtau.
    pr, pc, pv = [], [], []
    lam = smoothness
    if lam > 0:
        for i in normal_iv:
            a0, a1 = nb + i, nb + i + 1
            pr += [a0, a0, a1]
            pc += [a0, a1, a1]
            pv += [2 * lam * h / 3, lam * h / 3, 2 * lam * h / 3]
        for i in rest_iv:
            node = 1 if lay.kind[i] == REST_START else n - 1
            pr.append(node)
            pc.append(node)
            pv.append(2 * lam * (4 / 15) / h)
    P = sp.csc_matrix((pv, (pr, pc)), shape=(nx, nx))

    n_eq, n_le = eq.count, le.count
    rows = ([r for r in eq.r] + [r + n_eq for r in le.r]
            + [r + n_eq + n_le for r in cone_r])
    A = sp.csc_matrix((np.concatenate(eq.v + le.v + cone_v),
                       (np.concatenate(rows), np.concatenate(eq.c + le.c + cone_c))),
                      shape=(n_eq + n_le + 6 * n_t, nx))
    b = np.concatenate(eq.b + le.b + cone_b)
    cones = [clarabel.ZeroConeT(n_eq), clarabel.NonnegativeConeT(n_le)]
    cones += [clarabel.SecondOrderConeT(3)] * (2 * n_t)
    return P, q, A, b, cones, s0


def beta_at(lay: Layout, pts: Points, beta: FloatArray, acc: FloatArray) -> FloatArray:
    """Beta of the solution at the points (normal and rest intervals)."""
    cols, cb, _, _ = _maps(lay, pts)
    x = np.concatenate([beta, acc])
    out = np.einsum("ij,ij->i", cb, x[cols])
    rest_mask, rcol, rb, _, _ = _rest(lay, pts)
    return np.where(rest_mask, beta[rcol] * rb, out)


def limit_ratios(lay: Layout, pts: Points, beta: FloatArray, acc: FloatArray,
                 a_max: FloatArray, j_max: FloatArray) -> tuple[FloatArray, FloatArray,
                                                                 FloatArray, FloatArray]:
    """Exact ``(speed, acceleration, jerk)`` over their limits at every point (the
    largest axis), and beta there."""
    cols, cb, ca, ck = _maps(lay, pts)
    x = np.concatenate([beta, acc])
    xv = x[cols]
    b = np.einsum("ij,ij->i", cb, xv)
    a = np.einsum("ij,ij->i", ca, xv)
    kap = np.einsum("ij,ij->i", ck, xv)
    rest_mask, rcol, rb, ra, rg = _rest(lay, pts)
    c = beta[rcol]
    b = np.where(rest_mask, c * rb, b)
    a = np.where(rest_mask, c * ra, a)
    bp = np.maximum(b, 0.0)
    acc_v = pts.d1 * a[:, None] + pts.d2 * b[:, None]
    jerk = np.sqrt(bp)[:, None] * (pts.d3 * b[:, None] + 3 * pts.d2 * a[:, None]
                                   + pts.d1 * kap[:, None])
    jerk = np.where(rest_mask[:, None], (np.maximum(c, 0.0) ** 1.5)[:, None] * rg, jerk)
    s2 = np.einsum("ij,ij->i", pts.d1, pts.d1)
    with np.errstate(divide="ignore", invalid="ignore"):
        speed = np.where(np.isfinite(pts.lim2), np.sqrt(s2 * bp / pts.lim2), 0.0)
    return (speed, np.max(np.abs(acc_v) / a_max, axis=1),
            np.max(np.abs(jerk) / j_max, axis=1), b)


@dataclass(frozen=True)
class JerkSolve:
    """What the successive convexification found (``beta``, ``acc`` None on failure)."""

    beta: FloatArray | None
    acc: FloatArray | None
    steps: int
    status: str
    slack: float
    seconds: float


def solve(lay: Layout, pts: Points, a_max: FloatArray, j_max: FloatArray,
          bbar: FloatArray, smoothness: float, tol: float, given: SolverSettings) -> JerkSolve:
    """Successive convexification from ``bbar`` (beta at the points)."""
    settings = clarabel_settings(replace_settings(tol, given))
    start = time.perf_counter()
    last = math.inf
    beta = acc = None
    status, slack = "not run", math.inf
    steps = 0
    rest_mask = _rest(lay, pts)[0]
    jrow = ~rest_mask & (bbar > 1e-12 * max(float(bbar.max(initial=0.0)), 1e-300))
    solver = None
    pattern: tuple[FloatArray, FloatArray] | None = None
    for steps in range(1, MAX_STEPS + 1):  # noqa: B007 - the count is reported
        P, q, A, b, cones, s0 = _assemble(lay, pts, a_max, j_max, bbar, smoothness, jrow)
        try:
            # Same sparsity every step: update the data, keep the symbolic work.
            if (solver is not None and pattern is not None
                    and np.array_equal(pattern[0], A.indptr)
                    and np.array_equal(pattern[1], A.indices)):
                solver.update(q=q, A=A.data, b=b)
            else:
                solver = clarabel.DefaultSolver(P, q, A, b, cones, settings)
                pattern = (A.indptr.copy(), A.indices.copy())
            sol = solver.solve()
        except Exception as exc:  # noqa: BLE001 - the solver must never take the caller down
            return JerkSolve(None, None, steps, f"SolverError: {exc}", math.inf,
                             time.perf_counter() - start)
        status = str(sol.status).split(".")[-1]
        if status not in ("Solved", "AlmostSolved"):
            break
        x = np.asarray(sol.x)
        nb = lay.nb
        beta, acc = np.maximum(x[:nb], 0.0), x[nb:2 * nb]
        n_s = len(q) - s0 - (s0 - 2 * nb)
        slack = float(np.max(x[s0:s0 + n_s], initial=0.0))
        obj = float(q[2 * nb:s0] @ x[2 * nb:s0])
        bbar = np.maximum(beta_at(lay, pts, beta, acc), 0.0)
        if slack <= 1e-7 and abs(last - obj) <= STEP_TOL * obj:
            break
        last = obj if slack <= 1e-7 else math.inf
    ok = status in ("Solved", "AlmostSolved")
    return JerkSolve(beta if ok else None, acc if ok else None, steps, status, slack,
                     time.perf_counter() - start)


def replace_settings(tol: float, given: SolverSettings) -> SolverSettings:
    """Clarabel settings for the convexified problems: ``tol``, presolve off (the
    steps update the data of the same rows); the time and iteration limits of
    ``given`` (the input's)."""
    return SolverSettings(method="clarabel", tol=tol, presolve=False,
                          time_limit=given.time_limit, max_iter=given.max_iter)


__all__ = ["JerkSolve", "Layout", "Points", "beta_at", "limit_ratios", "make_points", "solve"]
