"""The ROTA problem on beta alone, as a chain: every limit couples two
neighbouring nodes only (paper Sec. III-D after eliminating alpha, zeta, gamma).

:class:`ChainProblem` is what every solver takes (:mod:`rota.solver`): the grid,
lambda, bounds and fixed values per node, and the rows ``a beta_i + c beta_{i+1}
<= 1`` of every interval, redundant rows removed exactly (each interval's rows
bound a polygon in the plane of its two nodes; only its edges are kept).
:func:`reach` runs the reachability passes on it (:mod:`rota.kernels.reach`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from rota.checkpoints import PathSamples
from rota.jit import kernels

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Remove the rows no beta within the bounds can make binding (exact presolve).
PRUNE_ROWS = True
#: The greedy profile counts as the top of a reachable set within this relative
#: distance (rounding of the polygon clipping); the time lost is below it.
CERTIFY_TOL = 1e-9
#: Names of the row kinds (see :mod:`rota.kernels.chain`).
KINDS = ("speed", "x acceleration", "x acceleration", "y acceleration", "y acceleration",
         "z acceleration", "z acceleration")


@dataclass(frozen=True)
class Boundary:
    """Equality constraints at the ends; None leaves the quantity free."""

    beta_start: float | None = 0.0
    alpha_start: float | None = None
    beta_end: float | None = 0.0

    def as_nan(self) -> tuple[float, float, float]:
        """``(beta_start, alpha_start, beta_end)`` with NaN for None (the kernels' form)."""
        return tuple(math.nan if x is None else float(x)  # type: ignore[return-value]
                     for x in (self.beta_start, self.alpha_start, self.beta_end))


@dataclass(frozen=True, eq=False)
class ChainProblem:
    """``min sum 2h / (sqrt b_i + sqrt b_{i+1}) + lambda sum alpha_i^2 h`` subject
    to ``lo <= b <= hi``, ``b = value`` where ``fixed``, and the rows.

    Rows of interval ``i`` are ``rptr[i]`` to ``rptr[i + 1] - 1``: coefficient
    ``ra`` on ``b_i``, ``rc`` on ``b_{i+1}``, right-hand side 1; ``rkind`` says
    which limit (index into :data:`KINDS`), ``rpoint`` at which check point.
    """

    tau: FloatArray
    smoothness: float
    lo: FloatArray
    hi: FloatArray
    fixed: NDArray[np.bool_]
    value: FloatArray
    rptr: IntArray
    rk: IntArray
    ra: FloatArray
    rc: FloatArray
    rkind: NDArray[np.int8]
    rpoint: IntArray

    @property
    def h(self) -> float:
        return float(self.tau[1] - self.tau[0])

    @property
    def n_nodes(self) -> int:
        return len(self.tau)

    def objective(self, beta: FloatArray) -> float:
        """Duration plus the smoothness term (paper Eqs. 21, 25)."""
        return objective_of(self.tau, self.smoothness, beta)


def objective_of(tau: FloatArray, smoothness: float, beta: FloatArray) -> float:
    """Duration plus the smoothness term (paper Eqs. 21, 25) of ``beta`` on the
    uniform grid ``tau``."""
    h = float(tau[1] - tau[0])
    r = np.sqrt(np.maximum(beta, 0.0))
    with np.errstate(divide="ignore"):
        t = float(np.sum(2 * h / (r[:-1] + r[1:])))
    return t + smoothness / (4 * h) * float(np.sum(np.diff(beta) ** 2))


def build(path: PathSamples, smoothness: float, boundary: Boundary) -> ChainProblem:
    """The chain problem of ``path`` with the boundary equalities of ``boundary``.

    A start acceleration fixes ``beta_1 = beta_0 + 2 h alpha_0`` as well.
    """
    n = len(path.tau)
    h = path.h
    fixed, value = kernels().boundary_nodes(n, h, *boundary.as_nan())
    hi = np.ascontiguousarray(path.beta_max, dtype=float)
    rk, ra, rc, kind, point, rptr = kernels().build_rows(
        h, path.offsets, path.frac, path.cd1, path.cd2, np.ascontiguousarray(path.vlim, float),
        path.a_max, hi, PRUNE_ROWS)
    return ChainProblem(tau=path.tau, smoothness=float(smoothness), lo=np.zeros(n), hi=hi,
                        fixed=fixed, value=value, rptr=rptr, rk=rk, ra=ra, rc=rc, rkind=kind,
                        rpoint=point)


@dataclass(frozen=True, eq=False)
class Reach:
    """Reachability of a chain problem (:mod:`rota.kernels.reach`).

    ``kl, ku``: controllable sets (beta from which the end can be reached);
    ``greedy``: the largest beta reachable node by node inside them;
    ``fail_node``, ``fail_row``: where the controllable sets became empty (-1:
    feasible; row -1: the node's own bounds); ``exact``: the greedy profile is
    the largest element of the feasible set, hence time-optimal.
    """

    kl: FloatArray
    ku: FloatArray
    greedy: FloatArray
    fail_node: int
    fail_row: int
    exact: bool

    @property
    def feasible(self) -> bool:
        return self.fail_node < 0


def reach(problem: ChainProblem, certify: bool = False) -> Reach:
    """Backward pass, then (when feasible) the greedy forward pass; with
    ``certify`` also the forward reachable sets, to tell whether the greedy profile
    is time-optimal (it is when it attains the top of every reachable set)."""
    n = problem.n_nodes
    kl, ku, greedy = np.empty(n), np.empty(n), np.empty(n)
    p = problem
    node, row, exact = kernels().passes(p.lo, p.hi, p.fixed, p.value, p.rptr, p.ra, p.rc,
                                        certify, CERTIFY_TOL, kl, ku, greedy)
    return Reach(kl, ku, greedy, int(node), int(row), bool(exact))


def tighten(problem: ChainProblem, rch: Reach) -> ChainProblem | None:
    """Bounds tightened to the controllable sets of ``rch`` (exact); nodes whose set
    is {0} are fixed at rest. None when infeasible, or when two neighbours must
    both stand still (:func:`rota.kernels.reach.tighten`)."""
    if not rch.feasible:
        return None
    hi, fixed, value, ok = kernels().tighten(problem.hi, problem.fixed, problem.value, rch.ku)
    return replace(problem, hi=hi, fixed=fixed, value=value) if ok else None


def describe(problem: ChainProblem, path: PathSamples, start_speed: float,
             end_speed: float, arclength: FloatArray) -> str:
    """Why the problem is infeasible, in words: where, and which limit.

    A forward reachability pass from the start state within the limits alone finds
    the first node the vehicle cannot reach within them, and what cut it off: a row
    (a speed or acceleration limit at a check point), the node's speed limit, or the
    requested end state.
    """
    p = problem
    n = p.n_nodes
    rl, ru = np.empty(n), np.empty(n)
    node, row = kernels().forward_reachable(p.lo, p.hi, p.fixed, p.value, p.rptr, p.ra, p.rc,
                                            rl, ru)
    head = "the limits cannot be met (the problem is infeasible)"
    if p.fixed[0] and start_speed > 0:
        head = "the limits cannot be met from this start state (the problem is infeasible)"
    if node < 0:
        return f"{head}: no feasible speed profile along the path"
    where = f"tau={p.tau[node]:.2f} s ({arclength[node]:.2f} m along the path)"
    speed = float(np.linalg.norm(path.d1[node]))
    slowest = np.sqrt(max(float(rl[node]), 0.0)) * speed
    start = f"from {start_speed:.2f} m/s at the start" if p.fixed[0] else "from the start"
    if node == n - 1 and p.fixed[-1]:
        what = "come to rest" if end_speed == 0 else f"slow down to {end_speed:.2f} m/s"
        return (f"{head}: {start} the vehicle cannot {what} by the end of the path "
                f"({arclength[-1]:.2f} m) within the acceleration limits; it arrives at "
                f"{slowest:.2f} m/s or faster")
    if row >= 0:
        kind = KINDS[int(p.rkind[row])]
        t_row = float(path.point_tau[int(p.rpoint[row])])
        return (f"{head}: {start} the vehicle cannot keep to the {kind} limit near "
                f"tau={t_row:.2f} s, before {where}")
    limit = float(path.vlim[node])
    return (f"{head}: {start} the vehicle arrives at {where} at {slowest:.2f} m/s or "
            f"faster, above the speed limit {limit:.2f} m/s there")


__all__ = ["Boundary", "ChainProblem", "Reach", "build", "describe", "objective_of", "reach",
           "tighten"]
