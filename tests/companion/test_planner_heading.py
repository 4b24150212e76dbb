"""The planner's heading (a trajectory's ``yaw`` / ``yaw_dt``, EGO-Planner's ``yaw_pts``):
parsed with errors in words, converted to ENU from a NED message, carried by the plan
over the re-timed time map, and streamed to PX4 in NED within the yaw limits."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from companion.flight.heading import wrap_deg
from companion.flight.plan import Command, Plan
from companion.flight.stream import SetpointStream
from companion.messages import Rejected, parse_trajectory
from companion.ros2.decode import decode_bspline
from companion.settings.config import from_dict
from companion.status import Reporter
from rota import Limits, RetimeInput, retime
from rota.errors import InputError
from rota.schema import Heading, trajectory_from_dict, trajectory_to_dict
from rota.trajectory import SampledTrajectory
from tests.helpers.ros2 import CFG, bspline_cdr

LINE = {"schema": "rota/trajectory", "version": 1, "id": "h", "type": "samples",
        "t": [0.0, 2.0, 4.0], "p": [[0, 0, 1], [2, 0, 1], [4, 0, 1]]}


def test_the_heading_turns_the_short_way_and_holds_its_ends():
    h = Heading((170.0, -170.0, -150.0), 0.5, t0=1.0)
    assert [round(h.at(t), 6) for t in (0.0, 1.0, 1.25, 1.5, 2.0, 9.0)] == \
        [170.0, 170.0, -180.0, -170.0, -150.0, -150.0]


@pytest.mark.parametrize(("extra", "words"), [
    ({"yaw": [0, 10]}, r"yaw_dt: must be a number"),
    ({"yaw_dt": 0.5}, r"yaw: must be a list of numbers"),
    ({"yaw": [0, "north"], "yaw_dt": 0.5}, r"yaw: must be a list of numbers"),
    ({"yaw": [0, True], "yaw_dt": 0.5}, r"yaw: must be a list of numbers"),
    ({"yaw": [], "yaw_dt": 0.5}, r"yaw: must be a non-empty list of finite numbers"),
    ({"yaw": [0, 1e400], "yaw_dt": 0.5}, r"yaw: must be a non-empty list of finite numbers"),
    ({"yaw": [0, 10], "yaw_dt": 0}, r"yaw_dt: must be a positive number"),
    ({"yaw": [0, 10], "yaw_dt": -1}, r"yaw_dt: must be a positive number"),
])
def test_a_bad_heading_is_refused_naming_the_field(extra, words):
    with pytest.raises(InputError, match=words):
        trajectory_from_dict({**LINE, **extra})


def test_a_heading_round_trips_and_starts_with_the_trajectory():
    msg = trajectory_from_dict({**LINE, "t": [1.0, 3.0, 5.0], "yaw": [0, 45, 90],
                                "yaw_dt": 2.0})
    assert msg.heading == Heading((0.0, 45.0, 90.0), 2.0, t0=1.0)
    again = trajectory_from_dict(trajectory_to_dict(msg))
    assert again.heading == msg.heading
    assert trajectory_from_dict(LINE).heading is None  # none sent: none


def test_a_ned_messages_heading_arrives_in_enu():
    """NED yaw 0 (north) is ENU 90; NED 90 (east) is ENU 0; the message's frame rules."""
    cfg = from_dict({"safety": {"require_stamp": False}})
    enu = {**LINE, "yaw": [0.0, 90.0, -90.0], "yaw_dt": 2.0}
    ned = {**enu, "frame": "NED", "p": [[0, 0, -1], [0, 2, -1], [0, 4, -1]]}
    inc = parse_trajectory(json.dumps(ned).encode(), cfg)
    assert inc.heading.yaw_deg == (90.0, 0.0, -180.0)
    enu = parse_trajectory(json.dumps(enu).encode(), cfg)
    assert enu.heading.yaw_deg == (0.0, 90.0, -90.0)


def test_the_yaw_list_is_capped_before_it_is_built():
    cfg = from_dict({"safety": {"require_stamp": False, "max_trajectory_points": 50}})
    with pytest.raises(Rejected, match="yaw: 51 entries is over the cap of 50"):
        parse_trajectory(json.dumps({**LINE, "yaw": [0] * 51, "yaw_dt": 0.1}).encode(), cfg)


def test_ego_planners_yaw_pts_become_the_heading_in_degrees():
    inc = decode_bspline(bspline_cdr(yaw_pts=[0.0, math.pi / 2, math.pi], yaw_dt=0.5), CFG)
    assert inc.heading.dt == 0.5 and inc.heading.t0 == inc.trajectory.domain[0]
    assert np.allclose(inc.heading.yaw_deg, (0.0, 90.0, 180.0))
    assert decode_bspline(bspline_cdr(), CFG).heading is None  # empty yaw_pts: the path's
    with pytest.raises(Rejected, match=r"yaw_pts\[1\]: must be finite"):
        decode_bspline(bspline_cdr(yaw_pts=[0.0, np.nan]), CFG)
    with pytest.raises(Rejected, match="yaw_dt: must be positive with yaw_pts"):
        decode_bspline(bspline_cdr(yaw_pts=[0.0, 1.0], yaw_dt=0.0), CFG)


def _plan(heading: Heading) -> Plan:
    traj = SampledTrajectory(t=[0.0, 2.0, 4.0], p=[[0, 0, 1], [2, 0, 1], [4, 0, 1]])
    result = retime(RetimeInput(trajectory=traj, limits=Limits(v_max=1.0, a_max=1.0)))
    return Plan("h", result, t0=100.0, heading=heading)


def test_the_plan_gives_the_heading_where_its_time_map_is_in_ned():
    """ENU 90 (north) at the start turning to ENU 0 (east) at the end: NED 0 then 90; the
    re-timed plan (slower than planned) reaches the end of the heading when it ends."""
    plan = _plan(Heading((90.0, 0.0), 4.0))
    assert plan.yaw_ned_deg(100.0) == pytest.approx(0.0, abs=1e-9)
    assert plan.yaw_ned_deg(plan.end_time) == pytest.approx(90.0, abs=1e-6)
    half = float(plan.result.timemap.evaluate(2.5)[0][0])  # trajectory time 2.5 s in
    assert plan.yaw_ned_deg(102.5) == pytest.approx(90.0 * half / 4.0, abs=1e-6)
    assert Plan("x", plan.result, 0.0).yaw_ned_deg(1.0) is None


class _Autopilot:
    offboard_loss_timeout_s = 1.0


@pytest.mark.parametrize("mode", ["path", "hold"])
def test_the_stream_turns_to_the_planners_heading_within_the_limits(mode):
    """Flying east with the planner's heading north: the yaw sent turns to north (NED 0)
    within the rate limit, not along the path (NED 90); ``yaw = "hold"`` keeps the start."""
    cfg = from_dict({"stream": {"yaw": mode}})
    s = SetpointStream(lambda: cfg, _Autopilot(), Reporter())
    s.begin(np.zeros(3), 90.0, "test")  # facing east (NED yaw 90)
    s.source = _plan(Heading((90.0,), 1.0))  # north, the whole way
    east = Command(np.zeros(3), np.array([1.0, 0.0, 0.0]))
    sent = []
    for k in range(300):
        s._update_yaw(east, 100.0 + k / cfg.stream.rate_hz)
        sent.append(s.yaw_ned)
    steps = np.abs([wrap_deg(b - a) for a, b in zip(sent[:-1], sent[1:], strict=True)])
    assert steps.max() <= cfg.stream.yaw_rate_max_deg_s / cfg.stream.rate_hz + 1e-9
    assert sent[-1] == pytest.approx(0.0 if mode == "path" else 90.0, abs=1e-6)


@pytest.mark.parametrize("yaw", ["path", "hold"])
def test_the_service_slows_where_the_heading_could_not_keep_up(yaw):
    """``[stream] slow_for_yaw``: the worker's re-time of a replan taken over on a path
    with a tight corner (joined onto the command: the stitched path) turns the direction
    of flight within the yaw-rate limit; with ``yaw = "hold"`` the heading does not turn
    with the path and nothing is slowed."""
    from companion.flight.retimer import ReplanJob, _replan
    from tests.rota.test_heading import corner, path_yaw_rate

    cfg = from_dict({"stream": {"slow_for_yaw": True, "yaw": yaw,
                                "yaw_rate_max_deg_s": 40.0}})
    traj = corner(1.0)
    take = retime(RetimeInput(trajectory=traj, limits=cfg.rota_limits())).sample(1.0)

    def replan(rate: float):
        out = _replan(ReplanJob(
            id="c", stamp=None, trajectory=traj, limits=cfg.rota_limits(), smoothness=0.5,
            dtau=cfg.limits.dtau, uncertainty=cfg.uncertainty_model(),
            chance=cfg.chance_params(), braking=cfg.braking_params(),
            take_position=take.position[0] + 0.05, take_velocity=take.velocity[0],
            yaw_rate_max=rate))
        assert out.result.ok, out.result.message
        return out.result

    free, slowed = replan(0.0), replan(cfg.yaw_slowdown_rad_s())
    if yaw == "hold":
        assert cfg.yaw_slowdown_rad_s() == 0.0 and slowed.duration == free.duration
        return
    assert path_yaw_rate(free) > math.radians(60.0)
    assert path_yaw_rate(slowed) <= math.radians(40.0) * 1.01  # measured: 40.01 deg/s
