"""The sampled trajectory's quintic Hermite spline, built in closed form, is the
spline scipy's ``BPoly.from_derivatives`` builds (which loops in Python over
every interval: the bulk of decoding a planner's message, before)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import interpolate

from rota.trajectory import SampledTrajectory, quintic_hermite


@pytest.mark.parametrize("n", [2, 3, 17, 301])
def test_closed_form_equals_scipys_from_derivatives(n):
    rng = np.random.default_rng(n)
    t = np.cumsum(rng.uniform(0.01, 0.3, n))
    p, v, a = rng.normal(size=(3, n, 3)) * [[[5.0]], [[2.0]], [[3.0]]]
    ref = interpolate.BPoly.from_derivatives(t, np.stack([p, v, a], axis=1), extrapolate=False)
    ours = SampledTrajectory(t=t, p=p, v=v, a=a)
    x = np.linspace(t[0], t[-1], 4001)
    for order in range(4):
        want = ref(x, order)
        got = interpolate.BPoly(quintic_hermite(np.diff(t), p, v, a), t)(x, order)
        # (rounding only: the same polynomial, its coefficients summed in another order)
        assert np.max(np.abs(got - want)) <= 1e-12 * max(1.0, np.max(np.abs(want)))
    assert np.allclose(ours.position(x), ref(x), rtol=0, atol=1e-12 * np.max(np.abs(p)))
