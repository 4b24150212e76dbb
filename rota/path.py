"""Compiled evaluation of a trajectory (paper Eqs. 3-5 need sigma, sigma', sigma'')."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from rota.jit import kernels
from rota.trajectory import Trajectory

FloatArray = NDArray[np.float64]


def evaluate(trajectory: Trajectory, tau: FloatArray) -> tuple[FloatArray, FloatArray,
                                                              FloatArray]:
    """``(position, sigma', sigma'')``, each ``(n, 3)``, at ``tau`` (clamped to the
    trajectory's domain): the same numbers as ``trajectory.evaluate``, compiled."""
    breaks, coefs = trajectory.pieces
    t0, t1 = trajectory.domain
    x = np.clip(np.ascontiguousarray(tau, dtype=float), t0, t1)
    n = x.shape[0]
    p, d1, d2 = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
    kernels().eval_pieces(breaks, coefs, x, p, d1, d2)
    return p, d1, d2


def on_grid(trajectory: Trajectory, n: int) -> tuple[FloatArray, FloatArray, FloatArray,
                                                     FloatArray]:
    """``(tau, position, sigma', sigma'')``: the grid of ``n`` intervals of
    :func:`rota.problem.make_grid` (the same numbers) and the path there, in one
    compiled call."""
    breaks, coefs = trajectory.pieces
    t0, t1 = trajectory.domain
    return kernels().grid_path(breaks, coefs, t0, t1, n)
