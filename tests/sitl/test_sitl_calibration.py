"""The ``sitl`` vehicle against real PX4 (SIH quadrotor): the recorded setpoints replayed
through the vehicle on the simulated clock, both responses measured the same way
(:mod:`sitl.calibration`; the tables are in docs/sitl.md, "Calibration").

Stated tolerances. They follow PX4's own spread between runs that should be alike (the out and
back runs of one line, the three boots): a single PX4 run wanders +-0.2-0.3 m in hover, so
figures are compared per speed (lines: out and back averaged) and the vehicle's over 3 seeds.

* lag: within 0.2 s at 2 and 3 m/s; 0.35 s at 1 m/s, where the fit is dominated by the wander
  (PX4's two runs gave -0.13 and +0.19 s);
* RMS and max tracking error: vehicle / PX4 within 0.75-1.35;
* overshoot after the end: within 0.3 m;
* mean distance from the end point 0-2 s after the end: within 0.45 m, and residual 3-4 s
  after the end (how far from settled): within 0.4 m (PX4's own runs at one speed differ by
  up to 0.34 m). Known weakness, not hidden by these numbers: the vehicle comes back to the
  end point sooner than PX4. At 2 m/s PX4 stays further from it (0.85 m vs ~0.5 m in the
  first 2 s, 0.71 m vs ~0.35-0.45 m after 3-4 s); PX4 does not settle to 0.5 m within the
  4 s hold in 7 of 9 runs, the vehicle does in about 1 s;
* hover: std of the estimate and of the velocity, largest distance in 30 s: vehicle / PX4
  within 0.7-1.5 (horizontal axes pooled);
* takeoff: times within 0.8 s (PX4's boots differ by up to 0.6 s), altitudes within 0.25 m;
* offboard loss: mode change within 0.03 s of PX4's, Return, back to OFFBOARD within 0.05 s;
* arming seen in the 1 Hz HEARTBEAT: median 0.35-0.65 s, max 0.8-1.0 s (PX4: 0.59 / 0.89 s).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from sitl.calibration_report import GROUPS, compare

pytestmark = pytest.mark.timeout(300)


@pytest.fixture(scope="module")
def res():
    return compare(seeds=(1, 2, 3), arm_trials=60)


@pytest.mark.parametrize("group", [name for name, _ in GROUPS])
def test_tracking_matches_px4(res, group):
    px4, sim = res["groups"][group]
    lag_tol = 0.35 if " 1 m/s" in group else 0.2
    assert abs(sim.lag_s - px4.lag_s) <= lag_tol, (px4, sim)
    assert 0.75 <= sim.rms_m / px4.rms_m <= 1.35, (px4, sim)
    assert 0.75 <= sim.max_m / px4.max_m <= 1.35, (px4, sim)
    assert abs(sim.overshoot_m - px4.overshoot_m) <= 0.3, (px4, sim)
    assert abs(sim.mean_after_m - px4.mean_after_m) <= 0.45, (px4, sim)
    assert abs(sim.residual_m - px4.residual_m) <= 0.4, (px4, sim)


def test_tracking_error_grows_with_speed_like_px4(res):
    """The ordering PX4 shows: the faster, the larger the RMS error and the lag."""
    for kind in ("lines", "circle"):
        sim = [res["groups"][f"{kind} {v} m/s"][1] for v in (1, 2, 3)]
        assert sim[0].rms_m < sim[1].rms_m < sim[2].rms_m


def test_hover_wander_matches_px4(res):
    px4, sim = res["hover"]

    def pooled(v):
        return math.hypot(v[0], v[1]) / math.sqrt(2.0)

    for key in ("std_m", "vel_std_m_s"):
        assert 0.7 <= pooled(sim[key]) / pooled(px4[key]) <= 1.5, (key, px4[key], sim[key])
        assert 0.7 <= sim[key][2] / px4[key][2] <= 1.5, (key, px4[key], sim[key])
    assert 0.7 <= sim["max_m"] / px4["max_m"] <= 1.5


def test_takeoff_matches_px4(res):
    px4, sim = res["takeoff"]
    for key in ("t_0.5m_s", "t_hold_s", "t_1.8m_s"):
        assert abs(sim[key] - px4[key]) <= 0.8, (key, px4[key], sim[key])
    for key in ("alt_at_hold_m", "alt_4s_after_hold_m", "max_alt_m"):
        assert abs(sim[key] - px4[key]) <= 0.25, (key, px4[key], sim[key])
    assert sim["alt_at_hold_m"] < 1.5  # Takeoff hands over to Hold well below the target


def test_offboard_loss_and_reentry_match_px4(res):
    px4, sim = res["loss"]
    assert len(sim) == len(px4) == 3
    for a, b in zip(px4, sim, strict=True):
        assert b["failsafe_mode"] == a["failsafe_mode"] == "AUTO_RTL"
        assert abs(b["loss_to_mode_s"] - a["loss_to_mode_s"]) <= 0.03
        assert b["resume_to_offboard_s"] <= 0.05 and a["resume_to_offboard_s"] <= 0.05


def test_armed_state_appears_with_the_1hz_heartbeat(res):
    px4, sim = res["arm"]
    assert 0.35 <= float(np.median(sim)) <= 0.65 and 0.8 <= sim.max() <= 1.0
    assert sim.min() >= 0.0
    assert float(np.median(px4)) == pytest.approx(0.59, abs=0.01)
