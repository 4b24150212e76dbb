"""The PX4 experiment's flight (rota-sitl experiment px4) on real PX4 SITL: one forest, its
three arms flown by one PX4 instance, judged on SIH's ground truth. Part of the PX4 tier
(with ROTA_PX4_BUILD; ROTA_PX4_TIER=0 leaves it out): about a minute and a half of
real-time PX4.

Limits, from the 40-trial run in docs/table1/px4 (120 flights):
* end miss (truth, 1 s after the last setpoint): PX4 overshoots the end and its estimate
  wanders; measured 0.09-1.85 m (median 0.66), so END_MISS_M = 3 m; a frame error (x and y
  swapped) ends the arm metres away;
* every arm stays in OFFBOARD, and the stream kept its deadlines (late setpoints below 2 %);
* SIH's truth covered the arm (no hole over TRUTH_HOLE_S): measured 42-45 ms on a quiet
  machine, 44-72 ms beside two test workers flying the fault tests (PX4 sends it at
  25 Hz). A count of samples is no measure of it: once CI's VM lost CPU to its host so
  often that one arm got 198 samples in 12.3 s (16 Hz) and was still judged every
  12 cm of flight; a truth stream that stopped leaves a hole to the arm's end;
* no ground strike (the experiment's other kind of crash; a vertical frame error flies the
  vehicle into the ground): the true altitude stays above 0 on the 2 m flight. Measured
  lowest: 1.29 m over the 120 flights of a quiet machine, 0.58 m beside two busy loops (PX4
  runs in real time and dips when starved of CPU).
"""

from __future__ import annotations

import os

import pytest

from sitl.experiment_px4 import ARMS, Px4ExperimentConfig, run
from sitl.px4 import px4_build, skip_reason

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(400),
              pytest.mark.skipif(os.environ.get("ROTA_PX4_TIER", "1") == "0",
                                 reason="ROTA_PX4_TIER=0 leaves the PX4 tier out")]

END_MISS_M = 3.0
TRUTH_HOLE_S = 0.25  # about 4x the largest hole measured; a host's takings are ~0.1 s each


def test_one_forest_flown_three_ways_on_px4():
    build = px4_build()
    if build is None:
        pytest.skip(skip_reason())
    result = run(Px4ExperimentConfig(trials=1), str(build))
    (trial,) = result["trials"]
    assert trial["status"] == "optimal" and trial["fitted_status"] == "rejected"
    assert set(trial["arms"]) == set(ARMS), trial.get("error")
    # smoothness as flown (SIH's true velocity) and as commanded, for every arm (the
    # jerk-limited arm, `--j-max`, flies in docs/jerk-px4, not here: 30 s more of PX4);
    # measured in docs/jerk-px4 (40 flights): flown 1.1-2.3 m/s^3, commanded 1.6-3.1 m/s^3
    for arm, f in trial["arms"].items():
        assert 0.3 < f["rms_jerk_truth"] < 10.0 and 0.3 < f["rms_jerk_commanded"] < 10.0, \
            (arm, f)
    for arm, f in trial["arms"].items():
        duration = trial["durations"][arm] + 1.0
        assert f["mode_after"] == "OFFBOARD", arm
        assert f["truth_hole"] <= TRUTH_HOLE_S, (arm, f["truth_samples"], duration, f)
        assert f["late_setpoints"] <= 0.02 * 50 * duration, arm
        assert f["end_miss"] < END_MISS_M, (arm, f)
        assert f["min_altitude"] > 0.0, (arm, f)
