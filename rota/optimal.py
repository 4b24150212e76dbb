"""The paper's re-time, without a jerk bound (:func:`retime_free`): the time-optimal
mapping under speed, acceleration and chance constraints (paper Eq. 11 on the grid
of Eq. 17). :func:`rota.retime.retime` calls it, or :func:`rota.jerk.retime_jerk`
when the limits bound the jerk (which calls it for the unlimited optimum first)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from rota.chain import Boundary, ChainProblem, describe
from rota.checkpoints import NO_POINTS, STILL, PathSamples, sample_path
from rota.path import on_grid
from rota.problem import RetimeInput, grid_intervals
from rota.result import FALLBACK, OPTIMAL, REJECTED, Diagnostics, Outcome, RetimeResult
from rota.robust import assess
from rota.rounds import Audit, finish, more_points, one_round
from rota.solver import SolverStats
from rota.timemap import TimeMap
from rota.trajectory import Trajectory

FloatArray = NDArray[np.float64]

#: A boundary velocity may deviate from the path tangent by this much (m/s, plus 5 %).
TANGENT_TOL = 0.05
#: Relative tolerance when checking the solver's solution against the constraints.
CHECK_TOL = 1e-3
#: Solves at most (1 + rounds of constraint generation).
MAX_ROUNDS = 4
#: Share of the smallest acceleration limit used to brake a start that is too fast.
BRAKE_SHARE = 0.5
#: The fallback's reason for a path that does not move.
DEGENERATE = "degenerate trajectory: the path does not move (its length is 0)"


class Infeasible(Exception):
    """Internal: the request cannot be met; the message goes into the result."""


def retime_free(inp: RetimeInput) -> RetimeResult:
    """Re-time ``inp.trajectory`` optimally (paper Eq. 11 on the grid of Eq. 17), its
    jerk free (``inp.limits.j_max`` is not read).

    With ``inp.safety`` the speed limit of every grid node also includes the
    chance-constraint limit in braking zones (Sec. III-B/C). The problem is
    solved on beta (:mod:`rota.chain`) by the solver ``inp.solver.method``
    (:mod:`rota.solver`), after a reachability pass that decides feasibility
    exactly and, at lambda = 0, often the optimum itself.
    """
    traj = inp.trajectory
    tau, pos, d1, d2 = on_grid(traj, grid_intervals(traj, inp.dtau))
    vlim = np.full(len(tau), inp.limits.v_max)
    if inp.speed_limits is not None:
        vlim = np.minimum(vlim, inp.speed_limits)
    found: dict = {}  # the Diagnostics' fields, as they are found
    warnings: list[str] = []

    def fallback(reason: str, stats: SolverStats | None = None,
                 status: Outcome = FALLBACK) -> RetimeResult:
        timemap = uniform_fallback(traj, tau, vlim, inp.limits.a_max_vec)
        return RetimeResult(status, reason, timemap, traj, stats, vlim, Diagnostics(**found),
                            tuple(warnings))

    if inp.safety is not None:
        seen = assess(traj, tau, inp.safety, position=pos, velocity=d1)
        vlim = np.minimum(vlim, seen.speed_limits)
        found.update(intervals=seen.zones.intervals, braking_mask=seen.zones.mask,
                      obstacle_distance=seen.zones.distance,
                      nearest_obstacle=seen.zones.nearest, chance_limits=seen.chance.limit,
                      approach_mask=seen.approach,
                      memory_s=inp.safety.uncertainty.memory_s)
        if seen.outside.any():
            i = int(np.argmax(seen.outside))
            warnings.append(f"the path leaves the map at tau={tau[i]:.2f} s; speed limited to "
                            f"{float(vlim[seen.outside].max()):.2f} m/s where the map knows "
                            f"nothing ({int(seen.outside.sum())} grid nodes)")
        if seen.collision.any():
            return fallback(seen.describe_collision(tau), status=REJECTED)
    a_max = inp.limits.a_max_vec
    limit_before = vlim
    v0 = math.sqrt(sum(x * x for x in inp.start_velocity.tolist()))
    if v0 > vlim[0] * (1 + 1e-9):
        vlim = _brake_from_start(inp, tau, pos, vlim, v0)
    try:
        boundary = _boundary(inp, d1[0], d2[0], d1[-1], vlim[0], vlim[-1])
    except Infeasible as exc:
        if not sample_path(traj, tau, vlim, a_max, d1, d2).moving:
            return fallback(DEGENERATE)
        return fallback(str(exc))

    more = NO_POINTS
    rounds = 0
    while True:
        rounds += 1
        rnd = one_round(traj, tau, d1, d2, vlim, a_max, boundary, inp.smoothness, inp.solver,
                        more)
        if inp.solver.keep_round:
            found["last_round"] = rnd
        path = rnd.path
        if not path.moving:
            return fallback(DEGENERATE)
        if not rnd.feasible:
            return fallback(_infeasible(rnd.problem, path, inp, pos))
        if not rnd.ok:
            return fallback("the limits cannot be met (the problem is infeasible): they "
                            "force the vehicle to stand still on the way")
        rnd = finish(traj, rnd, inp.solver)
        beta, stats, seen_limits = rnd.beta, rnd.stats, rnd.audit
        if beta is None or seen_limits is None:
            return fallback(_explain(stats), stats)
        # Constraint generation: a limit broken between the check points adds
        # check points there, then re-solve.
        if seen_limits.more is None or rounds == MAX_ROUNDS:
            break
        more = more_points(more, seen_limits.more)
    found["solve_rounds"] = rounds
    problem_text = check_solution(seen_limits, path, beta, boundary)
    timemap = TimeMap(tau, beta)
    if problem_text is None and not np.isfinite(timemap.duration):
        problem_text = "the optimal time mapping stops on the way (infinite duration)"
    if problem_text is not None:
        return fallback(f"solver solution rejected: {problem_text}", stats)
    if vlim is not limit_before:
        warnings.append(_brake_note(inp, path, beta, limit_before, v0))
    return RetimeResult(OPTIMAL, "", timemap, traj, stats, vlim, Diagnostics(**found),
                        tuple(warnings))


def _brake_from_start(inp: RetimeInput, tau: FloatArray, pos: FloatArray, vlim: FloatArray,
                      v0: float) -> FloatArray:
    """The vehicle is already faster than the limit at the start (for example a
    replan puts it just before a braking zone): raise the limits near the start
    to a braking profile at ``BRAKE_SHARE`` of the smallest acceleration limit,
    ``v(s) = sqrt(v0^2 - 2 a s)`` over the arc length ``s``, so the re-time
    brakes as hard as allowed instead of failing."""
    s = _arclength(pos)
    a_brake = BRAKE_SHARE * float(np.min(inp.limits.a_max_vec))
    brake = np.sqrt(np.maximum(v0**2 - 2.0 * a_brake * s, 0.0))
    return np.maximum(vlim, brake)


def _brake_note(inp: RetimeInput, path: PathSamples, beta: FloatArray, limit: FloatArray,
                v0: float) -> str:
    """The warning for a start that is too fast, with the distance over which the
    re-timed speed actually exceeds the limits (measured on the solution at every
    check point, not read off the raised limits)."""
    i = path.interval
    f = path.frac
    b = (1 - f) * beta[i] + f * beta[i + 1]
    speed = np.sqrt(np.einsum("ij,ij->i", path.cd1, path.cd1) * b)
    lim = np.sqrt((1 - f) * limit[i] ** 2 + f * limit[i + 1] ** 2)
    ratio = speed / lim - 1.0
    t = path.point_tau
    order = np.argsort(t, kind="stable")
    t, ratio, s1 = t[order], ratio[order], np.linalg.norm(path.cd1[order], axis=1)
    dist = np.concatenate([[0.0], np.cumsum(np.diff(t) * 0.5 * (s1[1:] + s1[:-1]))])
    over = np.flatnonzero(ratio > 1e-6)
    far = 0.0
    if len(over):
        k = int(over[-1])
        far = float(dist[k])
        if k + 1 < len(t) and ratio[k] > ratio[k + 1]:  # where it crosses the limit
            far += (dist[k + 1] - dist[k]) * ratio[k] / (ratio[k] - ratio[k + 1])
    a_brake = BRAKE_SHARE * float(np.min(inp.limits.a_max_vec))
    return (f"start speed {v0:.2f} m/s exceeds the speed limit {limit[0]:.2f} m/s at the "
            f"start; braking at {a_brake:.2f} m/s^2, the limits are exceeded for the first "
            f"{far:.2f} m")


def _arclength(pos: FloatArray) -> FloatArray:
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pos, axis=0), axis=1))])


def _boundary(inp: RetimeInput, d1_start: FloatArray, d2_start: FloatArray,
              d1_end: FloatArray, vlim_start: float, vlim_end: float) -> Boundary:
    """Boundary equalities that stitch the mapping onto the vehicle's state.

    A velocity ``v`` at a path point with tangent ``sigma'`` needs
    ``tau_dot = v . sigma' / |sigma'|^2`` (and ``v`` parallel to ``sigma'``); then
    ``beta = tau_dot^2``. An acceleration fixes ``alpha`` through its tangential
    component, ``alpha = (a - sigma'' beta) . sigma' / |sigma'|^2`` (Eq. 5).
    """
    beta0 = _boundary_beta(inp.start_velocity, d1_start, vlim_start, "start")
    beta1 = _boundary_beta(inp.end_velocity, d1_end, vlim_end, "end")
    alpha0 = None
    if inp.start_acceleration is not None and beta0 is not None:
        s2 = float(d1_start @ d1_start)
        alpha0 = float((inp.start_acceleration - d2_start * beta0) @ d1_start) / s2
        if beta0 == 0.0 and alpha0 <= 0.0:
            raise Infeasible("the vehicle is at rest and its start acceleration does not "
                             "point along the path: it cannot start moving")
    return Boundary(beta_start=beta0, alpha_start=alpha0, beta_end=beta1)


def _boundary_beta(v: FloatArray, d1: FloatArray, vlim: float, where: str) -> float | None:
    vx, vy, vz = v.tolist()
    dx, dy, dz = d1.tolist()
    speed = math.sqrt(vx * vx + vy * vy + vz * vz)
    s = math.sqrt(dx * dx + dy * dy + dz * dz)
    if speed > vlim * (1 + 1e-9):
        raise Infeasible(f"{where} speed {speed:.3f} m/s exceeds the speed limit "
                         f"{vlim:.3f} m/s at the {where} of the path")
    if s <= STILL:
        if speed > TANGENT_TOL:
            raise Infeasible(f"{where} velocity {speed:.3f} m/s is impossible: the path "
                             f"does not move at its {where}")
        return None  # physical velocity is zero whatever beta is
    tau_dot = (vx * dx + vy * dy + vz * dz) / (s * s)
    off = math.sqrt((vx - tau_dot * dx) ** 2 + (vy - tau_dot * dy) ** 2
                    + (vz - tau_dot * dz) ** 2)
    if tau_dot < 0 and speed > TANGENT_TOL:
        raise Infeasible(f"{where} velocity points backwards along the path")
    if off > TANGENT_TOL + 0.05 * speed:
        raise Infeasible(f"{where} velocity is not along the path: {off:.3f} m/s of it is "
                         f"across the path tangent")
    return max(tau_dot, 0.0) ** 2


def _infeasible(problem: ChainProblem, path: PathSamples, inp: RetimeInput,
                pos: FloatArray) -> str:
    return describe(problem, path, float(np.linalg.norm(inp.start_velocity)),
                    float(np.linalg.norm(inp.end_velocity)), _arclength(pos))


def check_solution(seen: Audit, path: PathSamples, beta: FloatArray,
                   boundary: Boundary) -> str | None:
    """Independent check of a solution against the limits at the nodes and every
    check point (``seen``: its :func:`audit`). None when they hold within
    :data:`CHECK_TOL`."""
    if not np.all(np.isfinite(beta)):
        return "non-finite beta"
    over_v = seen.speed - 1
    if over_v > CHECK_TOL:
        return f"speed limit exceeded by {100 * over_v:.2f} %"
    if seen.acc - 1 > CHECK_TOL:
        i = int(np.searchsorted(path.offsets, seen.point, side="right")) - 1
        at = path.tau[i] + path.frac[seen.point] * path.h
        return (f"{'xyz'[seen.axis]} acceleration limit exceeded by "
                f"{100 * (seen.acc - 1):.2f} % near tau={at:.3f}")
    for name, target, got in (("start", boundary.beta_start, beta[0]),
                              ("end", boundary.beta_end, beta[-1])):
        if target is not None and got != target:
            return f"{name} velocity not met (beta {got:.4g} instead of {target:.4g})"
    return None


def _explain(stats: SolverStats) -> str:
    words = {
        "PrimalInfeasible": "the limits cannot be met from this start state "
                            "(the problem is infeasible)",
        "AlmostPrimalInfeasible": "the limits can almost certainly not be met from this "
                                  "start state (the problem is nearly infeasible)",
        "DualInfeasible": "the problem is unbounded (degenerate trajectory)",
        "MaxIterations": "the solver hit its iteration limit",
        "MaxTime": "the solver hit its time limit",
        "NumericalError": "the solver ran into numerical trouble",
        "InsufficientProgress": "the solver made insufficient progress",
    }
    text = words.get(stats.status, f"the solver failed ({stats.status})")
    return f"{text} ({stats.note})" if stats.note else text


def uniform_fallback(trajectory: Trajectory, tau: FloatArray, vlim: FloatArray,
                     a_max: FloatArray) -> TimeMap:
    """The authors' fallback: the input uniformly slowed down (never sped up) until
    it meets the speed, per-node speed and acceleration limits.

    With a constant ``tau_dot = k`` velocity scales by ``k`` and acceleration by
    ``k^2``, so ``k = min(1, v_i / |sigma'_i|, sqrt(a_max / |sigma''|))``, checked on
    a grid four times finer than the nodes. The fallback does not honour a
    non-rest start or end state: it keeps the input's own boundary behaviour.
    """
    fine = np.linspace(tau[0], tau[-1], 4 * (len(tau) - 1) + 1)
    _, d1, d2 = trajectory.evaluate(fine)
    # Per-node limits hold on the intervals next to the node: take the lower one.
    node_lim = np.minimum(vlim[:-1], vlim[1:])
    seg = np.clip(np.searchsorted(tau, fine, side="right") - 1, 0, len(node_lim) - 1)
    lim = np.minimum(node_lim[seg], vlim[np.clip(seg + 1, 0, len(vlim) - 1)])
    with np.errstate(divide="ignore"):
        k_v = np.min(lim / np.linalg.norm(d1, axis=1))
        k_a = np.sqrt(np.min(a_max / np.abs(d2)))
    k = float(min(1.0, k_v, k_a))
    return TimeMap(tau, np.full(len(tau), k * k))
