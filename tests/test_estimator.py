"""The in-flight uncertainty estimator on synthetic data (issue #7)."""

from __future__ import annotations

import numpy as np
import pytest

from companion.estimator import EstimatorSettings, UncertaintyEstimator, tracking_std
from rota.chance import UncertaintyModel

PRIOR = UncertaintyModel(m=0.2, b=-0.1)


def synthetic(m: float, b: float, n: int, rng, outliers: float = 0.05, noise: float = 0.02,
              v_max: float = 3.0):
    speed = rng.uniform(0.0, v_max, n)
    z = np.maximum(0.0, m * speed + b) + rng.normal(0, noise, n)
    bad = rng.random(n) < outliers
    z[bad] = rng.uniform(0.0, 3.0, bad.sum())  # wild values: estimator glitches, jumps
    return speed, np.abs(z), bad


@pytest.mark.parametrize(("m", "b", "seed"), [(0.3, -0.1, 0), (0.12, 0.05, 1), (0.45, -0.2, 2)])
def test_estimate_within_10_percent_and_uncertainty_covers_truth(m, b, seed):
    rng = np.random.default_rng(seed)
    est = UncertaintyEstimator(PRIOR, EstimatorSettings(measurement_std=0.02))
    speed, z, _ = synthetic(m, b, 1500, rng)
    for k, (v, zz) in enumerate(zip(speed, z, strict=True)):
        est.observe(float(v), float(zz), t=0.1 * k)
    sm, sb = est.std
    assert est.m == pytest.approx(m, rel=0.10)
    assert abs(est.b - b) <= 0.1 * max(abs(b), 0.1)
    assert abs(est.m - m) <= 3 * sm and abs(est.b - b) <= 3 * sb  # covers the truth
    assert est.outliers >= 0.02 * len(z)  # the wild values were caught, not absorbed
    assert est.in_use() == "estimate" and est.model().m == pytest.approx(est.m)


def test_hover_carries_no_information():
    est = UncertaintyEstimator(PRIOR, EstimatorSettings())
    for k in range(500):
        assert est.observe(0.1, 0.5, t=0.1 * k) == "hover"
    assert est.m == PRIOR.m and est.samples == 0 and est.model() == PRIOR


def test_never_less_cautious_than_prior_before_enough_evidence():
    rng = np.random.default_rng(5)
    est = UncertaintyEstimator(PRIOR, EstimatorSettings(min_samples=100, measurement_std=0.02),
                               v_check=3.0)
    speed, z, _ = synthetic(0.1, -0.05, 60, rng, outliers=0.0)  # less uncertainty than prior
    for k, (v, zz) in enumerate(zip(speed, z, strict=True)):
        est.observe(float(v), float(zz), t=0.1 * k)
    assert est.samples < 100 and est.m < PRIOR.m
    assert est.model() == PRIOR  # not trusted yet
    speed, z, _ = synthetic(0.1, -0.05, 100, rng, outliers=0.0)
    for k, (v, zz) in enumerate(zip(speed, z, strict=True)):
        est.observe(float(v), float(zz), t=10 + 0.1 * k)
    assert est.model().m == pytest.approx(0.1, rel=0.15)
    # more uncertainty than the prior is used at once (more caution is always allowed)
    cautious = UncertaintyEstimator(PRIOR, EstimatorSettings(min_samples=1000))
    for k in range(30):
        cautious.observe(2.0, 0.8, t=0.1 * k)
        cautious.observe(1.0, 0.3, t=0.1 * k + 0.05)
    assert cautious.in_use() == "estimate" and cautious.model().m > PRIOR.m


def test_bounds_freeze_set_reset_and_persistence(tmp_path):
    path = tmp_path / "est.json"
    s = EstimatorSettings(m_max=0.4)
    est = UncertaintyEstimator(PRIOR, s, path)
    for k in range(300):
        est.observe(2.0, 2.0, t=0.1 * k)  # implausibly large: clamped, never beyond m_max
        est.observe(1.0, 1.0, t=0.1 * k + 0.05)
    assert est.m <= 0.4 + 1e-12
    est.save()
    again = UncertaintyEstimator(PRIOR, s, path)
    assert again.m == pytest.approx(est.m) and again.samples == est.samples
    again.freeze(True)
    assert again.observe(2.0, 0.1) == "frozen"
    again.set(0.25, -0.05)
    assert again.model().m == 0.25
    with pytest.raises(ValueError, match="outside the bounds"):
        again.set(0.9, 0.0)
    again.reset()
    assert again.m == PRIOR.m and again.samples == 0
    path.write_text("{broken")
    with pytest.raises(ValueError, match="cannot restore"):
        UncertaintyEstimator(PRIOR, s, path)


def test_tracking_std_removes_the_lag():
    rng = np.random.default_rng(1)
    lagged = np.array([0.3, 0.0, 0.0]) + rng.normal(0, 0.05, (200, 3))
    assert tracking_std(lagged) == pytest.approx(0.05, rel=0.15)
    assert np.isnan(tracking_std(lagged[:3]))


def test_evidence_prefers_px4_and_falls_back_to_tracking():
    from companion.estimator import evidence

    assert evidence(0.3, 0.4, include_tracking=False) == 0.3
    assert evidence(0.3, 0.4, include_tracking=True) == pytest.approx(0.5)
    assert evidence(float("nan"), 0.4, include_tracking=False) == 0.4
    assert np.isnan(evidence(float("nan"), float("nan"), include_tracking=True))
