"""Warming up: load (or compile) every kernel and run each once on a tiny re-time
(:func:`warm_up`; the cache directory's rules are in :mod:`rota.jit`)."""

from __future__ import annotations

import os
import time

import numpy as np

from rota.chance import DEFAULT_MEMORY_S, UncertaintyModel
from rota.jit import configure, kernels
from rota.problem import Limits, RetimeInput, SolverSettings
from rota.retime import retime
from rota.robust import Safety
from rota.trajectory import BSplineTrajectory, PolynomialTrajectory, SampledTrajectory
from rota.voxelmap import VoxelMap


def exercise() -> None:
    """Re-time small paths of every input kind, with and without a map, at
    lambda > 0 (interior-point solver) and lambda = 0 (reachability)."""
    cps = np.array([[0, 0, 1], [0, 0, 1], [0, 0, 1], [1, 0.2, 1], [2, 0, 1], [3, 0.5, 1],
                    [3, 0.5, 1], [3, 0.5, 1]], dtype=float)
    spline = BSplineTrajectory(control_points=cps, knot_span=0.5)
    t = np.linspace(0.0, 2.0, 5)
    p = np.column_stack([t, np.sin(t), np.ones_like(t)])
    samples = SampledTrajectory(t=t, p=p)
    coefs = np.zeros((1, 3, 6))
    coefs[0, 0, 3:] = [10.0, -15.0, 6.0]  # x: rest-to-rest quintic over 1 s
    poly = PolynomialTrajectory(durations=np.array([1.0]), coefficients=coefs)
    vmap = VoxelMap(0.1, np.array([[1.55, 0.55, 1.05]]))
    limits = Limits(1.5, 2.0)
    for traj in (spline, samples, poly):
        for lam in (0.5, 0.0):
            retime(RetimeInput(trajectory=traj, limits=limits, smoothness=lam, dtau=0.1))
    retime(RetimeInput(trajectory=spline, limits=limits, dtau=0.1, safety=Safety(map=vmap)))
    for per_axis in (False, True):  # error memory (the service's default) and the paper's axes
        model = UncertaintyModel(per_axis=per_axis, memory_s=DEFAULT_MEMORY_S)
        retime(RetimeInput(trajectory=spline, limits=limits, dtau=0.1,
                           safety=Safety(map=vmap, uncertainty=model)))
    # the Clarabel path (and the audit after it), and an infeasible request
    # (the forward pass that says where it fails)
    retime(RetimeInput(trajectory=spline, limits=limits, dtau=0.1,
                       solver=SolverSettings(method="clarabel")))
    retime(RetimeInput(trajectory=samples, limits=Limits(1.5, 0.1), dtau=0.1,
                       start_velocity=samples.evaluate([0.0])[1][0]))


def warm_up(cache_dir: str | os.PathLike[str] | None = None) -> float:
    """Load (or compile) every kernel and run each once on a tiny problem.

    Call it before the first re-time that matters (the flight service calls it
    before it reports ready). ``cache_dir``: where numba keeps compiled code (see
    the module docstring). Returns the seconds it took: about the import and
    load time with a warm cache, the full compile time with a cold one.
    """
    start = time.perf_counter()
    configure(cache_dir)
    kernels()
    exercise()
    return time.perf_counter() - start
