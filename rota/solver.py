"""Clarabel wrapper: solve a :class:`rota.socp.Socp`, never raise, never return NaN."""

from __future__ import annotations

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


def solve(problem: Socp, settings: SolverSettings) -> tuple[FloatArray | None, SolverStats]:
    """Solve with Clarabel. Returns ``(x, stats)``; ``x`` is None unless solved."""
    s = clarabel.DefaultSettings()
    s.verbose = settings.verbose
    s.max_iter = settings.max_iter
    s.time_limit = settings.time_limit
    s.tol_gap_abs = settings.tol
    s.tol_gap_rel = settings.tol
    s.tol_feas = settings.tol
    start = time.perf_counter()
    try:
        solver = clarabel.DefaultSolver(problem.P, problem.q, problem.A, problem.b,
                                        problem.cones, s)
        sol = solver.solve()
    except Exception as exc:  # noqa: BLE001 - the solver must never take the caller down
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
