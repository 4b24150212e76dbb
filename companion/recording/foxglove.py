"""The flight in Foxglove's terms: the map, the paths, the setpoints and the vehicle
as Foxglove's well-known messages (the schemas and encoders of ``foxglove-sdk``,
protobuf), and the figures to plot as JSON with their JSON Schemas.

:class:`Scene` turns the service's own messages (what the flight record holds and
Zenoh carries: ``map``, ``retimed``, ``setpoint``, ``telemetry``, ``config``,
``log``) into Foxglove messages. The flight record (:mod:`companion.recording.record`) writes
them beside its own channels, in its writer thread; ``rota-gs foxglove``
(:mod:`companion.gs.foxglove`) serves them live over Foxglove's WebSocket protocol.

Topics (frame ``map`` is the PX4 local frame, ENU, metres; ``base_link`` the vehicle):

=====================  ==============================  =====================================
topic                  message                         what
=====================  ==============================  =====================================
``/foxglove/map``      ``foxglove.SceneUpdate``        obstacles: one cube per vertical run
                                                       of occupied voxels (exactly the map)
``/foxglove/plan``     ``foxglove.SceneUpdate``        the planner's path (grey), the
                                                       re-timed path coloured by commanded
                                                       speed, its braking zones (orange)
``/foxglove/setpoint`` ``foxglove.PoseInFrame``        every setpoint sent (commanded heading)
``/foxglove/vehicle``  ``foxglove.PoseInFrame``        PX4's reported position
``/tf``                ``foxglove.FrameTransform``     ``map`` -> ``base_link``
``/foxglove/body``     ``foxglove.SceneUpdate``        the vehicle's body, in ``base_link``
``/foxglove/log``      ``foxglove.Log``                events, warnings, errors
``/plot/command``      JSON (``rota.plot.Command``)    per setpoint: commanded speed,
                                                       ``v_max``, chance-constrained limit
``/plot/vehicle``      JSON (``rota.plot.Vehicle``)    per telemetry: reported speed,
                                                       tracking error, its brake threshold
=====================  ==============================  =====================================

Telemetry carries no attitude: the vehicle's orientation is its commanded heading.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
from foxglove import messages as fm

MAP_FRAME, BODY_FRAME = "map", "base_link"
#: Colours (RGBA, 0-1): obstacles, the planner's path, braking zones.
OBSTACLE = (0.45, 0.42, 0.38, 1.0)
PLANNED = (0.6, 0.6, 0.6, 0.8)
ZONE = (1.0, 0.55, 0.0, 0.7)
#: Speed ramp for the re-timed path: stopped (blue) -> v_max (red).
SPEED_RAMP = np.array([[0.16, 0.33, 0.85], [0.1, 0.75, 0.35], [0.95, 0.85, 0.1],
                       [0.9, 0.15, 0.1]])
PATH_SAMPLES = 300

_LEVELS = {"DEBUG": fm.LogLevel.Debug, "INFO": fm.LogLevel.Info,
           "WARNING": fm.LogLevel.Warning, "ERROR": fm.LogLevel.Error,
           "CRITICAL": fm.LogLevel.Fatal}


def _number(description: str, nullable: bool = False) -> dict[str, Any]:
    kind: Any = ["number", "null"] if nullable else "number"
    return {"type": kind, "description": description}


#: The JSON Schemas of the plot channels (their messages validate against them).
PLOT_SCHEMAS: dict[str, dict[str, Any]] = {
    "rota.plot.Command": {
        "title": "rota.plot.Command", "type": "object",
        "description": "One setpoint sent to PX4, for plotting",
        "required": ["speed", "v_max", "chance_limit", "braking_zone", "plan"],
        "properties": {
            "speed": _number("commanded speed, m/s"),
            "v_max": _number("the speed limit in force ([limits] v_max), m/s", True),
            "chance_limit": _number("the plan's chance-constrained speed limit here, m/s "
                                    "(null where none applies)", True),
            "braking_zone": {"type": "boolean",
                             "description": "inside one of the plan's braking zones"},
            "plan": {"type": "string", "description": "plan id, hold or brake"},
        }},
    "rota.plot.Vehicle": {
        "title": "rota.plot.Vehicle", "type": "object",
        "description": "PX4's reported state, for plotting",
        "required": ["speed", "tracking_error", "brake_threshold"],
        "properties": {
            "speed": _number("reported speed, m/s", True),
            "tracking_error": _number("reported position - command, m (null when not "
                                      "streaming)", True),
            "brake_threshold": _number("[safety] max_tracking_error_m, m", True),
        }},
}


#: Every topic :class:`Scene` writes, and its message (a Foxglove class or a plot name).
TOPICS: dict[str, Any] = {
    "/foxglove/map": fm.SceneUpdate, "/foxglove/plan": fm.SceneUpdate,
    "/foxglove/body": fm.SceneUpdate, "/foxglove/setpoint": fm.PoseInFrame,
    "/foxglove/vehicle": fm.PoseInFrame, "/tf": fm.FrameTransform, "/foxglove/log": fm.Log,
    "/plot/command": "rota.plot.Command", "/plot/vehicle": "rota.plot.Vehicle"}


#: Topics whose last message stays in force (the map until the next one, the plan
#: until the next re-time, the body): a new part of a record starts with them again.
LATCHED = ("/foxglove/map", "/foxglove/plan", "/foxglove/body")


@dataclass(frozen=True)
class Schema:
    """How a topic is written: its schema (name, encoding, data) and message encoding."""

    name: str
    encoding: str
    data: bytes
    message_encoding: str


@dataclass(frozen=True)
class Out:
    """One Foxglove message: its topic, schema and encoded bytes."""

    topic: str
    schema: Schema
    data: bytes


_SCHEMAS: dict[str, Schema] = {}


def schema_of(kind: type | str) -> Schema:
    """The schema of a Foxglove message class, or of a plot channel by name."""
    key = kind if isinstance(kind, str) else kind.__name__
    if key not in _SCHEMAS:
        if isinstance(kind, str):
            _SCHEMAS[key] = Schema(key, "jsonschema", json.dumps(PLOT_SCHEMAS[key]).encode(),
                                   "json")
        else:
            s = kind.get_schema()
            _SCHEMAS[key] = Schema(s.name, s.encoding, bytes(s.data), "protobuf")
    return _SCHEMAS[key]


def _out(topic: str, message: Any) -> Out:
    return Out(topic, schema_of(type(message)), message.encode())


def _plot(topic: str, name: str, fields: dict[str, Any]) -> Out:
    return Out(topic, schema_of(name), json.dumps(fields, separators=(",", ":")).encode())


def _stamp(t: float) -> fm.Timestamp:
    return fm.Timestamp.from_epoch_secs(t)


def _v3(p: Any) -> fm.Vector3:
    return fm.Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2]))


def _p3(p: Any) -> fm.Point3:
    return fm.Point3(x=float(p[0]), y=float(p[1]), z=float(p[2]))


def _rgba(c: Any) -> fm.Color:
    return fm.Color(r=float(c[0]), g=float(c[1]), b=float(c[2]), a=float(c[3]))


def yaw_quaternion(yaw_ned_deg: float | None) -> tuple[float, float, float, float]:
    """(x, y, z, w): the rotation of a heading given as PX4 gives it (degrees
    clockwise from north) about ENU's z (anticlockwise from east)."""
    if yaw_ned_deg is None or not math.isfinite(yaw_ned_deg):
        return 0.0, 0.0, 0.0, 1.0
    yaw = math.pi / 2 - math.radians(yaw_ned_deg)
    return 0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)


def _quat(yaw_ned_deg: float | None) -> fm.Quaternion:
    x, y, z, w = yaw_quaternion(yaw_ned_deg)
    return fm.Quaternion(x=x, y=y, z=z, w=w)


def speed_colours(speed: np.ndarray, v_max: float) -> np.ndarray:
    """RGB of each speed on :data:`SPEED_RAMP`, from 0 to ``v_max``."""
    x = np.clip(np.asarray(speed, float) / max(v_max, 1e-6), 0.0, 1.0) * (len(SPEED_RAMP) - 1)
    nodes = np.arange(len(SPEED_RAMP))
    return np.stack([np.interp(x, nodes, SPEED_RAMP[:, k]) for k in range(3)], axis=1)


def voxel_boxes(occupied: np.ndarray, resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """Boxes covering exactly the occupied voxels: each vertical run of voxels in
    one column becomes one box. Returns (centres, heights), ``(n, 3)`` and ``(n,)``."""
    occ = np.asarray(occupied, float).reshape(-1, 3)
    if not len(occ):
        return np.zeros((0, 3)), np.zeros(0)
    base = occ.min(axis=0)  # a voxel centre: the others are whole voxels from it
    ijk = np.round((occ - base) / resolution).astype(np.int64)
    ijk = ijk[np.lexsort((ijk[:, 2], ijk[:, 1], ijk[:, 0]))]  # by x, then y, then z
    step = np.diff(ijk, axis=0)
    ijk = ijk[np.append(True, np.any(step != 0, axis=1))]  # each voxel once
    step = np.diff(ijk, axis=0)
    new_run = np.ones(len(ijk), bool)
    new_run[1:] = (step[:, 0] != 0) | (step[:, 1] != 0) | (step[:, 2] != 1)
    starts = np.flatnonzero(new_run)
    ends = np.append(starts[1:], len(ijk)) - 1
    lo, hi = ijk[starts], ijk[ends]
    centres = base + (lo + hi) / 2.0 * resolution
    heights = (hi[:, 2] - lo[:, 2] + 1) * resolution
    return centres, heights


@dataclass
class _Plan:
    t: np.ndarray  # real time of each node, from the plan's start
    tau: np.ndarray
    limits: np.ndarray  # chance-constrained limit per node (NaN: none)
    zones: list[tuple[float, float]]  # in trajectory time
    start: float | None = None  # UNIX time of its first setpoint


@dataclass(frozen=True, eq=False)
class PlanView:
    """A re-timed plan as :class:`Scene` draws it, in arrays only: made where the
    result is (the re-time worker, :func:`plan_view`) and drawn where ``rota`` is not
    loaded (the flight record's process)."""

    id: str
    status: str
    duration: float
    t: np.ndarray  # real time of each node
    tau: np.ndarray  # trajectory time of each node
    limits: np.ndarray  # chance-constrained limit per node (NaN: none)
    zones: tuple[tuple[float, float], ...]  # braking zones, in trajectory time
    planned: np.ndarray  # (PATH_SAMPLES, 3) the path as planned
    position: np.ndarray  # (PATH_SAMPLES, 3) the re-timed plan, evenly in time
    speed: np.ndarray  # (PATH_SAMPLES,) its commanded speed
    zone_paths: tuple[np.ndarray, ...]  # each braking zone's stretch of the path


def plan_view(res: Any, result: dict[str, Any]) -> PlanView:
    """The :class:`PlanView` of a :class:`rota.RetimeResult` ``res`` and its
    ``rota/result`` message ``result`` (for the id, status, limits and zones)."""
    limits = np.array([np.nan if x is None else x for x in
                       result.get("speed_limits") or [None] * len(res.t)], float)
    zones = tuple((float(a), float(b)) for a, b in result.get("braking_zones", []))
    traj = res.trajectory
    span = max(traj.domain[1] - traj.domain[0], 1e-9)
    sp = res.sample(np.linspace(0.0, res.duration, PATH_SAMPLES))
    return PlanView(
        id=str(result.get("id") or ""), status=str(result.get("status")),
        duration=float(res.duration), t=np.asarray(res.t, float),
        tau=np.asarray(res.tau, float), limits=limits, zones=zones,
        planned=traj.position(np.linspace(*traj.domain, PATH_SAMPLES)),
        position=np.asarray(sp.position), speed=np.linalg.norm(sp.velocity, axis=1),
        zone_paths=tuple(traj.position(np.linspace(a, b, max(2, int(40 * (b - a) / span) + 2)))
                         for a, b in zones))


class Scene:
    """Foxglove messages from the service's messages. Keeps what later messages
    need (the speed limit, the plans' limits and braking zones, the heading).
    Not thread-safe: one caller (the record's writer thread, or the live server)."""

    #: Cubes built between two calls of ``pause``.
    BATCH = 500

    def __init__(self, pause: Callable[[], None] = lambda: None) -> None:
        #: called between batches of a large scene: the record's writer thread sleeps
        #: there, so that the event loop streaming setpoints gets the GIL back at once
        self.pause = pause
        self.v_max: float | None = None
        self.brake_at: float | None = None
        self.plans: dict[str, _Plan] = {}
        self.yaw: float | None = None
        self._body_sent = False
        #: the last message of each :data:`LATCHED` topic (a new record part repeats them)
        self.latched: dict[str, Out] = {}

    def translate(self, channel: str, payload: Any, stamp: float) -> list[Out]:
        """The Foxglove messages for one of the service's messages (JSON bytes or
        its dict); none for the channels it does not show."""
        make = getattr(self, f"_{channel}", None)
        if make is None:
            return []
        if isinstance(payload, bytes | bytearray | memoryview):
            payload = json.loads(bytes(payload))
        drawn_apart = (channel == "map" and hasattr(payload, "occupied")) or \
            (channel == "plan" and isinstance(payload, PlanView))
        if not isinstance(payload, dict) and not drawn_apart:
            return []
        out = list(make(payload, stamp))
        for m in out:
            if m.topic in LATCHED:
                self.latched[m.topic] = m
        return out

    # ------------------------------------------------------------ per channel
    def _config(self, cfg: dict[str, Any], stamp: float) -> Iterator[Out]:
        cfg = cfg.get("config", cfg)
        self.v_max = _float(cfg.get("limits", {}).get("v_max"))
        self.brake_at = _float(cfg.get("safety", {}).get("max_tracking_error_m"))
        return iter(())

    def _map(self, vmap: Any, stamp: float) -> Iterator[Out]:
        """``vmap``: a :class:`rota.voxelmap.VoxelMap` or its ``rota/map`` dict."""
        if isinstance(vmap, dict):
            if "occupied" not in vmap or "resolution" not in vmap:
                return  # recorded by size only (too large), or not a map
            occupied, res = np.asarray(vmap["occupied"], float), float(vmap["resolution"])
        else:
            occupied, res = np.asarray(vmap.occupied, float), float(vmap.resolution)
        centres, heights = voxel_boxes(occupied, res)
        colour = _rgba(OBSTACLE)
        ident = fm.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
        cubes = []
        for k in range(0, len(centres), self.BATCH):
            cubes += [fm.CubePrimitive(pose=fm.Pose(position=_v3(c), orientation=ident),
                                       size=fm.Vector3(x=res, y=res, z=float(h)), color=colour)
                      for c, h in zip(centres[k:k + self.BATCH].tolist(),
                                      heights[k:k + self.BATCH].tolist(), strict=True)]
            self.pause()
        yield _out("/foxglove/map", fm.SceneUpdate(entities=[fm.SceneEntity(
            timestamp=_stamp(stamp), frame_id=MAP_FRAME, id="obstacles", cubes=cubes,
            metadata=[fm.KeyValuePair(key="voxels", value=str(len(occupied))),
                      fm.KeyValuePair(key="resolution_m", value=f"{res:g}")])]))

    def _retimed(self, result: dict[str, Any], stamp: float) -> Iterator[Out]:
        """A ``rota/result`` message: rebuilt with ``rota`` (the live view, old records)."""
        from rota.schema import result_from_dict

        if result.get("status") == "rejected" or "tau" not in result:
            return
        res, _ = result_from_dict(result)
        yield from self._plan(plan_view(res, result), stamp)

    def _plan(self, view: PlanView | None, stamp: float) -> Iterator[Out]:
        """A plan drawn from its :class:`PlanView` (arrays only)."""
        if not isinstance(view, PlanView):
            return
        self.plans[view.id] = _Plan(view.t, view.tau, view.limits, list(view.zones))
        v_top = self.v_max or float(view.speed.max(initial=0.0)) or 1.0
        rgb = speed_colours(view.speed, v_top)
        lines = [
            fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineStrip, thickness=0.04,
                             scale_invariant=False, points=[_p3(p) for p in view.planned.tolist()],
                             color=_rgba(PLANNED)),
            fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineStrip, thickness=0.1,
                             points=[_p3(p) for p in view.position.tolist()],
                             colors=[_rgba((*c, 1.0)) for c in rgb.tolist()]),
        ]
        for q in view.zone_paths:
            lines.append(fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineStrip,
                                          thickness=0.3, points=[_p3(p) for p in q.tolist()],
                                          color=_rgba(ZONE)))
        t = _stamp(stamp)
        meta = [fm.KeyValuePair(key=k, value=str(v)) for k, v in (
            ("plan", view.id), ("status", view.status),
            ("duration_s", f"{view.duration:.2f}"), ("braking_zones", len(view.zones)),
            ("colour", f"commanded speed, blue 0 to red {v_top:g} m/s"))]
        yield _out("/foxglove/plan", fm.SceneUpdate(entities=[
            fm.SceneEntity(timestamp=t, frame_id=MAP_FRAME, id="plan", lines=lines,
                           metadata=meta)]))

    def _setpoint(self, sp: dict[str, Any], stamp: float) -> Iterator[Out]:
        p, v = sp.get("p"), sp.get("v")
        if p is None:
            return
        self.yaw = _float(sp.get("yaw"))
        yield _out("/foxglove/setpoint", fm.PoseInFrame(
            timestamp=_stamp(stamp), frame_id=MAP_FRAME,
            pose=fm.Pose(position=_v3(p), orientation=_quat(self.yaw))))
        source = str(sp.get("source") or "")
        limit, in_zone = self._plan_at(source, stamp)
        speed = _norm(v) if v is not None else 0.0
        yield _plot("/plot/command", "rota.plot.Command", {
            "speed": round(speed, 4), "v_max": self.v_max, "chance_limit": limit,
            "braking_zone": in_zone, "plan": source})

    def _plan_at(self, source: str, stamp: float) -> tuple[float | None, bool]:
        """The chance-constrained limit and whether in a braking zone, ``stamp``
        into the plan ``source`` (timed from its first setpoint)."""
        plan = self.plans.get(source)
        if plan is None:
            return None, False
        if plan.start is None:
            plan.start = stamp
        t = stamp - plan.start
        tau = float(np.interp(t, plan.t, plan.tau))
        in_zone = any(a <= tau <= b for a, b in plan.zones)
        finite = np.isfinite(plan.limits)
        if not finite.any():
            return None, in_zone
        k = int(np.clip(np.searchsorted(plan.t, t), 0, len(plan.t) - 1))
        lim = float(np.interp(t, plan.t[finite], plan.limits[finite])) if finite[k] else None
        return (None if lim is None else round(lim, 4)), in_zone

    def _telemetry(self, tel: dict[str, Any], stamp: float) -> Iterator[Out]:
        p, v = tel.get("position"), tel.get("velocity")
        setpoint = tel.get("setpoint") or {}
        if setpoint.get("yaw_ned_deg") is not None:
            self.yaw = _float(setpoint["yaw_ned_deg"])
        t = _stamp(stamp)
        if p is not None:
            q = _quat(self.yaw)
            yield _out("/tf", fm.FrameTransform(timestamp=t, parent_frame_id=MAP_FRAME,
                                                child_frame_id=BODY_FRAME, translation=_v3(p),
                                                rotation=q))
            yield _out("/foxglove/vehicle", fm.PoseInFrame(
                timestamp=t, frame_id=MAP_FRAME, pose=fm.Pose(position=_v3(p), orientation=q)))
            if not self._body_sent:
                self._body_sent = True
                yield self.body(stamp)
        yield _plot("/plot/vehicle", "rota.plot.Vehicle", {
            "speed": None if v is None else round(_norm(v), 4),
            "tracking_error": _float(tel.get("tracking_error")),
            "brake_threshold": self.brake_at})

    def body(self, stamp: float) -> Out:
        """The vehicle's body, drawn in ``base_link`` (it moves with the transform)."""
        origin = fm.Pose(position=fm.Vector3(x=0.0, y=0.0, z=0.0),
                         orientation=fm.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0))
        return _out("/foxglove/body", fm.SceneUpdate(entities=[fm.SceneEntity(
            timestamp=_stamp(stamp), frame_id=BODY_FRAME, id="vehicle", frame_locked=True,
            cubes=[fm.CubePrimitive(pose=origin, size=fm.Vector3(x=0.45, y=0.45, z=0.1),
                                    color=_rgba((0.1, 0.1, 0.1, 0.9)))],
            arrows=[fm.ArrowPrimitive(pose=origin, shaft_length=0.4, shaft_diameter=0.05,
                                      head_length=0.15, head_diameter=0.12,
                                      color=_rgba((0.9, 0.1, 0.1, 1.0)))])]))

    def _log(self, entry: dict[str, Any], stamp: float) -> Iterator[Out]:
        yield _out("/foxglove/log", fm.Log(
            timestamp=_stamp(stamp), level=_LEVELS.get(str(entry.get("level")),
                                                       fm.LogLevel.Unknown),
            message=str(entry.get("message", "")), name=str(entry.get("logger", ""))))


def _norm(v: Any) -> float:
    return math.hypot(*(float(x) for x in v))


def _float(x: Any) -> float | None:
    try:
        f = float(x)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None
