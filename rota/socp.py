"""The ROTA problem as a second-order cone program for Clarabel (paper Sec. III-D).

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

Constraints: the bounds and rows of the :class:`rota.chain.ChainProblem` (speed,
Eq. 23, and per-axis acceleration, Eq. 26, at every check point, scaled so every
right-hand side is 1) and its fixed nodes as equalities.

The result is Clarabel's standard form ``min 1/2 x'Px + q'x, Ax + s = b,
s in K``, built with vectorised sparse assembly (no loops over samples).
"""

from __future__ import annotations

from dataclasses import dataclass

import clarabel
import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from rota.chain import ChainProblem

FloatArray = NDArray[np.float64]


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


def assemble(problem: ChainProblem) -> Socp:
    """Build the SOCP of paper Eqs. 21-26 for ``problem`` (vectorised, sparse)."""
    nb = problem.n_nodes
    n = nb - 1
    h = problem.h
    ib = np.arange(nb)  # beta indices
    iz = nb + np.arange(nb)  # zeta indices
    ig = 2 * nb + np.arange(n)  # gamma indices
    nx = 2 * nb + n

    # Objective: 2h * sum(gamma) + lambda/(4h) * sum((beta_{i+1}-beta_i)^2).
    q = np.zeros(nx)
    q[ig] = 2.0 * h
    w = problem.smoothness / (2.0 * h)  # 1/2 x'Px form: P = (lambda / 2h) D'D
    if w > 0:
        diag = np.full(nb, 2.0 * w)
        diag[[0, -1]] = w
        rows = np.concatenate([ib, ib[:-1]])
        cols = np.concatenate([ib, ib[1:]])
        vals = np.concatenate([diag, np.full(n, -w)])
        P = sp.csc_matrix((vals, (rows, cols)), shape=(nx, nx))
    else:
        P = sp.csc_matrix((nx, nx))

    r_all: list[np.ndarray] = []
    c_all: list[np.ndarray] = []
    v_all: list[np.ndarray] = []
    rhs: list[np.ndarray] = []
    cones: list = []
    offset = 0

    def block(r: np.ndarray, c: np.ndarray, v: np.ndarray, b: np.ndarray) -> None:
        nonlocal offset
        r_all.append(r + offset)
        c_all.append(c)
        v_all.append(v)
        rhs.append(b)
        offset += len(b)

    # Zero cone: the fixed nodes.
    fixed = np.flatnonzero(problem.fixed)
    if len(fixed):
        block(np.arange(len(fixed)), ib[fixed], np.ones(len(fixed)), problem.value[fixed])
        cones.append(clarabel.ZeroConeT(len(fixed)))
    # Nonnegative cone: beta_i <= hi_i on the free nodes (scaled), then every row.
    free = np.flatnonzero(~problem.fixed & np.isfinite(problem.hi))
    block(np.arange(len(free)), ib[free], 1.0 / problem.hi[free], np.ones(len(free)))
    m = len(problem.rk)
    r = np.arange(m)
    block(np.concatenate([r, r]), np.concatenate([ib[problem.rk], ib[problem.rk + 1]]),
          np.concatenate([problem.ra, problem.rc]), np.ones(m))
    cones.append(clarabel.NonnegativeConeT(len(free) + m))

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

    A = sp.csc_matrix((np.concatenate(v_all), (np.concatenate(r_all), np.concatenate(c_all))),
                      shape=(offset, nx))
    return Socp(P=sp.triu(P, format="csc"), q=q, A=A, b=np.concatenate(rhs), cones=cones,
                n_nodes=nb)
