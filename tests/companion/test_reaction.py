"""The reaction time: a trajectory's arrival at the service to the first setpoint
of its plan, with its parts, summed and summarised as status carries it."""

from __future__ import annotations

import numpy as np
import pytest

from companion.flight.reaction import KEPT, PARTS, Reactions, Timing


def test_the_parts_add_up_to_the_whole_and_are_summarised_in_ms():
    r = Reactions()
    assert r.summary() is None
    rng = np.random.default_rng(1)
    for k in range(50):
        t = 100.0 + k
        parts = rng.uniform(0.001, 0.05, 5)
        marks = t + np.cumsum(parts)
        r.flown(Timing(t, marks[0], marks[1], marks[2], marks[3]), marks[4])
    s = r.summary()
    assert s["count"] == 50 and set(s["parts_p50"]) == set(PARTS)
    assert s["p50"] <= s["p99"] <= s["max"] <= 250.0
    assert sum(s["parts_p50"].values()) == pytest.approx(s["p50"], rel=0.5)


def test_a_plan_without_timing_or_never_offered_is_not_counted_and_the_log_is_bounded():
    r = Reactions()
    r.flown(None, 1.0)
    r.flown(Timing(0.0, 0.1), 1.0)  # decoded, but never offered
    assert r.summary() is None
    for k in range(KEPT + 10):
        r.flown(Timing(k, k + 0.01, k + 0.02, k + 0.03, k + 0.04), k + 0.05)
    s = r.summary()
    assert s["count"] == KEPT and s["max"] == pytest.approx(50.0)
