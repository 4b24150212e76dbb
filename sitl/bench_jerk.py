"""``rota-sitl bench`` rows of the jerk-limited re-time (``Limits.j_max``, :mod:`rota.jerk`).

The same paths, map and limits as the rest of the benchmark, with the jerk bound
of PX4's auto modes (``MPC_JERK_AUTO`` = 4 m/s^3): the time of the whole
jerk-limited re-time (it runs the unlimited one first), the flight time next to
the unlimited optimum, and the jerk the vehicle is commanded: third differences
of the positions sampled at 500 Hz, before (unlimited) and after.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import replace
from typing import Any

import numpy as np

from rota.problem import Limits, RetimeInput
from rota.retime import retime
from rota.robust import Safety
from rota.trajectory import Trajectory

#: PX4's MPC_JERK_AUTO default (m/s^3).
J_MAX = 4.0
#: Rows: (trajectory, dtau); quick: the 7 m local replan only.
ROWS = (("7m", 0.5), ("7m", 0.1), ("7m", 0.05), ("30m", 0.5), ("30m", 0.1))
QUICK = (("7m", 0.1),)
#: Finite differences of the commanded positions at this rate (Hz).
FD_RATE = 500.0


def fd_jerk_peak(result) -> float:
    """Largest per-axis third difference of positions sampled at :data:`FD_RATE`."""
    t = np.arange(0.0, result.duration, 1 / FD_RATE)
    p = result.sample(t).position
    return float(np.abs(np.diff(p, 3, axis=0) * FD_RATE**3).max())


def jerk_row(name: str, dtau: float, traj: Trajectory, safety: Safety, v_max: float,
             a_max: float, smoothness: float, repeats: int) -> dict[str, Any]:
    """Time the jerk-limited re-time (median of ``repeats``) and measure it."""
    free = RetimeInput(trajectory=traj, limits=Limits(v_max, a_max), smoothness=smoothness,
                       dtau=dtau, safety=safety)
    limited = replace(free, limits=Limits(v_max, a_max, J_MAX))
    base = retime(free)
    times, cpu = [], []
    out = None
    for _ in range(repeats):
        start, start_cpu = time.perf_counter(), time.process_time()
        out = retime(limited)
        times.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    assert out is not None
    return {"trajectory": name, "dtau": dtau, "N": len(base.tau) - 1, "j_max": J_MAX,
            "status": out.status, "message": out.message,
            "median_s": statistics.median(times), "median_cpu_s": statistics.median(cpu),
            "unlimited_s": base.duration,
            "limited_s": out.duration,
            "cost": out.duration / base.duration - 1 if out.ok else float("nan"),
            "fd_jerk_unlimited": fd_jerk_peak(base), "fd_jerk_limited": fd_jerk_peak(out),
            "steps": out.diagnostics.jerk_steps}


def jerk_rows(trajs: dict[str, Trajectory], safety: Safety, v_max: float, a_max: float,
              smoothness: float, repeats: int, quick: bool, log=print) -> list[dict[str, Any]]:
    rows = []
    for name, dtau in QUICK if quick else ROWS:
        row = jerk_row(name, dtau, trajs[name], safety, v_max, a_max, smoothness,
                       max(1, min(repeats, 3)))
        log(f"jerk {name} dtau {dtau}: {1e3 * row['median_s']:.0f} ms, "
            f"{row['unlimited_s']:.2f} s -> {row['limited_s']:.2f} s, FD jerk "
            f"{row['fd_jerk_unlimited']:.0f} -> {row['fd_jerk_limited']:.2f} m/s^3")
        rows.append(row)
    return rows


def to_markdown(rows: list[dict[str, Any]]) -> list[str]:
    """The section of ``bench.md``."""
    if not rows:
        return []
    lines = ["", f"Jerk-limited re-time (`Limits.j_max` = {J_MAX:g} m/s^3, PX4's "
             "`MPC_JERK_AUTO`; same map and limits), milliseconds (median of up to 3 runs; "
             "in brackets the process's CPU time, less sensitive to a shared machine); "
             "flight time next to the unlimited optimum; peak jerk of the commanded "
             "positions (third differences at 500 Hz):", "",
             "| traj | dtau (s) | N | status | jerk-limited re-time (CPU) | convexified solves | "
             "unlimited (s) | jerk-limited (s) | cost | FD jerk unlimited | FD jerk limited |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['trajectory']} | {r['dtau']:g} | {r['N']} | {r['status']} | "
            f"{1e3 * r['median_s']:.0f} ({1e3 * r['median_cpu_s']:.0f}) | {r['steps']} | "
            f"{r['unlimited_s']:.3f} | "
            f"{r['limited_s']:.3f} | {100 * r['cost']:+.1f} % | "
            f"{r['fd_jerk_unlimited']:.0f} | {r['fd_jerk_limited']:.2f} |")
    return lines
