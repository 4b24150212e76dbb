"""Error memory in the chance-constrained speed limits: a braking point's limit also holds
over the memory window before it (rota.chance.memory_limits, UncertaintyModel.memory_s)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rota.chance import MAX_MEMORY_S, UncertaintyModel, memory_limits
from rota.errors import InputError
from tests.helpers.scenes import line, node_speed, pillar, run, safety


def _brute(s: np.ndarray, lim: np.ndarray, t: float) -> np.ndarray:
    out = lim.copy()
    if t == 0.0:  # the paper's model: nothing moves
        return out
    for i in np.flatnonzero(np.isfinite(lim)):
        before = np.flatnonzero(s <= s[i] - lim[i] * t)
        first = before[-1] if len(before) else 0
        cover = (np.arange(len(s)) >= first) & (np.arange(len(s)) <= i)
        out[cover] = np.minimum(out[cover], lim[i])
    return out


def test_hand_example():
    s = np.arange(0.0, 10.01, 0.5)
    lim = np.full(len(s), np.inf)
    lim[12], lim[14] = 1.0, 0.5  # at 6 m and 7 m
    one = memory_limits(s, lim, 1.0)  # windows [5, 6] and [6.5, 7]
    assert np.isinf(one[:10]).all() and np.isinf(one[15:]).all()
    assert one[10:15].tolist() == [1.0, 1.0, 1.0, 0.5, 0.5]
    two = memory_limits(s, lim, 2.0)  # windows [4, 6] and [6, 7]: the lower cap wins at 6 m
    assert two[8:15].tolist() == [1.0, 1.0, 1.0, 1.0, 0.5, 0.5, 0.5]
    # A window starting between nodes also caps the node before it.
    short = memory_limits(s, lim, 0.7)  # [5.3, 6] -> from the node at 5 m; [6.65, 7]
    assert np.isinf(short[9]) and short[10:15].tolist() == [1.0, 1.0, 1.0, 0.5, 0.5]
    assert np.array_equal(memory_limits(s, lim, 0.0), lim)


@settings(max_examples=150, deadline=None)
@given(st.lists(st.floats(0.0, 2.0), min_size=1, max_size=60),
       st.lists(st.one_of(st.just(np.inf), st.floats(0.0, 3.0)), min_size=60, max_size=60),
       st.floats(0.0, 4.0))
def test_matches_brute_force(steps, limits, t):
    s = np.cumsum(steps)
    lim = np.array(limits[: len(s)])
    got = memory_limits(s, lim, t)
    assert np.array_equal(got, _brute(s, lim, t))
    assert np.all(got <= lim)


@pytest.mark.parametrize("args,field", [
    ((np.array([0.0, 1.0]), np.array([1.0]), 1.0), "limit"),
    ((np.array([1.0, 0.0]), np.array([1.0, 1.0]), 1.0), "arclength"),
    ((np.array([0.0, 1.0]), np.array([np.nan, 1.0]), 1.0), "limit"),
    ((np.array([0.0, 1.0]), np.array([1.0, 1.0]), -1.0), "memory_s"),
    ((np.array([0.0, 1.0]), np.array([1.0, 1.0]), MAX_MEMORY_S + 1), "memory_s"),
])
def test_bad_input_names_field(args, field):
    with pytest.raises(InputError) as exc:
        memory_limits(*args)
    assert exc.value.field == field


def test_model_validates_memory():
    assert UncertaintyModel().memory_s == 0.0
    with pytest.raises(InputError) as exc:
        UncertaintyModel(memory_s=-0.5)
    assert exc.value.field == "memory_s"


def _with_memory(t: float):
    safe = safety(pillar())
    return run(line(0.0, 10.0), type(safe)(
        map=safe.map, uncertainty=UncertaintyModel(m=0.2, b=-0.1, memory_s=t),
        chance=safe.chance, braking=safe.braking))


def test_zero_memory_is_the_papers_retime():
    paper = run(line(0.0, 10.0), safety(pillar()))
    zero = _with_memory(0.0)
    assert np.array_equal(paper.beta, zero.beta)
    assert not zero.diagnostics.approach_mask.any() and zero.diagnostics.memory_s == 0.0


@pytest.mark.parametrize("t", [0.5, 1.0, 2.0])
def test_vehicle_is_at_the_limit_for_memory_seconds_before_each_braking_point(t):
    """The flown speed is at most L_i over the last T seconds before every braking point i
    (checked on the re-timed trajectory sampled at 1 kHz, not on the caps)."""
    res = _with_memory(t)
    assert res.ok, res.message
    mask = res.diagnostics.braking_mask
    limits = res.diagnostics.chance_limits
    assert mask.any() and res.diagnostics.approach_mask.any()
    times = res.timemap.t
    fine = np.arange(0.0, res.duration, 1e-3)
    speed = np.linalg.norm(res.sample(fine).velocity, axis=1)
    for i in np.flatnonzero(mask):
        window = (fine >= times[i] - t) & (fine <= times[i])
        assert speed[window].max() <= limits[i] * (1 + 2e-3), (i, speed[window].max())


def test_more_memory_brakes_earlier_and_takes_longer():
    res = [_with_memory(t) for t in (0.0, 0.5, 1.0, 2.0)]
    assert all(r.ok for r in res)
    durations = [r.duration for r in res]
    assert durations == sorted(durations) and durations[-1] > durations[0] * 1.02
    approach = [int(r.diagnostics.approach_mask.sum()) for r in res]
    assert approach == sorted(approach) and approach[0] == 0
    # The per-point chance limits are the paper's; memory only adds caps (also inside a
    # zone, where a closer point ahead already limits the points before it).
    for r in res[1:]:
        assert np.array_equal(r.diagnostics.chance_limits, res[0].diagnostics.chance_limits)
        assert np.array_equal(r.diagnostics.braking_mask, res[0].diagnostics.braking_mask)
        assert np.all(r.speed_limits <= res[0].speed_limits)
    assert node_speed(res[-1]).max() > 2.5  # far from the pillar it is fast again
