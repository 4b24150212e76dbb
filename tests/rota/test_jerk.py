"""Jerk-limited re-timing (``Limits.j_max``, issue 32), measured from the outside:
finite differences of the positions the result produces, never the jerk it
reports; an exact S-curve; the same problem on a finer grid."""

from __future__ import annotations

import numpy as np
import pytest

from rota import InputError, Limits, RetimeInput, SampledTrajectory, SolverSettings, retime
from rota.trajectory import PolynomialTrajectory, Window
from tests.helpers.kinematics import measured_kinematics
from tests.helpers.strategies import bspline, polynomial, sampled

#: FD of the sampled positions: third differences at 500 Hz (the issue's measure).
RATE = 500.0
#: Allowed excess of a measured limit (the issue: within 1 %). Measured on these
#: cases: FD jerk peaks 0.00-0.1 % above j_max (the audit allows 0.1 % between
#: check points, the 6 ms window of the third difference averages).
FD_TOL = 0.01
LIMITS = Limits(2.0, 3.0, 6.0)


def fd_jerk(result, t0: float = 0.0, t1: float | None = None) -> np.ndarray:
    """Per-axis peak of the third differences of positions sampled at :data:`RATE`."""
    t = np.arange(t0, result.duration if t1 is None else t1, 1 / RATE)
    p = result.sample(t).position
    return np.abs(np.diff(p, 3, axis=0) * RATE**3).max(axis=0)


PATHS = {
    "bspline": lambda: bspline(1, 7, 0.5),
    "polynomial": lambda: polynomial(2, 6, 1.0),
    "samples": lambda: sampled(3, 7, 0.8, False),
}


@pytest.mark.parametrize("kind", sorted(PATHS))
def test_jerk_bound_holds_by_finite_differences(kind):
    traj = PATHS[kind]()
    free = retime(RetimeInput(trajectory=traj, limits=Limits(2.0, 3.0), smoothness=0.0))
    result = retime(RetimeInput(trajectory=traj, limits=LIMITS, smoothness=0.0))
    assert result.ok, result.message
    # Unlimited: the acceleration steps at every node (the issue measured
    # 495-600 m/s^3); limited: within the bound on every axis.
    assert fd_jerk(free).max() > 100.0
    assert np.all(fd_jerk(result) <= 6.0 * (1 + FD_TOL)), fd_jerk(result)
    _, speed, acc = measured_kinematics(result)
    assert speed.max() <= 2.0 * (1 + FD_TOL)
    assert np.abs(acc).max() <= 3.0 * (1 + FD_TOL)
    assert result.duration >= free.duration
    assert result.diagnostics.unlimited_duration == pytest.approx(free.duration)
    # ends at rest, with no acceleration left to drop
    end = result.sample([0.0, result.duration])
    assert np.allclose(end.velocity, 0.0, atol=1e-9)
    assert np.allclose(end.acceleration, 0.0, atol=1e-6)


@pytest.mark.parametrize("share", [0.15, 0.4])
@pytest.mark.parametrize("kind", sorted(PATHS))
def test_replan_from_a_moving_state_keeps_the_jerk_bounded(kind, share):
    """A replan part-way (while gaining speed, and later): the new plan starts from
    the old plan's velocity and acceleration; the stream (old plan, then new plan)
    keeps the bound across it. (At 0.15 of the B-spline the 0.025 s jerk grid was
    infeasible from the pinned state; the re-time makes it finer.)"""
    traj = PATHS[kind]()
    first = retime(RetimeInput(trajectory=traj, limits=LIMITS, smoothness=0.0))
    assert first.ok, first.message
    t_c = share * first.duration
    state = first.sample(t_c)
    rest = Window(base=traj, start=float(state.tau[0]))
    second = retime(RetimeInput(trajectory=rest, limits=LIMITS, smoothness=0.0,
                                start_velocity=state.velocity[0],
                                start_acceleration=state.acceleration[0]))
    assert second.ok, second.message
    start = second.sample(0.0)
    assert np.allclose(start.velocity[0], state.velocity[0], atol=1e-6)
    assert np.allclose(start.acceleration[0], state.acceleration[0], atol=1e-4)
    assert np.all(fd_jerk(second) <= 6.0 * (1 + FD_TOL)), fd_jerk(second)
    # The stitched stream: old plan up to t_c, the new one after.
    t = np.arange(t_c - 0.05, t_c + 0.05, 1 / RATE)
    p = np.where((t < t_c)[:, None], first.sample(t).position,
                 second.sample(t - t_c).position)
    assert np.abs(np.diff(p, 3, axis=0) * RATE**3).max() <= 6.0 * (1 + FD_TOL)


def test_s_curve_on_a_straight_line_is_the_analytic_optimum():
    """Rest to rest over 10 m with v 2, a 3, j 6: the classic S-curve takes
    D/v + v/a + a/j = 6.1667 s (both limits reached). Measured: 6.1744 s (0.13 %
    longer: the tau grid; never shorter)."""
    t = np.arange(6.0)
    traj = SampledTrajectory(t=t, p=np.c_[2 * t, 0 * t, 0 * t])
    result = retime(RetimeInput(trajectory=traj, limits=LIMITS, smoothness=0.0))
    assert result.ok, result.message
    exact = 10 / 2 + 2 / 3 + 3 / 6
    assert exact * (1 - 1e-6) <= result.duration <= exact * 1.005
    assert fd_jerk(result)[0] <= 6.0 * (1 + FD_TOL)


@pytest.mark.slow
def test_same_problem_on_an_eight_times_finer_grid(monkeypatch):
    """The dense reference: the same constraints on a grid 8 times finer (the jerk
    problem's steps of 0.025 s cut to 0.003125 s). Measured (two random
    B-splines): 0.24 % and 0.40 % longer at dtau 0.1."""
    import rota.jerk

    for seed, n, span in ((11, 4, 0.5), (21, 5, 0.4)):
        traj = bspline(seed, n, span)
        coarse = retime(RetimeInput(trajectory=traj, limits=LIMITS, smoothness=0.0))
        with monkeypatch.context() as m:
            m.setattr(rota.jerk, "JERK_DTAU", rota.jerk.JERK_DTAU / 8)
            fine = retime(RetimeInput(trajectory=traj, limits=LIMITS, smoothness=0.0,
                                      solver=SolverSettings(time_limit=300.0)))
        assert coarse.ok and fine.ok, (coarse.message, fine.message)
        assert len(fine.tau) - 1 == 8 * (len(coarse.tau) - 1)
        assert abs(coarse.duration / fine.duration - 1) <= 0.005
        assert coarse.duration >= coarse.diagnostics.unlimited_duration


def test_a_path_whose_acceleration_jumps_falls_back_in_words():
    # Two linear-then-quadratic segments: the acceleration jumps at the joint.
    coefs = np.zeros((2, 3, 3))
    coefs[0, 0, 1] = 1.0  # x = t
    coefs[1, 0, :] = [1.0, 1.0, 0.5]  # x = 1 + t + t^2 / 2
    traj = PolynomialTrajectory(durations=np.array([1.0, 1.0]), coefficients=coefs)
    result = retime(RetimeInput(trajectory=traj, limits=LIMITS))
    assert result.status == "fallback"
    assert "acceleration jumps at tau=1.000" in result.message


@pytest.mark.parametrize("bad", [-1.0, 0.0, (1.0, 2.0), (1.0, np.nan, 1.0), "x"])
def test_bad_jerk_limits_are_refused_by_name(bad):
    with pytest.raises(InputError, match="limits.j_max"):
        Limits(2.0, 3.0, bad)


def test_per_axis_jerk_limits():
    limits = Limits(2.0, 3.0, (6.0, 6.0, 2.0))
    assert limits.j_max == (6.0, 6.0, 2.0)
    assert Limits(2.0, 3.0, 4).j_max == (4.0, 4.0, 4.0)
    assert Limits(2.0, 3.0).j_max is None


def test_config_carries_the_jerk_limit_tighten_only():
    from companion.settings.config import ConfigError, from_dict
    from companion.settings.envelope import check_change

    assert from_dict({}).rota_limits().j_max is None  # default: no jerk limit
    file = from_dict({"limits": {"j_max": 4.0}})
    assert file.rota_limits().j_max == (4.0, 4.0, 4.0)
    with pytest.raises(ConfigError, match=r"\[limits\] j_max"):
        from_dict({"limits": {"j_max": -1.0}})
    for value, ok in ((2.0, True), (4.0, True), (8.0, False), (0.0, False)):
        new = from_dict({"limits": {"j_max": value}})
        if ok:
            check_change(file, new, {"limits": {"j_max": value}})
        else:
            with pytest.raises(ConfigError, match=r"\[limits\] j_max: .* refused"):
                check_change(file, new, {"limits": {"j_max": value}})
    # None in the file: setting one is tightening.
    check_change(from_dict({}), file, {"limits": {"j_max": 4.0}})


def test_a_jerk_limited_result_survives_its_message():
    from rota.schema import TrajectoryMessage, result_from_dict, result_to_dict

    traj = PATHS["bspline"]()
    result = retime(RetimeInput(trajectory=traj, limits=LIMITS, smoothness=0.0))
    msg = TrajectoryMessage(id="j", frame="ENU", trajectory=traj)
    import json

    back, _ = result_from_dict(json.loads(json.dumps(result_to_dict(result, msg))))
    t = np.linspace(0.0, result.duration, 200)
    assert back.duration == pytest.approx(result.duration, rel=1e-12)
    assert np.allclose(back.sample(t).position, result.sample(t).position, atol=1e-9)


def test_rota_retime_takes_a_jerk_limit(tmp_path):
    import json
    import subprocess
    import sys

    from rota.cli import example_path
    from rota.schema import result_from_dict

    out = tmp_path / "r.json"
    r = subprocess.run([sys.executable, "-m", "rota.cli", "retime", str(example_path()),
                        "-o", str(out), "--j-max", "4"], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    d = json.loads(out.read_text())
    assert d["status"] == "optimal" and "acc" in d
    result, _ = result_from_dict(d)
    assert fd_jerk(result).max() <= 4.0 * (1 + FD_TOL)
    bad = subprocess.run([sys.executable, "-m", "rota.cli", "retime", str(example_path()),
                          "-o", str(out), "--j-max", "-1"], capture_output=True, text=True,
                         timeout=300)
    assert bad.returncode == 2 and "j_max" in bad.stderr


def _job(traj, limits, take):
    from companion.flight.retimer import ReplanJob
    from companion.settings.config import from_dict

    cfg = from_dict({})
    return ReplanJob(id="j", stamp=None, trajectory=traj, limits=limits, smoothness=0.0,
                     dtau=0.1, uncertainty=cfg.uncertainty_model(), chance=cfg.chance_params(),
                     braking=cfg.braking_params(), take_position=take.position[0],
                     take_velocity=take.velocity[0], take_acceleration=take.acceleration[0])


def test_the_service_replan_starts_on_the_commanded_acceleration():
    """The service's re-time (the worker's function, in this process): a replan of
    the same path taken over mid-flight starts on the commanded acceleration, so
    the stream's jerk stays bounded across the takeover; at rest (a hover) it is a
    jerk-limited start from rest."""
    from companion.flight.retimer import _replan

    traj = PATHS["bspline"]()
    first = retime(RetimeInput(trajectory=traj, limits=LIMITS, smoothness=0.0))
    t_c = 0.1 * first.duration  # still gaining speed: a free start would step
    take = first.sample(t_c)
    out = _replan(_job(traj, LIMITS, take))
    second = out.result
    assert second.ok, second.message
    assert np.allclose(second.sample(0.0).acceleration[0], take.acceleration[0], atol=1e-3)
    t = np.arange(t_c - 0.05, t_c + 0.05, 1 / RATE)
    p = np.where((t < t_c)[:, None], first.sample(t).position,
                 second.sample(t - t_c).position)
    assert np.abs(np.diff(p, 3, axis=0) * RATE**3).max() <= 6.0 * (1 + FD_TOL)
    rest = _replan(_job(traj, LIMITS, first.sample(0.0))).result
    assert rest.ok, rest.message
    assert fd_jerk(rest).max() <= 6.0 * (1 + FD_TOL)
