"""ROS 2 message types: the standard definitions (ROS 2 Jazzy) that ``rosbags``
carries, plus the planner's B-spline registered from its ``.msg`` text. CDR
(de)serialisation and the RIHS01 type hashes of REP 2011 (the hash ``rosidl``
generates and ``rmw_zenoh`` puts in its key expressions) come from ``rosbags``;
nothing here parses CDR by hand.
"""

from __future__ import annotations

import functools
from pathlib import Path

from rosbags.typesys import get_types_from_msg
from rosbags.typesys.store import Typestore
from rosbags.typesys.stores import ros2_jazzy

PATH = "nav_msgs/msg/Path"
MULTIDOF = "trajectory_msgs/msg/MultiDOFJointTrajectory"
POINTCLOUD = "sensor_msgs/msg/PointCloud2"
STRING = "std_msgs/msg/String"

# The planners' Bspline.msg in ROS 2 syntax (ROS 1's `time` is builtin_interfaces/Time).
# EGO-Planner (ZJU-FAST-Lab/ego-planner, package ego_planner) and Fast-Planner
# (HKUST-Aerial-Robotics/Fast-Planner, package plan_manage) share one layout;
# ego-planner-swarm (package traj_utils; its ROS 2 port on Humble keeps it) adds a
# leading drone_id.
_EGO_PLANNER = """int32 order
int64 traj_id
builtin_interfaces/Time start_time
float64[] knots
geometry_msgs/Point[] pos_pts
float64[] yaw_pts
float64 yaw_dt
"""
#: Built-in Bspline layouts (``[ros2] bspline_msg``); anything else is a file path.
BSPLINE_MSGS = {"ego-planner": _EGO_PLANNER, "fast-planner": _EGO_PLANNER,
                "ego-planner-swarm": "int32 drone_id\n" + _EGO_PLANNER}
#: The planners' real message types and their upstream layouts: ``[ros2]
#: bspline_type`` chooses one (``bspline_msg = ""``, the default).
BSPLINE_PRESETS = {"traj_utils/msg/Bspline": "ego-planner-swarm",
                   "ego_planner/msg/Bspline": "ego-planner",
                   "plan_manage/msg/Bspline": "fast-planner"}
#: Fields the service reads from a Bspline, whatever else the definition has.
BSPLINE_FIELDS = ("order", "start_time", "knots", "pos_pts")


def bspline_layout(bspline_msg: str, typename: str) -> str:
    """The layout name or .msg path in force: ``bspline_msg``, or when it is empty
    the upstream layout of ``typename``; ``ValueError`` for an unknown type."""
    if bspline_msg:
        return bspline_msg
    if typename not in BSPLINE_PRESETS:
        raise ValueError(f"unknown Bspline type {typename!r}: the known ones are "
                         f"{', '.join(BSPLINE_PRESETS)}; for another planner's message set "
                         "bspline_msg to the path of its Bspline.msg")
    return BSPLINE_PRESETS[typename]


@functools.lru_cache(maxsize=8)
def bspline_definition(bspline_msg: str, typename: str) -> str:
    """The ``.msg`` text of the configured Bspline (a built-in variant or a file);
    ``ValueError`` if it cannot be read or lacks a field the service needs."""
    bspline_msg = bspline_layout(bspline_msg, typename)
    text = BSPLINE_MSGS.get(bspline_msg)
    if text is None:
        try:
            text = Path(bspline_msg).read_text()
        except OSError as exc:
            raise ValueError(f"neither a built-in definition ({', '.join(BSPLINE_MSGS)}) nor "
                             f"a readable .msg file: {bspline_msg!r} ({exc.strerror})") from None
    try:
        fields = get_types_from_msg(text, typename)[typename][1]
    except Exception as exc:  # noqa: BLE001 - rosbags raises its own parse errors
        why = " ".join(str(exc).split())
        raise ValueError(f"{bspline_msg!r} is not a valid .msg definition ({why})") from None
    missing = set(BSPLINE_FIELDS) - {name for name, _ in fields}
    if missing:
        raise ValueError(f"{bspline_msg!r} lacks the field(s) {', '.join(sorted(missing))}")
    return text


@functools.lru_cache(maxsize=16)
def typestore(bspline_msg: str = "ego-planner", bspline_type: str = "traj_utils/msg/Bspline",
              max_sequence: int = 2**32 - 1) -> Typestore:
    """ROS 2 Jazzy's types plus the Bspline. Sequences longer than ``max_sequence``
    are refused while deserialising, before any array is built (rosbags checks
    every sequence length against the cap and the bytes left)."""
    store = Typestore(ros2_jazzy, max_sequence_length=max_sequence)
    store.register(get_types_from_msg(bspline_definition(bspline_msg, bspline_type),
                                      bspline_type))
    return store


#: What ROS 2 Humble's rmw_zenoh writes where later distros put the type hash
#: (Humble's type support has no hashes: ros2/rmw_zenoh PR 388).
HUMBLE_HASH = "TypeHashNotSupported"


def type_hash(typename: str, bspline_msg: str = "ego-planner",
              bspline_type: str = "traj_utils/msg/Bspline", distro: str = "jazzy") -> str:
    """The type hash of ``distro``'s rmw_zenoh: RIHS01 (REP 2011), e.g.
    ``RIHS01_df66...`` for std_msgs/msg/String, on Jazzy and later; Humble's
    :data:`HUMBLE_HASH`."""
    if distro == "humble":
        return HUMBLE_HASH
    return typestore(bspline_msg, bspline_type).hash_rihs01(typename)


def dds_type_name(typename: str) -> str:
    """``pkg/msg/Name`` -> ``pkg::msg::dds_::Name_`` (the name DDS and rmw_zenoh use)."""
    pkg, kind, name = typename.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"
