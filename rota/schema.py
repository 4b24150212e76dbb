"""Versioned JSON messages shared by the ``rota`` CLI and the flight service.

Documented in ``docs/protocol.md``. Every message is a JSON object with
``"schema"`` (its kind) and ``"version"``; readers reject unknown kinds and
versions, and every validation error names the offending field with a path such
as ``control_points[3][1]``.

Kinds defined here: ``rota/trajectory`` (input) and ``rota/result`` (output).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rota.errors import InputError
from rota.jerkmap import JerkTimeMap
from rota.result import Diagnostics, Outcome, RetimeResult
from rota.solver import SolverStats
from rota.timemap import TimeMap
from rota.trajectory import (
    BSplineTrajectory,
    PolynomialTrajectory,
    SampledTrajectory,
    Trajectory,
    Window,
)

VERSION = 1
TRAJECTORY = "rota/trajectory"
RESULT = "rota/result"
FRAMES = ("ENU", "NED")


@dataclass(frozen=True)
class Heading:
    """The planner's heading along a trajectory: ``yaw_deg[k]`` at trajectory time
    ``t0 + k dt`` (degrees, in the message's frame: ENU counter-clockwise from east,
    NED clockwise from north), as EGO-Planner's ``yaw_pts`` / ``yaw_dt``. Between
    samples it turns the short way (linearly, unwrapped); before the first and after
    the last it holds them. Not part of the re-timing: the flight service streams it
    within its yaw-rate and yaw-acceleration limits."""

    yaw_deg: tuple[float, ...]
    dt: float
    t0: float = 0.0

    def __post_init__(self) -> None:
        yaw = np.asarray(self.yaw_deg, dtype=float)
        if yaw.ndim != 1 or not len(yaw) or not np.all(np.isfinite(yaw)):
            raise InputError("yaw", "must be a non-empty list of finite numbers (degrees)")
        if not (math.isfinite(self.dt) and self.dt > 0):
            raise InputError("yaw_dt", f"must be a positive number (s), got {self.dt!r}")
        object.__setattr__(self, "yaw_deg", tuple(float(y) for y in yaw))
        # (the short way between samples, and the samples' times: once, not per call)
        object.__setattr__(self, "_unwrapped", np.degrees(np.unwrap(np.radians(yaw))))
        object.__setattr__(self, "_times", np.arange(len(yaw)) * self.dt + self.t0)

    def at(self, tau: float) -> float:
        """The heading (degrees, -180 to 180) at trajectory time ``tau``."""
        yaw = np.interp(tau, self._times, self._unwrapped)  # type: ignore[attr-defined]
        return float((yaw + 180.0) % 360.0 - 180.0)

    def mapped(self, fn: Any) -> Heading:
        """The same heading with each sample mapped by ``fn`` (e.g. to another frame)."""
        return Heading(tuple(fn(y) for y in self.yaw_deg), self.dt, self.t0)


@dataclass(frozen=True)
class TrajectoryMessage:
    """A trajectory with its envelope: id, coordinate frame and time stamp, and the
    planner's heading if it sends one."""

    trajectory: Trajectory
    id: str = ""
    frame: str = "ENU"
    stamp: float | None = None  # UNIX time (s) at which the planner published it
    heading: Heading | None = None


#: The fields of a trajectory message: every kind's, then each ``type``'s own.
TRAJECTORY_FIELDS = ("schema", "version", "id", "frame", "stamp", "type", "start",
                     "start_offset", "start_blend", "yaw", "yaw_dt")
TYPE_FIELDS = {"bspline": ("degree", "control_points", "knot_span", "knots"),
               "polynomial": ("durations", "coefficients"),
               "samples": ("t", "p", "v", "a")}
#: The fields of a result message (:func:`result_to_dict`).
RESULT_FIELDS = ("schema", "version", "id", "frame", "status", "message", "warnings",
                 "duration", "input_duration", "tau", "beta", "t", "speed_limits", "solver",
                 "braking_zones", "trajectory", "setpoints",
                 "acc", "rest_start", "rest_end")  # (a jerk-limited result's time map)


def check_fields(d: Mapping[str, Any], allowed: tuple[str, ...], what: str = "") -> None:
    """Refuse a field not in ``allowed``, naming it (a typo such as ``"degre"`` would
    otherwise be ignored and its default used without a word)."""
    extra = sorted(str(k) for k in d if k not in allowed)
    if extra:
        raise InputError(extra[0], f"unknown field{what} (allowed: {', '.join(allowed)})")


def _require(d: dict[str, Any], key: str) -> Any:
    if key not in d:
        raise InputError(key, "is required")
    return d[key]


def check_envelope(d: object, kind: str, version: int = VERSION) -> Mapping[str, Any]:
    """Check that ``d`` is a message of ``kind`` in a version we read."""
    if not isinstance(d, Mapping):
        raise InputError("(message)", f"must be a JSON object, got {type(d).__name__}")
    if d.get("schema") != kind:
        raise InputError("schema", f"must be {kind!r}, got {d.get('schema')!r}")
    if isinstance(d.get("version"), bool) or d.get("version") != version:
        raise InputError("version", f"version {d.get('version')!r} is not supported "
                         f"(this build reads version {version})")
    return d


def _optional_str(d: dict[str, Any], key: str, default: str) -> str:
    value = d.get(key, default)
    if not isinstance(value, str):
        raise InputError(key, f"must be a string, got {type(value).__name__}")
    return value


def trajectory_from_dict(d: object) -> TrajectoryMessage:
    """Parse a ``rota/trajectory`` message (see ``docs/protocol.md``)."""
    d = check_envelope(d, TRAJECTORY)
    frame = _optional_str(d, "frame", "ENU").upper()
    if frame not in FRAMES:
        raise InputError("frame", f"must be one of {FRAMES}, got {d.get('frame')!r}")
    stamp = d.get("stamp")
    if stamp is not None and (not isinstance(stamp, int | float) or isinstance(stamp, bool)
                              or not math.isfinite(stamp)):
        raise InputError("stamp", f"must be a finite number (UNIX seconds), got {stamp!r}")
    kind = _require(d, "type")
    if kind in TYPE_FIELDS:
        check_fields(d, TRAJECTORY_FIELDS + TYPE_FIELDS[kind], f" of a {kind!r} trajectory")
    try:
        if kind == "bspline":
            traj: Trajectory = BSplineTrajectory(
                control_points=_require(d, "control_points"),
                degree=_require_int(d, "degree", 3),
                knot_span=d.get("knot_span"),
                knots=d.get("knots"),
            )
        elif kind == "polynomial":
            traj = PolynomialTrajectory(durations=_require(d, "durations"),
                                        coefficients=_require(d, "coefficients"))
        elif kind == "samples":
            traj = SampledTrajectory(t=_require(d, "t"), p=_require(d, "p"), v=d.get("v"),
                                     a=d.get("a"))
        else:
            raise InputError("type", f"must be 'bspline', 'polynomial' or 'samples', got {kind!r}")
    except (TypeError, ValueError) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError("(trajectory)", str(exc)) from None
    heading = None
    if d.get("yaw") is not None or d.get("yaw_dt") is not None:
        yaw, dt = d.get("yaw"), d.get("yaw_dt")
        if not isinstance(yaw, list) or any(isinstance(y, bool) or not isinstance(y, int | float)
                                            for y in yaw):
            raise InputError("yaw", f"must be a list of numbers (degrees), got {_short(yaw)}")
        if isinstance(dt, bool) or not isinstance(dt, int | float):
            raise InputError("yaw_dt", f"must be a number (s between yaw samples), got "
                                       f"{_short(dt)}")
        heading = Heading(tuple(yaw), float(dt), traj.domain[0])
    if d.get("start") is not None or d.get("start_offset") is not None:
        start = traj.domain[0] if d.get("start") is None else d["start"]
        blend = d.get("start_blend", 0.0)
        for key, value in (("start", start), ("start_blend", blend)):
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise InputError(key, f"must be a number (trajectory time), got {value!r}")
        traj = Window(base=traj, start=float(start), offset=d.get("start_offset"),
                      blend=float(blend))
    return TrajectoryMessage(traj, id=_optional_str(d, "id", ""), frame=frame,
                             stamp=None if stamp is None else float(stamp), heading=heading)


def _short(x: Any) -> str:
    text = repr(x)
    return text if len(text) <= 60 else text[:57] + "..."


def _require_int(d: dict[str, Any], key: str, default: int) -> int:
    value = d.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int):
        raise InputError(key, f"must be an integer, got {value!r}")
    return value


def trajectory_to_dict(msg: TrajectoryMessage) -> dict[str, Any]:
    """Serialise a trajectory message; inverse of :func:`trajectory_from_dict`."""
    traj = msg.trajectory
    out: dict[str, Any] = {"schema": TRAJECTORY, "version": VERSION, "id": msg.id,
                           "frame": msg.frame}
    if isinstance(traj, Window):
        if traj.end != traj.base.domain[1]:  # type: ignore[union-attr]
            raise TypeError("only windows that run to the end of the trajectory serialise")
        out["start"] = traj.start
        if traj.offset is not None:
            out["start_offset"] = traj.offset.tolist()
            out["start_blend"] = traj.blend
        traj = traj.base
    if msg.stamp is not None:
        out["stamp"] = msg.stamp
    if msg.heading is not None:
        if abs(msg.heading.t0 - traj.domain[0]) > 1e-9:
            raise TypeError("only a heading from the trajectory's start serialises")
        out.update(yaw=list(msg.heading.yaw_deg), yaw_dt=msg.heading.dt)
    if isinstance(traj, BSplineTrajectory):
        out.update(type="bspline", degree=int(traj.degree),
                   control_points=traj.control_points.tolist())
        if traj.knot_span is not None:
            out["knot_span"] = float(traj.knot_span)
        else:
            out["knots"] = np.asarray(traj.knots).tolist()
    elif isinstance(traj, PolynomialTrajectory):
        out.update(type="polynomial", durations=traj.durations.tolist(),
                   coefficients=traj.coefficients.tolist())
    elif isinstance(traj, SampledTrajectory):
        out.update(type="samples", t=traj.t.tolist(), p=traj.p.tolist())
        if traj.v is not None:
            out["v"] = np.asarray(traj.v).tolist()
            out["a"] = np.asarray(traj.a).tolist()
    else:
        raise TypeError(f"cannot serialise {type(traj).__name__}")
    return out


def result_to_dict(result: RetimeResult, msg: TrajectoryMessage,
                   rate_hz: float | None = None) -> dict[str, Any]:
    """Serialise a re-time result; with ``rate_hz`` it also carries setpoints."""
    out: dict[str, Any] = {
        "schema": RESULT,
        "version": VERSION,
        "id": msg.id,
        "frame": msg.frame,
        "status": result.status,
        "message": result.message,
        "warnings": list(result.warnings),
        "duration": result.duration,
        "input_duration": result.trajectory.duration,
        "tau": result.tau.tolist(),
        "beta": result.beta.tolist(),
        "t": result.t.tolist(),
        "speed_limits": [x if math.isfinite(x) else None for x in result.speed_limits.tolist()],
        "solver": None if result.solver is None else {
            "status": result.solver.status,
            "iterations": result.solver.iterations,
            "solve_time": result.solver.solve_time,
            "wall_time": result.solver.wall_time,
            "objective": result.solver.objective if math.isfinite(result.solver.objective)
            else None,
        },
        "braking_zones": [list(map(float, iv)) for iv in result.diagnostics.intervals],
        "trajectory": trajectory_to_dict(msg),
    }
    if isinstance(result.timemap, JerkTimeMap):  # jerk-limited: tau_ddot continuous
        tm = result.timemap
        out["acc"] = tm.acc.tolist()
        out["rest_start"], out["rest_end"] = tm.rest_start, tm.rest_end
    if rate_hz is not None:
        sp = result.sample_rate(rate_hz)
        out["setpoints"] = {"rate": rate_hz, "t": sp.t.tolist(), "p": sp.position.tolist(),
                            "v": sp.velocity.tolist(), "a": sp.acceleration.tolist()}
    return out


def result_from_dict(d: object) -> tuple[RetimeResult, TrajectoryMessage]:
    """Rebuild a result (and its trajectory) from a ``rota/result`` message."""
    d = check_envelope(d, RESULT)
    check_fields(d, RESULT_FIELDS)
    try:
        msg = trajectory_from_dict(_require(d, "trajectory"))
    except InputError as exc:
        raise exc.within("trajectory") from None
    tau = np.asarray(_require(d, "tau"), dtype=float)
    beta = np.asarray(_require(d, "beta"), dtype=float)
    if tau.ndim != 1 or tau.shape != beta.shape or len(tau) < 2:
        raise InputError("beta", "tau and beta must be equal-length lists of >= 2 numbers")
    if not (np.all(np.isfinite(tau)) and np.all(np.isfinite(beta)) and np.all(beta >= 0)):
        raise InputError("beta", "tau and beta must be finite, beta >= 0")
    if np.any(np.diff(tau) <= 0):
        raise InputError("tau", "must be strictly increasing")
    raw = d.get("speed_limits") or [None] * len(tau)
    limits = np.array([np.inf if x is None else x for x in raw], dtype=float)
    s = d.get("solver")
    stats = None if s is None else SolverStats(str(s["status"]), int(s["iterations"]),
                                               float(s["solve_time"]), float(s["wall_time"]),
                                               float("nan") if s["objective"] is None
                                               else float(s["objective"]))
    status = str(_require(d, "status"))
    if status not in set(Outcome):
        raise InputError("status", f"must be one of {', '.join(Outcome)}, got {status!r}")
    found = Diagnostics(intervals=[tuple(iv) for iv in d.get("braking_zones", [])])
    result = RetimeResult(Outcome(status), str(d.get("message", "")),
                          _timemap(d, tau, beta), msg.trajectory, stats, limits, found,
                          tuple(str(w) for w in d.get("warnings", [])))
    return result, msg


def _timemap(d: dict, tau: np.ndarray, beta: np.ndarray) -> TimeMap | JerkTimeMap:
    """The time mapping of a result message: with ``acc``, jerk-limited."""
    if d.get("acc") is None:
        return TimeMap(tau, beta)
    acc = np.asarray(d["acc"], dtype=float)
    if acc.shape != tau.shape or not np.all(np.isfinite(acc)):
        raise InputError("acc", "must be a list of finite numbers, one per node")
    return JerkTimeMap(tau, beta, acc, bool(d.get("rest_start", False)),
                       bool(d.get("rest_end", False)))


def load(path: str | Path) -> Any:
    """Read a JSON file, turning syntax errors into :class:`InputError`."""
    try:
        return json.loads(Path(path).read_text())
    except json.JSONDecodeError as exc:
        raise InputError(str(path), f"is not valid JSON: {exc}") from None


def dump(obj: Any, path: str | Path) -> None:
    Path(path).write_text(json.dumps(obj, indent=1, allow_nan=False) + "\n")
