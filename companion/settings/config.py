"""Service configuration: frozen dataclasses loaded from TOML and validated at start.

Every setting is documented in ``configs/companion.toml``; an error names the
setting (``[limits] v_max: must be positive``). Unknown settings are errors too,
so a typo never silently falls back to a default.
"""

from __future__ import annotations

import difflib
import json
import math
import sys
import tomllib
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from companion.protocol import KEY_PREFIX, vehicle_key
from companion.recording.settings import RecordSettings
from companion.ros2.settings import Ros2Settings
from companion.ros2.settings import check as check_ros2
from companion.uncertainty.settings import EstimatorSettings
from rota.braking import BrakingParams
from rota.chance import DEFAULT_MEMORY_S, ChanceParams, UncertaintyModel
from rota.errors import InputError
from rota.problem import Limits


class ConfigError(ValueError):
    """A configuration setting is missing, unknown or out of range."""


@dataclass(frozen=True)
class ServiceSection:
    vehicle_id: str = "drone1"  # Zenoh key expressions are <key_prefix>/<vehicle_id>/...
    key_prefix: str = KEY_PREFIX
    log_level: str = "INFO"
    state_dir: str = "/var/lib/rota-companion"  # persisted state (estimator)
    nice: int = -5  # CPU priority of the service (needs CAP_SYS_NICE; else it says so)


#: Measured on PX4 SITL (docs/service.md, "Stalls"): the least time (s) before PX4's
#: offboard-loss timeout at which a resumed stream is still sure to reach PX4 in time.
OFFBOARD_LOSS_MARGIN_S = 0.3


@dataclass(frozen=True)
class MavlinkSection:
    url: str = "udpin://127.0.0.1:14540"  # MAVSDK connection URL (PX4 offboard link)
    connect_timeout_s: float = 30.0
    health_timeout_s: float = 30.0
    link_timeout_s: float = 1.5  # no telemetry for this long = link lost
    # PX4's COM_OF_LOSS_T; the smaller of this and the value read from PX4 is used
    offboard_loss_timeout_s: float = 1.0
    # a stall may end in a hold in OFFBOARD only if the stream's last setpoint was sent less
    # than (offboard-loss timeout - this) ago; otherwise the stream ends (docs/service.md)
    offboard_loss_margin_s: float = OFFBOARD_LOSS_MARGIN_S


@dataclass(frozen=True)
class ZenohSection:
    config_file: str = ""  # a Zenoh JSON5 configuration; empty = the embedded default
    mode: str = "peer"
    listen: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    connect: tuple[str, ...] = ()
    telemetry_rate_hz: float = 10.0
    status_rate_hz: float = 2.0
    insecure: bool = False  # true: start even if reachable without authentication (warned)


@dataclass(frozen=True)
class StreamSection:
    rate_hz: float = 50.0  # setpoint stream rate
    prestream_s: float = 1.5  # setpoints streamed before requesting OFFBOARD (PX4: ~1 s)
    yaw: str = "path"  # "path": face along the path; "hold": keep the yaw at start
    yaw_rate_max_deg_s: float = 45.0  # the streamed yaw turns no faster (PX4 MPC_YAWRAUTO_MAX)
    yaw_accel_max_deg_s2: float = 90.0  # nor changes its rate faster (companion/flight/heading.py)
    slow_for_yaw: bool = False  # re-time so the heading keeps up with the path (rota/heading.py)
    takeoff_altitude_m: float = 1.5
    auto_start: bool = False  # arm, take off and start offboard on the first trajectory
    stall_budget_s: float = 0.25  # a longer stall of the loop brakes (docs/service.md)


@dataclass(frozen=True)
class InputsSection:
    """Caps on what arrives from the network (checked before anything is built)."""

    max_trajectory_bytes: int = 4_000_000
    max_map_bytes: int = 32_000_000
    max_query_bytes: int = 65_536  # commands, config and estimator queries
    max_map_voxels: int = 1_000_000
    max_polynomial_degree: int = 15
    max_json_depth: int = 16
    max_messages_per_s: float = 50.0  # trajectories per second; more are dropped
    max_maps_per_s: float = 2.0  # maps per second (each may be 32 MB): more are dropped
    max_queries_per_s: float = 20.0  # per queryable (cmd, config, estimator); more refused
    decode_timeout_s: float = 5.0  # a decode slower than this is abandoned


@dataclass(frozen=True)
class LimitsSection:
    v_max: float = 2.0  # speed limit, m/s
    a_max: tuple[float, float, float] = (2.0, 2.0, 1.5)  # per axis (x, y, z), m/s^2
    j_max: float = 0.0  # jerk limit per axis, m/s^3 (PX4's MPC_JERK_AUTO: 4); 0: none
    smoothness: float = 0.5  # lambda of the paper's Eq. 10
    dtau: float = 0.05  # re-timing grid step, s of trajectory time
    max_solve_s: float = 2.0  # a re-time slower than this is abandoned
    solver_max_iter: int = 200  # the solver's iteration budget (fewer: the fallback)


@dataclass(frozen=True)
class SafetySection:
    input_frame: str = "ENU"  # frame of trajectories that do not say (ENU or NED)
    geofence_min: tuple[float, float, float] = (-50.0, -50.0, 0.0)  # ENU, m, from home
    geofence_max: tuple[float, float, float] = (50.0, 50.0, 10.0)
    max_message_age_s: float = 2.0  # older trajectories/maps are rejected (needs "stamp")
    max_input_speed: float = 10.0  # reject trajectories planned faster than this, m/s
    stitch_tolerance_m: float = 1.0  # max gap between the command and a new trajectory
    planner_timeout_s: float = 0.0  # >0: hold when no trajectory for this long in flight
    # reported position this far from every setpoint of the last tracking_lag_s -> hold
    max_tracking_error_m: float = 1.5
    tracking_lag_s: float = 1.0
    max_trajectory_points: int = 100000
    # false: the planner has no clock; unstamped trajectories are accepted, by arrival
    require_stamp: bool = True


@dataclass(frozen=True)
class UncertaintySection:
    m: float = 0.2  # std = m * speed + b (paper Eq. 15 defaults)
    b: float = -0.1
    floor: float = 0.0
    per_axis: bool = False
    delta: float = 1e-4  # collision probability bound per sample (paper: 0.01 %)
    semi_axes: tuple[float, float, float] = (0.3, 0.3, 0.3)  # robot ellipsoid, m
    obstacle_std: float = 0.03
    v_floor: float = 0.5
    # braking zones follow the risk (docs/safety-model.md, section 2); d_th > 0 also makes
    # every obstacle within d_th metres a braking point (an override; 0: none)
    d_th: float = 0.0
    # error memory T, s: a braking point's speed limit also holds over the T seconds before
    # it (0: the paper's ROTA); default from the collision experiment (docs/table1.md)
    memory_s: float = DEFAULT_MEMORY_S


@dataclass(frozen=True)
class Config:
    service: ServiceSection = field(default_factory=ServiceSection)
    mavlink: MavlinkSection = field(default_factory=MavlinkSection)
    zenoh: ZenohSection = field(default_factory=ZenohSection)
    stream: StreamSection = field(default_factory=StreamSection)
    inputs: InputsSection = field(default_factory=InputsSection)
    limits: LimitsSection = field(default_factory=LimitsSection)
    safety: SafetySection = field(default_factory=SafetySection)
    uncertainty: UncertaintySection = field(default_factory=UncertaintySection)
    estimator: EstimatorSettings = field(default_factory=EstimatorSettings)
    record: RecordSettings = field(default_factory=RecordSettings)
    ros2: Ros2Settings = field(default_factory=Ros2Settings)

    # ----------------------------------------------------------- derived objects
    def rota_limits(self) -> Limits:
        return Limits(self.limits.v_max, self.limits.a_max, self.limits.j_max or None)

    def yaw_slowdown_rad_s(self) -> float:
        """The yaw rate (rad/s) the re-time slows the path for (``[stream] slow_for_yaw``,
        only while the heading follows the path or the planner: ``yaw = "path"``); 0: it
        does not."""
        s = self.stream
        return math.radians(s.yaw_rate_max_deg_s) if s.slow_for_yaw and s.yaw == "path" \
            else 0.0

    def uncertainty_model(self) -> UncertaintyModel:
        u = self.uncertainty
        return UncertaintyModel(m=u.m, b=u.b, floor=u.floor, per_axis=u.per_axis,
                                memory_s=u.memory_s)

    def chance_params(self) -> ChanceParams:
        u = self.uncertainty
        return ChanceParams(delta=u.delta, semi_axes=u.semi_axes,
                            obstacle_std=(u.obstacle_std,) * 3,
                            v_floor=min(u.v_floor, self.limits.v_max), v_max=self.limits.v_max)

    def braking_params(self) -> BrakingParams:
        return BrakingParams(d_th=self.uncertainty.d_th)

    def key(self, *parts: str) -> str:
        """A Zenoh key expression under this vehicle: ``rota/drone1/<parts>``."""
        return vehicle_key(self.service.key_prefix, self.service.vehicle_id, *parts)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


_SECTION_TYPES = {
    "service": ServiceSection, "mavlink": MavlinkSection, "zenoh": ZenohSection,
    "stream": StreamSection, "inputs": InputsSection, "limits": LimitsSection,
    "safety": SafetySection, "uncertainty": UncertaintySection, "estimator": EstimatorSettings,
    "record": RecordSettings, "ros2": Ros2Settings,
}
#: The sections of a config file.
SECTIONS = tuple(_SECTION_TYPES)


#: Names and values are shown in messages at most this long (a 10,000-character
#: name or value sent over the network is not copied whole into status and log).
SHOWN_CHARS = 64
#: Integer settings hold at most this magnitude (a C ``int64``; numpy takes them).
MAX_INT = 2**63 - 1


def short(text: str, limit: int = SHOWN_CHARS) -> str:
    """``text``, cut to ``limit`` characters ending in an ellipsis when longer."""
    return text if len(text) <= limit else text[:limit - 1] + "\u2026"


def shown(value: Any, limit: int = SHOWN_CHARS) -> str:
    """``repr(value)`` for a message, cut to ``limit`` characters."""
    if isinstance(value, int) and not isinstance(value, bool) \
            and value.bit_length() > 3 * sys.get_int_max_str_digits():
        return f"an integer of {value.bit_length()} bits"  # repr would raise
    return short(repr(value), limit)


def hint(name: str, known: Any) -> str:
    """``did you mean 'x'? `` when ``name`` is close to one of ``known``; else ''."""
    close = difflib.get_close_matches(name[:SHOWN_CHARS], list(known), n=1, cutoff=0.6)
    return f"did you mean {close[0]!r}? " if close else ""


def unknown_section(section: str, known: Any, words: str) -> ConfigError:
    """The error for a section name that is not one of ``known`` (``words``: what the
    list of known names is)."""
    known = list(known)
    return ConfigError(f"[{short(section)}]: unknown section {short(section)!r} "
                       f"({hint(section, known)}{words}: {', '.join(known)})")


def flag(value: Any, where: str) -> bool:
    """A strict boolean: ``true`` or ``false``, never a truthy string or number."""
    if not isinstance(value, bool):
        raise ConfigError(f"{where}: must be true or false, got {shown(value)}")
    return value


def number(value: Any, where: str) -> float:
    """A finite number (an integer too, if a float can hold it); never a boolean."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"{where}: must be a number, got {shown(value)}")
    try:
        out = float(value)
    except OverflowError:
        raise ConfigError(f"{where}: must be a finite number, got an integer beyond the "
                          f"range of a float ({shown(value)})") from None
    if not math.isfinite(out):
        raise ConfigError(f"{where}: must be finite, got {shown(value)}")
    return out


def integer(value: Any, where: str) -> int:
    """An integer of at most :data:`MAX_INT` in magnitude; never a boolean."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(f"{where}: must be an integer, got {shown(value)}")
    if abs(value) > MAX_INT:
        raise ConfigError(f"{where}: must be an integer from -{MAX_INT} to {MAX_INT}, got "
                          f"{shown(value)}")
    return value


def _coerce(section: str, name: str, default: Any, value: Any) -> Any:
    where = f"[{section}] {name}"
    if isinstance(default, bool):
        return flag(value, where)
    if isinstance(default, int):
        return integer(value, where)
    if isinstance(default, float):
        return number(value, where)
    if isinstance(default, str):
        if not isinstance(value, str):
            raise ConfigError(f"{where}: must be a string, got {shown(value)}")
        return value
    if isinstance(default, tuple):
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{where}: must be a list, got {shown(value)}")
        if default and isinstance(default[0], float):
            if len(value) != len(default):
                raise ConfigError(f"{where}: must be {len(default)} numbers, got {shown(value)}")
            return tuple(_coerce(section, name, 0.0, v) for v in value)
        return tuple(_coerce(section, name, "", v) for v in value)
    raise ConfigError(f"{where}: unsupported setting type")  # pragma: no cover


def from_dict(data: dict[str, Any], base: Config | None = None) -> Config:
    """Build a configuration from nested dicts (TOML tables), over ``base``."""
    cfg = base or Config()
    if not isinstance(data, dict):
        raise ConfigError("configuration must be a table")
    for section, values in data.items():
        if section not in _SECTION_TYPES:
            raise unknown_section(section, SECTIONS, "known")
        if not isinstance(values, dict):
            raise ConfigError(f"[{section}]: must be a table")
        current = getattr(cfg, section)
        known = {f.name for f in fields(current)}
        updates = {}
        for name, value in values.items():
            if name not in known:
                raise ConfigError(f"[{section}] {short(name)}: unknown setting "
                                  f"{short(name)!r} ({hint(name, sorted(known))}known: "
                                  f"{', '.join(sorted(known))})")
            updates[name] = _coerce(section, name, getattr(current, name), value)
        cfg = replace(cfg, **{section: replace(current, **updates)})
    validate(cfg)
    return cfg


#: Plausible limits of a file envelope for a small multicopter.
PLAUSIBLE = {
    ("limits", "v_max"): 30.0,  # m/s
    ("limits", "a_max"): 30.0,  # m/s^2 per axis
    ("limits", "j_max"): 1000.0,  # m/s^3 per axis
    ("limits", "max_solve_s"): 30.0,
    ("safety", "max_message_age_s"): 60.0,
    ("safety", "max_input_speed"): 60.0,
    ("safety", "stitch_tolerance_m"): 5.0,
    ("safety", "max_tracking_error_m"): 10.0,
    ("safety", "tracking_lag_s"): 5.0,
    ("safety", "max_trajectory_points"): 1_000_000,
    ("uncertainty", "m"): 5.0,
    ("uncertainty", "semi_axes"): 10.0,
    ("uncertainty", "d_th"): 20.0,
    ("inputs", "max_trajectory_bytes"): 256_000_000,
    ("inputs", "max_map_bytes"): 1_000_000_000,
    ("inputs", "max_query_bytes"): 1_000_000,
    ("inputs", "max_map_voxels"): 50_000_000,
    ("inputs", "decode_timeout_s"): 60.0,
}
#: The geofence: horizontally within this many metres of home; vertically from
#: -100 m (below home: a valley) to this altitude.
PLAUSIBLE_FENCE_M = 10_000.0
PLAUSIBLE_CEILING_M = 1_000.0


def check_plausible(cfg: Config) -> None:
    """Refuse a config file whose envelope is implausible (a typo of units, a
    fence round the planet)."""
    for (section, name), limit in PLAUSIBLE.items():
        value = getattr(getattr(cfg, section), name)
        if any(v > limit for v in (value if isinstance(value, tuple) else (value,))):
            raise ConfigError(f"[{section}] {name}: {value!r} is implausible for a small "
                              f"multicopter (at most {limit}); check the units")
    lo, hi = cfg.safety.geofence_min, cfg.safety.geofence_max
    if max(abs(v) for v in (*lo[:2], *hi[:2])) > PLAUSIBLE_FENCE_M or lo[2] < -100.0 \
            or hi[2] > PLAUSIBLE_CEILING_M:
        raise ConfigError(f"[safety] geofence_min / geofence_max: {list(lo)} to {list(hi)} is "
                          f"implausible (at most {PLAUSIBLE_FENCE_M:.0f} m from home "
                          f"horizontally, -100 m to {PLAUSIBLE_CEILING_M:.0f} m vertically)")
    if not 0 < cfg.uncertainty.delta <= 0.5:
        raise ConfigError(f"[uncertainty] delta: {cfg.uncertainty.delta} is implausible (a "
                          "collision probability bound in (0, 0.5])")
    if not 1e-3 <= cfg.limits.dtau <= 1.0:
        raise ConfigError(f"[limits] dtau: {cfg.limits.dtau} is implausible (1e-3 to 1 s)")


def load(path: str | Path | None) -> Config:
    """Read and validate a TOML file (None: the defaults)."""
    if path is None:
        return from_dict({})
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text())
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read ({exc.strerror})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: not valid TOML ({exc})") from None
    cfg = from_dict(data)
    check_plausible(cfg)  # a file's envelope must make sense for a multicopter
    return cfg


def to_toml(cfg: Config) -> str:
    """``cfg`` as a TOML file that :func:`load` reads back to the same settings."""
    lines = []
    for section, values in cfg.to_dict().items():
        lines.append(f"[{section}]")
        lines += [f"{k} = {json.dumps(list(v) if isinstance(v, tuple) else v)}"
                  for k, v in values.items()]
    return "\n".join(lines) + "\n"


def validate(cfg: Config) -> None:
    """Range checks that need more than a type; errors name the setting."""

    def positive(section: str, name: str) -> None:
        v = getattr(getattr(cfg, section), name)
        values = v if isinstance(v, tuple) else (v,)
        if any(x <= 0 for x in values):
            raise ConfigError(f"[{section}] {name}: must be positive, got {v!r}")

    for section, name in [("mavlink", "connect_timeout_s"), ("mavlink", "health_timeout_s"),
                          ("mavlink", "link_timeout_s"), ("mavlink", "offboard_loss_timeout_s"),
                          ("stream", "stall_budget_s"), ("zenoh", "telemetry_rate_hz"),
                          ("stream", "yaw_rate_max_deg_s"), ("stream", "yaw_accel_max_deg_s2"),
                          ("zenoh", "status_rate_hz"), ("stream", "rate_hz"),
                          ("stream", "takeoff_altitude_m"), ("limits", "v_max"),
                          ("limits", "a_max"), ("limits", "dtau"), ("limits", "max_solve_s"),
                          ("limits", "solver_max_iter"),
                          ("safety", "max_message_age_s"), ("safety", "max_input_speed"),
                          ("safety", "stitch_tolerance_m"), ("safety", "max_tracking_error_m"),
                          ("safety", "tracking_lag_s"),
                          ("safety", "max_trajectory_points"),
                          ("record", "max_file_mb"), ("record", "queue")] + [
                          ("inputs", f.name) for f in fields(InputsSection)]:
        positive(section, name)
    if not cfg.uncertainty.d_th >= 0:
        raise ConfigError(f"[uncertainty] d_th: must be >= 0, got {cfg.uncertainty.d_th!r}")
    m = cfg.mavlink
    if not 0.05 <= m.offboard_loss_margin_s < m.offboard_loss_timeout_s:
        raise ConfigError("[mavlink] offboard_loss_margin_s: must be at least 0.05 s (what a "
                          "setpoint takes to reach PX4 on a busy machine) and below "
                          f"offboard_loss_timeout_s, got {m.offboard_loss_margin_s!r}")
    s = cfg.stream
    if s.rate_hz < 2.5:
        raise ConfigError("[stream] rate_hz: PX4 needs offboard setpoints faster than 2 Hz")
    if s.prestream_s < 0.5:
        raise ConfigError("[stream] prestream_s: PX4 needs >= 0.5 s of setpoints before "
                          "OFFBOARD (newer PX4 about 1 s)")
    if s.yaw not in ("path", "hold"):
        raise ConfigError(f"[stream] yaw: must be 'path' or 'hold', got {s.yaw!r}")
    if cfg.safety.input_frame not in ("ENU", "NED"):
        raise ConfigError(f"[safety] input_frame: must be 'ENU' or 'NED', "
                          f"got {cfg.safety.input_frame!r}")
    if any(lo >= hi for lo, hi in zip(cfg.safety.geofence_min, cfg.safety.geofence_max,
                                      strict=True)):
        raise ConfigError("[safety] geofence_min: must be below geofence_max on every axis")
    if cfg.safety.planner_timeout_s < 0:
        raise ConfigError("[safety] planner_timeout_s: must be >= 0 (0 disables it)")
    if cfg.limits.smoothness < 0:
        raise ConfigError("[limits] smoothness: must be >= 0")
    if not cfg.limits.j_max >= 0:
        raise ConfigError("[limits] j_max: must be >= 0 (0: no jerk limit)")
    if cfg.zenoh.mode not in ("peer", "client", "router"):
        raise ConfigError(f"[zenoh] mode: must be peer, client or router, got {cfg.zenoh.mode!r}")
    if not -20 <= cfg.service.nice <= 19:
        raise ConfigError(f"[service] nice: must be -20 to 19, got {cfg.service.nice}")
    if cfg.service.log_level.upper() not in ("DEBUG", "INFO", "WARNING", "ERROR"):
        raise ConfigError(f"[service] log_level: unknown level {cfg.service.log_level!r}")
    for name in ("vehicle_id", "key_prefix"):
        v = getattr(cfg.service, name)
        if not v or any(c in v for c in "/*$?#") or v != v.strip():
            raise ConfigError(f"[service] {name}: must be a non-empty Zenoh key chunk "
                              f"without / * $ ? #, got {v!r}")
    if cfg.record.max_total_mb < cfg.record.max_file_mb:
        raise ConfigError("[record] max_total_mb: must be at least max_file_mb")
    e = cfg.estimator
    if e.min_samples < 0 or e.min_speed < 0 or e.gate <= 0 or e.sample_weight <= 0:
        raise ConfigError("[estimator] min_samples, min_speed >= 0; gate, sample_weight > 0")
    if not (e.m_min <= cfg.uncertainty.m <= e.m_max and e.b_min <= cfg.uncertainty.b <= e.b_max):
        raise ConfigError("[estimator] m_min: the bounds must contain the configured "
                          "[uncertainty] m and b")
    try:
        check_ros2(cfg.ros2)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    try:
        cfg.rota_limits()
        cfg.uncertainty_model()
        cfg.chance_params()
        cfg.braking_params()
    except InputError as exc:
        section = "limits" if exc.field.startswith("limits") else "uncertainty"
        raise ConfigError(f"[{section}] {exc.field.split('.')[-1]}: {exc.message}") from None
