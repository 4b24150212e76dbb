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

# EGO-Planner's traj_utils/Bspline (Fast-Planner's bspline/Bspline has the same
# fields) in ROS 2 syntax: ROS 1's `time` is builtin_interfaces/Time.
_EGO_PLANNER = """int32 order
int64 traj_id
builtin_interfaces/Time start_time
float64[] knots
geometry_msgs/Point[] pos_pts
float64[] yaw_pts
float64 yaw_dt
"""
#: Built-in Bspline definitions; ego-planner-swarm adds a leading drone_id.
BSPLINE_MSGS = {"ego-planner": _EGO_PLANNER,
                "ego-planner-swarm": "int32 drone_id\n" + _EGO_PLANNER}
#: Fields the service reads from a Bspline, whatever else the definition has.
BSPLINE_FIELDS = ("order", "start_time", "knots", "pos_pts")


@functools.lru_cache(maxsize=8)
def bspline_definition(bspline_msg: str, typename: str) -> str:
    """The ``.msg`` text of the configured Bspline (a built-in variant or a file);
    ``ValueError`` if it cannot be read or lacks a field the service needs."""
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


def type_hash(typename: str, bspline_msg: str = "ego-planner",
              bspline_type: str = "traj_utils/msg/Bspline") -> str:
    """The RIHS01 type hash, e.g. ``RIHS01_df66...`` for std_msgs/msg/String."""
    return typestore(bspline_msg, bspline_type).hash_rihs01(typename)


def dds_type_name(typename: str) -> str:
    """``pkg/msg/Name`` -> ``pkg::msg::dds_::Name_`` (the name DDS and rmw_zenoh use)."""
    pkg, kind, name = typename.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"
