"""One round of the re-time: check points, the chain problem, reachability, the
solve, and the audit of its answer between the check points (paper Sec. III-D,
with constraint generation around it).

:func:`one_round` does it in one compiled call (:mod:`rota.kernels.rounds`),
made of the same kernels that :func:`rota.checkpoints.sample_path`,
:func:`rota.chain.build`, :func:`rota.chain.reach` and :func:`rota.solver.solve`
call one by one; the interior-point solver runs inside it when it is the chosen
method. Clarabel, and the hand-over to Clarabel when the fast solver reports
trouble, stay in Python (:func:`finish`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from rota.chain import (
    CERTIFY_TOL,
    PRUNE_ROWS,
    Boundary,
    ChainProblem,
    build,
    objective_of,
    reach,
    tighten,
)
from rota.checkpoints import (
    BETA_CAP_FACTOR,
    NO_POINTS,
    PIECE_PARTS,
    STILL,
    PathSamples,
    uniform_parts,
)
from rota.jit import kernels
from rota.problem import SolverSettings
from rota.solver import START_CAP, START_SHARE, SolverStats, fast_status, hand_over, solve
from rota.trajectory import Trajectory

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: A limit broken by more than this share between check points (speed, or
#: acceleration on any axis) triggers a re-solve with more check points.
REFINE_TOL = 5e-4


@dataclass(frozen=True, eq=False)
class Audit:
    """The limits at a solution (:func:`audit`).

    ``more``: the points ``(interval, fraction)`` between check points where a limit
    is broken by more than :data:`REFINE_TOL`, or None; ``speed``: the largest speed
    squared over its limit squared (nodes and check points); ``acc``: the largest
    acceleration over its limit at the check points, on ``axis`` at check point
    ``point``.
    """

    more: tuple[IntArray, FloatArray] | None
    speed: float
    acc: float
    axis: int
    point: int


def audit(traj: Trajectory, path: PathSamples, beta: FloatArray) -> Audit:
    """Check ``beta`` at every node and check point, and probe the midpoint of every
    gap between check points (one compiled pass, :func:`rota.kernels.path.audit`)."""
    m = len(path.frac)
    bad_i, bad_f = np.empty(m, dtype=np.int64), np.empty(m)
    breaks, coefs = traj.pieces
    n_bad, speed, acc, axis, point = kernels().audit(
        np.ascontiguousarray(beta, dtype=float), path.tau, path.offsets, path.frac, path.cd1,
        path.cd2, path.vlim, path.a_max, path.beta_max, breaks, coefs, REFINE_TOL, bad_i, bad_f)
    return _audit(n_bad, bad_i[:n_bad], bad_f[:n_bad], speed, acc, axis, point)


def _audit(n_bad: int, bad_i: IntArray, bad_f: FloatArray, speed: float, acc: float,
           axis: int, point: int) -> Audit:
    more = (bad_i, bad_f) if n_bad else None
    return Audit(more, float(speed), float(acc), int(axis), int(point))


@dataclass(frozen=True, eq=False)
class Round:
    """What a round found.

    ``path``: the check points; ``greedy``: the greedy profile of reachability;
    ``fail_node``, ``fail_row``: where the problem became infeasible (-1:
    feasible, see :class:`rota.chain.Reach`); ``exact``: the greedy profile is
    certified time-optimal; ``ok``: feasible, and tightening the bounds to the
    controllable sets leaves no two neighbours standing still; ``beta``,
    ``stats``, ``audit``: the answer, how it was found and its audit, None until
    :func:`finish` (or the compiled solve) found one. :attr:`problem` and
    :attr:`tight` are made again from ``path`` when asked for (the rare paths:
    an infeasible request's diagnosis, Clarabel), with the same kernels.
    """

    path: PathSamples
    smoothness: float
    boundary: Boundary
    greedy: FloatArray
    fail_node: int
    fail_row: int
    exact: bool
    ok: bool
    beta: FloatArray | None = None
    stats: SolverStats | None = None
    audit: Audit | None = None

    @property
    def feasible(self) -> bool:
        return self.fail_node < 0

    @cached_property
    def problem(self) -> ChainProblem:
        """The chain problem as built (bounds from the speed limits)."""
        return build(self.path, self.smoothness, self.boundary)

    @cached_property
    def tight(self) -> ChainProblem | None:
        """:attr:`problem` with the bounds tightened to the controllable sets; None
        unless :attr:`ok`."""
        return tighten(self.problem, reach(self.problem)) if self.ok else None


def one_round(traj: Trajectory, tau: FloatArray, d1: FloatArray, d2: FloatArray,
              vlim: FloatArray, a_max: FloatArray, boundary: Boundary, smoothness: float,
              settings: SolverSettings,
              more: tuple[IntArray, FloatArray] = NO_POINTS) -> Round:
    """Check points of the grid ``tau`` (plus ``more``, added by earlier rounds'
    audits), the chain problem with the limits ``vlim`` (per node) and ``a_max``
    and the ``boundary`` equalities, reachability, and with ``settings.method ==
    "fast"`` the interior-point solve and its audit, in one compiled call.
    ``d1``, ``d2``: the path's derivatives at the nodes. At lambda = 0 the
    reachability pass may certify the greedy profile time-optimal; then no solver
    runs. The fast solver's stats give the time of the whole compiled call (the
    solve inside it cannot be timed apart)."""
    fast = settings.method == "fast"
    certify = smoothness == 0.0 and fast
    breaks, coefs = traj.pieces
    t0, t1 = traj.domain
    h = float(tau[1] - tau[0])
    start = time.perf_counter()
    p, r, s, a = kernels().one_round(
        breaks, coefs, t0, t1, tau, d1, vlim, a_max, uniform_parts(h), PIECE_PARTS, STILL,
        BETA_CAP_FACTOR, more[0], more[1], smoothness, *boundary.as_nan(), PRUNE_ROWS,
        certify, CERTIFY_TOL, fast, START_SHARE, START_CAP, settings.fast_tol,
        settings.max_iter, REFINE_TOL)
    wall = time.perf_counter() - start
    offsets, frac, cd1, cd2, beta_max, moving = p
    path = PathSamples(tau, d1, d2, beta_max, vlim, a_max, offsets, frac, cd1, cd2, moving)
    greedy, node, row, exact, ok = r
    found = (path, smoothness, boundary, greedy, node, row, exact, ok)
    x, code, iterations, objective = s
    checked = None if a[0] < 0 else _audit(*a)
    if ok and exact:
        stats = SolverStats("Solved", 0, 0.0, 0.0, objective_of(tau, smoothness, greedy),
                            "reachability")
        return Round(*found, greedy, stats, checked)
    if code < 0:  # the interior-point method did not run (rota.kernels.rounds.NOT_RUN)
        return Round(*found)
    stats = SolverStats(fast_status(code), int(iterations), wall, wall, float(objective), "fast")
    return Round(*found, x if code == 0 else None, stats, checked)


def finish(traj: Trajectory, rnd: Round, settings: SolverSettings) -> Round:
    """``rnd`` with an answer: Clarabel when it is the chosen method, or when the
    fast solver inside the round did not converge (then its stats go into the
    note). Returns ``rnd`` itself when it has one, or when it is infeasible."""
    if rnd.beta is not None or not rnd.ok:
        return rnd
    tight = rnd.tight
    if rnd.stats is None:
        beta, stats = solve(tight, settings, start=rnd.greedy)
    else:
        beta, stats = hand_over(tight, settings, rnd.stats)
    checked = None if beta is None else audit(traj, rnd.path, beta)
    return replace(rnd, beta=beta, stats=stats, audit=checked)


def more_points(before: tuple[IntArray, FloatArray],
                found: tuple[IntArray, FloatArray]) -> tuple[IntArray, FloatArray]:
    """The added check points of the rounds so far and those an audit ``found``."""
    return np.concatenate([before[0], found[0]]), np.concatenate([before[1], found[1]])


__all__ = ["REFINE_TOL", "Audit", "Round", "audit", "finish", "more_points", "one_round"]
