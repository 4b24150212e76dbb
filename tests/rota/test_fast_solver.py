"""The fast solver (compiled interior-point method on beta, with reachability)
against Clarabel on the same chain problems: random paths of all three input
kinds, random limits, lambda and start states. Same feasibility verdict, and
objectives within 1e-6 (Clarabel at 1e-9)."""

from __future__ import annotations

import json
import multiprocessing
from dataclasses import replace

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rota import Limits, RetimeInput, retime
from rota.chain import Boundary, build, reach
from rota.checkpoints import sample_path
from rota.path import evaluate
from rota.problem import SolverSettings, make_grid
from rota.rounds import audit, finish, one_round
from rota.solver import solve, solve_clarabel, solve_fast
from tests.helpers.strategies import bspline, limits, sampled, trajectories

REFERENCE = SolverSettings(method="clarabel", tol=1e-9, max_iter=500)
TIGHT = SolverSettings(method="clarabel", tol=1e-11, max_iter=2000)


def chain_problem(traj, lim: Limits, lam: float, n: int, start_share: float = 0.0):
    """The chain problem of a re-time, starting at ``start_share`` of the speed
    limit along the path (0: at rest)."""
    inp = RetimeInput(trajectory=traj, limits=lim, smoothness=lam, dtau=traj.duration / n)
    tau = make_grid(traj, inp.dtau)
    _, d1, _ = evaluate(traj, tau)
    path = sample_path(traj, tau, np.full(len(tau), lim.v_max), lim.a_max_vec)
    s = float(np.linalg.norm(d1[0]))
    beta0 = (start_share * lim.v_max / s) ** 2 if s > 1e-6 else None
    return build(path, lam, Boundary(beta_start=beta0, beta_end=0.0 if np.linalg.norm(
        d1[-1]) > 1e-6 else None))


def agree(problem) -> None:
    rch = reach(problem)
    ref, ref_stats = solve_clarabel(problem, REFERENCE)
    if not rch.feasible:
        assert ref is None and "Infeasible" in ref_stats.status, ref_stats.status
        return
    assert ref is not None, ref_stats.status
    beta, stats = solve_fast(problem, SolverSettings(), start=rch.greedy)
    assert beta is not None, stats
    ours, theirs = problem.objective(beta), problem.objective(ref)
    if ours < theirs * (1 - 1e-6):
        # At lambda = 0 (an LP-like, degenerate optimum) Clarabel at 1e-9 can stop
        # short: then a tighter solve must come to our objective.
        ref, ref_stats = solve_clarabel(problem, TIGHT)
        assert ref is not None, ref_stats.status
        theirs = problem.objective(ref)
    assert abs(ours - theirs) <= 1e-6 * theirs, (ours, theirs, stats)
    # and the fast answer is feasible: every row and bound within rounding
    rows = problem.ra * beta[problem.rk] + problem.rc * beta[problem.rk + 1]
    assert rows.max(initial=0.0) <= 1 + 1e-7
    assert np.all(beta <= problem.hi * (1 + 1e-7)) and np.all(beta >= 0)


@settings(deadline=None, max_examples=60, suppress_health_check=[HealthCheck.too_slow])
@given(traj=trajectories(), lim=limits(), n=st.integers(8, 300),
       lam=st.sampled_from([0.0, 1e-3, 0.5, 2.0]))
def test_fast_solver_matches_clarabel_at_rest(traj, lim, n, lam):
    agree(chain_problem(traj, lim, lam, n))


@settings(deadline=None, max_examples=40, suppress_health_check=[HealthCheck.too_slow])
@given(traj=trajectories(), lim=limits(), n=st.integers(8, 200),
       lam=st.sampled_from([0.0, 0.5]), share=st.floats(0.0, 1.0))
def test_fast_solver_matches_clarabel_moving_start(traj, lim, n, lam, share):
    """Moving starts include infeasible ones (too fast to stop on a short path)."""
    agree(chain_problem(traj, lim, lam, n, share))


def test_infeasible_verdicts_agree():
    traj = sampled(5, 5, 0.4, with_velocity=False)  # moving at both ends
    lim = Limits(4.0, 0.3)
    problem = chain_problem(traj, lim, 0.5, 60, start_share=1.0)
    assert not reach(problem).feasible
    agree(problem)


def _staged(traj, tau, d1, d2, vlim, lim, boundary, lam, more):
    """A round step by step, the tightening written out in numpy."""
    path = sample_path(traj, tau, vlim, lim.a_max_vec, d1, d2)
    if len(more[0]):
        interval = np.concatenate([path.interval, more[0]])
        frac = np.concatenate([path.frac, more[1]])
        key = interval * 2.0 + frac
        order = np.argsort(key, kind="stable")
        keep = np.concatenate([[True], np.diff(key[order]) > 1e-12])
        interval, frac = interval[order][keep], frac[order][keep]
        offsets = np.zeros(len(tau), dtype=np.int64)
        np.cumsum(np.bincount(interval, minlength=len(tau) - 1), out=offsets[1:])
        _, c1, c2 = evaluate(traj, tau[interval] + frac * (tau[1] - tau[0]))
        path = replace(path, offsets=offsets, frac=frac, cd1=c1, cd2=c2)
    problem = build(path, lam, boundary)
    rch = reach(problem, certify=lam == 0.0)
    if not path.moving or not rch.feasible:
        return path, problem, rch, None, None
    free = ~problem.fixed
    hi = np.where(free, np.minimum(problem.hi, rch.ku), problem.hi)
    still = free & (hi <= 0.0)
    fixed = problem.fixed | still
    value = np.where(still, 0.0, problem.value)
    zero = fixed & (value <= 0.0)
    if still.any() and np.any(zero[:-1] & zero[1:]):
        return path, problem, rch, None, None
    tight = replace(problem, hi=hi, fixed=fixed, value=value)
    beta = rch.greedy if rch.exact else solve_fast(tight, SolverSettings(), start=rch.greedy)[0]
    return path, problem, rch, tight, beta


@settings(deadline=None, max_examples=40, suppress_health_check=[HealthCheck.too_slow])
@given(traj=trajectories(), lim=limits(), n=st.integers(8, 150),
       lam=st.sampled_from([0.0, 0.5]), share=st.floats(0.0, 1.0),
       more=st.lists(st.tuples(st.integers(0, 149), st.floats(0.0, 1.0)), max_size=6))
def test_compiled_round_is_the_steps_one_by_one(traj, lim, n, lam, share, more):
    """rota.rounds.one_round (one compiled call) gives exactly what the steps give
    one by one: check points (with points added by an earlier audit, sorted, a
    duplicate dropped), reachability's verdict and greedy profile (which the rows
    decide), the tightened bounds, the fast solver's answer and its audit."""
    tau = make_grid(traj, traj.duration / n)
    _, d1, d2 = evaluate(traj, tau)
    s = float(np.linalg.norm(d1[0]))
    boundary = Boundary(beta_start=(share * lim.v_max / s) ** 2 if s > 1e-6 else None,
                        beta_end=0.0 if np.linalg.norm(d1[-1]) > 1e-6 else None)
    more = [(i % (len(tau) - 1), f) for i, f in more]
    more = (np.array([i for i, _ in more] + [i for i, _ in more[:1]], dtype=np.int64),
            np.array([f for _, f in more] + [f for _, f in more[:1]]))  # one twice
    vlim = np.full(len(tau), lim.v_max)
    rnd = one_round(traj, tau, d1, d2, vlim, lim.a_max_vec, boundary, lam, SolverSettings(),
                    more)
    path, problem, rch, tight, beta = _staged(traj, tau, d1, d2, vlim, lim, boundary, lam, more)
    for name in ("offsets", "frac", "cd1", "cd2", "beta_max"):
        assert np.array_equal(getattr(rnd.path, name), getattr(path, name)), name
    assert rnd.path.moving == path.moving
    for name in ("fixed", "value", "rptr", "rk", "ra", "rc", "rkind", "rpoint"):
        assert np.array_equal(getattr(rnd.problem, name), getattr(problem, name)), name
    assert (rnd.fail_node, rnd.fail_row) == (rch.fail_node, rch.fail_row)
    if not path.moving:
        return
    assert rnd.exact == rch.exact and np.array_equal(rnd.greedy, rch.greedy)
    assert rnd.ok == (tight is not None) and (rnd.tight is None) == (tight is None)
    if tight is None:
        return
    for name in ("hi", "fixed", "value"):
        assert np.array_equal(getattr(rnd.tight, name), getattr(tight, name)), name
    assert (rnd.beta is None) == (beta is None)
    if beta is not None:
        assert np.array_equal(rnd.beta, beta)
        seen = audit(traj, path, beta)
        assert (rnd.audit.speed, rnd.audit.acc, rnd.audit.axis, rnd.audit.point) == (
            seen.speed, seen.acc, seen.axis, seen.point)
        assert (rnd.audit.more is None) == (seen.more is None)
        if seen.more is not None:
            assert all(np.array_equal(a, b) for a, b in zip(rnd.audit.more, seen.more,
                                                            strict=True))


def test_round_hands_over_to_clarabel():
    """A round whose interior-point method does not converge is finished by
    Clarabel, and the answer says so; with Clarabel chosen the round leaves the
    solve to it."""
    traj = bspline(2, 6, 1.0)
    lim = Limits(2.0, 2.0)
    tau = make_grid(traj, traj.duration / 80)
    _, d1, d2 = evaluate(traj, tau)
    vlim = np.full(len(tau), lim.v_max)
    args = (traj, tau, d1, d2, vlim, lim.a_max_vec, Boundary(), 0.5)
    stuck = one_round(*args, SolverSettings(max_iter=1))
    assert stuck.beta is None and stuck.stats.status == "MaxIterations"
    done = finish(traj, stuck, SolverSettings(max_iter=1))
    assert done.stats.method == "clarabel" and "fast solver: MaxIterations" in done.stats.note
    fast = one_round(*args, SolverSettings())
    left = one_round(*args, SolverSettings(method="clarabel"))
    assert left.beta is None and left.stats is None
    ref = finish(traj, left, SolverSettings(method="clarabel"))
    assert ref.stats.method == "clarabel"
    assert abs(fast.problem.objective(fast.beta) - ref.problem.objective(ref.beta)) <= (
        1e-5 * ref.problem.objective(ref.beta))


def test_solver_choice_and_handover():
    traj = bspline(2, 6, 1.0)
    problem = chain_problem(traj, Limits(2.0, 2.0), 0.5, 80)
    rch = reach(problem)
    fast, f_stats = solve(problem, SolverSettings(), start=rch.greedy)
    ref, r_stats = solve(problem, SolverSettings(method="clarabel"))
    assert f_stats.method == "fast" and r_stats.method == "clarabel"
    assert abs(problem.objective(fast) - problem.objective(ref)) <= 1e-5 * problem.objective(ref)
    # one iteration is not enough: the fast solver reports it and Clarabel answers
    beta, stats = solve(problem, SolverSettings(max_iter=1), start=rch.greedy)
    assert stats.method == "clarabel" and "fast solver: MaxIterations" in stats.note


def test_warm_up_and_cache_directory(tmp_path, monkeypatch):
    import rota
    from rota import jit

    monkeypatch.setenv("ROTA_CACHE_DIR", str(tmp_path / "env"))
    assert jit.resolve_cache_dir(tmp_path / "given") == tmp_path / "given"
    assert jit.resolve_cache_dir() == tmp_path / "env"
    monkeypatch.delenv("ROTA_CACHE_DIR")
    monkeypatch.setenv("CACHE_DIRECTORY", str(tmp_path / "systemd"))
    assert jit.resolve_cache_dir() == tmp_path / "systemd"
    seconds = rota.warm_up()
    assert seconds > 0 and jit.kernels() is jit.kernels()


def _compiled_by_the_service() -> dict[str, list[str]]:
    """In a fresh process: warm up, then re-time as the flight service does; the kernel
    signatures that were compiled (or loaded) after the warm-up."""
    import pickle

    import rota
    from companion.messages import parse_map, parse_trajectory
    from companion.ros2.decode import (
        decode_bspline,
        decode_multidof,
        decode_path,
        decode_pointcloud,
    )
    from companion.ros2.encode import bspline_cdr, pointcloud_cdr
    from companion.settings.config import Config
    from rota import jit
    from rota.chance import UncertaintyModel
    from rota.robust import Safety
    from sitl.demo import map_message, to_local, trajectory_message
    from sitl.planner import plan
    from sitl.proving import circle_message
    from sitl.world import get_world
    from tests.helpers.ros2 import cfg as ros2_cfg
    from tests.helpers.ros2 import multidof_cdr, path_cdr

    rota.warm_up()
    k = jit.kernels()

    def compiled() -> dict[str, list[str]]:
        return {name: [str(s) for s in getattr(k, name).signatures] for name in k.__all__}

    def sent(obj):  # as it reaches the re-time worker: pickled twice
        return pickle.loads(pickle.dumps(pickle.loads(pickle.dumps(obj))))

    before = compiled()
    cfg, now = Config(), None
    def local_map(world):  # noqa: ANN001, ANN202
        home = np.array([world.start[0], world.start[1], 0.0])
        return home, sent(parse_map(json.dumps(map_message(world, home)).encode(), cfg, now))

    forest = get_world("forest", seed=5)
    home, forest_map = local_map(forest)
    spline = to_local(plan(forest, 2.0, 2.0, clearance=0.6), home)
    circle = circle_message(np.array([3.6, 0.0, 2.0]), 3.6, np.pi, 2.0, 10.0, "c")  # proving
    flights = [(sent(parse_trajectory(json.dumps(m).encode(), cfg, now).trajectory), vmap)
               for m, vmap in ((trajectory_message(spline, "s"), forest_map),
                               (circle, local_map(get_world("pillar"))[1]))]
    # the same over ROS 2 (rmw_zenoh's CDR): EGO-Planner's B-spline, nav_msgs/Path,
    # MultiDOFJointTrajectory and a PointCloud2 map
    ros = ros2_cfg(enabled=True)
    cloud = sent(decode_pointcloud(pointcloud_cdr(forest.voxel_points(0.1) - home, ros.ros2),
                                   ros, now))
    samples = spline.position(np.linspace(*spline.domain, 40))
    flights += [(sent(decode(payload, ros, now).trajectory), cloud) for decode, payload in (
        (decode_bspline, bspline_cdr(spline, ros.ros2)),
        (decode_path, path_cdr(samples, np.linspace(0.0, spline.duration, 40))),
        (decode_multidof, multidof_cdr(samples, dt=spline.duration / 39)))]
    for traj, vmap in flights:
        for model in (UncertaintyModel(m=0.27, b=0.06, memory_s=1.0),
                      UncertaintyModel(memory_s=1.5, per_axis=True), UncertaintyModel()):
            r = retime(RetimeInput(trajectory=traj, limits=Limits(2.0, (2.0, 2.0, 1.5)),
                                   dtau=0.05, safety=Safety(map=vmap, uncertainty=model)))
            assert r.ok, r.message
    after = compiled()
    return {name: sorted(set(after[name]) - set(before[name])) for name in after
            if set(after[name]) != set(before[name])}


def test_warm_up_compiles_what_the_flight_service_runs():
    """After warm_up, re-timing as the service does (a forest B-spline and a sampled
    circle, decoded from JSON and pickled to the worker, with the map likewise, error
    memory, per-axis acceleration limits, an estimator's model) compiles nothing more:
    every kernel signature it needs was made before READY. Run in a fresh process, as
    the worker is. (Found missing: the error-memory kernel, which made a first replan
    take 0.4 s; and arrays unpickled writable, a kernel type of their own, which made
    the first re-time after a map miss its 2 s budget on a cold cache.)"""
    ctx = multiprocessing.get_context("spawn")
    with ctx.Pool(1) as pool:
        new = pool.apply(_compiled_by_the_service)
    assert not new, new


def test_greedy_profile_stays_feasible_on_a_long_deceleration():
    """Regression: on the bundled 30 m path at dtau 0.01 s (limits at the nodes) the
    greedy profile met the top of a controllable set, rounding put the next lower
    bound just above the next set, and the profile left the sets: 1e-10 grew node by
    node along the final deceleration, and a row with c = -2e-13 at the end made it
    break a row 33,000-fold. It must meet every row and never beat the optimum."""
    from sitl.bench import load_data, run_rota_nodes

    traj = load_data()[0]["30m"]
    tau = make_grid(traj, 0.01)
    _, (problem, greedy) = run_rota_nodes(traj, tau, exact=False)
    _, (_, best) = run_rota_nodes(traj, tau, exact=True)
    rows = problem.ra * greedy[problem.rk] + problem.rc * greedy[problem.rk + 1]
    assert rows.max() <= 1 + 1e-7
    assert np.all(greedy <= problem.hi * (1 + 1e-7)) and np.all(greedy >= 0)
    assert problem.objective(greedy) >= problem.objective(best) * (1 - 1e-9)
    certified = reach(problem, certify=True)
    assert not certified.exact or np.allclose(certified.greedy, greedy)


def test_greedy_profile_meets_the_rows_where_the_path_nearly_stops():
    """Regression: on the bundled paths at dtau 0.001 s (limits at the nodes) the
    speed bound of the last nodes is 1e15-4e24 (the path's derivative vanishes at
    the end); clipping a polygon interpolated from that far corner and rounded the
    controllable set to its ulp (12932.0 for 12931.89), and the greedy profile broke
    the last deceleration row by 8.7e-6 (7 m) and 1.2e-7 (30 m)."""
    from sitl.bench import load_data, run_rota_nodes

    for name in ("7m", "30m"):
        traj = load_data()[0][name]
        _, (problem, greedy) = run_rota_nodes(traj, make_grid(traj, 0.001), exact=False)
        assert problem.hi.max() > 1e14  # the case: a far bound
        rows = problem.ra * greedy[problem.rk] + problem.rc * greedy[problem.rk + 1]
        assert rows.max() <= 1 + 1e-10, name


def test_fast_solver_converges_where_the_gap_outran_the_dual_residual():
    """Regression: at lambda = 0 on the smallest grid and limits (n = 8, v_max 0.5,
    a_max 1) the duality gap fell to rounding level while one dual residual stayed
    near 1e-7; the Newton solve could no longer reduce it and the solver stopped
    with NumericalError (after 162 and 171 steps). Both paths are solved, in few
    steps, to Clarabel's objective."""
    for seed, n_points, span in ((338294138, 8, 0.8494841387933806),
                                 (2078732403, 8, 1.9024161472914347)):
        problem = chain_problem(bspline(seed, n_points, span), Limits(0.5, (1.0, 1.0, 1.0)),
                                0.0, 8)
        rch = reach(problem)
        assert rch.feasible
        beta, stats = solve_fast(problem, SolverSettings(), start=rch.greedy)
        assert beta is not None and stats.iterations <= 40, stats
        agree(problem)
