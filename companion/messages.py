"""The service's Zenoh messages: parsing and validation of what comes in,
construction of what goes out. Formats: ``docs/protocol.md``.

Every incoming message is checked before it can touch the flight: JSON and
schema, finite numbers, frame, age, size, planned speed and geofence. A
rejected message raises :class:`Rejected` with a message naming the problem.
"""

from __future__ import annotations

import json
import math
import re
import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from companion.flight.reaction import Timing
from companion.frames import SIGN, SWAP, ned_to_enu, yaw_ned_to_enu_deg
from companion.protocol import COMMANDS, CONFIG, REPLY, STATUS, TELEMETRY  # noqa: F401 - msgs.X
from companion.settings.config import Config
from rota.errors import InputError
from rota.schema import VERSION, Heading, TrajectoryMessage, trajectory_from_dict
from rota.trajectory import (
    BSplineTrajectory,
    PolynomialTrajectory,
    SampledTrajectory,
    Trajectory,
    Window,
)
from rota.voxelmap import VoxelMap

MAX_DURATION_S = 3600.0
MAX_ID_CHARS = 128
#: JSON values a trajectory message may hold per trajectory point (p, v, a, t and
#: brackets of a sample; 3 x 16 coefficients of a degree-15 polynomial segment are
#: counted as 16 points)
ITEMS_PER_POINT = 16
_STRING = re.compile(rb'"(?:[^"\\]|\\.)*"')


class Rejected(ValueError):
    """An incoming message was refused; ``str()`` says why."""


@dataclass(frozen=True)
class Incoming:
    """A validated trajectory, converted to ENU."""

    id: str
    trajectory: Trajectory
    frame: str
    stamp: float | None
    timing: Timing | None = None  #: its way through the service, for the reaction time
    heading: Heading | None = None  #: the planner's heading, ENU degrees


def decode(payload: bytes, what: str, max_depth: int = 16,
           max_items: int | None = None) -> Any:
    """JSON ``payload`` as Python objects. Nesting depth and the number of values
    are checked on the raw bytes first (strings blanked, then brackets and commas
    counted), so nothing large is built from a message over its caps."""
    shape = _STRING.sub(b'""', payload)
    b = np.frombuffer(shape, dtype=np.uint8)
    opens = (b == ord("[")) | (b == ord("{"))
    closes = (b == ord("]")) | (b == ord("}"))
    if b.size and int(np.cumsum(opens.astype(np.int32) - closes).max()) > max_depth:
        raise Rejected(f"{what}: nested deeper than {max_depth} levels")
    items = int(np.count_nonzero(b == ord(","))) + int(np.count_nonzero(opens))
    if max_items is not None and items > max_items:
        raise Rejected(f"{what}: {items} values is over the cap of {max_items}")
    try:
        return json.loads(payload)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise Rejected(f"{what}: not valid JSON ({exc})") from None
    except RecursionError:
        raise Rejected(f"{what}: nested too deeply") from None


def check_age(stamp: float | None, cfg: Config, what: str, now: float | None = None) -> None:
    """Reject a message stamped more than ``max_message_age_s`` ago (or ahead)."""
    if stamp is None:
        return
    age = (time.time() if now is None else now) - stamp
    limit = cfg.safety.max_message_age_s
    if age > limit:
        raise Rejected(f"{what}: stale, stamped {age:.2f} s ago (limit {limit} s)")
    if age < -limit:
        raise Rejected(f"{what}: stamped {-age:.2f} s in the future (clock skew?)")


def _points(traj: Trajectory) -> int:
    """Size of a trajectory in points: control points, samples, or polynomial
    coefficients per axis (segments x (degree + 1))."""
    base = traj.base if isinstance(traj, Window) else traj
    if isinstance(base, BSplineTrajectory):
        return len(base.control_points)
    if isinstance(base, SampledTrajectory):
        return len(base.t)
    if isinstance(base, PolynomialTrajectory):
        return int(base.coefficients.shape[0] * base.coefficients.shape[-1])
    return 0


def _precheck_trajectory(raw: Any, cfg: Config) -> None:
    """Counts of the raw message, before any array is built."""
    if not isinstance(raw, dict):
        return  # trajectory_from_dict names the problem
    cap = cfg.safety.max_trajectory_points
    for name in ("control_points", "t", "durations", "yaw"):
        value = raw.get(name)
        if isinstance(value, list) and len(value) > cap:
            raise Rejected(f"trajectory: {name}: {len(value)} entries is over the cap "
                           f"of {cap}")
    coeffs = raw.get("coefficients")
    if isinstance(coeffs, list) and coeffs and isinstance(coeffs[0], list) and coeffs[0] \
            and isinstance(coeffs[0][0], list):
        degree = len(coeffs[0][0]) - 1
        if degree > cfg.inputs.max_polynomial_degree:
            raise Rejected(f"trajectory: coefficients: degree {degree} is over the cap of "
                           f"{cfg.inputs.max_polynomial_degree}")
    ident = raw.get("id")
    if isinstance(ident, str) and len(ident) > MAX_ID_CHARS:
        raise Rejected(f"trajectory: id: {len(ident)} characters is over {MAX_ID_CHARS}")


def parse_trajectory(payload: bytes, cfg: Config, now: float | None = None) -> Incoming:
    """Decode and validate a ``rota/trajectory`` payload; the result is in ENU."""
    raw = decode(payload, "trajectory", cfg.inputs.max_json_depth,
                 ITEMS_PER_POINT * cfg.safety.max_trajectory_points + 1024)
    _precheck_trajectory(raw, cfg)
    try:
        msg: TrajectoryMessage = trajectory_from_dict(raw)
    except InputError as exc:
        raise Rejected(f"trajectory: {exc}") from None
    frame = msg.frame if "frame" in raw else cfg.safety.input_frame
    what = f"trajectory {msg.id!r}" if msg.id else "trajectory"
    return check_trajectory(replace(msg, frame=frame), cfg, what, now)


def check_trajectory(msg: TrajectoryMessage, cfg: Config, what: str,
                     now: float | None = None) -> Incoming:
    """The checks every trajectory passes, whatever format it came in: stamp and
    age, size, duration, planned speed and geofence; the result is in ENU."""
    if msg.stamp is None and cfg.safety.require_stamp:
        raise Rejected(f"{what}: no stamp (UNIX seconds); the service orders trajectories "
                       "by stamp ([safety] require_stamp = false if the planner has no clock)")
    check_age(msg.stamp, cfg, what, now)
    if _points(msg.trajectory) > cfg.safety.max_trajectory_points:
        raise Rejected(f"{what}: too many points ({_points(msg.trajectory)} > "
                       f"{cfg.safety.max_trajectory_points})")
    if msg.trajectory.duration > MAX_DURATION_S:
        raise Rejected(f"{what}: duration {msg.trajectory.duration:.0f} s is over "
                       f"{MAX_DURATION_S:.0f} s")
    traj = trajectory_to_enu(msg.trajectory, msg.frame)
    tau = np.linspace(*traj.domain, 2001)
    p, v, _ = traj.evaluate(tau)
    speed = float(np.linalg.norm(v, axis=1).max())
    if speed > cfg.safety.max_input_speed:
        raise Rejected(f"{what}: planned speed {speed:.1f} m/s is over the plausible "
                       f"{cfg.safety.max_input_speed} m/s (wrong units?)")
    lo, hi = np.asarray(cfg.safety.geofence_min), np.asarray(cfg.safety.geofence_max)
    out = np.any((p < lo) | (p > hi), axis=1)
    if out.any():
        i = int(np.argmax(out))
        raise Rejected(f"{what}: leaves the geofence at tau={tau[i]:.2f} s, position "
                       f"{np.round(p[i], 2).tolist()} (ENU; fence {lo.tolist()} to "
                       f"{hi.tolist()})")
    heading = msg.heading
    if heading is not None and msg.frame == "NED":
        heading = heading.mapped(yaw_ned_to_enu_deg)
    return Incoming(msg.id, traj, msg.frame, msg.stamp, heading=heading)


def parse_map(payload: bytes, cfg: Config, now: float | None = None) -> VoxelMap:
    """Decode and validate a ``rota/map`` payload (ENU)."""
    cap = cfg.inputs.max_map_voxels
    raw = decode(payload, "map", cfg.inputs.max_json_depth, 4 * cap + 1024)
    occupied = raw.get("occupied") if isinstance(raw, dict) else None
    if isinstance(occupied, list) and len(occupied) > cap:
        raise Rejected(f"map: occupied: {len(occupied)} voxels is over the cap of {cap}")
    try:
        vmap = VoxelMap.from_dict(raw)
    except InputError as exc:
        raise Rejected(f"map: {exc}") from None
    stamp = raw.get("stamp")
    if stamp is not None and (not isinstance(stamp, int | float) or not math.isfinite(stamp)):
        raise Rejected("map: stamp: must be a finite number (UNIX seconds)")
    check_age(stamp, cfg, "map", now)
    return vmap


def envelope(kind: str, **body: Any) -> dict[str, Any]:
    return {"schema": kind, "version": VERSION, "stamp": time.time(), **body}


def reply(command: str, ok: bool, message: str = "", **extra: Any) -> bytes:
    return dumps(envelope(REPLY, command=command, ok=ok, message=message, **extra))


def dumps(obj: Any) -> bytes:
    return json.dumps(obj, allow_nan=False, default=_jsonable).encode()


def _jsonable(x: Any) -> Any:
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, tuple):
        return list(x)
    raise TypeError(f"not JSON serialisable: {type(x).__name__}")


def vec(x: Any, digits: int = 4) -> list[float] | None:
    if x is None:
        return None
    return [round(float(v), digits) for v in np.asarray(x).ravel()]


def trajectory_to_enu(traj: Trajectory, frame: str) -> Trajectory:
    """The same path expressed in ENU (``frame`` is the one it is given in)."""
    if frame == "ENU":
        return traj
    if frame != "NED":
        raise ValueError(f"unknown frame {frame!r}")
    if isinstance(traj, Window):
        offset = None if traj.offset is None else ned_to_enu(traj.offset)
        return replace(traj, base=trajectory_to_enu(traj.base, frame), offset=offset)
    if isinstance(traj, BSplineTrajectory):
        return replace(traj, control_points=ned_to_enu(traj.control_points))
    if isinstance(traj, PolynomialTrajectory):
        c = traj.coefficients[:, SWAP, :] * SIGN[None, :, None]
        return replace(traj, coefficients=c)
    if isinstance(traj, SampledTrajectory):
        v = None if traj.v is None else ned_to_enu(traj.v)
        a = None if traj.a is None else ned_to_enu(traj.a)
        return replace(traj, p=ned_to_enu(traj.p), v=v, a=a)
    raise TypeError(f"cannot convert {type(traj).__name__}")
