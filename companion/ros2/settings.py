"""The ``[ros2]`` configuration section: which Zenoh layout, which ROS topics.

Topic names follow ROS 2's rules (``/planning/bspline``, or relative
``planning/bspline``); an empty topic turns that input or output off. Checked by
:func:`check` when the configuration loads, so a typo never silently subscribes
to nothing.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

LAYOUTS = ("rmw_zenoh", "ros2dds")
#: The maintained ROS 2 distributions. Their rmw_zenoh differ in one thing the service
#: meets: what it writes for a type hash, "humble" TypeHashNotSupported, the others
#: RIHS01 hashes (Jazzy, Kilted and Rolling speak alike).
DISTROS = ("humble", "jazzy", "kilted", "rolling")
#: Bspline message definitions built in (``bspline_msg``); anything else is a file path.
BSPLINE_VARIANTS = ("ego-planner", "ego-planner-swarm", "fast-planner")

_TOKEN = r"[A-Za-z_][A-Za-z0-9_]*"
_NAME = re.compile(rf"/?{_TOKEN}(/{_TOKEN})*")
_NAMESPACE = re.compile(rf"(/{_TOKEN})*/?")
_TYPE = re.compile(rf"{_TOKEN}/msg/{_TOKEN}")


@dataclass(frozen=True)
class Ros2Settings:
    """How the service meets ROS 2 (see ``docs/ros2.md``)."""

    enabled: bool = False  # subscribe and publish ROS topics on the service's Zenoh session
    layout: str = "rmw_zenoh"  # "rmw_zenoh" (ROS 2 with RMW_IMPLEMENTATION=rmw_zenoh_cpp)
    #                            or "ros2dds" (DDS-based ROS 2 behind zenoh-bridge-ros2dds)
    distro: str = "jazzy"  # the planner's ROS 2: "humble", "jazzy", "kilted" or "rolling"
    domain_id: int = 0  # ROS_DOMAIN_ID (part of every rmw_zenoh key expression)
    namespace: str = ""  # rmw_zenoh: the service node's namespace (resolves relative
    #                      topics); ros2dds: the bridge's `namespace` setting (prefixes all)
    node_name: str = "rota_companion"  # the node other ROS 2 tools see (rmw_zenoh)
    frame_id: str = "world"  # header.frame_id inputs must carry: ENU (REP 103), origin at
    #                          PX4's local origin. Bspline has no header and is taken as this.
    bspline_topic: str = "/planning/bspline"  # EGO-Planner / Fast-Planner B-splines in
    bspline_type: str = "traj_utils/msg/Bspline"  # the planner's message: traj_utils/msg/
    #   Bspline (ego-planner-swarm), ego_planner/msg/Bspline (EGO-Planner) or
    #   plan_manage/msg/Bspline (Fast-Planner), each read in its upstream layout
    bspline_msg: str = ""  # "" = bspline_type's upstream layout; else "ego-planner",
    #   "ego-planner-swarm" (with drone_id), "fast-planner" or the path of a Bspline.msg
    path_topic: str = ""  # nav_msgs/Path in (stamped poses as samples); "" = off
    multidof_topic: str = ""  # trajectory_msgs/MultiDOFJointTrajectory in; "" = off
    pointcloud_topic: str = ""  # sensor_msgs/PointCloud2 occupancy map in; "" = off
    cloud_resolution: float = 0.1  # m, voxel size the point cloud is binned to
    max_cloud_points: int = 2000000  # reject larger point clouds
    status_topic: str = "/rota/status"  # std_msgs/String (the JSON status) out; "" = off
    retimed_topic: str = "/rota/retimed"  # trajectory_msgs/MultiDOFJointTrajectory out
    retimed_rate_hz: float = 20.0  # sample rate of the re-timed trajectory message


def check(s: Ros2Settings) -> None:
    """Range and name checks; raises ``ValueError("[ros2] name: why")``."""

    def fail(name: str, why: str) -> None:
        raise ValueError(f"[ros2] {name}: {why}, got {getattr(s, name)!r}")

    if s.layout not in LAYOUTS:
        fail("layout", f"must be one of {', '.join(LAYOUTS)}")
    if s.distro not in DISTROS:
        fail("distro", f"must be one of {', '.join(DISTROS)}")
    if not 0 <= s.domain_id <= 232:
        fail("domain_id", "must be a ROS domain id from 0 to 232")
    if not _NAMESPACE.fullmatch(s.namespace):
        fail("namespace", "must be empty or a ROS namespace like /robot1")
    if not re.fullmatch(_TOKEN, s.node_name):
        fail("node_name", "must be a ROS node name (letters, digits, _)")
    if not s.frame_id or any(c in s.frame_id for c in " \t\n"):
        fail("frame_id", "must be a non-empty frame name")
    for name in ("bspline_topic", "path_topic", "multidof_topic", "pointcloud_topic",
                 "status_topic", "retimed_topic"):
        value = getattr(s, name)
        if value and not _NAME.fullmatch(value):
            fail(name, "must be empty or a ROS topic name like /planning/bspline")
    if not _TYPE.fullmatch(s.bspline_type):
        fail("bspline_type", "must be a ROS message type like traj_utils/msg/Bspline")
    if not math.isfinite(s.cloud_resolution) or s.cloud_resolution <= 0:
        fail("cloud_resolution", "must be positive")
    if s.max_cloud_points <= 0:
        fail("max_cloud_points", "must be positive")
    if not math.isfinite(s.retimed_rate_hz) or not 0 < s.retimed_rate_hz <= 1000:
        fail("retimed_rate_hz", "must be in (0, 1000]")
    if s.bspline_topic:
        from companion.ros2.types import bspline_definition

        try:
            bspline_definition(s.bspline_msg, s.bspline_type)
        except ValueError as exc:
            name = "bspline_msg" if s.bspline_msg else "bspline_type"
            raise ValueError(f"[ros2] {name}: {exc}") from None
