"""The two estimation-error models of the simulated vehicle (sitl.estimation): the correlated
model (amplitude follows the speed) and the drift model (speed drives the increments)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sitl.estimation import DRIFT, EstimationErrorParams, PositionErrorModel


def _run(params: EstimationErrorParams, speeds: np.ndarray, dt: float, seed: int = 5):
    model = PositionErrorModel(params, np.random.default_rng(seed))
    err, std = [], []
    for s in speeds:
        err.append(model.step(dt, np.array([s, 0.0, 0.0])))
        std.append(model.std.copy())
    return np.array(err), np.array(std)


def test_drift_stationary_std_and_correlation_at_constant_speed():
    """At a constant 3 m/s the drift model's std is sigma (0.5 m) per horizontal axis, half
    that vertically, with autocorrelation exp(-lag / tau)."""
    dt, tau = 0.02, 3.0
    params = EstimationErrorParams(kind="drift", correlation_time_s=tau)
    e, std = _run(params, np.full(150_000, 3.0), dt)
    e, std = e[1000:], std[1000:]
    assert e.std(axis=0) == pytest.approx([0.5, 0.5, 0.25], rel=0.08)
    assert std[-1] == pytest.approx([0.5, 0.5, 0.25], rel=1e-6)
    lag = int(tau / dt)
    z = e[:, :2] / 0.5
    assert np.mean(z[:-lag] * z[lag:]) == pytest.approx(math.exp(-1.0), abs=0.08)


def test_drift_variance_grows_with_distance_and_speed():
    """From hover, the variance added per metre flown is larger at 3 m/s than at 1.5 m/s,
    and the reported std follows the exact running variance."""
    dt = 0.01
    out = {}
    for speed in (1.5, 3.0):
        n_steps = int(round(4.0 / speed / dt))  # 4 m of flight
        e = []
        for seed in range(400):
            err, std = _run(DRIFT, np.full(n_steps, speed), dt, seed)
            e.append(err[-1, :2])
        out[speed] = (np.var(np.array(e)), std[-1, 0] ** 2)
    (var_slow, exact_slow), (var_fast, exact_fast) = out[1.5], out[3.0]
    assert var_slow == pytest.approx(exact_slow, rel=0.15)
    assert var_fast == pytest.approx(exact_fast, rel=0.15)
    assert var_fast > 1.5 * var_slow


def test_correlated_std_drops_at_once_drift_std_fades():
    dt = 0.01
    speeds = np.concatenate([np.full(500, 3.0), np.zeros(100)])
    _, std_c = _run(EstimationErrorParams(), speeds, dt)
    _, std_d = _run(DRIFT, speeds, dt)
    assert std_c[-1, 0] == pytest.approx(0.02)  # the floor, right after stopping
    assert std_d[-1, 0] == pytest.approx(
        math.sqrt(std_d[499, 0] ** 2 * math.exp(-2.0 / 3.0) + 0.02**2 * (1 - math.exp(-2 / 3))),
        rel=1e-9)


def test_vertical_scale_and_validation():
    params = EstimationErrorParams(vertical_scale=0.0)
    e, _ = _run(params, np.full(200, 2.0), 0.01)
    assert np.all(e[:, 2] == 0.0) and np.abs(e[:, :2]).max() > 0.0
    with pytest.raises(ValueError):
        EstimationErrorParams(kind="white")
    with pytest.raises(ValueError):
        EstimationErrorParams(vertical_scale=-1.0)
