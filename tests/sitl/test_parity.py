"""The parity table (rota-sitl parity): spread per figure and backend, failures counted."""

from __future__ import annotations

import math

import numpy as np
import pytest

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
    # the means 6 s apart, PX4's sd 0.707 s: outside two of them
    assert ("| flight time to the goal (s) | 12.5 ± 0.707 (12-13) | 18.5 ± 0.707 (18-19) | -6 "
            "| no (±1.41) |") in text
    assert "| max tracking error (the service's) (m) | 0.4 ± 0 (0.4-0.4) | 0.4 ± 0 (0.4-0.4) " \
           "| +0 | yes (±0) |" in text
    assert text.splitlines()[-1] == "| reached the goal without a collision | 2 of 2 | 1 of 3 | | |"


def test_match_is_the_mean_difference_against_two_px4_sd():
    from sitl.parity import match

    assert match([1.0, 1.2], [1.0, 2.0, 3.0]) == pytest.approx((-0.9, 2.0, True))
    assert match([4.5], [1.0, 2.0, 3.0])[2] is False  # 2.5 from PX4's mean, band 2.0
    assert match([1.0], [2.0]) is None and match([], [1.0, 2.0]) is None


def test_tracking_figures_find_a_known_lag_overshoot_and_settling():
    """A record made up to known answers: the vehicle 0.3 s behind a 1 m/s line to x = 10 m,
    then past its end by 0.6 exp(-t / 0.5) m (sampled at 20 Hz)."""
    from companion.gs.replay import Flight
    from sitl.parity import tracking_figures

    sp_t = np.arange(0.0, 15.0, 0.02)
    sp_p = np.zeros((len(sp_t), 3))
    sp_p[:, 0] = np.minimum(sp_t, 10.0)
    source = ["p-0" if t <= 10.0 else "hold" for t in sp_t]
    tel_t = np.arange(0.0, 15.0, 0.05)
    x = np.where(tel_t <= 10.3, np.clip(tel_t - 0.3, 0.0, 10.0),
                 10.0 + 0.6 * np.exp(-(tel_t - 10.3) / 0.5))
    pos = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    f = Flight(config={}, tel_t=tel_t, position=pos, velocity=np.zeros_like(pos),
               tracking_error=np.zeros(len(tel_t)), sp_t=sp_t, sp_p=sp_p,
               sp_v=np.zeros_like(sp_p), sp_a=np.zeros_like(sp_p), sp_source=source,
               retimed=[(-1.0, {"id": "p-0"})], map=None, commands=[], statuses=[])
    fig = tracking_figures(f)
    assert fig["lag_s"] == pytest.approx(0.3, abs=0.011)
    # (the first 0.3 s the vehicle waits at 0 while the line leaves: a little more than 0.3)
    assert 0.29 < fig["rms_tracking_error_m"] < 0.31
    assert fig["overshoot_m"] == pytest.approx(0.6 * math.exp(-0.05 / 0.5), abs=1e-3)
    assert fig["settle_s"] == pytest.approx(0.40, abs=1e-6)  # first sample under 0.5 m


def test_tracking_figures_say_when_the_vehicle_never_settles():
    from companion.gs.replay import Flight
    from sitl.parity import tracking_figures

    sp_t = np.arange(0.0, 8.0, 0.02)
    sp_p = np.column_stack([np.minimum(sp_t, 3.0), np.zeros(len(sp_t)), np.zeros(len(sp_t))])
    tel_t = np.arange(0.0, 8.0, 0.05)
    pos = np.column_stack([np.where(tel_t < 3.0, tel_t, 4.0), np.zeros(len(tel_t)),
                           np.zeros(len(tel_t))])  # 1 m past the end, staying there
    f = Flight(config={}, tel_t=tel_t, position=pos, velocity=np.zeros_like(pos),
               tracking_error=np.zeros(len(tel_t)), sp_t=sp_t, sp_p=sp_p,
               sp_v=np.zeros_like(sp_p), sp_a=np.zeros_like(sp_p),
               sp_source=["p-0" if t <= 3.0 else "hold" for t in sp_t],
               retimed=[(-1.0, {"id": "p-0"})], map=None, commands=[], statuses=[])
    fig = tracking_figures(f)
    assert fig["settle_s"] is None and fig["overshoot_m"] == pytest.approx(1.0)
    assert table([{"backend": "px4", "runs": [{**_run(12.0, 0.5), **fig}], "failed": []}],
                 (("settle_s", "settled", "s"),), reached=False).splitlines()[-1] \
        == "| settled (s) | - [1 without] |"


def test_px4_flights_can_come_from_an_earlier_table():
    """After a change of the `sitl` vehicle alone, its flights beside PX4's earlier ones,
    and the table says when PX4 flew."""
    from sitl.parity import render, with_px4_from

    sitl = {"backend": "sitl", "runs": [_run(12.0, 0.8)], "failed": []}
    old_sitl = {"backend": "sitl", "runs": [_run(99.0, 0.8)], "failed": []}
    px4 = {"backend": "px4", "runs": [_run(19.0, 0.3), _run(18.0, 0.4)], "failed": []}
    earlier = {"measured": "2026-12-01", "demo": [old_sitl, px4], "tier": []}
    demo, tier, day = with_px4_from(earlier, [sitl], [], "2026-12-07")
    assert demo == [sitl, px4] and tier == []
    text = render(demo, tier, day)
    assert "measured 2026-12-07 (PX4's flights: 2026-12-01)" in text
    assert "| 12 (12-12) | 18.5 ± 0.707 (18-19) |" in text  # not the old sitl's 99 s
    with pytest.raises(ValueError, match="no PX4 flights"):
        with_px4_from({"measured": "x", "demo": [old_sitl], "tier": []}, [sitl], [], "y")
