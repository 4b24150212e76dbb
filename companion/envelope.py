"""The vehicle's safety envelope: the hard limits of the service's config file.

At run time, a ground station may change ``[limits]``, ``[safety]`` and
``[uncertainty]`` over Zenoh, but only *within* the file's envelope: a speed or
acceleration limit may go down, never up; the geofence may shrink, never grow;
the uncertainty model may grow more cautious, never less; and so on, per
setting, in :data:`RULES`. A change outside is refused with the allowed range.
Settings not in :data:`RULES` cannot change at run time.

:func:`check_plausible` refuses a file envelope that is itself implausible for
a small multicopter (``check-config`` and start-up run it).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from companion.config import Config, ConfigError

#: How each run-time setting may change relative to the file:
#: "max": at most the file's value (per axis for lists); "min": at least the
#: file's; ("range", lo, hi): anywhere in [lo, hi] (``None``: the file's value);
#: "on": a flag that may only be switched on; "timeout": as "max", but the file's
#: 0 (disabled) allows any value (enabling it is tightening).
RULES: dict[tuple[str, str], Any] = {
    ("limits", "v_max"): "max",
    ("limits", "a_max"): "max",
    ("limits", "j_max"): "timeout",  # the file's 0 (none): any limit is tighter
    ("limits", "smoothness"): ("range", 0.0, 10.0),
    ("limits", "dtau"): ("range", None, 1.0),  # coarser only: a finer grid costs more
    ("limits", "max_solve_s"): "max",
    ("limits", "solver_max_iter"): "max",
    ("safety", "geofence_min"): "min",
    ("safety", "geofence_max"): "max",
    ("safety", "max_message_age_s"): "max",
    ("safety", "max_input_speed"): "max",
    ("safety", "stitch_tolerance_m"): "max",
    ("safety", "planner_timeout_s"): "timeout",
    ("safety", "max_tracking_error_m"): "max",
    ("safety", "tracking_lag_s"): "max",
    ("safety", "max_trajectory_points"): "max",
    ("safety", "require_stamp"): "on",
    ("uncertainty", "m"): "min",  # more cautious: a larger position std per speed
    ("uncertainty", "b"): "min",
    ("uncertainty", "floor"): "min",
    ("uncertainty", "delta"): "max",  # a smaller collision probability
    ("uncertainty", "semi_axes"): "min",
    ("uncertainty", "obstacle_std"): "min",
    ("uncertainty", "v_floor"): "max",
    ("uncertainty", "d_th"): "min",
    ("uncertainty", "memory_s"): "min",  # a longer error memory brakes earlier
}


def _allowed(rule: Any, name: str, file_value: Any) -> tuple[Callable[[Any], bool], str]:
    """A test of a new value, and the allowed range in words."""
    if rule == "max":
        return (lambda v: _each(v, file_value, lambda a, b: a <= b),
                f"at most {file_value} (the config file's value)")
    if rule == "min":
        return (lambda v: _each(v, file_value, lambda a, b: a >= b),
                f"at least {file_value} (the config file's value)")
    if rule == "on":
        return ((lambda v: v or not file_value),
                "true (the config file sets it)" if file_value else "true or false")
    if rule == "timeout":
        if file_value == 0:
            return (lambda v: True), "any (the config file leaves it off)"
        return ((lambda v: 0 < v <= file_value),
                f"more than 0 and at most {file_value} (the config file's value)")
    _, lo, hi = rule
    lo = file_value if lo is None else lo
    return (lambda v: lo <= v <= hi), f"from {lo} to {hi}"


def _each(new: Any, old: Any, ok: Callable[[Any, Any], bool]) -> bool:
    if isinstance(new, tuple):
        return all(ok(a, b) for a, b in zip(new, old, strict=True))
    return ok(new, old)


def check_change(file: Config, new: Config, changes: dict[str, dict[str, Any]]) -> None:
    """Refuse ``changes`` (as requested) unless ``new`` stays inside ``file``'s
    envelope; the error names the setting and the allowed range."""
    for section, values in changes.items():
        for name in values:
            rule = RULES.get((section, name))
            if rule is None:
                raise ConfigError(f"[{section}] {name}: cannot change at run time (only the "
                                  "config file sets it; restart to change it)")
            file_value = getattr(getattr(file, section), name)
            value = getattr(getattr(new, section), name)
            test, words = _allowed(rule, name, file_value)
            if not test(value):
                raise ConfigError(f"[{section}] {name}: {value!r} refused; allowed: {words}")
    u, e = new.uncertainty, new.estimator
    if not (u.m <= e.m_max and u.b <= e.b_max):
        raise ConfigError(f"[uncertainty] m, b: ({u.m}, {u.b}) refused; allowed: m at most "
                          f"{e.m_max}, b at most {e.b_max} (the estimator's bounds)")


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
