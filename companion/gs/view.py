"""What the ground station shows of a vehicle, as text (``rota-gs status`` and
``watch``) and as the figures the web page draws: the current plan's braking
zones ahead, in seconds from now."""

from __future__ import annotations

from typing import Any

import numpy as np


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


def render_status(status: dict[str, Any], telemetry: dict[str, Any],
                  retimed: list[dict[str, Any]], events: list[str] | None = None,
                  width: int = 78, v_max: float | None = None) -> str:
    """A screenful: state, position, speed against the limit, plan, braking zones
    ahead, the newest error, warnings and events."""
    s, tel = status, telemetry
    lines = [f"vehicle {s.get('vehicle', '?')}   state {s.get('state', '?').upper()}   "
             f"PX4 {s.get('flight_mode') or '-'} ({s.get('landed_state') or '-'})   "
             f"link {'ok' if s.get('link') else 'LOST'}   "
             f"{'armed' if s.get('armed') else 'disarmed'}"]
    pos, vel = tel.get("position"), tel.get("velocity")
    lines.append(f"position ENU {_vec(pos)} m")
    speed = float(np.linalg.norm(vel)) if vel is not None else None
    result = current_result(s, retimed)
    limit = v_max
    if limit is None and result is not None:
        limit = max((x for x in result.get("speed_limits", []) if x), default=None)
    if speed is None:
        lines.append("speed -")
    elif limit:
        lines.append(f"speed {speed:4.2f} m/s {_bar(speed, limit, max(width - 36, 10))} "
                     f"limit {limit:g}")
    else:
        lines.append(f"speed {speed:4.2f} m/s")
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
                     f"{1e3 * (last.get('solve_time') or 0):.0f} ms")
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
    return "\n".join(line[:width] if len(line) > width else line for line in lines)
