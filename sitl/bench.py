"""``rota-sitl bench``: the paper's Table II, side by side with peers.

Re-creates Table II (computation time of the time allocation for a 7 m and a 30 m
trajectory through a forest map at six trajectory-time steps) on the bundled data
(``sitl/data/bench_*.json``, made by ``examples/make_bench_data.py``) and, on the
same path and limits, runs

* the full ROTA pipeline (:func:`rota.retime` with the map: braking zones, chance
  constraints, reachability, the fast solver, constraint generation, checks), the
  solver alone (run again on the last round's problem), its peak memory, and the
  same pipeline with Clarabel;
* the peers on the time-optimal problem (lambda = 0, no chance constraints):
  toppra (seidel) and copp-py (``topp2_ra``, reachability in Rust, and
  ``copp2_socp``, Rust on Clarabel), next to ROTA on its own problem and on the
  problem as the peers pose it (limits at the nodes only);
* a straightforward cvxpy formulation of the full ROTA problem (same speed
  limits) solved by Clarabel, what a user would write by hand (:mod:`sitl.bench_peers`).

Every ROTA answer is checked twice: against Clarabel at 1e-9 on the very same
problem (objective within 1e-6), and against an independent high-accuracy
reference: the cvxpy formulation with constraints at 41, 9 or 3 points per
interval, solved by Clarabel at 1e-9 (objectives within 0.1 %), with the re-timed
trajectory, sampled every 2 ms in real time, meeting the speed and per-axis
acceleration limits by finite differences of its positions. The time-optimal
answers are checked the same way against each other.

Timings interleave the methods within each repetition and report medians (the
machine may be shared). Peak memory: ``tracemalloc`` peak of Python (incl. numpy)
allocations during one pipeline run, and the growth of the process's maximum
resident set size (``getrusage`` maxrss) over that run.
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import os
import resource
import statistics
import time
import tracemalloc
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

import rota.checkpoints as _cp
from rota import chain as _chain
from rota.path import evaluate as _evaluate
from rota.problem import Limits, RetimeInput, SolverSettings, make_grid
from rota.retime import retime
from rota.robust import Safety
from rota.schema import trajectory_from_dict
from rota.trajectory import Trajectory
from rota.voxelmap import VoxelMap
from sitl import bench_jerk
from sitl.bench_machine import calibration_s, host_steal_s, machine, startup_costs
from sitl.bench_peers import A_MAX, V_MAX, cvxpy_solve, run_copp, run_toppra

T = TypeVar("T")
DATA = Path(__file__).resolve().parent / "data"
LAMBDA = 0.5
DTAUS = (0.5, 0.1, 0.05, 0.01, 0.005, 0.001)
#: Paper Table II (C++, Mosek, i7-12700K), seconds.
PAPER = {"7m": dict(zip(DTAUS, (0.006, 0.017, 0.026, 0.093, 0.178, 0.857), strict=True)),
         "30m": dict(zip(DTAUS, (0.018, 0.049, 0.085, 0.400, 0.840, 5.440), strict=True))}
QUICK_ROWS = (("7m", 0.1), ("30m", 0.5))
#: Samples of the time-optimal head-to-head.
TOPP_SAMPLES = 3000
#: Reference constraints at 41 points per interval up to FINE_REF_MAX intervals, 9
#: up to DENSE_REF_MAX, 3 beyond (the reference must fit in the 5-minute budget).
FINE_REF_MAX = 100
DENSE_REF_MAX = 4000
#: Beyond this many intervals the comparison columns (time-optimal ROTA, toppra,
#: copp-py, cvxpy) are timed once, not `repeats` times, to keep the whole benchmark
#: within 5 minutes; ROTA's Table II figures always use `repeats` runs.
CVXPY_ONCE = 4000
#: A call quicker than WARM_BELOW_S seconds is also timed warm: WARM_CALLS more
#: calls straight after it, their median.
WARM_BELOW_S = 0.05
WARM_CALLS = 5
OBJ_TOL = 1e-3
#: Clarabel tolerance of the reference solves.
REF_TOL = 1e-9
#: The answer must match Clarabel (at REF_TOL) on the very same problem this closely.
SAME_TOL = 1e-6
CLARABEL = SolverSettings(method="clarabel")
FD_DT = 0.002
#: Limits hold at ROTA's check points (within 0.1 %); between them, and with the
#: error of second differences, the finite-difference check allows this much.
FD_TOL = 0.03


# ------------------------------------------------------------------------ data
def load_data() -> tuple[dict[str, Trajectory], VoxelMap]:
    trajs = {name: trajectory_from_dict(json.loads(
        (DATA / f"bench_traj_{name}.json").read_text())).trajectory for name in ("7m", "30m")}
    vmap = VoxelMap.from_dict(json.loads((DATA / "bench_forest_map.json").read_text()))
    return trajs, vmap


def objective(tau: np.ndarray, beta: np.ndarray, lam: float) -> float:
    """duration + lambda * sum(alpha_i^2 h), computed from beta alone."""
    h = np.diff(tau)
    r = np.sqrt(np.maximum(beta, 0.0))
    alpha = np.diff(beta) / (2 * h)
    with np.errstate(divide="ignore"):
        return float(np.sum(2 * h / (r[:-1] + r[1:])) + lam * np.sum(alpha**2 * h))


# ------------------------------------------------------------------- ROTA runs
def solver_alone(rnd: Any, settings: SolverSettings) -> float:
    """Seconds of the solver alone on a round's problem (tightened bounds, from the
    greedy profile, as inside the round), run again on its own: the fast solver
    runs inside the round's single compiled call, where it cannot be timed apart.
    0 when reachability alone gave the answer."""
    from rota.solver import solve

    if rnd is None or not rnd.ok or rnd.stats is None or rnd.stats.iterations == 0:
        return 0.0
    tight = rnd.tight
    t0 = time.perf_counter()
    solve(tight, settings, start=rnd.greedy)
    return time.perf_counter() - t0


def run_rota(inp: RetimeInput, keep: dict | None = None) -> tuple[float, float, Any]:
    """One timed re-time of ``inp`` on a fresh copy of its trajectory (a replan
    brings a new one: its conversion to polynomial pieces is timed too). With
    ``keep``, also the solver alone on the last round's problem (:func:`solver_alone`,
    after the timed call) and that problem in ``keep["problem"]``."""
    inp = replace(inp, trajectory=inp.trajectory.fresh())
    inp = replace(inp, solver=replace(inp.solver, keep_round=True))
    t0 = time.perf_counter()
    res = retime(inp)
    wall = time.perf_counter() - t0
    solver_s = float("nan")
    if keep is not None:
        last = res.diagnostics.last_round
        keep["problem"] = None if last is None else last.problem
        solver_s = solver_alone(last, inp.solver)
    return wall, solver_s, res


def _breaks_rows(problem: _chain.ChainProblem, beta: np.ndarray) -> str | None:
    """Whether ``beta`` breaks a row or a bound of ``problem`` by more than 1e-7."""
    rows = problem.ra * beta[problem.rk] + problem.rc * beta[problem.rk + 1]
    worst = max(float(rows.max(initial=0.0)) - 1,
                float(np.max(beta / np.maximum(problem.hi, 1e-300))) - 1)
    return f"breaks a limit by {100 * worst:.2g} %" if worst > 1e-7 else None


def same_problem_error(problem: _chain.ChainProblem, beta: np.ndarray) -> float:
    """Relative objective error of ``beta`` against Clarabel at REF_TOL on the same
    chain problem (same check points and rows); NaN when ``beta`` breaks a row or a
    bound by more than 1e-7 (a lower objective then means nothing)."""
    from rota.solver import solve_clarabel

    if _breaks_rows(problem, beta):
        return float("nan")
    ref, stats = solve_clarabel(problem, SolverSettings(method="clarabel", tol=REF_TOL,
                                                        max_iter=500))
    if ref is None:
        return float("nan")
    return problem.objective(beta) / problem.objective(ref) - 1.0


def run_rota_nodes(traj: Trajectory, tau: np.ndarray, exact: bool) -> tuple[float, Any]:
    """The time-optimal problem posed as copp-py and toppra pose it: speed and
    acceleration limits at the grid nodes only (both ends of every interval), rest
    at both ends. ``exact=False``: our reachability pass alone (the greedy
    profile, as copp-py's ``topp2_ra`` and toppra answer); True: then our
    interior-point solver to the optimum. Returns ``(seconds, (problem, beta))``."""
    from rota.solver import solve

    t0 = time.perf_counter()
    n = len(tau) - 1
    _, d1, d2 = _evaluate(traj, tau)
    speed2 = np.maximum(np.einsum("ij,ij->i", d1, d1), 1e-24)
    path = _cp.PathSamples(tau=tau, d1=d1, d2=d2, beta_max=V_MAX**2 / speed2,
                           vlim=np.full(n + 1, V_MAX), a_max=np.full(3, A_MAX),
                           offsets=np.arange(n + 1, dtype=np.int64) * 2,
                           frac=np.tile([0.0, 1.0], n),
                           cd1=np.repeat(d1, 2, axis=0)[1:-1], cd2=np.repeat(d2, 2, axis=0)[1:-1])
    problem = _chain.build(path, 0.0, _chain.Boundary(0.0, None, 0.0))
    rch = _chain.reach(problem, certify=exact)
    beta = rch.greedy
    if exact and not rch.exact:
        beta, _ = solve(problem, SolverSettings(), start=rch.greedy)
    return time.perf_counter() - t0, (problem, beta)


def peak_memory(inp: RetimeInput) -> tuple[float, float]:
    """(tracemalloc peak MiB, maxrss growth MiB) of one pipeline run."""
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    tracemalloc.start()
    retime(inp)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    rss1 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 2**20, (rss1 - rss0) / 1024


REF_FINE = np.linspace(0.0, 1.0, 41)  # includes the 0.1 s knots at dtau 0.5 s
REF_DENSE = np.linspace(0.0, 1.0, 9)
REF_SPARSE = np.array([0.0, 0.5, 1.0])
PEER_FRACTIONS = np.array([0.0, 0.5, 1.0])


# ---------------------------------------------------------------------- checks
#: Overshoot (fraction) found by the last :func:`fd_check`.
FD_LAST: dict[str, float] = {}


def fd_check(traj: Trajectory, timemap, vlim: np.ndarray) -> str | None:
    """Limits met by the re-timed positions (finite differences every FD_DT)."""
    t = np.arange(0.0, timemap.duration, FD_DT)
    tau = timemap.evaluate(t)[0]
    p = traj.position(tau)
    v = (p[2:] - p[:-2]) / (2 * FD_DT)
    a = (p[2:] - 2 * p[1:-1] + p[:-2]) / FD_DT**2
    lim = np.interp(tau[1:-1], timemap.tau, vlim)
    over_v = float(np.max(np.linalg.norm(v, axis=1) / lim)) - 1
    over_a = float(np.max(np.abs(a))) / A_MAX - 1
    FD_LAST.update(speed=over_v, accel=over_a)
    if over_v > FD_TOL:
        return f"speed exceeds its limit by {100 * over_v:.2f} %"
    if over_a > FD_TOL:
        return f"acceleration exceeds its limit by {100 * over_a:.2f} %"
    return None


def verdict(obj: float, ref: float, fd: str | None) -> dict[str, Any]:
    err = (obj - ref) / ref
    ok = abs(err) <= OBJ_TOL and fd is None
    why = fd or ("" if abs(err) <= OBJ_TOL else f"objective off by {100 * err:.3f} %")
    return {"ok": bool(ok), "obj_rel_err": float(err), "why": why}


# ---------------------------------------------------------------- the table
def _median(xs: list[float]) -> float:
    return float(statistics.median(xs)) if xs else float("nan")


def bench_row(name: str, dtau: float, traj: Trajectory, safety: Safety, repeats: int,
              log) -> dict[str, Any]:
    lim = Limits(V_MAX, A_MAX)
    full_inp = RetimeInput(trajectory=traj, limits=lim, smoothness=LAMBDA, dtau=dtau,
                           safety=safety)
    topp_inp = RetimeInput(trajectory=traj, limits=lim, smoothness=0.0, dtau=dtau)
    tau = make_grid(traj, full_inp.dtau)
    n = len(tau) - 1
    # Warm-up (imports, caches), then the reference solves (not timed).
    _, _, res = run_rota(full_inp, {})
    vlim = np.asarray(res.speed_limits)
    fr = REF_FINE if n <= FINE_REF_MAX else REF_DENSE if n <= DENSE_REF_MAX else REF_SPARSE
    ref_beta, ref_secs = cvxpy_solve(traj, tau, vlim, LAMBDA, fr, tol=REF_TOL)
    ref_obj = objective(tau, ref_beta, LAMBDA)
    keys = ("full", "solver", "full_clarabel", "topp_rota", "nodes_reach", "nodes_exact",
            "toppra", "copp_ra", "copp_socp", "cvxpy")
    times: dict[str, list[float]] = {k: [] for k in keys}
    warm: dict[str, list[float]] = {k: [] for k in keys}

    def timed(key: str, fn: Callable[[], T], secs_of: Callable[[T], float]) -> T:
        """``fn()`` timed as it comes, after the other methods (*interleaved*), then,
        if quicker than WARM_BELOW_S, WARM_CALLS times more at once (*warm*: its
        data and code in the caches, as in a loop of re-times); the garbage
        collector paused meanwhile, as ``timeit`` does."""
        gc.disable()
        try:
            out = fn()
            secs = secs_of(out)
            again = [secs_of(fn()) for _ in range(WARM_CALLS)] if secs < WARM_BELOW_S else [secs]
        finally:
            gc.enable()
        times[key].append(secs)
        warm[key].append(_median(again))
        return out

    rounds = 0
    outs: dict[str, Any] = {}
    kept: dict[str, Any] = {}
    clarabel_inp = replace(full_inp, solver=CLARABEL)
    for rep in range(repeats):
        _, solver_s, res = timed("full", lambda: run_rota(full_inp, kept), lambda o: o[0])
        times["solver"].append(solver_s)
        rounds = res.diagnostics.solve_rounds
        outs["full"] = res
        if rep and n > CVXPY_ONCE:
            continue  # beyond CVXPY_ONCE intervals the comparison columns run once
        outs["full_clarabel"] = timed("full_clarabel", lambda: run_rota(clarabel_inp),
                                      lambda o: o[0])[2]
        outs["topp_rota"] = timed("topp_rota",
                                  lambda: run_rota(topp_inp, kept.setdefault("topp", {})),
                                  lambda o: o[0])[2]
        for key, fn in (("nodes_reach", lambda: run_rota_nodes(traj, tau, exact=False)),
                        ("nodes_exact", lambda: run_rota_nodes(traj, tau, exact=True)),
                        ("toppra", lambda: run_toppra(traj, tau)),
                        ("copp_ra", lambda: run_copp(traj, tau, socp=False)),
                        ("copp_socp", lambda: run_copp(traj, tau, socp=True))):
            try:
                _, beta = timed(key, fn, lambda o: o[0])
            except Exception as exc:  # noqa: BLE001 - a peer failing is a result
                outs[key] = f"failed: {exc}"
                continue
            outs.setdefault(key, beta)
            if not isinstance(outs[key], str):
                outs[key] = beta
        if rep == 0 or n <= CVXPY_ONCE:
            outs["cvxpy"] = timed("cvxpy", lambda: cvxpy_solve(traj, tau, vlim, LAMBDA,
                                                               PEER_FRACTIONS), lambda o: o[1])[0]
    mem_py, mem_rss = peak_memory(full_inp)
    med = {k: _median(v) for k, v in times.items()}
    med_warm = {k: _median(v) for k, v in warm.items()}
    full = outs["full"]
    checks = {"full": verdict(objective(tau, full.timemap.beta, LAMBDA), ref_obj,
                              None if full.ok else f"status {full.status}: {full.message}")}
    if full.ok:
        checks["full"] = verdict(objective(tau, full.timemap.beta, LAMBDA), ref_obj,
                                 fd_check(traj, full.timemap, vlim))
    fd_over = dict(FD_LAST)
    checks["cvxpy"] = verdict(objective(tau, outs["cvxpy"], LAMBDA), ref_obj, None)
    # Time-optimal: ROTA against the reference with ROTA's semantics; the peers
    # against a reference on their own terms (limits at both ends of every interval,
    # toppra's "interpolation" scheme and copp's, and beta = 0 at the
    # ends), so each answer is checked for the problem it solves.
    t_ours = outs["topp_rota"]
    vmax = np.full(n + 1, V_MAX)
    ref0 = objective(tau, cvxpy_solve(traj, tau, vmax, 0.0, fr, tol=REF_TOL)[0], 0.0)
    ref0_peer = objective(tau, cvxpy_solve(traj, tau, vmax, 0.0, np.array([0.0, 1.0]), tol=REF_TOL,
                                           rota_ends=False)[0], 0.0)
    checks["topp_rota"] = verdict(objective(tau, t_ours.timemap.beta, 0.0), ref0,
                                  fd_check(traj, t_ours.timemap, vmax)
                                  if t_ours.ok else f"status {t_ours.status}")
    broken: dict[str, str | None] = {}
    for k in ("nodes_reach", "nodes_exact"):
        if not isinstance(outs[k], str):
            problem, outs[k] = outs[k]
            broken[k] = _breaks_rows(problem, outs[k])
    for k in ("nodes_reach", "nodes_exact", "toppra", "copp_ra", "copp_socp"):
        if isinstance(outs[k], str):
            checks[k] = {"ok": False, "obj_rel_err": float("nan"), "why": outs[k]}
        else:
            checks[k] = verdict(objective(tau, outs[k], 0.0), ref0_peer, broken.get(k))
    # The same problem (check points, rows) solved by Clarabel at REF_TOL.
    same = {"full": same_problem_error(kept["problem"], full.timemap.beta),
            "topp_rota": same_problem_error(kept["topp"]["problem"], t_ours.timemap.beta)}
    for k, err in same.items():
        checks[k]["same_problem_rel_err"] = err
        # One-sided: below the reference (and feasible) means Clarabel stopped short.
        if not err <= SAME_TOL:
            checks[k]["ok"] = False
            checks[k]["why"] += f" objective off the same-problem Clarabel solve by {err:.2e}"
    paper = PAPER.get(name, {}).get(dtau)
    row = {"trajectory": name, "dtau": dtau, "N": n, "rounds": rounds,
           "duration_s": full.duration, "objective": objective(tau, full.timemap.beta, LAMBDA),
           "reference_objective": ref_obj, "reference_points_per_interval": len(fr),
           "reference_solve_s": ref_secs, "paper_s": paper,
           "median_s": med, "median_warm_s": med_warm, "mem_tracemalloc_MiB": mem_py,
           "mem_maxrss_growth_MiB": mem_rss,
           "repeats": repeats, "cvxpy_repeats": len(times["cvxpy"]), "checks": checks,
           "fd_overshoot": fd_over}
    ok = all(checks[k]["ok"] for k in OURS)
    log(f"{name:>4} dtau={dtau:<6g} N={n:<6d} full {1e3 * med['full']:8.2f} ms "
        f"(paper x{paper / med['full'] if paper else float('nan'):5.2f}; warm "
        f"{1e3 * med_warm['full']:.2f} ms)  solver "
        f"{1e3 * med['solver']:8.2f} ms  Clarabel {1e3 * med['full_clarabel']:8.2f} ms  "
        f"cvxpy {1e3 * med['cvxpy']:8.1f} ms "
        f"(x{med['cvxpy'] / med['full']:5.2f})  | topp: rota {1e3 * med['topp_rota']:7.2f} "
        f"nodes {1e3 * med['nodes_reach']:6.2f} / {1e3 * med['nodes_exact']:6.2f} "
        f"(warm reach {1e3 * med_warm['nodes_reach']:.2f}) "
        f"toppra {1e3 * med['toppra']:7.2f} copp-ra {1e3 * med['copp_ra']:6.2f} "
        f"(warm {1e3 * med_warm['copp_ra']:.2f}) copp-socp "
        f"{1e3 * med['copp_socp']:7.2f} ms  mem {mem_py:6.1f} MiB  "
        f"{'ok' if ok else 'FAILED'} "
        f"{ {k: c['why'] for k, c in checks.items() if not c['ok']} or ''}")
    return row


def fit_exponent(ns: list[int], ts: list[float]) -> float:
    if len(ns) < 2:
        return float("nan")
    return float(np.polyfit(np.log(ns), np.log(ts), 1)[0])


# -------------------------------------------------------------------- output
def _ms(x: float | None) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{1e3 * x:.2f}"


def to_markdown(report: dict[str, Any]) -> str:
    m = report["machine"]
    lines = [f"Machine: {m['cpu']}, {m['cores']} cores, {m['system']}, Python {m['python']}; "
             f"{m['packages']}.", ""]
    if "calibration_ms" in report:
        lines += ["Speed of the machine in this run: the fixed calibration work "
                  f"(`sitl.bench_machine.calibration_s`) took {report['calibration_ms']:.2f} "
                  "ms; the "
                  f"hypervisor took {100 * report['host_steal_share']:.1f} % of the CPUs' time "
                  "during the run.", ""]
    if report.get("startup"):
        st = report["startup"]
        lines += [f"Start-up, each in a fresh process: `import rota` {st['import_rota_s']:.2f} s; "
                  f"`rota.warm_up()` {st['warm_up_cold_s']:.1f} s with an empty cache "
                  f"(compiles every kernel), {st['warm_up_warm_s']:.2f} s with a warm one "
                  "(imports numba, loads the kernels).", ""]
    lines += [f"Medians of {report['repeats']} interleaved runs, milliseconds; "
              "x = paper time / ours (or peer / ours). *warm*: the median of "
              f"{WARM_CALLS} more calls straight after each (calls under "
              f"{WARM_BELOW_S * 1e3:.0f} ms), the rest as interleaved.", "",
              "| traj | dtau (s) | N | rounds | ROTA full | warm | paper | x paper (warm) | "
              "solver alone | ROTA with Clarabel | x Clarabel | cvxpy+Clarabel | x cvxpy | "
              "mem (MiB, py / rss) | ref. check (objective; same problem) | "
              "FD overshoot v / a |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in report["rows"]:
        med = r["median_s"]
        hot = r["median_warm_s"]
        paper = r["paper_s"]
        c = r["checks"]["full"]
        ok = "ok" if c["ok"] else "FAIL"
        x = (f"{paper / med['full']:.1f} ({paper / hot['full']:.1f})" if paper else "-")
        lines.append(
            f"| {r['trajectory']} | {r['dtau']:g} | {r['N']} | {r['rounds']} | "
            f"{_ms(med['full'])} | {_ms(hot['full'])} | {_ms(paper)} | {x} | "
            f"{_ms(med['solver'])} | "
            f"{_ms(med['full_clarabel'])} | {med['full_clarabel'] / med['full']:.1f} | "
            f"{_ms(med['cvxpy'])} | {med['cvxpy'] / med['full']:.1f} | "
            f"{r['mem_tracemalloc_MiB']:.1f} / {r['mem_maxrss_growth_MiB']:.1f} | "
            f"{ok} ({100 * c['obj_rel_err']:+.4f} %; {c.get('same_problem_rel_err', 0):+.1e}) | "
            f"{100 * r['fd_overshoot'].get('speed', float('nan')):+.2f} / "
            f"{100 * r['fd_overshoot'].get('accel', float('nan')):+.2f} % |")
    lines += ["", "Time-optimal problem (lambda = 0, no chance constraints), milliseconds. "
              "*ROTA*: our own problem (limits between the nodes too); *nodes*: the problem "
              "as toppra and copp-py pose it (limits at the nodes only), our reachability "
              "pass alone / with the interior-point solver to the optimum; objective errors "
              "against Clarabel at 1e-9 on each problem:", "",
              "| traj | dtau (s) | N | ROTA | nodes: reach (warm) | nodes: exact | "
              "toppra (seidel) | copp-py topp2_ra (warm) | copp-py copp2_socp | "
              "x copp topp2_ra (reach; warm) | "
              "ROTA error | reach error | exact error | copp topp2_ra error |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in report["rows"] + report.get("topp_rows", []):
        med = r["median_s"]
        hot = r["median_warm_s"]
        ch = r["checks"]
        lines.append(
            f"| {r['trajectory']} | {r['dtau']:.4g} | {r['N']} | {_ms(med['topp_rota'])} | "
            f"{_ms(med['nodes_reach'])} ({_ms(hot['nodes_reach'])}) | "
            f"{_ms(med['nodes_exact'])} | {_ms(med['toppra'])} | "
            f"{_ms(med['copp_ra'])} ({_ms(hot['copp_ra'])}) | {_ms(med['copp_socp'])} | "
            f"{med['copp_ra'] / med['nodes_reach']:.2f}; "
            f"{hot['copp_ra'] / hot['nodes_reach']:.2f} | "
            f"{ch['topp_rota'].get('same_problem_rel_err', float('nan')):+.1e} | "
            f"{ch['nodes_reach']['obj_rel_err']:+.1e} | {ch['nodes_exact']['obj_rel_err']:+.1e} | "
            f"{ch['copp_ra']['obj_rel_err']:+.1e} |")
    fits = report["fit"]
    lines += ["", "Growth of the time with the number of samples (log-log slope, rows with "
              "N >= 100): " + ", ".join(f"{k} {v:.2f}" for k, v in fits.items()) + "."]
    lines += bench_jerk.to_markdown(report.get("jerk_rows", []))
    return "\n".join(lines) + "\n"


def run_bench(out_dir: str | Path, quick: bool = False, repeats: int = 5,
              log=print) -> dict[str, Any]:
    """Run the benchmark, write ``bench.md`` and ``bench.json`` to ``out_dir``,
    return the report. ``quick``: two small rows, no optimisation-step study."""
    start = time.perf_counter()
    steal0, calibration = host_steal_s(), calibration_s()
    trajs, vmap = load_data()
    safety = Safety(map=vmap)
    rows_spec = list(QUICK_ROWS) if quick else [(n, d) for n in ("7m", "30m") for d in DTAUS]
    log(f"rota-sitl bench: {len(rows_spec)} rows, {repeats} repeats")
    rows = [bench_row(name, dtau, trajs[name], safety, repeats, log)
            for name, dtau in rows_spec]
    topp_rows = []
    if not quick:
        traj = trajs["30m"]
        dt = traj.duration / TOPP_SAMPLES
        log(f"time-optimal head-to-head at {TOPP_SAMPLES} samples (30 m):")
        topp_rows.append(bench_row("30m", dt, traj, safety, repeats, log))
    fit = {}
    for key in ("full", "solver", "full_clarabel"):
        for name in ("7m", "30m"):
            sel = [r for r in rows if r["trajectory"] == name and r["N"] >= 100]
            fit[f"{key} {name}"] = fit_exponent([r["N"] for r in sel],
                                                [r["median_s"][key] for r in sel])
    jerk_rows = bench_jerk.jerk_rows(trajs, safety, V_MAX, A_MAX, LAMBDA, repeats, quick, log)
    startup = {} if quick else startup_costs()
    seconds = time.perf_counter() - start
    report = {"machine": machine(), "repeats": repeats, "rows": rows, "topp_rows": topp_rows,
              "jerk_rows": jerk_rows, "fit": fit, "startup": startup, "seconds": seconds,
              "calibration_ms": 1e3 * calibration,
              "host_steal_share": (host_steal_s() - steal0) / (seconds * (os.cpu_count() or 1))}
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench.json").write_text(json.dumps(report, indent=1, default=str) + "\n")
    (out / "bench.md").write_text(to_markdown(report))
    log(f"fit exponents: {fit}")
    log(f"wrote {out / 'bench.md'} and {out / 'bench.json'} in {report['seconds']:.1f} s")
    return report


def _bench_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="out/bench", help="directory for bench.md / bench.json")
    p.add_argument("--quick", action="store_true", help="two small rows (what CI runs)")
    p.add_argument("--repeats", type=int, default=5, help="runs per figure (median)")


def add_bench_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``rota-sitl bench [--out DIR] [--quick] [--repeats N]``."""
    p = subparsers.add_parser("bench", help="re-create the paper's Table II next to peers")
    _bench_arguments(p)
    p.set_defaults(func=bench_main)
    return p


def bench_main(args: argparse.Namespace) -> int:
    report = run_bench(args.out, quick=args.quick, repeats=args.repeats)
    return 0 if rota_ok(report) else 1


#: The answers whose failure fails the benchmark (the peers' are reported only).
OURS = ("full", "topp_rota")


def rota_ok(report: dict[str, Any]) -> bool:
    return all(r["checks"][k]["ok"] for r in report["rows"] + report["topp_rows"] for k in OURS)


def main(argv: list[str] | None = None) -> int:
    """``python -m sitl.bench [--out DIR] [--quick] [--repeats N]``."""
    parser = argparse.ArgumentParser(prog="python -m sitl.bench")
    _bench_arguments(parser)
    return bench_main(parser.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
