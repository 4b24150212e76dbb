"""The parity table (rota-sitl parity): spread per figure and backend, failures counted."""

from __future__ import annotations

import math

from sitl.parity import spread, table


def _run(t: float, closest: float, zones: int = 1) -> dict:
    return {"flight_time_s": t, "max_tracking_error_m": 0.4, "closest_approach_m": closest,
            "max_speed_m_s": 2.0, "braking_zones": zones, "setpoint_jitter_p99_ms": 1.0,
            "reached_goal": True, "collisions": int(closest < 0)}


def test_spread_is_the_sample_spread():
    s = spread([1.0, 2.0, 3.0])
    assert s["n"] == 3 and s["mean"] == 2.0 and s["sd"] == 1.0 and (s["min"], s["max"]) == (1, 3)
    assert math.isnan(spread([5.0])["sd"]) and spread([]) == {"n": 0}


def test_the_table_counts_failed_runs_and_collisions():
    sitl = {"backend": "sitl", "runs": [_run(12.0, 0.8), _run(13.0, 0.6)], "failed": []}
    px4 = {"backend": "px4", "runs": [_run(19.0, 0.3), _run(18.0, -0.1)],
           "failed": ["run 3: TimeoutError: the goal"]}
    text = table([sitl, px4])
    assert "`sitl` (2 of 2 runs)" in text and "`px4` (2 of 3 runs)" in text
    assert "| flight time to the goal (s) | 12.5 ± 0.707 (12-13) | 18.5 ± 0.707 (18-19) |" in text
    assert text.splitlines()[-1] == "| reached the goal without a collision | 2 of 2 | 1 of 3 |"
