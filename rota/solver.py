"""The solvers of a :class:`rota.chain.ChainProblem` behind one interface.

* ``"fast"`` (default): the structure-exploiting interior-point method of
  :mod:`rota.kernels.ipm` (one O(N) tridiagonal Newton solve per step, compiled);
* ``"clarabel"``: the SOCP of paper Sec. III-D (:mod:`rota.socp`) solved by
  Clarabel, the reference and the fallback when the fast solver reports trouble.

:func:`solve` never raises and never returns NaN.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass

import clarabel
import numpy as np
from numpy.typing import NDArray

from rota.chain import ChainProblem
from rota.jit import kernels
from rota.problem import SolverSettings
from rota.socp import Socp, assemble

FloatArray = NDArray[np.float64]

_OK = {"Solved", "AlmostSolved"}
_FAST_STATUS = {0: "Solved", 1: "MaxIterations", 2: "NumericalError"}
#: The fast solver starts from the greedy profile scaled by this (strictly feasible).
START_SHARE = 0.9
#: With smoothing (lambda > 0) the start is at most this many times the median of
#: the greedy profile (measured: 14-24 steps instead of 19-46 on the bench rows).
START_CAP = 2.0


@dataclass(frozen=True)
class SolverStats:
    """What the solver reported. ``status`` uses Clarabel's status names;
    ``method`` is the solver that produced the answer, ``note`` what happened
    before (for example why the fast solver handed over to Clarabel)."""

    status: str
    iterations: int
    solve_time: float  # seconds, as reported by the solver
    wall_time: float  # seconds, setup + solve, measured here
    objective: float
    method: str = "clarabel"
    note: str = ""

    @property
    def ok(self) -> bool:
        return self.status in _OK


def solve(problem: ChainProblem, settings: SolverSettings,
          start: FloatArray | None = None) -> tuple[FloatArray | None, SolverStats]:
    """Solve with ``settings.method``; the fast solver hands over to Clarabel when
    it does not converge. ``start``: a feasible beta (the greedy profile of
    :func:`rota.chain.reach`) for the fast solver. Returns ``(beta, stats)``;
    ``beta`` is None unless solved; fixed nodes hold exactly their values."""
    if settings.method == "fast":
        beta, stats = solve_fast(problem, settings, start)
        if beta is not None:
            return beta, stats
        return hand_over(problem, settings, stats)
    return solve_clarabel(problem, settings)


def hand_over(problem: ChainProblem, settings: SolverSettings,
              failed: SolverStats) -> tuple[FloatArray | None, SolverStats]:
    """Clarabel on ``problem`` after the fast solver did not converge (``failed``:
    what it reported, which goes into the note)."""
    beta, fallback = solve_clarabel(problem, settings)
    note = f"fast solver: {failed.status} after {failed.iterations} iterations"
    return beta, SolverStats(fallback.status, fallback.iterations, fallback.solve_time,
                             fallback.wall_time + failed.wall_time, fallback.objective,
                             fallback.method, note)


def fast_status(code: int) -> str:
    """The status name of the interior-point kernel's return ``code``."""
    return _FAST_STATUS.get(int(code), f"code {code}")


def solve_fast(problem: ChainProblem, settings: SolverSettings,
               start: FloatArray | None = None) -> tuple[FloatArray | None, SolverStats]:
    """The compiled interior-point method (:mod:`rota.kernels.ipm`)."""
    t0 = time.perf_counter()
    p = problem
    k = kernels()
    if start is None:
        start = np.where(np.isfinite(p.hi), p.hi, 1.0)
    # The greedy profile runs up to the bound where the path stands still (a clamped
    # end: any beta is at rest there); with smoothing the optimum does not, and
    # starting there costs the solver a dozen steps: hence the cap.
    x = np.empty(p.n_nodes)
    try:
        code, iters, obj = k.ipm_solve(p.h, p.smoothness, p.lo, p.hi, p.fixed, p.value,
                                       np.ascontiguousarray(start, dtype=float), START_SHARE,
                                       START_CAP, p.rk, p.ra, p.rc, settings.fast_tol,
                                       settings.max_iter, x)
    except Exception as exc:  # noqa: BLE001 - the solver must never take the caller down
        wall = time.perf_counter() - t0
        return None, SolverStats(f"SolverError: {exc}", 0, wall, wall, float("nan"), "fast")
    wall = time.perf_counter() - t0
    status = fast_status(code)
    stats = SolverStats(status, int(iters), wall, wall, float(obj), "fast")
    if status != "Solved":
        return None, stats
    return x, stats


class _SymbolicCache:
    """The last Clarabel solver, reusable for a problem of identical sparsity."""

    key: bytes | None = None
    solver: clarabel.DefaultSolver | None = None

    @staticmethod
    def fingerprint(problem: Socp, settings: SolverSettings) -> bytes:
        h = hashlib.blake2b(digest_size=16)
        for m in (problem.P, problem.A):
            h.update(np.asarray(m.shape, dtype=np.int64).tobytes())
            h.update(m.indptr.tobytes())
            h.update(m.indices.tobytes())
        h.update(repr(problem.cones[:2]).encode())  # zero and nonnegative cone sizes
        h.update(np.asarray([len(problem.cones)], dtype=np.int64).tobytes())
        h.update(repr(settings).encode())
        return h.digest()


_cache = _SymbolicCache()


def clarabel_settings(settings: SolverSettings) -> clarabel.DefaultSettings:
    """The Clarabel settings for ``settings`` (see :class:`SolverSettings`)."""
    s = clarabel.DefaultSettings()
    s.verbose = settings.verbose
    s.max_iter = settings.max_iter
    s.time_limit = settings.time_limit
    s.tol_gap_abs = settings.tol
    s.tol_gap_rel = settings.tol
    s.tol_feas = settings.tol
    s.iterative_refinement_enable = settings.iterative_refinement
    s.equilibrate_enable = settings.equilibrate
    s.presolve_enable = settings.presolve
    return s


def _make_solver(problem: Socp, settings: SolverSettings) -> clarabel.DefaultSolver:
    if not settings.reuse_symbolic:
        return clarabel.DefaultSolver(problem.P, problem.q, problem.A, problem.b,
                                      problem.cones, clarabel_settings(settings))
    key = _cache.fingerprint(problem, settings)
    solver = _cache.solver
    if key == _cache.key and solver is not None:
        solver.update(P=problem.P.data, q=problem.q, A=problem.A.data, b=problem.b)
        return solver
    # Data updates need the problem's rows unchanged: no presolve (it may drop rows).
    solver = clarabel.DefaultSolver(problem.P, problem.q, problem.A, problem.b, problem.cones,
                                    clarabel_settings(settings))
    if solver.is_data_update_allowed():
        _cache.key, _cache.solver = key, solver
    return solver


def solve_clarabel(problem: ChainProblem,
                   settings: SolverSettings) -> tuple[FloatArray | None, SolverStats]:
    """The SOCP of :mod:`rota.socp` with Clarabel."""
    start = time.perf_counter()
    try:
        socp = assemble(problem)
        solver = _make_solver(socp, settings)
        sol = solver.solve()
    except Exception as exc:  # noqa: BLE001 - the solver must never take the caller down
        _cache.key = _cache.solver = None
        wall = time.perf_counter() - start
        return None, SolverStats(f"SolverError: {exc}", 0, 0.0, wall, float("nan"))
    wall = time.perf_counter() - start
    status = str(sol.status).split(".")[-1]
    x = np.asarray(sol.x, dtype=float)
    stats = SolverStats(status, int(sol.iterations), float(sol.solve_time), wall,
                        float(sol.obj_val))
    if status not in _OK or not np.all(np.isfinite(x)):
        return None, stats
    beta = np.maximum(socp.beta(x), 0.0)
    # The equalities hold to the solver's tolerance only: impose them exactly.
    return np.where(problem.fixed, problem.value, beta), stats
