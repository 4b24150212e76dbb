"""ROS input -> the service's validated trajectories and maps.

Pure module-level functions of ``(payload, cfg)``: picklable, so the service runs
them in its decoding worker, never on the event loop. Each one

1. refuses a payload larger than :func:`max_payload_bytes` (a constant-time check
   the Zenoh callback can make too);
2. deserialises the CDR with ``rosbags``, whose sequence-length cap
   (``[safety] max_trajectory_points``) refuses oversized arrays before they are
   built;
3. checks what JSON input is checked for: finite numbers (naming the ROS field,
   ``pos_pts[3].y``), ``header.frame_id`` against ``[ros2] frame_id`` (ROS frames are
   ENU, REP 103), stamp age, and then :func:`companion.messages.check_trajectory`
   (size, duration, planned speed, geofence).

Any problem raises :class:`companion.messages.Rejected` naming the topic and field.
"""

from __future__ import annotations

import math
import re
from typing import Any

import numpy as np

from companion.messages import Incoming, Rejected, check_age, check_trajectory
from companion.ros2.types import MULTIDOF, PATH, POINTCLOUD, typestore
from companion.settings.config import Config
from rota.errors import InputError
from rota.schema import Heading, TrajectoryMessage
from rota.trajectory import BSplineTrajectory, SampledTrajectory
from rota.voxelmap import VoxelMap

#: Generous serialized bytes per trajectory point / cloud point, for the size cap.
_BYTES_PER_POINT = {"bspline": 64, "path": 160, "multidof": 256, "pointcloud": 128}
_OVERHEAD = 4096
_SEQUENCE_SLACK = 16  # knots = points + order + 1
_FLOAT_FIELDS = {7: "f4", 8: "f8"}  # sensor_msgs/PointField FLOAT32, FLOAT64


def max_payload_bytes(kind: str, cfg: Config) -> int:
    """The largest payload of ``kind`` the size caps allow (check before decoding)."""
    cap = (cfg.ros2.max_cloud_points if kind == "pointcloud"
           else cfg.safety.max_trajectory_points)
    return _OVERHEAD + _BYTES_PER_POINT[kind] * cap


def _deserialize(payload: bytes, typename: str, kind: str, cfg: Config, what: str) -> Any:
    limit = max_payload_bytes(kind, cfg)
    if len(payload) > limit:
        raise Rejected(f"{what}: {len(payload)} bytes is more than the size caps allow "
                       f"({limit} bytes)")
    s = cfg.ros2
    cap = (2**32 - 1 if kind == "pointcloud"
           else cfg.safety.max_trajectory_points + _SEQUENCE_SLACK)
    try:
        return typestore(s.bspline_msg, s.bspline_type, cap).deserialize_cdr(payload, typename)
    except Exception as exc:  # noqa: BLE001 - rosbags raises several types for bad bytes
        raise Rejected(f"{what}: not a valid CDR {typename} or a sequence over "
                       f"{cap} elements ({type(exc).__name__}: {exc})") from None


def _stamp(t: Any, what: str, field: str) -> float | None:
    """builtin_interfaces/Time -> UNIX seconds; a zero stamp means "not stamped"."""
    if not 0 <= t.nanosec < 1_000_000_000:
        raise Rejected(f"{what}: {field}.nanosec: must be below 1e9, got {t.nanosec}")
    return None if t.sec == 0 and t.nanosec == 0 else t.sec + t.nanosec * 1e-9


def _check_frame(frame_id: str, cfg: Config, what: str, field: str) -> None:
    expected = cfg.ros2.frame_id
    if frame_id.lstrip("/") != expected.lstrip("/"):
        raise Rejected(f"{what}: {field}: {frame_id!r} is not the configured frame "
                       f"{expected!r} ([ros2] frame_id; inputs must be ENU in PX4's local "
                       "frame)")


def _finite(arr: np.ndarray, what: str, name: str, axes: str = "") -> None:
    """Raise naming the first non-finite entry: ``name`` is a format with ``{i}``."""
    bad = ~np.isfinite(arr)
    if bad.any():
        idx = np.argwhere(bad)[0]
        field = name.format(i=int(idx[0])) + (f".{axes[int(idx[1])]}" if axes else "")
        raise Rejected(f"{what}: {field}: must be finite, got {float(arr[tuple(idx)])}")


_PATH_RE = re.compile(r"(\w+)(?:\[(\d+)\])?(.*)")


def _ros_error(exc: InputError, what: str, names: dict[str, str]) -> Rejected:
    """A library error with its field renamed to the ROS message's field."""
    m = _PATH_RE.fullmatch(exc.field)
    if m and m.group(1) in names:
        template = names[m.group(1)]
        field = template.format(i=m.group(2)) if m.group(2) else template.split("[")[0]
        return Rejected(f"{what}: {field}{m.group(3)}: {exc.message}")
    return Rejected(f"{what}: {exc}")


def _vectors(items: Any) -> np.ndarray:
    """Points or vectors (``.x``, ``.y``, ``.z``) -> an ``(n, 3)`` array."""
    return np.array([[r.x, r.y, r.z] for r in items], dtype=float).reshape(-1, 3)


def _headed(payload: bytes, typename: str, kind: str, cfg: Config, what: str,
            items: str) -> tuple[Any, list[Any], float | None, str]:
    """A message with a header and a list ``items`` of at least 2: (message, list,
    stamp, id), its frame checked."""
    m = _deserialize(payload, typename, kind, cfg, what)
    _check_frame(m.header.frame_id, cfg, what, "header.frame_id")
    stamp = _stamp(m.header.stamp, what, "header.stamp")
    seq = getattr(m, items)
    if len(seq) < 2:
        raise Rejected(f"{what}: {items}: need at least 2, got {len(seq)}")
    return m, seq, stamp, message_id(kind, m)


def message_id(kind: str, m: Any) -> str:
    """The id a ROS trajectory gets (status, re-timed results): ``bspline-<traj_id>``, or
    ``<kind>-<header stamp>`` (``path-1718000000.250000000``)."""
    if kind == "bspline":
        return f"bspline-{m.traj_id}"
    return f"{kind}-{m.header.stamp.sec}.{m.header.stamp.nanosec:09d}"


def _finish(traj: Any, ident: str, stamp: float | None, what: str, cfg: Config,
            now: float | None, heading: Heading | None = None) -> Incoming:
    msg = TrajectoryMessage(traj, id=ident, frame="ENU", stamp=stamp, heading=heading)
    return check_trajectory(msg, cfg, f"{what} {ident!r}", now)


# ============================================================== trajectories
def decode_bspline(payload: bytes, cfg: Config, now: float | None = None) -> Incoming:
    """``traj_utils/Bspline`` (EGO-Planner, Fast-Planner): ``order`` is the degree,
    ``knots`` the full knot vector, ``pos_pts`` the control points, ``start_time``
    the stamp; ``yaw_pts`` (ENU radians), if any, the planner's heading at the
    trajectory's start plus k ``yaw_dt``: they are the control points of the
    planner's uniform yaw B-spline, which a smooth heading follows closely (the
    service streams it within its yaw limits; none: it faces along the path). A
    Bspline has no header: it is taken in ``[ros2] frame_id``."""
    s = cfg.ros2
    what = f"bspline {s.bspline_topic}"
    m = _deserialize(payload, s.bspline_type, "bspline", cfg, what)
    knots = np.asarray(m.knots, dtype=float)
    cps = _vectors(m.pos_pts)
    _finite(knots, what, "knots[{i}]")
    _finite(cps, what, "pos_pts[{i}]", "xyz")
    stamp = _stamp(m.start_time, what, "start_time")
    try:
        traj = BSplineTrajectory(control_points=cps, degree=int(m.order), knots=knots)
    except InputError as exc:
        raise _ros_error(exc, what, {"control_points": "pos_pts", "degree": "order",
                                     "knots": "knots[{i}]"}) from None
    heading = None
    yaw = np.asarray(m.yaw_pts, dtype=float)
    if len(yaw) > cfg.safety.max_trajectory_points:
        raise Rejected(f"{what}: yaw_pts: {len(yaw)} entries is over the cap of "
                       f"{cfg.safety.max_trajectory_points}")
    if len(yaw):
        _finite(yaw, what, "yaw_pts[{i}]")
        if not (math.isfinite(m.yaw_dt) and m.yaw_dt > 0):
            raise Rejected(f"{what}: yaw_dt: must be positive with yaw_pts, got {m.yaw_dt!r}")
        heading = Heading(tuple(np.degrees(yaw)), float(m.yaw_dt), traj.domain[0])
    return _finish(traj, message_id("bspline", m), stamp, what, cfg, now, heading)


def decode_path(payload: bytes, cfg: Config, now: float | None = None) -> Incoming:
    """``nav_msgs/Path``: the poses' positions as samples at their stamps (relative
    to the first). A path whose poses are all unstamped is timed by arc length at
    ``[limits] v_max`` (ROTA re-times it anyway). Orientations are not used."""
    what = f"path {cfg.ros2.path_topic}"
    _, poses, stamp, ident = _headed(payload, PATH, "path", cfg, what, "poses")
    for i, ps in enumerate(poses):
        if ps.header.frame_id:
            _check_frame(ps.header.frame_id, cfg, what, f"poses[{i}].header.frame_id")
    p = _vectors([ps.pose.position for ps in poses])
    _finite(p, what, "poses[{i}].pose.position", "xyz")
    stamps = [_stamp(ps.header.stamp, what, f"poses[{i}].header.stamp")
              for i, ps in enumerate(poses)]
    if all(t is None for t in stamps):
        keep = np.r_[True, np.any(np.diff(p, axis=0) != 0, axis=1)]
        p = p[keep]
        t = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))] \
            / cfg.limits.v_max
    else:
        if any(t is None for t in stamps):
            i = stamps.index(None)
            raise Rejected(f"{what}: poses[{i}].header.stamp: zero while others are stamped")
        t = np.asarray(stamps, dtype=float) - stamps[0]
    try:
        traj = SampledTrajectory(t=t, p=p)
    except InputError as exc:
        raise _ros_error(exc, what, {"t": "poses[{i}].header.stamp",
                                     "p": "poses"}) from None
    return _finish(traj, ident, stamp, what, cfg, now)


def decode_multidof(payload: bytes, cfg: Config, now: float | None = None) -> Incoming:
    """``trajectory_msgs/MultiDOFJointTrajectory``: the first joint's translations,
    with its linear velocities and accelerations where every point has them, at
    ``time_from_start``."""
    what = f"multidof {cfg.ros2.multidof_topic}"
    _, pts, stamp, ident = _headed(payload, MULTIDOF, "multidof", cfg, what, "points")
    for i, pt in enumerate(pts):
        if not pt.transforms:
            raise Rejected(f"{what}: points[{i}].transforms: empty (need the first joint's)")
    t = np.array([pt.time_from_start.sec + pt.time_from_start.nanosec * 1e-9 for pt in pts])
    p = _vectors([pt.transforms[0].translation for pt in pts])
    _finite(p, what, "points[{i}].transforms[0].translation", "xyz")
    v = a = None
    if all(pt.velocities for pt in pts):
        v = _vectors([pt.velocities[0].linear for pt in pts])
        _finite(v, what, "points[{i}].velocities[0].linear", "xyz")
        if all(pt.accelerations for pt in pts):
            a = _vectors([pt.accelerations[0].linear for pt in pts])
            _finite(a, what, "points[{i}].accelerations[0].linear", "xyz")
    try:
        traj = SampledTrajectory(t=t, p=p, v=v, a=a)
    except InputError as exc:
        raise _ros_error(exc, what, {
            "t": "points[{i}].time_from_start", "p": "points[{i}].transforms[0].translation",
            "v": "points[{i}].velocities[0].linear",
            "a": "points[{i}].accelerations[0].linear"}) from None
    return _finish(traj, ident, stamp, what, cfg, now)


# ====================================================================== map
def decode_pointcloud(payload: bytes, cfg: Config, now: float | None = None) -> VoxelMap:
    """``sensor_msgs/PointCloud2`` -> an occupancy map binned at ``[ros2]
    cloud_resolution``. ``x``, ``y``, ``z`` must be FLOAT32 or FLOAT64; points with
    a non-finite coordinate are dropped (ROS marks invalid points with NaN)."""
    s = cfg.ros2
    what = f"pointcloud {s.pointcloud_topic}"
    m = _deserialize(payload, POINTCLOUD, "pointcloud", cfg, what)
    _check_frame(m.header.frame_id, cfg, what, "header.frame_id")
    check_age(_stamp(m.header.stamp, what, "header.stamp"), cfg, what, now)
    n = int(m.width) * int(m.height)
    if n > s.max_cloud_points:
        raise Rejected(f"{what}: {n} points is over [ros2] max_cloud_points "
                       f"({s.max_cloud_points})")
    fields = {f.name: f for f in m.fields}
    order = ">" if m.is_bigendian else "<"
    names, formats, offsets = [], [], []
    for axis in "xyz":
        f = fields.get(axis)
        if f is None or f.datatype not in _FLOAT_FIELDS or f.count != 1:
            raise Rejected(f"{what}: fields: need {axis!r} as one FLOAT32 or FLOAT64, got "
                           f"{[(g.name, g.datatype, g.count) for g in m.fields]}")
        names.append(axis)
        formats.append(order + _FLOAT_FIELDS[f.datatype])
        offsets.append(int(f.offset))
    step, row = int(m.point_step), int(m.row_step)
    size = max(np.dtype(fmt).itemsize + off for fmt, off in zip(formats, offsets, strict=True))
    if step < size or row < step * int(m.width) or len(m.data) < row * int(m.height):
        raise Rejected(f"{what}: point_step {step}, row_step {row} and {len(m.data)} data "
                       f"bytes do not hold {m.width} x {m.height} points")
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets,
                      "itemsize": step})
    data = np.asarray(m.data, dtype=np.uint8)[: row * int(m.height)]
    rows = data.reshape(int(m.height), row)[:, : step * int(m.width)]
    pts = np.ascontiguousarray(rows).view(dtype).reshape(-1)
    xyz = np.column_stack([pts[a].astype(float) for a in "xyz"]).reshape(-1, 3)
    xyz = xyz[np.isfinite(xyz).all(axis=1)]
    vmap = VoxelMap.from_points(xyz, s.cloud_resolution)
    if len(vmap) > cfg.inputs.max_map_voxels:
        raise Rejected(f"{what}: {len(vmap)} occupied voxels at {s.cloud_resolution} m is "
                       f"over [inputs] max_map_voxels ({cfg.inputs.max_map_voxels})")
    return vmap


# ================================================================= mismatch
def wrong_type(payload: bytes, cfg: Config, now: float | None = None, *, what: str, got: str,
               want: str) -> Incoming:
    """Stands in for a decoder when a message arrives with another type hash than the
    service expects: a peer of another ROS 2 distribution (``[ros2] distro``), or the
    planner's message differs (``[ros2] bspline_type`` / ``bspline_msg``)."""
    from companion.ros2.types import HUMBLE_HASH

    ignored = f"{len(payload)} bytes ignored"
    if got == HUMBLE_HASH:
        raise Rejected(f"{what}: the publisher runs ROS 2 Humble (its rmw_zenoh writes "
                       f"{HUMBLE_HASH} where the type hash goes) and the service is set for "
                       'Jazzy or later: set [ros2] distro = "humble"; ' + ignored)
    if want == HUMBLE_HASH:
        raise Rejected(f"{what}: the publisher runs ROS 2 Jazzy, Kilted or Rolling (type hash "
                       f"{got}) and the service is set for Humble: set [ros2] distro = "
                       '"jazzy"; ' + ignored)
    raise Rejected(f"{what}: the publisher's type hash {got} is not {want}, the one of "
                   f"the definition configured ([ros2] bspline_type, bspline_msg: is it "
                   f"the planner's message?); " + ignored)
