"""Jerk-limited re-timing (``Limits.j_max`` set): :func:`retime_jerk`.

The unlimited re-time runs first (:func:`rota.optimal.retime_free` without the jerk
bound): its grid, per-node speed limits (braking zones, chance constraints, a
start that is too fast) and boundary come from it, its optimum is where the
successive convexification of :mod:`rota.jerkproblem` starts, and its duration
is the flight-time cost's reference (``diagnostics.unlimited_duration``). When it
fails, or the jerk-limited problem does, the result is the fallback with the
reason in words; the fallback's uniform slow-down honours the jerk bound too.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from rota.checkpoints import BETA_CAP_FACTOR, STILL
from rota.jerkmap import JerkTimeMap, derivatives
from rota.jerkproblem import (
    AUDIT_FACTOR,
    LIMIT_TOL,
    MAX_ROUNDS,
    NORMAL,
    PARTS,
    REST_END,
    REST_START,
    Layout,
    beta_at,
    limit_ratios,
    make_points,
    solve,
)
from rota.optimal import Infeasible, _boundary, retime_free, uniform_fallback
from rota.problem import RetimeInput
from rota.result import FALLBACK, OPTIMAL, REJECTED, Outcome, RetimeResult
from rota.solver import SolverStats
from rota.timemap import TimeMap

FloatArray = NDArray[np.float64]

#: The jerk-limited problem's grid is the re-time's grid with every interval cut
#: into parts of at most this much trajectory time (s): the jerk's shape can only
#: change at nodes. Measured on random 4-waypoint B-splines and quintic
#: polynomials (v 2, a 3, j 6) against the same problem on a grid 16 times finer
#: than dtau 0.1: steps of 0.1 s 2.5-4.6 % longer, 0.05 s 0.9-1.4 %, 0.025 s
#: 0.2-0.45 %.
JERK_DTAU = 0.025
#: A start on a given acceleration may make the grid up to this many times finer.
MAX_FINER = 4
#: The convexified problems are solved to this tolerance (Clarabel).
SOLVE_TOL = 1e-8
#: A start acceleration along the path below this (tau_ddot) counts as none.
REST_ACC = 1e-9
#: The path's acceleration may jump by this share of its size at a breakpoint.
C2_TOL = 1e-6


def retime_jerk(inp: RetimeInput, finer: int = 1) -> RetimeResult:
    """Re-time ``inp`` with its jerk bound ``inp.limits.j_max`` (see the module).

    A start on a given acceleration (a replan) pins the first interval's state:
    its ``tau_ddot`` is linear, which may not follow the jerk a moving vehicle
    needs (it may be about to switch): then the grid is made ``finer`` (2, then
    4 times; measured: mid-ramp replans of the tests' B-spline failed at the
    0.025 s grid and succeed at 0.0125 s)."""
    j_max = inp.limits.j_max_vec
    assert j_max is not None
    a_max = inp.limits.a_max_vec
    inp = _hovering(inp)
    base = retime_free(replace(inp, limits=replace(inp.limits, j_max=None)))
    traj = inp.trajectory
    step = float(base.timemap.tau[1] - base.timemap.tau[0])
    parts = max(1, math.ceil(step / JERK_DTAU - 1e-9)) * finer
    tau, vlim = refine_grid(base.timemap.tau, base.speed_limits, parts)
    found = replace(base.diagnostics, unlimited_duration=base.duration if base.ok else math.nan)

    def fallback(reason: str, status: Outcome = FALLBACK,
                 stats: SolverStats | None = base.solver) -> RetimeResult:
        timemap = jerk_fallback(inp, tau, vlim)
        return RetimeResult(status, reason, timemap, traj, stats, vlim, found, base.warnings)

    if base.status == REJECTED:
        return fallback(base.message, REJECTED)
    if not base.ok:
        return fallback(f"{base.message} (without the jerk bound already; the fallback "
                        "honours the jerk bound but not the start and end states)")
    jump = _acceleration_jump(inp)
    if jump is not None:
        return fallback(jump)
    first1, first2, _ = derivatives(traj, tau[:1])
    d1, d2 = first1[0], first2[0]
    d1_end = derivatives(traj, tau[-1:], left=True)[0][0]
    try:
        bnd = _boundary(inp, d1, d2, d1_end, vlim[0], vlim[-1])
    except Infeasible as exc:  # the unlimited re-time met it: not expected
        return fallback(str(exc))
    n = len(tau) - 1
    kind = np.full(n, NORMAL)
    moving_start = float(np.linalg.norm(d1)) > STILL
    moving_end = float(np.linalg.norm(d1_end)) > STILL
    acc_start = bnd.alpha_start
    if (moving_start and bnd.beta_start == 0.0
            and (acc_start is None or acc_start <= REST_ACC)):
        kind[0] = REST_START
    if moving_end and bnd.beta_end == 0.0:
        kind[-1] = REST_END
    _, gd1, _ = derivatives(traj, tau)
    s2 = np.einsum("ij,ij->i", gd1, gd1)
    with np.errstate(divide="ignore"):
        bmax = np.where(s2 > STILL**2, vlim**2 / s2, np.inf)
    finite = bmax[np.isfinite(bmax)]
    cap = BETA_CAP_FACTOR * float(np.median(finite)) if len(finite) else 1.0
    lay = Layout(tau, kind, bnd.beta_start, acc_start, bnd.beta_end, cap)
    dense = make_points(inp, tau, vlim, PARTS * AUDIT_FACTOR)
    extra = None
    steps = 0
    seconds = 0.0
    worst = (0.0, 0.0, 0.0)
    js = None
    for _ in range(MAX_ROUNDS):
        pts = make_points(inp, tau, vlim, PARTS, extra)
        if js is None:  # from the unlimited optimum, then from the last solution
            at = tau[pts.interval] + pts.frac * lay.h
            bbar = np.interp(at, base.tau, base.beta)
        else:
            bbar = np.maximum(beta_at(lay, pts, js.beta, js.acc), 0.0)
        js = solve(lay, pts, a_max, j_max, bbar, inp.smoothness, SOLVE_TOL, inp.solver)
        steps += js.steps
        seconds += js.seconds
        stats = SolverStats("Solved" if js.beta is not None else js.status, steps, seconds,
                            seconds, math.nan, "clarabel-scp")
        pinned = acc_start is not None and kind[0] == NORMAL
        if pinned and finer < MAX_FINER and (js.slack > 1e-7 or "Infeasible" in js.status):
            return retime_jerk(inp, 2 * finer)
        if js.beta is None or js.acc is None:
            why = ("the jerk bound cannot be met from this start state with these limits"
                   if "Infeasible" in js.status else "the solver did not finish")
            return fallback(f"the jerk-limited problem could not be solved (Clarabel: "
                            f"{js.status} after {js.steps} convexified solves): {why}",
                            stats=stats)
        if js.slack > 1e-7:
            return fallback("the jerk bound cannot be met from this start state with these "
                            f"limits (it is exceeded by up to {100 * js.slack:.1f} % of beta "
                            "where it binds)", stats=stats)
        speed, acc, jerk, b = limit_ratios(lay, dense, js.beta, js.acc, a_max, j_max)
        worst = (float(speed.max()), float(acc.max()), float(jerk.max()))
        bad = ((speed > 1 + LIMIT_TOL) | (acc > 1 + LIMIT_TOL) | (jerk > 1 + LIMIT_TOL)
               | (b < -1e-12))
        if not bad.any():
            break
        add = (dense.interval[bad], dense.frac[bad])
        extra = add if extra is None else (np.concatenate([extra[0], add[0]]),
                                           np.concatenate([extra[1], add[1]]))
    else:
        names = ("speed", "acceleration", "jerk")
        k = int(np.argmax(worst))
        return fallback(f"the {names[k]} limit is exceeded by {100 * (worst[k] - 1):.2f} % "
                        f"between the check points after {MAX_ROUNDS} rounds", stats=stats)
    timemap = JerkTimeMap(tau, js.beta, js.acc, kind[0] == REST_START, kind[-1] == REST_END)
    if not np.isfinite(timemap.duration):
        return fallback("the jerk-limited time mapping stops on the way (infinite duration)",
                        stats=stats)
    stats = replace(stats, objective=timemap.duration)
    found = replace(found, jerk_steps=steps, jerk_ratio=worst[2],
                    unlimited_duration=base.duration, jerk_finer=finer)
    return RetimeResult(OPTIMAL, "", timemap, traj, stats, vlim, found, base.warnings)


def refine_grid(tau: FloatArray, vlim: FloatArray, parts: int
                ) -> tuple[FloatArray, FloatArray]:
    """The grid ``tau`` with every interval cut in ``parts``, and the speed limits
    there (their squares interpolated, as between check points)."""
    n = len(tau) - 1
    fine = np.linspace(tau[0], tau[-1], parts * n + 1)
    fine[::parts] = tau
    lim2 = np.interp(fine, tau, np.where(np.isfinite(vlim), vlim**2, 1e300))
    return fine, np.where(lim2 >= 1e299, np.inf, np.sqrt(lim2))


def _hovering(inp: RetimeInput) -> RetimeInput:
    """``inp`` without its start acceleration when the vehicle is at rest and the
    acceleration does not push it along the path (a hover): the jerk-limited start
    from rest (a rest interval) begins at zero acceleration anyway, and the
    unlimited re-time refuses a start at rest that cannot move."""
    a = inp.start_acceleration
    if a is None or float(np.linalg.norm(inp.start_velocity)) > 0.0:
        return inp
    d1 = derivatives(inp.trajectory, inp.trajectory.domain[:1])[0][0]
    s2 = float(d1 @ d1)
    if s2 <= STILL**2 or float(a @ d1) / s2 <= REST_ACC:
        return replace(inp, start_acceleration=None)
    return inp


def _acceleration_jump(inp: RetimeInput) -> str | None:
    """Why no time mapping can bound the jerk: the path's velocity or
    acceleration jumps at a breakpoint (the path is not C2). None when it is."""
    traj = inp.trajectory
    t0, t1 = traj.domain
    edges = traj.edges
    inner = edges[(edges > t0) & (edges < t1)]
    if not len(inner):
        return None
    l1, l2, _ = derivatives(traj, inner, left=True)
    r1, r2, _ = derivatives(traj, inner, left=False)
    for name, lft, rgt in (("velocity", l1, r1), ("acceleration", l2, r2)):
        scale = max(float(np.max(np.abs(lft))), float(np.max(np.abs(rgt))), 1e-9)
        gap = np.max(np.abs(lft - rgt), axis=1)
        if gap.max() > C2_TOL * scale:
            at = float(inner[int(np.argmax(gap))])
            return (f"the path's {name} jumps at tau={at:.3f} s (it is not twice "
                    "continuously differentiable): no time mapping bounds the jerk there")
    return None


def jerk_fallback(inp: RetimeInput, tau: FloatArray, vlim: FloatArray) -> TimeMap:
    """The uniform slow-down of :func:`rota.optimal.uniform_fallback`, slowed further
    until the jerk at constant ``tau_dot = k`` (``k^3 sigma'''``) meets the bound.
    Like that fallback it keeps the input's own start and end behaviour."""
    plain = uniform_fallback(inp.trajectory, tau, vlim, inp.limits.a_max_vec)
    k = math.sqrt(float(plain.beta[0]))
    j_max = inp.limits.j_max_vec
    if j_max is not None:
        fine = np.linspace(tau[0], tau[-1], 4 * (len(tau) - 1) + 1)
        d3 = np.concatenate([derivatives(inp.trajectory, fine)[2],
                             derivatives(inp.trajectory, fine, left=True)[2]])
        with np.errstate(divide="ignore"):
            k = min(k, float(np.cbrt(np.min(j_max / np.abs(d3)))))
    return TimeMap(tau, np.full(len(tau), k * k))


__all__ = ["jerk_fallback", "retime_jerk"]
