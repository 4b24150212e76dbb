"""With lambda close to 0, ROTA's duration matches toppra's time-optimal duration
for the same path and limits within 1 % (issue #2)."""

from __future__ import annotations

import numpy as np
import pytest

from rota import Limits, RetimeInput, Trajectory, retime
from tests.strategies import bspline, polynomial

ta = pytest.importorskip("toppra.algorithm")
tc = pytest.importorskip("toppra.constraint")
ti = pytest.importorskip("toppra.interpolator")


class ToppraPath(ti.AbstractGeometricPath):
    """Our trajectory seen by toppra as a 3-DOF geometric path."""

    def __init__(self, traj: Trajectory) -> None:
        self.traj = traj

    def __call__(self, s, order=0):
        out = self.traj.evaluate(np.atleast_1d(s))[order]
        return out[0] if np.ndim(s) == 0 else out

    @property
    def dof(self):
        return 3

    @property
    def path_interval(self):
        return np.array(self.traj.domain)


def toppra_duration(traj: Trajectory, lim: Limits, n: int) -> float:
    path = ToppraPath(traj)

    # The speed limit on the norm as an equivalent per-axis limit that varies
    # along the path: |q_k' sdot| <= v |q_k'| / |q'|  <=>  sdot <= v / |q'|.
    def vlim(s):
        d = path(s, 1)
        share = np.abs(d) / max(np.linalg.norm(d), 1e-12)
        bound = np.maximum(lim.v_max * share, 1e-9)
        return np.column_stack([-bound, bound])

    constraints = [tc.JointVelocityConstraintVarying(vlim),
                   tc.JointAccelerationConstraint(lim.a_max_vec)]
    grid = np.linspace(*traj.domain, n + 1)
    algo = ta.TOPPRA(constraints, path, gridpoints=grid, solver_wrapper="seidel",
                     parametrizer="ParametrizeConstAccel")
    out = algo.compute_trajectory(0.0, 0.0)
    assert out is not None, "toppra failed"
    return float(out.duration)


@pytest.mark.parametrize(("make", "seed"), [(bspline, 3), (bspline, 11), (polynomial, 5)])
def test_duration_matches_toppra(make, seed):
    traj = make(seed, 7, 1.0)
    lim = Limits(2.0, (2.0, 2.5, 1.5))
    n = 600
    ours = retime(RetimeInput(trajectory=traj, limits=lim, smoothness=1e-6,
                              dtau=traj.duration / n))
    assert ours.ok, ours.message
    theirs = toppra_duration(traj, lim, n)
    assert ours.duration == pytest.approx(theirs, rel=0.01)
