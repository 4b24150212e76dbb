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


@pytest.mark.parametrize("seed", range(12))
def test_a_window_with_a_start_offset_has_the_pieces_of_its_blend(seed: int) -> None:
    """A replan joined onto the command: shifted at its start, the shift fading out
    along the path. Its compiled pieces (what ROTA re-times) are the path it says it
    is, wherever the blend's ends fall (on a knot, between knots, at the end)."""
    from rota.schema import TrajectoryMessage, trajectory_from_dict, trajectory_to_dict
    from rota.trajectory import Window
    from tests.helpers.strategies import bspline, polynomial, sampled

    rng = np.random.default_rng(seed)
    base = (bspline(seed, 8, 0.1), polynomial(seed, 6, 0.7),
            sampled(seed, 9, 0.4, seed % 2 == 1))[seed % 3]
    t0, t1 = base.domain
    start = float(rng.choice([t0, t0 + rng.uniform(0, 0.5) * (t1 - t0),
                              base.edges[len(base.edges) // 2]]))
    blend = float(rng.choice([rng.uniform(0.05, 0.5) * (t1 - start), t1 - start]))
    offset = rng.normal(size=3) * 0.4
    win = Window(base=base, start=start, offset=offset, blend=blend)
    _same(win)
    np.testing.assert_allclose(win.position(start)[0], base.position(start)[0] + offset,
                               atol=1e-12)
    p, d1, d2 = win.evaluate([start])  # the shift adds no velocity or acceleration there
    _, b1, b2 = base.evaluate([start])
    np.testing.assert_allclose(np.vstack([d1, d2]), np.vstack([b1, b2]), atol=1e-9)
    after = np.linspace(start + blend, t1, 7)  # and nothing after the blend
    np.testing.assert_allclose(win.position(after), base.position(after), atol=1e-12)
    back = trajectory_from_dict(trajectory_to_dict(TrajectoryMessage(win))).trajectory
    d = trajectory_to_dict(TrajectoryMessage(win)) | {"start": None}  # offset from the start
    assert trajectory_from_dict(d).trajectory.start == t0
    np.testing.assert_allclose(back.position(np.linspace(start, t1, 50)),
                               win.position(np.linspace(start, t1, 50)), atol=1e-12)


def test_a_start_offset_must_be_three_finite_numbers_and_fade_within_the_path() -> None:
    from rota.errors import InputError
    from rota.trajectory import Window
    from tests.helpers.strategies import bspline

    base = bspline(1, 6, 0.2)
    t0, t1 = base.domain
    for offset, blend, words in (([0.1, 0.2], 0.5, "start_offset"),
                                 ([0.1, np.nan, 0.0], 0.5, "start_offset[1]"),
                                 ([0.1, 0.2, 0.0], 0.0, "start_blend"),
                                 ([0.1, 0.2, 0.0], t1 - t0 + 1.0, "start_blend")):
        with pytest.raises(InputError, match=words.replace("[", r"\[")):
            Window(base=base, start=t0, offset=offset, blend=blend)


@pytest.mark.parametrize(("dtau", "span"), [(0.5, 0.1), (0.1, 0.1), (0.37, 0.05), (0.05, 0.5)])
def test_check_points_cut_every_piece_and_are_no_denser_than_needed(dtau, span) -> None:
    """Every input piece is cut in at least PIECE_PARTS parts, every interval in
    parts no longer than SPACING; a piece that its own points cut gets no uniform
    points inside it as well (they would only add rows)."""
    from rota.checkpoints import PIECE_PARTS, SPACING, sample_path
    from rota.problem import make_grid
    from tests.helpers.strategies import bspline

    traj = bspline(4, 40, span)
    tau = make_grid(traj, dtau)
    path = sample_path(traj, tau, np.full(len(tau), 2.0), np.full(3, 2.0))
    at = np.unique(np.round(path.point_tau, 12))
    assert np.all(np.isin(np.round(tau, 12), at))  # the nodes
    edges = traj.edges
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        inside = at[(at > a + 1e-12) & (at < b - 1e-12)]
        gaps = np.diff(np.concatenate([[a], inside, [b]]))
        assert gaps.max() <= (b - a) / PIECE_PARTS + 1e-9
        # no more than the piece's own points and the interval ends in it
        assert len(inside) <= PIECE_PARTS - 1 + np.count_nonzero((tau > a) & (tau < b)) \
            or (b - a) / PIECE_PARTS > SPACING
