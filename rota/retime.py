"""The entry point: :func:`retime` takes a :class:`RetimeInput`, returns a
:class:`RetimeResult`. It never raises for solver trouble and never returns NaN:
when the optimum cannot be had, the result says why and carries the fallback."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from rota.problem import RetimeInput, make_grid
from rota.result import FALLBACK, OPTIMAL, REJECTED, RetimeResult
from rota.robust import assess
from rota.socp import STILL, Boundary, PathSamples, assemble, sample_path
from rota.solver import SolverStats, solve
from rota.timemap import TimeMap
from rota.trajectory import Trajectory

FloatArray = NDArray[np.float64]

#: A boundary velocity may deviate from the path tangent by this much (m/s, plus 5 %).
TANGENT_TOL = 0.05
#: Relative tolerance when checking the solver's solution against the constraints.
CHECK_TOL = 1e-3
#: A limit broken by more than this at an unconstrained check point triggers a re-solve.
REFINE_TOL = 2e-4
#: Solves at most (1 + rounds of constraint generation).
MAX_ROUNDS = 4
#: Share of the smallest acceleration limit used to brake a start that is too fast.
BRAKE_SHARE = 0.5


class Infeasible(Exception):
    """Internal: the request cannot be met; the message goes into the result."""


def retime(inp: RetimeInput) -> RetimeResult:
    """Re-time ``inp.trajectory`` optimally (paper Eq. 11 as the SOCP of Sec. III-D).

    With ``inp.safety`` the speed limit of every grid node also includes the
    chance-constraint limit in braking zones (Sec. III-B/C).
    """
    tau = make_grid(inp.trajectory, inp.dtau)
    _, d1, d2 = inp.trajectory.evaluate(tau)
    vlim = np.full(len(tau), inp.limits.v_max)
    if inp.speed_limits is not None:
        vlim = np.minimum(vlim, inp.speed_limits)
    speed = np.linalg.norm(d1, axis=1)
    extras: dict = {}
    warnings: list[str] = []

    def fallback(reason: str, stats: SolverStats | None = None,
                 status: str = FALLBACK) -> RetimeResult:
        timemap = uniform_fallback(inp.trajectory, tau, vlim, inp.limits.a_max_vec)
        return RetimeResult(status, reason, timemap, inp.trajectory, stats, vlim, extras,
                            tuple(warnings))

    if inp.safety is not None:
        seen = assess(inp.trajectory, tau, inp.safety)
        vlim = np.minimum(vlim, seen.speed_limits)
        extras.update(intervals=seen.zones.intervals, braking_mask=seen.zones.mask,
                      obstacle_distance=seen.zones.distance,
                      nearest_obstacle=seen.zones.nearest, chance_limits=seen.chance.limit)
        if seen.outside.any():
            i = int(np.argmax(seen.outside))
            warnings.append(f"the path leaves the map at tau={tau[i]:.2f} s; speed limited to "
                            f"{float(vlim[seen.outside].max()):.2f} m/s where the map knows "
                            f"nothing ({int(seen.outside.sum())} grid nodes)")
        if seen.collision.any():
            return fallback(seen.describe_collision(tau), status=REJECTED)
    if speed.max() <= STILL:
        return fallback("degenerate trajectory: the path does not move (its length is 0)")
    v0 = float(np.linalg.norm(inp.start_velocity))
    if v0 > vlim[0] * (1 + 1e-9):
        vlim, note = _brake_from_start(inp, tau, vlim, v0)
        warnings.append(note)
    try:
        boundary = _boundary(inp, d1[0], d2[0], d1[-1], vlim[0], vlim[-1])
    except Infeasible as exc:
        return fallback(str(exc))

    path = sample_path(inp.trajectory, tau, vlim, inp.limits.a_max_vec)
    rounds = 0
    while True:
        rounds += 1
        x, stats = solve(assemble(path, inp.smoothness, boundary), inp.solver)
        if x is None:
            return fallback(_explain(stats), stats)
        beta = np.maximum(x[: len(tau)], 0.0)
        # Constraint generation: a limit broken at a candidate check point that
        # was not constrained gets its whole interval constrained, then re-solve.
        v2, acc = path.ratios(beta)
        bad = ~path.active & ((v2 > 1 + REFINE_TOL) | (acc > 1 + REFINE_TOL))
        if not bad.any() or rounds == MAX_ROUNDS:
            break
        path = path.activate(np.unique(path.pt_interval[bad]))
    extras["solve_rounds"] = rounds
    problem = check_solution(path, beta, boundary)
    timemap = TimeMap(tau, beta)
    if problem is None and not np.isfinite(timemap.duration):
        problem = "the optimal time mapping stops on the way (infinite duration)"
    if problem is not None:
        return fallback(f"solver solution rejected: {problem}", stats)
    return RetimeResult(OPTIMAL, "", timemap, inp.trajectory, stats, vlim, extras,
                        tuple(warnings))


def _brake_from_start(inp: RetimeInput, tau: FloatArray, vlim: FloatArray,
                      v0: float) -> tuple[FloatArray, str]:
    """The vehicle is already faster than the limit at the start (for example a
    replan puts it just before a braking zone): raise the limits near the start
    to a braking profile at ``BRAKE_SHARE`` of the smallest acceleration limit,
    ``v(s) = sqrt(v0^2 - 2 a s)`` over the arc length ``s``, so the re-time
    brakes as hard as allowed instead of failing. Returns the limits and a note."""
    p = inp.trajectory.position(tau)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    a_brake = BRAKE_SHARE * float(np.min(inp.limits.a_max_vec))
    brake = np.sqrt(np.maximum(v0**2 - 2.0 * a_brake * s, 0.0))
    raised = brake > vlim
    last = int(np.flatnonzero(raised)[-1])
    note = (f"start speed {v0:.2f} m/s exceeds the speed limit {vlim[0]:.2f} m/s at the start; "
            f"braking at {a_brake:.2f} m/s^2, the limits are exceeded for the first "
            f"{s[last]:.2f} m")
    return np.maximum(vlim, brake), note


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
    return Boundary(beta_start=beta0, alpha_start=alpha0, beta_end=beta1)


def _boundary_beta(v: FloatArray, d1: FloatArray, vlim: float, where: str) -> float | None:
    speed = float(np.linalg.norm(v))
    s = float(np.linalg.norm(d1))
    if speed > vlim * (1 + 1e-9):
        raise Infeasible(f"{where} speed {speed:.3f} m/s exceeds the speed limit "
                         f"{vlim:.3f} m/s at the {where} of the path")
    if s <= STILL:
        if speed > TANGENT_TOL:
            raise Infeasible(f"{where} velocity {speed:.3f} m/s is impossible: the path "
                             f"does not move at its {where}")
        return None  # physical velocity is zero whatever beta is
    tau_dot = float(v @ d1) / (s * s)
    off = float(np.linalg.norm(v - tau_dot * d1))
    if tau_dot < 0 and speed > TANGENT_TOL:
        raise Infeasible(f"{where} velocity points backwards along the path")
    if off > TANGENT_TOL + 0.05 * speed:
        raise Infeasible(f"{where} velocity is not along the path: {off:.3f} m/s of it is "
                         f"across the path tangent")
    return max(tau_dot, 0.0) ** 2


def check_solution(path: PathSamples, beta: FloatArray, boundary: Boundary) -> str | None:
    """Independent check of a solution against the constraints at the nodes and
    every candidate check point. None when it holds within :data:`CHECK_TOL`."""
    if not np.all(np.isfinite(beta)):
        return "non-finite beta"
    v2, acc = path.ratios(beta)
    over_v = max(float(np.max(beta / path.beta_max)), float(np.max(v2))) - 1
    if over_v > CHECK_TOL:
        return f"speed limit exceeded by {100 * over_v:.2f} %"
    k = int(np.argmax(acc))
    if acc[k] - 1 > CHECK_TOL:
        return (f"acceleration limit exceeded by {100 * (acc[k] - 1):.2f} % near "
                f"tau={path.tau[path.pt_interval[k]]:.3f}")
    scale = max(1.0, float(np.max(beta)))
    for name, target, got in (("start", boundary.beta_start, beta[0]),
                              ("end", boundary.beta_end, beta[-1])):
        if target is not None and abs(got - target) > CHECK_TOL * scale:
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
    return words.get(stats.status, f"the solver failed ({stats.status})")


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
