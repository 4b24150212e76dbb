"""The service's Zenoh messages: parsing and validation of what comes in,
construction of what goes out. Formats: ``docs/protocol.md``.

Every incoming message is checked before it can touch the flight: JSON and
schema, finite numbers, frame, age, size, planned speed and geofence. A
rejected message raises :class:`Rejected` with a message naming the problem.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from companion.config import Config
from companion.frames import trajectory_to_enu
from rota.errors import InputError
from rota.schema import VERSION, TrajectoryMessage, trajectory_from_dict
from rota.trajectory import BSplineTrajectory, SampledTrajectory, Trajectory, Window
from rota.voxelmap import VoxelMap

STATUS = "rota/status"
TELEMETRY = "rota/telemetry"
REPLY = "rota/reply"
CONFIG = "rota/config"
COMMANDS = ("arm", "disarm", "takeoff", "start", "hold", "land", "abort")
MAX_DURATION_S = 3600.0


class Rejected(ValueError):
    """An incoming message was refused; ``str()`` says why."""


@dataclass(frozen=True)
class Incoming:
    """A validated trajectory, converted to ENU."""

    id: str
    trajectory: Trajectory
    frame: str
    stamp: float | None


def decode(payload: bytes, what: str) -> Any:
    try:
        return json.loads(payload)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise Rejected(f"{what}: not valid JSON ({exc})") from None


def _check_age(stamp: float | None, cfg: Config, what: str, now: float | None) -> None:
    if stamp is None:
        return
    age = (time.time() if now is None else now) - stamp
    limit = cfg.safety.max_message_age_s
    if age > limit:
        raise Rejected(f"{what}: stale, stamped {age:.2f} s ago (limit {limit} s)")
    if age < -limit:
        raise Rejected(f"{what}: stamped {-age:.2f} s in the future (clock skew?)")


def _points(traj: Trajectory) -> int:
    base = traj.base if isinstance(traj, Window) else traj
    if isinstance(base, BSplineTrajectory):
        return len(base.control_points)
    if isinstance(base, SampledTrajectory):
        return len(base.t)
    return int(np.asarray(getattr(base, "durations", [])).size)


def parse_trajectory(payload: bytes, cfg: Config, now: float | None = None) -> Incoming:
    """Decode and validate a ``rota/trajectory`` payload; the result is in ENU."""
    raw = decode(payload, "trajectory")
    try:
        msg: TrajectoryMessage = trajectory_from_dict(raw)
    except InputError as exc:
        raise Rejected(f"trajectory: {exc}") from None
    frame = msg.frame if "frame" in raw else cfg.safety.input_frame
    what = f"trajectory {msg.id!r}" if msg.id else "trajectory"
    _check_age(msg.stamp, cfg, what, now)
    if _points(msg.trajectory) > cfg.safety.max_trajectory_points:
        raise Rejected(f"{what}: too many points ({_points(msg.trajectory)} > "
                       f"{cfg.safety.max_trajectory_points})")
    if msg.trajectory.duration > MAX_DURATION_S:
        raise Rejected(f"{what}: duration {msg.trajectory.duration:.0f} s is over "
                       f"{MAX_DURATION_S:.0f} s")
    traj = trajectory_to_enu(msg.trajectory, frame)
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
    return Incoming(msg.id, traj, frame, msg.stamp)


def parse_map(payload: bytes, cfg: Config, now: float | None = None) -> VoxelMap:
    """Decode and validate a ``rota/map`` payload (ENU)."""
    raw = decode(payload, "map")
    try:
        vmap = VoxelMap.from_dict(raw)
    except InputError as exc:
        raise Rejected(f"map: {exc}") from None
    stamp = raw.get("stamp")
    if stamp is not None and (not isinstance(stamp, int | float) or not math.isfinite(stamp)):
        raise Rejected("map: stamp: must be a finite number (UNIX seconds)")
    _check_age(stamp, cfg, "map", now)
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
