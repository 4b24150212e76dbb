"""Property tests: random trajectories of all three kinds, re-timed,
then measured independently from finite differences of re-timed positions."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rota import RetimeInput, retime
from tests.helpers.kinematics import measured_kinematics
from tests.helpers.strategies import limits, trajectories

TOL = 0.01  # 1 % of the limit


@settings(deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(traj=trajectories(), lim=limits(), n=st.integers(40, 250),
       smoothness=st.sampled_from([0.0, 1e-3, 0.5, 2.0]))
def test_retimed_trajectory_meets_limits_on_finer_grid(traj, lim, n, smoothness):
    result = retime(RetimeInput(trajectory=traj, limits=lim, smoothness=smoothness,
                                dtau=traj.duration / n))
    assert np.isfinite(result.duration) and result.duration > 0
    _, speed, acc = measured_kinematics(result, refine=10)
    assert speed.max() <= lim.v_max * (1 + TOL), (result.status, result.message)
    assert np.all(np.abs(acc).max(axis=0) <= lim.a_max_vec * (1 + TOL)), (
        result.status, np.abs(acc).max(axis=0), lim.a_max)
    # Time mapping is monotone, starts at the path's start and ends at its end.
    assert np.all(np.diff(result.t) > 0)
    tau, tau_dot, _ = result.timemap.evaluate(np.linspace(0, result.duration, 2000))
    assert np.all(np.diff(tau) >= 0) and np.all(tau_dot >= 0)
    assert tau[0] == traj.domain[0] and abs(tau[-1] - traj.domain[1]) < 1e-9
    # Re-timed positions lie on the input path: compare with a dense polyline.
    sp = result.sample(np.linspace(0, result.duration, 300))
    dense = traj.position(np.linspace(*traj.domain, 20001))
    seg = np.linalg.norm(np.diff(dense, axis=0), axis=1).max()
    d = np.min(np.linalg.norm(sp.position[:, None, :] - dense[None, ::10, :], axis=2), axis=1)
    assert d.max() <= 10 * seg + 1e-9


@settings(deadline=None)
@given(traj=trajectories(), lim=limits())
def test_rest_to_rest_and_velocity_reported_matches_positions(traj, lim):
    result = retime(RetimeInput(trajectory=traj, limits=lim, dtau=traj.duration / 100))
    if not result.ok:  # the fallback keeps the input's own boundary behaviour
        return
    ends = result.sample([0.0, result.duration])
    assert np.allclose(ends.velocity, 0.0, atol=1e-3 * lim.v_max)
    t = np.linspace(0.05, 0.95, 50) * result.duration
    h = 1e-5 * result.duration
    fd = (result.sample(t + h).position - result.sample(t - h).position) / (2 * h)
    assert np.allclose(result.sample(t).velocity, fd, atol=1e-3 * lim.v_max)
