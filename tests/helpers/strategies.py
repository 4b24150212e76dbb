"""Hypothesis strategies: random trajectories of the three input kinds."""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st
from scipy import interpolate

from rota import BSplineTrajectory, Limits, PolynomialTrajectory, SampledTrajectory, Trajectory


def _waypoints(seed: int, n: int) -> np.ndarray:
    """A wandering 3-D walk (metres), not self-reversing, like a planner's path."""
    rng = np.random.default_rng(seed)
    heading = rng.uniform(0, 2 * np.pi)
    steps = []
    for _ in range(n - 1):
        heading += rng.uniform(-1.0, 1.0)
        length = rng.uniform(0.5, 2.0)
        steps.append([length * np.cos(heading), length * np.sin(heading),
                      rng.uniform(-0.3, 0.3)])
    return np.vstack([np.zeros(3), np.cumsum(steps, axis=0)])


def bspline(seed: int, n: int, span: float) -> BSplineTrajectory:
    pts = _waypoints(seed, n)
    # Repeat the end points so the path starts and ends at rest (EGO-Planner style).
    cps = np.vstack([pts[:1], pts[:1], pts, pts[-1:], pts[-1:]])
    return BSplineTrajectory(control_points=cps, knot_span=span)


def polynomial(seed: int, n: int, span: float) -> PolynomialTrajectory:
    """Quintic segments through the waypoints (C2), at rest at both ends."""
    pts = _waypoints(seed, n)
    t = np.arange(n) * span
    v = np.gradient(pts, t, axis=0)
    a = np.gradient(v, t, axis=0)
    v[[0, -1]] = 0.0
    a[[0, -1]] = 0.0
    bp = interpolate.BPoly.from_derivatives(t, np.stack([pts, v, a], axis=1))
    pp = interpolate.PPoly.from_bernstein_basis(bp)
    coefs = np.transpose(pp.c[::-1], (1, 2, 0))  # (segments, 3, deg+1), ascending powers
    return PolynomialTrajectory(durations=np.diff(pp.x), coefficients=coefs)


def sampled(seed: int, n: int, span: float, with_velocity: bool) -> SampledTrajectory:
    pts = _waypoints(seed, n)
    t = np.arange(n) * span
    if not with_velocity:
        return SampledTrajectory(t=t, p=pts)
    v = np.gradient(pts, t, axis=0)
    v[[0, -1]] = 0.0
    return SampledTrajectory(t=t, p=pts, v=v)


@st.composite
def trajectories(draw: st.DrawFn) -> Trajectory:
    kind = draw(st.sampled_from(["bspline", "polynomial", "samples", "samples_v"]))
    seed = draw(st.integers(0, 2**31 - 1))
    n = draw(st.integers(4, 9))
    span = draw(st.floats(0.4, 2.0))
    if kind == "bspline":
        return bspline(seed, n, span)
    if kind == "polynomial":
        return polynomial(seed, n, span)
    return sampled(seed, n, span, kind == "samples_v")


@st.composite
def limits(draw: st.DrawFn) -> Limits:
    v = draw(st.floats(0.5, 4.0))
    a = draw(st.lists(st.floats(1.0, 6.0), min_size=3, max_size=3))
    return Limits(v, tuple(a))
