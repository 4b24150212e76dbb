"""The vehicle's safety envelope: the hard limits of the service's config file.

At run time, a ground station may change ``[limits]``, ``[safety]`` and
``[uncertainty]`` over Zenoh, but only *within* the file's envelope, and every
change is judged by its effect on safety, not by its sign: each setting in
:data:`RULES` may move only in the direction that brakes earlier, flies slower or
checks more (a speed limit down, the geofence smaller, the uncertainty model more
cautious, the smoothness weight up), with the reason in words. A change outside is
refused with the allowed range and that reason. Settings not in :data:`RULES`
cannot change at run time; :data:`FIXED` says why for those that look as if they
could (the re-timing grid). ``tests/companion/test_envelope.py`` tries random sequences of
run-time changes and checks that no braking-point speed limit rises.

:func:`companion.settings.config.check_plausible` refuses a file envelope that is itself
implausible for a small multicopter (``check-config`` and start-up run it).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from companion.settings.config import Config, ConfigError, shown


@dataclass(frozen=True)
class Rule:
    """How a run-time setting may change relative to the config file.

    ``kind``: "max": at most the file's value (per axis for lists); "min": at least
    the file's; "range": from the file's value (``lo`` None) or ``lo`` to ``hi``;
    "on": a flag that may only be switched on; "timeout": as "max", but the file's
    0 (disabled) allows any value (enabling it is tightening). ``why``: why that
    direction is the safe one.
    """

    kind: str
    why: str
    lo: float | None = None
    hi: float | None = None


_SLOWER = "a lower limit can only slow the flight"
_CAUTIOUS = ("a larger value means a larger expected position error, so lower speed limits "
             "near obstacles")

#: The rule of every setting that may change at run time (``why`` reads after "as").
RULES: dict[tuple[str, str], Rule] = {
    ("limits", "v_max"): Rule("max", _SLOWER + " (it also caps every braking-point limit)"),
    ("limits", "a_max"): Rule("max", _SLOWER + " (the re-time still meets every speed limit)"),
    ("limits", "j_max"): Rule("timeout", "a lower jerk limit only smooths and slows the flight "
                              "(the file's 0, none, allows any limit: setting one tightens)"),
    ("limits", "smoothness"): Rule(
        "range", "a larger weight gives a gentler, slower speed profile (less acceleration "
        "and jerk, which the vehicle tracks better) and a smaller one flies nearer the limits",
        None, 10.0),
    ("limits", "max_solve_s"): Rule("max", "a re-time over budget is abandoned and the "
                                    "vehicle keeps (or brakes on) the plan it has"),
    ("limits", "solver_max_iter"): Rule("max", "fewer iterations lead to the uniformly slowed "
                                        "fallback, which keeps every speed limit"),
    ("stream", "yaw_rate_max_deg_s"): Rule("max", "a lower limit only turns the heading more "
                                           "slowly (it stays continuous either way)"),
    ("stream", "yaw_accel_max_deg_s2"): Rule("max", "a lower limit only changes the heading's "
                                             "turn rate more gently"),
    ("stream", "slow_for_yaw"): Rule("on", "slowing where the heading could not keep up only "
                                     "lowers speed limits"),
    ("safety", "geofence_min"): Rule("min", "the geofence may only shrink"),
    ("safety", "geofence_max"): Rule("max", "the geofence may only shrink"),
    ("safety", "max_message_age_s"): Rule("max", "a lower age refuses more stale trajectories "
                                          "and maps"),
    ("safety", "max_input_speed"): Rule("max", "a lower value refuses more fast-planned "
                                        "trajectories"),
    ("safety", "stitch_tolerance_m"): Rule("max", "a lower value allows smaller jumps at a "
                                           "takeover"),
    ("safety", "planner_timeout_s"): Rule("timeout", "a shorter timeout holds sooner when the "
                                          "planner falls silent"),
    ("safety", "max_tracking_error_m"): Rule("max", "the tracking-error brake acts sooner"),
    ("safety", "tracking_lag_s"): Rule("max", "the position is compared with fewer recent "
                                       "setpoints, so the tracking-error brake acts sooner"),
    ("safety", "max_trajectory_points"): Rule("max", "a lower value refuses larger "
                                              "trajectories"),
    ("safety", "require_stamp"): Rule("on", "unstamped (possibly stale) trajectories are "
                                      "refused"),
    ("uncertainty", "m"): Rule("min", _CAUTIOUS),
    ("uncertainty", "b"): Rule("min", _CAUTIOUS),
    ("uncertainty", "floor"): Rule("min", _CAUTIOUS),
    ("uncertainty", "delta"): Rule("max", "a lower bound on the collision probability means "
                                   "lower speed limits near obstacles"),
    ("uncertainty", "semi_axes"): Rule("min", "a larger robot is nearer every obstacle"),
    ("uncertainty", "obstacle_std"): Rule("min", _CAUTIOUS),
    ("uncertainty", "v_floor"): Rule("max", "the lowest speed limit (also the speed where the "
                                     "map knows nothing) may only go down"),
    ("uncertainty", "d_th"): Rule("min", "a larger threshold makes more braking points"),
    ("uncertainty", "memory_s"): Rule("min", "a longer memory holds a braking point's limit "
                                      "over a longer approach"),
}

#: Settings of the run-time sections that cannot change at run time, and why.
FIXED: dict[tuple[str, str], str] = {
    ("limits", "dtau"): (
        "the re-timing grid is where braking points are found and their speed limits "
        "imposed: a coarser grid misses them and a finer one moves them, and either can "
        "raise a limit near an obstacle (docs/security.md)"),
    ("uncertainty", "per_axis"): "neither reading of the model is more cautious everywhere",
    ("stream", "rate_hz"): "the stream's budgets and PX4's offboard-loss margin are counted "
                           "in its ticks",
}


def _allowed(rule: Rule, file_value: Any) -> tuple[Callable[[Any], bool], str]:
    """A test of a new value, and the allowed range in words."""
    if rule.kind == "max":
        return (lambda v: _each(v, file_value, lambda a, b: a <= b),
                f"at most {file_value} (the config file's value)")
    if rule.kind == "min":
        return (lambda v: _each(v, file_value, lambda a, b: a >= b),
                f"at least {file_value} (the config file's value)")
    if rule.kind == "on":
        return ((lambda v: v or not file_value),
                "true (the config file sets it)" if file_value else "true or false")
    if rule.kind == "timeout":
        if file_value == 0:
            return (lambda v: True), "any (the config file leaves it off)"
        return ((lambda v: 0 < v <= file_value),
                f"more than 0 and at most {file_value} (the config file's value)")
    lo = file_value if rule.lo is None else rule.lo
    hi = max(lo, rule.hi) if rule.hi is not None else float("inf")
    mark = " (the config file's value)" if rule.lo is None else ""
    return (lambda v: lo <= v <= hi), f"from {lo}{mark} to {hi}"


def _each(new: Any, old: Any, ok: Callable[[Any, Any], bool]) -> bool:
    if isinstance(new, tuple):
        return all(ok(a, b) for a, b in zip(new, old, strict=True))
    return ok(new, old)


def check_change(file: Config, new: Config, changes: dict[str, dict[str, Any]]) -> None:
    """Refuse ``changes`` (as requested) unless ``new`` stays inside ``file``'s
    envelope; the error names the setting, the allowed range and why."""
    for section, values in changes.items():
        for name in values:
            rule = RULES.get((section, name))
            if rule is None:
                why = FIXED.get((section, name), "only the config file sets it")
                raise ConfigError(f"[{section}] {name}: cannot change at run time ({why}; "
                                  "restart with a new config file to change it)")
            file_value = getattr(getattr(file, section), name)
            value = getattr(getattr(new, section), name)
            test, words = _allowed(rule, file_value)
            if not test(value):
                raise ConfigError(f"[{section}] {name}: {shown(value)} refused; allowed: "
                                  f"{words}, as {rule.why}")
    u, e = new.uncertainty, new.estimator
    if not (u.m <= e.m_max and u.b <= e.b_max):
        raise ConfigError(f"[uncertainty] m, b: ({u.m}, {u.b}) refused; allowed: m at most "
                          f"{e.m_max}, b at most {e.b_max} (the estimator's bounds)")
