"""End-to-end: an EGO-Planner-like ROS 2 node, on rmw_zenoh or behind a
zenoh-bridge-ros2dds with a namespace (emulated from the layouts' documents: keys,
attachments, liveliness tokens; CDR by rosbags), sends the map as a PointCloud2 and
its trajectories as traj_utils/Bspline; the service flies them on the ``sitl``
vehicle through MAVSDK, and its status and re-timed trajectories come back as ROS
messages."""

from __future__ import annotations

import asyncio
import base64
import json
import queue
import tempfile
from pathlib import Path

import numpy as np
import pytest

from companion.gs.replay import load
from companion.recording.record import read
from companion.ros2.encode import bspline_cdr, pointcloud_cdr
from companion.ros2.settings import Ros2Settings
from sitl.demo import (
    closest_approach,
    demo_config,
    free_tcp_port,
    plan_async,
    running,
    start_holding,
    take_off,
    to_local,
)
from sitl.mavsdk_util import free_udp_port
from sitl.process import SimProcess
from sitl.proving import statuses_errors
from sitl.world import get_world
from tests.helpers.ros2 import BSPLINE, STRING_HASH, TS, RosPeer, open_session
from tests.helpers.ros2 import bspline_cdr as raw_bspline_cdr

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(240)]
SPEED = 2.0
CLOUD = "/map_generator/global_cloud"
MULTIDOF_HASH = "RIHS01_3a18fd095292a65cfde8833c72985a30af981f3ec44494655c6267262b443a4a"


#: (service settings, ROS peer, status key, re-timed key, tokens of the two subscriptions)
LAYOUTS = {
    "rmw_zenoh": ({}, {}, f"0/rota/status/std_msgs::msg::dds_::String_/{STRING_HASH}",
                  f"0/rota/retimed/trajectory_msgs::msg::dds_::MultiDOFJointTrajectory_/"
                  f"{MULTIDOF_HASH}", "@ros2_lv/0/*/0/*/MS/%/%/rota_companion/**"),
    "ros2dds": ({"namespace": "/bot1"}, {"namespace": "/bot1"}, "bot1/rota/status",
                "bot1/rota/retimed", "@/*/@ros2_lv/MS/**"),
}


# One flight, over rmw_zenoh; zenoh-bridge-ros2dds' keys, tokens and messages are
# checked in tests/companion/test_ros2_link.py without a flight (the suite's time budget).
@pytest.mark.parametrize("layout", ["rmw_zenoh"])
def test_ego_planner_over_zenoh_flies_the_forest(layout):
    world = get_world("forest", seed=3)
    mav, zport = free_udp_port(), free_tcp_port()
    extra, peer_kw, status_key, retimed_key, ms_tokens = LAYOUTS[layout]
    # the EGO-Planner layout of tests/companion/test_ros2_decode.py under traj_utils/msg/Bspline
    ros2 = {"enabled": True, "layout": layout, "pointcloud_topic": CLOUD,
            "bspline_msg": "ego-planner", **extra}
    statuses: queue.Queue = queue.Queue()
    retimed: queue.Queue = queue.Queue()

    async def scenario(gs, sim) -> dict:
        home = sim.home_enu
        ros = open_session(connect=f"tcp/127.0.0.1:{zport}")
        peer = RosPeer(ros, layout, **peer_kw)
        subs = [ros.declare_subscriber(status_key, lambda s: statuses.put(s.payload.to_bytes())),
                ros.declare_subscriber(retimed_key, lambda s: retimed.put(s.payload.to_bytes()))]
        try:
            await gs.wait_for(lambda st: st["state"] == "ready", 60, "the vehicle to be ready")
            # the service is on the ROS graph: its two subscriptions' tokens
            await asyncio.to_thread(peer.wait_tokens, ms_tokens, 2)
            s = Ros2Settings(enabled=True, bspline_msg="ego-planner")
            hb = TS.hash_rihs01(BSPLINE)
            bkey = peer.advertise("/planning/bspline", BSPLINE, "traj_utils::msg::dds_::Bspline_",
                                  hb)
            ckey = peer.advertise(CLOUD, "sensor_msgs/msg/PointCloud2",
                                  "sensor_msgs::msg::dds_::PointCloud2_",
                                  TS.hash_rihs01("sensor_msgs/msg/PointCloud2"))
            # the map, as the planner's global cloud (local ENU frame, origin at home), sent
            # again every 2 s until the service has it, as a planner's map publisher repeats
            cloud = pointcloud_cdr(world.voxel_points(0.1) - home, s)
            for attempt in range(15):
                peer.publish(ckey, cloud)
                try:
                    await gs.wait_for(lambda st: st.get("map_voxels"), 2, "the map over ROS")
                    break
                except TimeoutError:
                    if attempt == 14:
                        raise
            await take_off(gs)
            here = await start_holding(gs) + home  # the planner plans from the hold
            goal = np.array([world.goal[0], world.goal[1], here[2]])
            first = await plan_async(world, v_max=SPEED, a_max=2.0, start=here, goal=goal)
            peer.publish(bkey, bspline_cdr(to_local(first, home), s, traj_id=0))
            await gs.wait_for(lambda st: st.get("trajectory_id") == "bspline-0"
                              and (st.get("progress") or 0) > 0.35, 40, "bspline-0 under way")
            # a replan from the commanded state, as EGO-Planner does, and a broken one
            sp = gs.telemetry["setpoint"]
            new = await plan_async(world, v_max=SPEED, a_max=2.0,
                                   start=np.asarray(sp["position"]) + home, goal=goal,
                                   start_velocity=np.asarray(sp["velocity"]), strict=False)
            bad = to_local(first, home)
            cps = bad.control_points.copy()
            cps[5, 1] = np.nan
            peer.publish(bkey, raw_bspline_cdr(cps, dt=bad.knot_span))
            peer.publish(bkey, bspline_cdr(to_local(new, home), s, traj_id=1))
            goal = goal - home
            await gs.wait_for(
                lambda st: st.get("trajectory_id") == "bspline-1" or st.get("command") == "hold",
                30, "the replan")
            await gs.wait_for(
                lambda st: st.get("command") == "hold" and gs.telemetry.get("position")
                is not None and np.linalg.norm(np.asarray(gs.telemetry["position"]) - goal) < 0.5,
                90, "the goal")
            return {"statuses": list(gs.statuses)}
        finally:
            for sub in subs:
                sub.undeclare()
            peer.close()
            ros.close()

    with tempfile.TemporaryDirectory() as state:
        cfg = demo_config(mav, zport, SPEED, state, ros2=ros2)

        async def main():
            async with running(cfg) as (_service, gs):
                return await scenario(gs, sim)

        with SimProcess(port=mav, world="forest", seed=3) as sim:
            out = asyncio.run(main())
        # the flight record: ROS inputs on their own channel, every channel readable
        files = sorted((Path(state) / "records").glob("*.mcap"))
        recorded = list(read(files))
        flight = load(files)
    report = sim.report
    ros_in = [m for ch, _, m in recorded if ch == "ros2"]
    assert {m["input"] for m in ros_in} == {"trajectory", "map"}
    kinds = [TS.deserialize_cdr(base64.b64decode(m["cdr_base64"]), BSPLINE).traj_id
             for m in ros_in if m["input"] == "trajectory"]
    assert {0, 1, 17} <= set(kinds)  # both plans and the broken one, as received
    assert not [m for ch, _, m in recorded if ch == "trajectory"]  # JSON channel: JSON only
    assert len(flight.retimed) >= 2
    ids = {st.get("trajectory_id") for st in out["statuses"]} - {None}
    assert {"bspline-0", "bspline-1"} <= ids, ids
    errors = statuses_errors(out["statuses"])
    assert any("bspline /planning/bspline" in e and "pos_pts[5].y: must be finite" in e
               for e in errors), errors
    assert not report.collisions
    assert closest_approach(world, report) > 0
    # what a ROS 2 node on rmw_zenoh received: status (std_msgs/String) ...
    ros_status = [json.loads(TS.deserialize_cdr(b, "std_msgs/msg/String").data)
                  for b in drain(statuses)]
    assert {"offboard"} <= {st["state"] for st in ros_status}
    assert "bspline-1" in {st.get("trajectory_id") for st in ros_status}
    # ... and the re-timed trajectories (MultiDOFJointTrajectory), within the limits
    plans = [TS.deserialize_cdr(b, "trajectory_msgs/msg/MultiDOFJointTrajectory")
             for b in drain(retimed)]
    assert len(plans) >= 2
    for m in plans:
        v = np.array([[p.velocities[0].linear.x, p.velocities[0].linear.y,
                       p.velocities[0].linear.z] for p in m.points])
        assert m.header.frame_id == "world"
        assert np.linalg.norm(v, axis=1).max() <= SPEED + 1e-2
    voxels = max(st.get("map_voxels") or 0 for st in out["statuses"])
    print(f"{layout}: ROS map {voxels} voxels; flown {sorted(ids)}; {len(ros_status)} ROS "
          f"status and {len(plans)} re-timed messages received; closest approach "
          f"{closest_approach(world, report):.2f} m; rejected: "
          f"{next(e for e in errors if 'pos_pts' in e)}")


def drain(q: queue.Queue) -> list:
    out = []
    while not q.empty():
        out.append(q.get_nowait())
    return out
