"""ROS messages out, as CDR (little-endian, with its 4-byte encapsulation header) by
``rosbags``: the service's status and re-timed trajectory, and, for planners and
tests that hold a trajectory or a map, the messages a ROS planner would send.

Pure functions, so the service may run them in a worker process as well.
"""

from __future__ import annotations

import json
import math
import time
from typing import Any

import numpy as np
from rosbags.typesys.base import Nodetype

from companion.ros2.settings import Ros2Settings
from companion.ros2.types import MULTIDOF, POINTCLOUD, STRING, typestore
from rota.result import RetimeResult
from rota.schema import result_from_dict
from rota.trajectory import BSplineTrajectory

#: The joint of the re-timed MultiDOFJointTrajectory (the vehicle's body).
JOINT = "base_link"


def _types(s: Ros2Settings) -> Any:
    return typestore(s.bspline_msg, s.bspline_type)


def ros_time(types: dict[str, Any], t: float, kind: str = "Time") -> Any:
    sec = math.floor(t)
    return types[f"builtin_interfaces/msg/{kind}"](
        sec=int(sec), nanosec=min(int(round((t - sec) * 1e9)), 999_999_999))


def _vec(types: dict[str, Any], name: str, v: np.ndarray) -> Any:
    return types[f"geometry_msgs/msg/{name}"](x=float(v[0]), y=float(v[1]), z=float(v[2]))


def _header(types: dict[str, Any], s: Ros2Settings, stamp: float | None) -> Any:
    return types["std_msgs/msg/Header"](stamp=ros_time(types, time.time() if stamp is None
                                                    else stamp), frame_id=s.frame_id)


def status_cdr(status: dict[str, Any], s: Ros2Settings) -> bytes:
    """The ``rota/status`` JSON in a ``std_msgs/String`` (``ros2 topic echo`` shows it)."""
    store = _types(s)
    msg = store.types[STRING](data=json.dumps(status, allow_nan=False, default=str))
    return bytes(store.serialize_cdr(msg, STRING))


def retimed_cdr(result: RetimeResult, s: Ros2Settings, stamp: float | None = None) -> bytes:
    """The re-timed trajectory as ``trajectory_msgs/MultiDOFJointTrajectory``: joint
    ``base_link``, sampled at ``[ros2] retimed_rate_hz`` with position, velocity and
    acceleration (ENU, ``[ros2] frame_id``); ``time_from_start`` counts from the start of
    the re-timed trajectory; orientation is identity (the yaw is the service's own)."""
    store = _types(s)
    t = store.types
    sp = result.sample_rate(s.retimed_rate_hz)
    zero = np.zeros(3)
    rot = t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
    points = [t["trajectory_msgs/msg/MultiDOFJointTrajectoryPoint"](
        transforms=[t["geometry_msgs/msg/Transform"](
            translation=_vec(t, "Vector3", sp.position[i]), rotation=rot)],
        velocities=[t["geometry_msgs/msg/Twist"](linear=_vec(t, "Vector3", sp.velocity[i]),
                                                 angular=_vec(t, "Vector3", zero))],
        accelerations=[t["geometry_msgs/msg/Twist"](
            linear=_vec(t, "Vector3", sp.acceleration[i]), angular=_vec(t, "Vector3", zero))],
        time_from_start=ros_time(t, float(sp.t[i]), "Duration")) for i in range(len(sp.t))]
    msg = t[MULTIDOF](header=_header(t, s, stamp), joint_names=[JOINT], points=points)
    return bytes(store.serialize_cdr(msg, MULTIDOF))


def retimed_cdr_from_json(payload: bytes, s: Ros2Settings) -> bytes:
    """:func:`retimed_cdr` of a ``rota/result`` message (the service's ``retimed``)."""
    result, _ = result_from_dict(json.loads(payload))
    return retimed_cdr(result, s)


# ============================================================ planner side
def bspline_cdr(traj: BSplineTrajectory, s: Ros2Settings, traj_id: int = 0,
                stamp: float | None = None, **fields: Any) -> bytes:
    """The ``[ros2] bspline_type`` message EGO-Planner would send for ``traj``
    (``fields``: any other fields of the definition, e.g. ``drone_id``)."""
    store = _types(s)
    t = store.types
    if "drone_id" in t[s.bspline_type].__dataclass_fields__:
        fields.setdefault("drone_id", 0)  # ego-planner-swarm's
    msg = t[s.bspline_type](
        order=int(traj.degree), traj_id=int(traj_id),
        start_time=ros_time(t, time.time() if stamp is None else stamp),
        knots=np.asarray(traj.knot_vector, dtype=float),
        pos_pts=[_vec(t, "Point", p) for p in traj.control_points],
        yaw_pts=np.zeros(0), yaw_dt=float(traj.knot_span or 0.0), **fields)
    return bytes(store.serialize_cdr(msg, s.bspline_type))


def pointcloud_cdr(points: np.ndarray, s: Ros2Settings, stamp: float | None = None) -> bytes:
    """An unorganised ``sensor_msgs/PointCloud2`` of FLOAT32 ``x``, ``y``, ``z``."""
    store = _types(s)
    t = store.types
    xyz = np.ascontiguousarray(np.asarray(points, dtype="<f4").reshape(-1, 3))
    fields = [t["sensor_msgs/msg/PointField"](name=a, offset=4 * k, datatype=7, count=1)
              for k, a in enumerate("xyz")]
    msg = t[POINTCLOUD](header=_header(t, s, stamp), height=1, width=len(xyz), fields=fields,
                        is_bigendian=False, point_step=12, row_step=12 * len(xyz),
                        data=np.frombuffer(xyz.tobytes(), dtype=np.uint8), is_dense=True)
    return bytes(store.serialize_cdr(msg, POINTCLOUD))


# ===================================================== from ROS field names
_FLOATS = {"float32": "<f4", "float64": "<f8"}
_INTS = {"int8": "<i1", "int16": "<i2", "int32": "<i4", "int64": "<i8", "uint8": "<u1",
         "uint16": "<u2", "uint32": "<u4", "uint64": "<u8", "byte": "<u1", "char": "<u1",
         "octet": "<u1"}


def message_from_dict(typename: str, data: Any, s: Ros2Settings) -> Any:
    """A ``typename`` message from nested dicts and lists in ROS field names, as
    ``ros2 topic echo`` prints it (YAML); fields left out take their defaults, as with
    ``ros2 topic pub``. ``ValueError`` names the field, e.g. ``pos_pts[3].y: must be a
    number, got 'a'``. The message is built from the definitions ``rosbags`` holds."""
    store = _types(s)
    return _struct(store, typename, data, "")


def _fail(where: str, why: str) -> ValueError:
    return ValueError(f"{where or 'message'}: {why}")


def _struct(store: Any, typename: str, value: Any, where: str) -> Any:
    fields = dict(store.fielddefs[typename][1])
    if not isinstance(value, dict):
        raise _fail(where, f"must be a {typename} (a mapping of {', '.join(fields)}), "
                    f"got {value!r:.60}")
    unknown = [k for k in value if k not in fields]
    if unknown:
        raise _fail(f"{where}.{unknown[0]}".lstrip("."),
                    f"not a field of {typename} (its fields: {', '.join(fields)})")
    return store.types[typename](**{
        name: (_value(store, desc, value[name], f"{where}.{name}".lstrip("."))
               if name in value else _default(store, desc)) for name, desc in fields.items()})


def _value(store: Any, desc: Any, value: Any, where: str) -> Any:
    kind, detail = desc
    if kind == Nodetype.NAME:
        return _struct(store, detail, value, where)
    if kind == Nodetype.BASE:
        return _base(detail[0], value, where)
    sub, length = detail  # ARRAY: its length; SEQUENCE: its bound (0: none)
    if not isinstance(value, list):
        raise _fail(where, f"must be a list, got {value!r:.60}")
    if any(isinstance(v, str) and v == "..." for v in value):
        raise _fail(where, "cut short with '...' (ros2 topic echo shortens long arrays: "
                    "echo with --full-length)")
    if kind == Nodetype.ARRAY and len(value) != length:
        raise _fail(where, f"must have {length} elements, got {len(value)}")
    if kind == Nodetype.SEQUENCE and length and len(value) > length:
        raise _fail(where, f"must have at most {length} elements, got {len(value)}")
    items = [_value(store, sub, v, f"{where}[{i}]") for i, v in enumerate(value)]
    dtype = _dtype(sub)
    return items if dtype is None else np.array(items, dtype=dtype)


def _base(base: str, value: Any, where: str) -> Any:
    if base == "string":
        if not isinstance(value, str):
            raise _fail(where, f"must be a string, got {value!r:.60}")
        return value
    if base == "bool":
        if not isinstance(value, bool):
            raise _fail(where, f"must be true or false, got {value!r:.60}")
        return value
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise _fail(where, f"must be a number, got {value!r:.60}")
    if base in _FLOATS:
        if base == "float32" and math.isfinite(value) and abs(value) > np.finfo("f4").max:
            raise _fail(where, f"must fit a float32, got {value!r}")
        return float(value)
    info = np.iinfo(_INTS[base])
    if not isinstance(value, int) or not info.min <= value <= info.max:
        raise _fail(where, f"must be an integer from {info.min} to {info.max} ({base}), "
                    f"got {value!r}")
    return value


def _dtype(desc: Any) -> str | None:
    """The numpy dtype rosbags keeps an array of ``desc`` in (None: a list)."""
    kind, detail = desc
    if kind != Nodetype.BASE or detail[0] == "string":
        return None
    return "bool" if detail[0] == "bool" else _FLOATS.get(detail[0]) or _INTS[detail[0]]


def _default(store: Any, desc: Any) -> Any:
    kind, detail = desc
    if kind == Nodetype.NAME:
        return store.types[detail](**{name: _default(store, d)
                                       for name, d in store.fielddefs[detail][1]})
    if kind == Nodetype.BASE:
        return {"string": "", "bool": False}.get(detail[0], 0.0 if detail[0] in _FLOATS else 0)
    sub, length = detail
    n = length if kind == Nodetype.ARRAY else 0
    dtype = _dtype(sub)
    return [_default(store, sub) for _ in range(n)] if dtype is None else np.zeros(n, dtype)
