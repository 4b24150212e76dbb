"""Clarabel wrapper: solve a :class:`rota.socp.Socp`, never raise, never return NaN."""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass

import clarabel
import numpy as np
from numpy.typing import NDArray

from rota.problem import SolverSettings
from rota.socp import Socp

FloatArray = NDArray[np.float64]

_OK = {"Solved", "AlmostSolved"}


@dataclass(frozen=True)
class SolverStats:
    """What the solver reported. ``status`` is Clarabel's status name."""

    status: str
    iterations: int
    solve_time: float  # seconds, as reported by Clarabel
    wall_time: float  # seconds, setup + solve, measured here
    objective: float

    @property
    def ok(self) -> bool:
        return self.status in _OK


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


class _SymbolicCache:
    """The last solver, reusable for a problem of identical sparsity and cones."""

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


def solve(problem: Socp, settings: SolverSettings) -> tuple[FloatArray | None, SolverStats]:
    """Solve with Clarabel. Returns ``(x, stats)``; ``x`` is None unless solved."""
    start = time.perf_counter()
    try:
        solver = _make_solver(problem, settings)
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
    return x, stats
