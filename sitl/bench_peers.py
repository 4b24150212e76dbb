"""The peers of ``rota-sitl bench`` (:mod:`sitl.bench`): the ROTA problem written in
cvxpy, toppra and copp-py, each on the bench's path and limits."""

from __future__ import annotations

import time

import numpy as np

import rota.checkpoints as _cp
from rota.trajectory import Trajectory

V_MAX, A_MAX = 2.0, 1.5


# ------------------------------------------------------------------ cvxpy form
def cvxpy_solve(traj: Trajectory, tau: np.ndarray, vlim: np.ndarray, lam: float,
                fractions: np.ndarray, tol: float | None = None,
                rota_ends: bool = True) -> tuple[np.ndarray, float]:
    """The ROTA problem as a user writes it in cvxpy: beta >= 0 on the nodes,
    duration via DCP atoms, smoothness sum_squares(alpha), speed and per-axis
    acceleration at ``fractions`` of every interval, rest at both ends.

    ``rota_ends``: ROTA's semantics at a clamped end, where the path stands still
    (|sigma'| = 0): any beta there means zero velocity, so beta is free (below
    ROTA's cap of 1e4 times the median speed bound) instead of 0. False: beta = 0
    at both ends, as toppra and copp-py impose.
    Returns (beta, seconds including cvxpy's compilation)."""
    import cvxpy as cp
    import scipy.sparse as sp

    t0 = time.perf_counter()
    n = len(tau) - 1
    h = float(tau[1] - tau[0])
    i = np.repeat(np.arange(n), len(fractions))
    f = np.tile(fractions, n)
    _, d1, d2 = traj.evaluate(tau[i] + f * h)
    rows = np.arange(len(i))
    lo = sp.csr_matrix((1 - f, (rows, i)), shape=(len(i), n + 1))
    hi = sp.csr_matrix((f, (rows, i + 1)), shape=(len(i), n + 1))
    interp = lo + hi  # beta at the points
    diff = sp.csr_matrix((np.r_[-np.ones(len(i)), np.ones(len(i))],
                          (np.r_[rows, rows], np.r_[i, i + 1])), shape=(len(i), n + 1))
    beta = cp.Variable(n + 1, nonneg=True)
    alpha = (beta[1:] - beta[:-1]) / (2 * h)
    cons = []
    speed = np.linalg.norm(traj.evaluate(tau[[0, -1]])[1], axis=1)
    for k, end in ((0, 0), (1, -1)):
        if not rota_ends or speed[k] > _cp.STILL:
            cons.append(beta[end] == 0)
    if rota_ends:
        s_nodes = np.linalg.norm(traj.evaluate(tau)[1], axis=1)
        moving = s_nodes > _cp.STILL
        cap = _cp.BETA_CAP_FACTOR * float(np.median(vlim[moving] ** 2 / s_nodes[moving] ** 2))
        cons.append(beta <= cap)
    lim2 = (1 - f) * vlim[i] ** 2 + f * vlim[i + 1] ** 2
    s2 = np.einsum("ij,ij->i", d1, d1)
    cons.append(cp.multiply(s2 / lim2, interp @ beta) <= 1)
    for k in range(3):
        acc = (cp.multiply(d1[:, k] / (2 * h), diff @ beta)
               + cp.multiply(d2[:, k], interp @ beta))
        cons += [acc <= A_MAX, acc >= -A_MAX]
    duration = cp.sum(2 * h * cp.inv_pos(cp.sqrt(beta[:-1]) + cp.sqrt(beta[1:])))
    prob = cp.Problem(cp.Minimize(duration + lam * h * cp.sum_squares(alpha)), cons)
    opts = {} if tol is None else dict(tol_gap_abs=tol, tol_gap_rel=tol, tol_feas=tol,
                                       max_iter=500)
    prob.solve(solver=cp.CLARABEL, **opts)
    secs = time.perf_counter() - t0
    if beta.value is None:
        raise RuntimeError(f"cvxpy: {prob.status}")
    return np.maximum(np.asarray(beta.value), 0.0), secs


# ----------------------------------------------------------------------- peers
class _ToppraPath:
    def __new__(cls, traj: Trajectory):
        import toppra.interpolator as ti

        class P(ti.AbstractGeometricPath):
            def __call__(self, s, order=0):
                out = traj.evaluate(np.atleast_1d(s))[order]
                return out[0] if np.ndim(s) == 0 else out

            @property
            def dof(self):
                return 3

            @property
            def path_interval(self):
                return np.array(traj.domain)

        return P()


def run_toppra(traj: Trajectory, tau: np.ndarray, v_max: float = V_MAX,
               a_max: np.ndarray | float = A_MAX) -> tuple[float, np.ndarray]:
    """toppra (seidel) on ``traj`` over the grid ``tau``: ``(seconds, beta)``. The
    speed limit on the norm becomes the equivalent per-axis limit varying along the
    path, ``|q_k' sdot| <= v |q_k'| / |q'|``, i.e. ``sdot <= v / |q'|``."""
    import toppra.algorithm as ta
    import toppra.constraint as tc

    t0 = time.perf_counter()
    path = _ToppraPath(traj)

    def vlim(s):  # the speed norm as an equivalent varying per-axis limit
        d = path(s, 1)
        bound = np.maximum(v_max * np.abs(d) / max(np.linalg.norm(d), 1e-12), 1e-9)
        return np.column_stack([-bound, bound])

    cons = [tc.JointVelocityConstraintVarying(vlim),
            tc.JointAccelerationConstraint(np.broadcast_to(np.asarray(a_max, float), (3,)))]
    algo = ta.TOPPRA(cons, path, gridpoints=tau, solver_wrapper="seidel")
    sd = algo.compute_parameterization(0.0, 0.0)[1]
    secs = time.perf_counter() - t0
    if sd is None:
        raise RuntimeError("toppra failed")
    return secs, np.asarray(sd) ** 2


def run_copp(traj: Trajectory, tau: np.ndarray, socp: bool) -> tuple[float, np.ndarray]:
    import copp_py as copp

    t0 = time.perf_counter()
    n = len(tau)
    q, d1, d2 = traj.evaluate(tau)
    robot = copp.Robot(3)
    robot.append_s(tau)
    robot.set_q(q, d1, d2, 0)
    speed = np.maximum(np.linalg.norm(d1, axis=1), 1e-12)
    up = np.maximum(V_MAX * np.abs(d1) / speed[:, None], 1e-9)
    robot.add_velocity_limits(up, -up, start_idx_s=0, length=n)
    robot.add_acceleration_limits(np.full(3, A_MAX), -np.full(3, A_MAX), start_idx_s=0)
    if socp:
        prob = copp.solver.copp2_socp.Problem(robot, [copp.objective.Time(1.0)], (0, n - 1),
                                              (0.0, 0.0))
        a = copp.solver.copp2_socp.solve(prob)
    else:
        a = copp.solver.topp2_ra.solve(copp.solver.topp2_ra.Problem(robot.constraints,
                                                                    (0, n - 1), (0.0, 0.0)))
    return time.perf_counter() - t0, np.maximum(np.asarray(a), 0.0)


