"""With lambda close to 0, ROTA's duration matches toppra's time-optimal duration
for the same path and limits within 1 %."""

from __future__ import annotations

import numpy as np
import pytest

from rota import Limits, RetimeInput, retime
from rota.timemap import TimeMap
from tests.helpers.strategies import bspline, polynomial

pytest.importorskip("toppra")


@pytest.mark.parametrize(("make", "seed"), [(bspline, 3), (bspline, 11), (polynomial, 5)])
def test_duration_matches_toppra(make, seed):
    from sitl.bench import run_toppra

    traj = make(seed, 7, 1.0)
    lim = Limits(2.0, (2.0, 2.5, 1.5))
    n = 600
    ours = retime(RetimeInput(trajectory=traj, limits=lim, smoothness=1e-6,
                              dtau=traj.duration / n))
    assert ours.ok, ours.message
    grid = np.linspace(*traj.domain, n + 1)
    _, beta = run_toppra(traj, grid, lim.v_max, lim.a_max_vec)
    theirs = TimeMap(grid, beta).duration
    assert ours.duration == pytest.approx(theirs, rel=0.01)
