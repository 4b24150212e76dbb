"""``[stream] slow_for_yaw`` flown end to end: over real Zenoh and UDP, a planner's path
with a 1 m corner, the heading following the path (``yaw = "path"``) within
``yaw_rate_max_deg_s``. With the option the re-time slows into the corner so that the
heading the vehicle receives keeps up with the direction it is commanded to fly."""

from __future__ import annotations

import time

import numpy as np
import pytest

from rota.trajectory import BSplineTrajectory
from sitl.demo import start_holding, take_off, trajectory_message
from tests.e2e.test_companion_e2e import run_flight
from tests.helpers.kinematics import corner

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(240)]


def heading_lag_deg(setpoints, window: tuple[float, float], floor: float = 0.5) -> float:
    """The largest angle between the yaw the vehicle received and the direction of the
    velocity it was commanded (NED, degrees), where that velocity is over ``floor``, from
    the moment the two first agreed within a degree (the yaw held at the start is the
    vehicle's, not the path's: the first turn toward the path is not the corner's)."""
    sp = setpoints
    keep = (sp["wall_time"] >= window[0]) & (sp["wall_time"] <= window[1])
    v = np.asarray(sp["velocity"], float)[keep]  # ENU
    yaw = np.asarray(sp["yaw_ned_deg"], float)[keep]
    fast = np.hypot(v[:, 0], v[:, 1]) > floor
    direction = np.degrees(np.arctan2(v[fast, 0], v[fast, 1]))  # NED yaw of (east, north)
    lag = np.abs((yaw[fast] - direction + 180.0) % 360.0 - 180.0)
    return float(lag[int(np.argmax(lag < 1.0)):].max())


def test_the_heading_keeps_up_with_a_corner_when_the_re_time_slows_for_it():
    """Measured (one flight each): with ``slow_for_yaw`` the received yaw lagged the
    commanded direction by at most 10.6 deg (9.4 s from the plan's take-over to its end);
    without, 47.0 deg (7.8 s). What remains with it is the yaw-acceleration ramp, which the
    re-time does not bound: reaching 45 deg/s at 90 deg/s^2 lags omega^2 / (2 alpha) =
    11.25 deg. The bound is that and 4 deg; a frame error (ENU yaw sent as NED) lags 90."""
    async def scenario(gs, service, sim, world):
        await take_off(gs)  # (no map: the empty world has nothing to draw)
        here = await start_holding(gs)
        path = corner(1.0)
        local = BSplineTrajectory(path.control_points - path.control_points[0] + here,
                                  path.degree, path.knot_span)
        gs.publish("trajectory", trajectory_message(local, "corner"))
        await gs.wait_for(lambda s: s.get("trajectory_id") == "corner", 30, "the plan")
        t0 = time.monotonic()
        await gs.wait_for(lambda s: s.get("command") == "hold"
                          and s.get("trajectory_id") is None, 60, "the end of the plan")
        return (t0, time.monotonic()), service.cfg.stream

    (window, stream), report = run_flight(scenario, world_name="empty",
                                          stream={"slow_for_yaw": True})
    lag = heading_lag_deg(report.setpoints, window)
    ramp = stream.yaw_rate_max_deg_s ** 2 / (2.0 * stream.yaw_accel_max_deg_s2)
    print(f"heading lag at most {lag:.1f} deg (the ramp's {ramp:.2f}), "
          f"{window[1] - window[0]:.2f} s")
    assert lag <= ramp + 4.0
    assert not report.collisions
