"""What the ground station shows of a vehicle, as text (``rota-gs status`` and
``watch``) and as the figures the web page draws: the current plan's braking
zones ahead, in seconds from now; how long ago the service was last heard, and
"no contact" when it falls silent."""

from __future__ import annotations

import textwrap
from typing import Any

import numpy as np

#: Silence (no status and no telemetry) after which the ground station shows "no
#: contact", s. The service sends telemetry at 10 Hz and status at 2 Hz (the
#: defaults); the web page uses the same figure (``static/app.js``).
NO_CONTACT_S = 1.5
_DIM, _ALERT, _PLAIN = "\x1b[2m", "\x1b[1;7;31m", "\x1b[0m"


def current_result(status: dict[str, Any], retimed: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The newest re-timed result of the trajectory being flown."""
    ident = status.get("trajectory_id")
    if ident is None:
        return None
    return next((r for r in reversed(retimed) if r.get("id") == ident), None)


def zones_ahead(status: dict[str, Any], result: dict[str, Any] | None
                ) -> list[tuple[float, float]]:
    """The braking zones not yet passed: (seconds until it begins, its length in s)."""
    if result is None or status.get("progress") is None:
        return []
    tau, t = np.asarray(result["tau"]), np.asarray(result["t"])
    now = float(status["progress"]) * float(result["duration"])
    out = []
    for a, b in result.get("braking_zones", []):
        ta, tb = float(np.interp(a, tau, t)), float(np.interp(b, tau, t))
        if tb > now:
            out.append((max(ta - now, 0.0), tb - max(ta, now)))
    return out


def _bar(value: float, limit: float, width: int) -> str:
    fill = int(round(min(value / limit, 1.0) * width)) if limit > 0 else 0
    return "[" + "#" * fill + "." * (width - fill) + "]" + ("!" if value > limit else " ")


def _vec(x: list[float] | None) -> str:
    return "-" if x is None else "(" + ", ".join(f"{v:6.2f}" for v in x) + ")"


def _ago(age: float | None) -> str:
    return "never" if age is None else f"{age:.1f} s ago"


def contact_age(ages: dict[str, float | None]) -> float | None:
    """Seconds since the service was last heard (status or telemetry); None: never."""
    heard = [a for a in (ages.get("status"), ages.get("telemetry")) if a is not None]
    return min(heard) if heard else None


def limits_in_force(status: dict[str, Any], fallback: float | None = None) -> float | None:
    """The speed limit the service says is in force (its status, after every
    run-time change), else ``fallback``."""
    limits = status.get("limits")
    if isinstance(limits, dict) and isinstance(limits.get("v_max"), int | float):
        return float(limits["v_max"])
    return fallback


def render_status(status: dict[str, Any], telemetry: dict[str, Any],
                  retimed: list[dict[str, Any]], events: list[str] | None = None,
                  width: int = 0, v_max: float | None = None,
                  ages: dict[str, float | None] | None = None, ansi: bool = False) -> str:
    """A screenful: contact (with ``ages``: seconds since the newest status and
    telemetry), state, position, speed against the limit in force, plan, braking
    zones ahead, the newest error, warnings and events. Lines longer than
    ``width`` wrap (0: never); ``ansi``: a silent service's values are dimmed.
    ``v_max``: the limit when the status does not carry ``limits``."""
    s, tel = status, telemetry
    silent = tel_old = False
    lines = []
    if ages is not None:
        age = contact_age(ages)
        silent = age is None or age > NO_CONTACT_S
        tel_old = ages.get("telemetry") is None or ages["telemetry"] > NO_CONTACT_S
        heard = f"status {_ago(ages.get('status'))}, telemetry {_ago(ages.get('telemetry'))}"
        lines.append(f"NO CONTACT: nothing from the service for {age:.1f} s ({heard}); "
                     "all below is as it was then, not now" if silent and age is not None
                     else f"NO CONTACT: nothing from the service yet ({heard})" if silent
                     else f"contact: {heard}")
    lines.append(("last known: " if silent else "")
                 + f"vehicle {s.get('vehicle', '?')}   state {s.get('state', '?').upper()}   "
                 f"PX4 {s.get('flight_mode') or '-'} ({s.get('landed_state') or '-'})   "
                 f"link {'ok' if s.get('link') else 'LOST'}   "
                 f"{'armed' if s.get('armed') else 'disarmed'}")
    old = f" ({_ago(ages.get('telemetry'))})" if tel_old and ages is not None else ""
    pos, vel = tel.get("position"), tel.get("velocity")
    lines.append(f"position ENU {_vec(pos)} m{old}")
    speed = float(np.linalg.norm(vel)) if vel is not None else None
    result = current_result(s, retimed)
    limit = limits_in_force(s, v_max)
    if limit is None and result is not None:
        limit = max((x for x in result.get("speed_limits", []) if x), default=None)
    bar = max(width - 36, 10) if width else 30
    if speed is None:
        lines.append("speed -")
    elif limit:
        lines.append(f"speed {speed:4.2f} m/s{old} {_bar(speed, limit, bar)} limit {limit:g}")
    else:
        lines.append(f"speed {speed:4.2f} m/s{old}")
    if tel.get("tracking_error") is not None:
        lines.append(f"tracking error {tel['tracking_error']:.2f} m")
    cmd = s.get("command")
    if cmd == "plan":
        lines.append(f"plan {s.get('trajectory_id')}: {100 * (s.get('progress') or 0):.0f} %, "
                     f"{s.get('remaining_s') or 0:.1f} s to go")
        ahead = zones_ahead(s, result)
        lines.append("braking zones ahead: " + (", ".join(
            f"in {a:.1f} s for {d:.1f} s" for a, d in ahead) if ahead else "none"))
    elif cmd:
        lines.append(f"{cmd}: {s.get('hold_reason') or ''}")
    else:
        lines.append("not streaming")
    last = s.get("last_retime")
    if last:
        lines.append(f"last re-time {last.get('id')}: {last.get('status')}, "
                     f"{last.get('input_duration')} s -> {last.get('duration')} s, "
                     f"{len(last.get('braking_zones') or [])} braking zone(s), solve "
                     f"{1e3 * (last.get('solve_time') or 0):.0f} ms"
                     + (f" ({last['message']})" if last.get("status") == "rejected"
                        and last.get("message") else ""))
    lines.append(f"map {s.get('map_voxels') or 'none'} voxels; setpoint jitter p99 "
                 f"{s.get('setpoint_jitter_p99_ms')} ms")
    err = s.get("last_error")
    if err:
        lines.append(f"last error ({err.get('source')}): {err.get('message')}")
    for w in s.get("warnings") or []:
        lines.append(f"warning: {w}")
    if events:
        lines.append("events:")
        lines += [f"  {e}" for e in events]
    if width:
        lines = [part for line in lines for part in textwrap.wrap(
            line, width, subsequent_indent="    ", break_on_hyphens=False) or [""]]
    if ansi and silent:
        return "\n".join((_ALERT if line.startswith("NO CONTACT") else _DIM) + line + _PLAIN
                         for line in lines)
    return "\n".join(lines)
