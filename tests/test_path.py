"""The compiled path (:mod:`rota.path`): the same numbers as the trajectories' own
scipy evaluation, for every input kind, at every degree and with repeated knots."""

from __future__ import annotations

import numpy as np
import pytest

from rota.path import evaluate
from rota.trajectory import BSplineTrajectory, PolynomialTrajectory, SampledTrajectory


def _same(traj) -> None:
    t0, t1 = traj.domain
    x = np.concatenate([np.linspace(t0, t1, 997), traj.edges, [t0 - 1.0, t1 + 1.0]])
    want = traj.evaluate(x)
    got = evaluate(traj, x)
    for w, g in zip(want, got, strict=True):
        np.testing.assert_allclose(g, w, rtol=1e-10, atol=1e-10 * (1.0 + np.abs(w).max()))


@pytest.mark.parametrize("seed", range(40))
def test_bspline_pieces_match_scipy(seed: int) -> None:
    rng = np.random.default_rng(seed)
    k = int(rng.integers(3, 8))
    n = int(rng.integers(k + 1, 30))
    cps = rng.normal(size=(n, 3))
    if seed % 2:
        traj = BSplineTrajectory(control_points=cps, degree=k, knot_span=rng.uniform(0.05, 1))
    else:  # clamped, irregular, with a repeated inner knot
        inner = np.sort(rng.uniform(0.0, 5.0, n - k - 1))
        if len(inner) > 2:
            inner[1] = inner[0]
        knots = np.concatenate([np.zeros(k + 1), inner, np.full(k + 1, 5.0)])
        traj = BSplineTrajectory(control_points=cps, degree=k, knots=knots)
    _same(traj)
    _same(traj.fresh())


def test_polynomial_and_sampled_pieces_match_scipy() -> None:
    rng = np.random.default_rng(3)
    _same(PolynomialTrajectory(durations=np.array([2.0]), coefficients=rng.normal(size=(1, 3, 6))))
    t = np.cumsum(rng.uniform(0.001, 0.5, 20))
    _same(SampledTrajectory(t=t, p=rng.normal(size=(20, 3))))
    _same(SampledTrajectory(t=t, p=rng.normal(size=(20, 3)), v=rng.normal(size=(20, 3))))
