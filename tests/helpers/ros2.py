"""ROS 2 messages as a ROS install writes them (CDR), and ROS peers over Zenoh."""

from __future__ import annotations

import json
import queue
import struct
import time

import numpy as np
import zenoh
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from companion.settings.config import from_dict

# The planners' Bspline.msg as their repositories have them (ROS 1 `time` written as
# ROS 2's builtin_interfaces/Time, as their ROS 2 ports do): EGO-Planner's and
# Fast-Planner's, and ego-planner-swarm's with its drone id
EGO_MSG = """int32 order
int64 traj_id
builtin_interfaces/Time start_time

float64[] knots
geometry_msgs/Point[] pos_pts

float64[] yaw_pts
float64 yaw_dt
"""
SWARM_MSG = "int32 drone_id\n\n" + EGO_MSG


BSPLINE = "traj_utils/msg/Bspline"


def store(msg: str = EGO_MSG):
    """A planner's view of the types: rosbags' Jazzy store plus its Bspline.msg."""
    ts = get_typestore(Stores.ROS2_JAZZY)
    ts.register(get_types_from_msg(msg, BSPLINE))
    return ts


TS = store()


T = TS.types


def cfg(**ros2):
    # EGO-Planner's layout under traj_utils/msg/Bspline, as the tests below build it
    ros2.setdefault("bspline_msg", "ego-planner")
    return from_dict({"ros2": {"enabled": True, "path_topic": "/path",
                               "multidof_topic": "/traj", "pointcloud_topic": "/cloud", **ros2},
                      "safety": {"geofence_min": [-30.0, -30.0, -1.0],
                                 "geofence_max": [30.0, 30.0, 5.0]}})


CFG = cfg()


def stamp(t: float | None = None):
    t = time.time() if t is None else t
    return T["builtin_interfaces/msg/Time"](sec=int(t), nanosec=int((t % 1) * 1e9))


def header(frame: str = "world", t: float | None = None):
    return T["std_msgs/msg/Header"](stamp=stamp(t), frame_id=frame)


def point(p):
    return T["geometry_msgs/msg/Point"](x=float(p[0]), y=float(p[1]), z=float(p[2]))


QUAT = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)


def vec3(p):
    return T["geometry_msgs/msg/Vector3"](x=float(p[0]), y=float(p[1]), z=float(p[2]))


CPS = np.array([[0, 0, 1], [0, 0, 1], [0, 0, 1], [1, 0.5, 1], [2, 1, 1.5], [3, 1, 1.5],
                [3, 1, 1.5], [3, 1, 1.5]], dtype=float)


DT = 0.4


def bspline_cdr(cps=CPS, order=3, dt=DT, t=None, ts=TS, yaw_pts=(), yaw_dt=None,
                **extra) -> bytes:
    """EGO-Planner's message: uniform knots starting at -order * dt (``yaw_pts``: ENU
    radians every ``yaw_dt``, default ``dt``)."""
    knots = (np.arange(len(cps) + order + 1) - order) * dt
    msg = ts.types[BSPLINE](order=order, traj_id=17, start_time=stamp(t), knots=knots,
                            pos_pts=[point(p) for p in cps],
                            yaw_pts=np.asarray(yaw_pts, dtype=float),
                            yaw_dt=dt if yaw_dt is None else yaw_dt, **extra)
    return bytes(ts.serialize_cdr(msg, BSPLINE))


# ------------------------------------------------------------------- path
def path_cdr(p, times=None, frame="world", pose_frame="") -> bytes:
    t0 = time.time()
    poses = []
    for i, q in enumerate(p):
        ts = None if times is None else t0 + times[i]
        pose = T["geometry_msgs/msg/Pose"](
            position=point(q), orientation=QUAT)
        h = T["std_msgs/msg/Header"](stamp=stamp(ts) if ts is not None else
                                     T["builtin_interfaces/msg/Time"](sec=0, nanosec=0),
                                     frame_id=pose_frame)
        poses.append(T["geometry_msgs/msg/PoseStamped"](header=h, pose=pose))
    msg = T["nav_msgs/msg/Path"](header=header(frame, t0), poses=poses)
    return bytes(TS.serialize_cdr(msg, "nav_msgs/msg/Path"))


# --------------------------------------------------------------- multidof
def twist(x):
    return [T["geometry_msgs/msg/Twist"](linear=vec3(x), angular=vec3([0, 0, 0]))]


def multidof_cdr(p, v=None, a=None, dt=0.5, frame="world") -> bytes:
    pts = []
    for i, q in enumerate(p):
        tf = T["geometry_msgs/msg/Transform"](translation=vec3(q), rotation=QUAT)
        pts.append(T["trajectory_msgs/msg/MultiDOFJointTrajectoryPoint"](
            transforms=[tf], velocities=[] if v is None else twist(v[i]),
            accelerations=[] if a is None else twist(a[i]),
            time_from_start=T["builtin_interfaces/msg/Duration"](
                sec=int(i * dt), nanosec=int(round((i * dt % 1) * 1e9)))))
    msg = T["trajectory_msgs/msg/MultiDOFJointTrajectory"](
        header=header(frame), joint_names=["base_link"], points=pts)
    return bytes(TS.serialize_cdr(msg, "trajectory_msgs/msg/MultiDOFJointTrajectory"))


STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"


ZID = "aac3178e146ba6f1fc6e6a4085e77f21"  # the session id of the design document's examples


def open_session(listen: str | None = None, connect: str | None = None) -> zenoh.Session:
    c = zenoh.Config()
    c.insert_json5("mode", '"peer"')
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("listen/endpoints", json.dumps([listen] if listen else []))
    c.insert_json5("connect/endpoints", json.dumps([connect] if connect else []))
    return zenoh.open(c)


class RosPeer:
    """What a ROS 2 process puts on Zenoh, written from the documents (not from
    companion.ros2.layout): an rmw_zenoh node, or a zenoh-bridge-ros2dds."""

    def __init__(self, session: zenoh.Session, layout: str, node: str = "ego_planner_node",
                 domain: int = 0, namespace: str = "") -> None:
        self.s, self.layout, self.node, self.domain, self.ns = (session, layout, node, domain,
                                                                 namespace)
        self.zid = str(session.zid())
        self.tokens = []
        self.seq = 0
        self.gid = bytes(range(100, 116))
        if layout == "rmw_zenoh":  # @ros2_lv/<domain>/<zid>/<nid>/<nid>/NN/<enclave>/<ns>/<node>
            self.declare(f"@ros2_lv/{domain}/{self.zid}/0/0/NN/%/%/{node}")
        else:  # the bridge's own token
            self.declare(f"@/{self.zid}/@ros2_lv")

    def declare(self, token: str) -> None:
        self.tokens.append(self.s.liveliness().declare_token(token))

    def key(self, topic: str, dds_type: str, type_hash: str) -> str:
        if self.layout == "rmw_zenoh":
            return f"{self.domain}/{topic.strip('/')}/{dds_type}/{type_hash}"
        return "/".join(p for p in (self.ns.strip("/"), topic.strip("/")) if p)

    def advertise(self, topic: str, ros_type: str, dds_type: str, type_hash: str,
                  kind: str = "MP") -> str:
        """Declare the publisher's (or subscription's) token; return the data key."""
        if self.layout == "rmw_zenoh":
            self.declare(f"@ros2_lv/{self.domain}/{self.zid}/0/{10 + len(self.tokens)}/{kind}/"
                         f"%/%/{self.node}/{topic.replace('/', '%')}/{dds_type}/{type_hash}/"
                         "::,10:,:,:,,")
        else:
            key = self.key(topic, dds_type, type_hash).replace("/", "§")
            self.declare(f"@/{self.zid}/@ros2_lv/{kind}/{key}/{ros_type.replace('/', '§')}/"
                         f":1:0:0,10:typehash={type_hash};")
        return self.key(topic, dds_type, type_hash)

    def publish(self, key: str, cdr: bytes) -> None:
        if self.layout == "rmw_zenoh":  # int64 seq, int64 time ns (LE), GID length + GID
            self.seq += 1
            att = struct.pack("<qqB16s", self.seq, time.time_ns(), 16, self.gid)
            self.s.put(key, cdr, attachment=att)
        else:
            self.s.put(key, cdr)

    def wait_tokens(self, pattern: str, n: int, timeout: float = 10.0) -> set[str]:
        end = time.monotonic() + timeout
        found: set[str] = set()
        while time.monotonic() < end:
            found = {str(r.ok.key_expr) for r in self.s.liveliness().get(pattern, timeout=1.0)
                     if r.ok is not None}
            if len(found) >= n:
                return found
            time.sleep(0.05)
        raise TimeoutError(f"{len(found)} of {n} tokens on {pattern}: {found}")

    def wait_gone(self, pattern: str, timeout: float = 10.0) -> None:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if not [r for r in self.s.liveliness().get(pattern, timeout=1.0) if r.ok]:
                return
            time.sleep(0.05)
        raise TimeoutError(f"tokens on {pattern} still there")

    def close(self) -> None:
        for t in self.tokens:
            t.undeclare()


class Inbox:
    def __init__(self) -> None:
        self.q: queue.Queue = queue.Queue()

    def __call__(self, kind, fn, payload) -> None:
        self.q.put((kind, fn, payload))

    def get(self, timeout: float = 10.0):
        return self.q.get(timeout=timeout)


def bspline_fields() -> dict:
    """The Bspline of ``bspline_cdr(t=T0)`` in ROS field names."""
    knots = (np.arange(len(CPS) + 4) - 3) * DT
    return {"order": 3, "traj_id": 17, "start_time": {"sec": 1718000000, "nanosec": 250000000},
            "knots": knots.tolist(), "pos_pts": [dict(zip("xyz", p, strict=True)) for p in
                                                 CPS.tolist()],
            "yaw_pts": [], "yaw_dt": DT}


def echo_yaml(fields: dict) -> str:
    """How ``ros2 topic echo --once`` prints a Bspline (block style, then ``---``)."""
    f = fields
    lines = [f"order: {f['order']}", f"traj_id: {f['traj_id']}", "start_time:",
             f"  sec: {f['start_time']['sec']}", f"  nanosec: {f['start_time']['nanosec']}",
             "knots:", *(f"- {k!r}" for k in f["knots"]), "pos_pts:"]
    for p in f["pos_pts"]:
        lines += [f"- x: {p['x']!r}", f"  y: {p['y']!r}", f"  z: {p['z']!r}"]
    lines += ["yaw_pts: []", f"yaw_dt: {f['yaw_dt']!r}", "---"]
    return "\n".join(lines) + "\n"
