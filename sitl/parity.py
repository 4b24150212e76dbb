"""``rota-sitl parity``: the demo flight, N times on each vehicle backend, side by side.

The same forest, seed and speed as ``rota-sitl demo``, flown ``runs`` times on the
``sitl`` vehicle and, with ``--px4 BUILD``, on real PX4 SITL (SIH), each run from a
fresh state folder (the estimator learns nothing between runs). Per backend and figure:
mean, standard deviation, min and max, and how many runs reached the goal; written as a
Markdown table (docs/sitl.md, "Parity with PX4") and as JSON beside it. Closest approach
is from each simulator's ground truth (``sitl``: its true position; PX4: SIH's
``HIL_STATE_QUATERNION``), the robot's radius subtracted.

A run that does not complete (a timeout, the vehicle not reaching the goal) is counted
and its error kept; it is not retried.
"""

from __future__ import annotations

import json
import math
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

#: The figures compared: (summary key, label, unit).
FIGURES = (
    ("flight_time_s", "flight time to the goal", "s"),
    ("max_tracking_error_m", "max tracking error", "m"),
    ("closest_approach_m", "closest approach to a trunk (truth)", "m"),
    ("max_speed_m_s", "max speed flown", "m/s"),
    ("braking_zones", "braking zones", ""),
    ("setpoint_jitter_p99_ms", "setpoint jitter p99", "ms"),
)


def fly(runs: int, px4_build: str | None, seed: int = 3, speed: float = 2.0,
        ) -> dict[str, Any]:
    """``runs`` demo flights on one backend: their summaries and failures."""
    from sitl.demo import run_demo

    out: dict[str, Any] = {"backend": "px4" if px4_build else "sitl", "runs": [],
                           "failed": []}
    for k in range(runs):
        with tempfile.TemporaryDirectory(prefix="rota-parity-") as tmp:
            t0 = time.monotonic()
            try:
                summary = run_demo(out_dir=tmp, seed=seed, speed=speed, px4_build=px4_build)
            except Exception as exc:  # noqa: BLE001 - counted and said, the next run goes on
                out["failed"].append(f"run {k + 1}: {type(exc).__name__}: {exc}")
                continue
        summary["wall_s"] = round(time.monotonic() - t0, 1)
        summary.pop("record", None)
        out["runs"].append(summary)
    return out


def spread(values: list[float]) -> dict[str, float]:
    a = np.asarray(values, float)
    if not len(a):
        return {"n": 0}
    return {"n": len(a), "mean": float(a.mean()), "sd": float(a.std(ddof=1)) if len(a) > 1
            else math.nan, "min": float(a.min()), "max": float(a.max())}


def _cell(s: dict[str, float]) -> str:
    if not s.get("n"):
        return "-"
    sd = "" if math.isnan(s["sd"]) else f" ± {s['sd']:.3g}"
    return f"{s['mean']:.3g}{sd} ({s['min']:.3g}-{s['max']:.3g})"


def table(backends: list[dict[str, Any]]) -> str:
    """The Markdown table: one row per figure, one column per backend."""
    head = ["figure"] + [f"`{b['backend']}` ({len(b['runs'])} of "
                         f"{len(b['runs']) + len(b['failed'])} runs)" for b in backends]
    rows = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for key, label, unit in FIGURES:
        cells = [_cell(spread([r[key] for r in b["runs"] if r.get(key) is not None]))
                 for b in backends]
        rows.append(f"| {label}{f' ({unit})' if unit else ''} | " + " | ".join(cells) + " |")
    reached = [f"{sum(bool(r.get('reached_goal')) and not r.get('collisions') for r in b['runs'])}"
               f" of {len(b['runs']) + len(b['failed'])}" for b in backends]
    rows.append("| reached the goal without a collision | " + " | ".join(reached) + " |")
    return "\n".join(rows) + "\n"


def run_parity(runs: int, px4_build: str | None, out: str | None) -> str:
    """Fly, print and (with ``out``) write the table and its JSON beside it."""
    backends = [fly(runs, None)]
    if px4_build:
        backends.append(fly(runs, px4_build))
    text = (f"Demo flight (forest seed 3, 2 m/s), {runs} runs per backend; mean ± sd "
            f"(min-max); measured {time.strftime('%Y-%m-%d', time.gmtime())}.\n\n"
            + table(backends))
    for b in backends:
        for f in b["failed"]:
            text += f"\n* `{b['backend']}` {f}"
    if out:
        Path(out).write_text(text + "\n")
        Path(out).with_suffix(".json").write_text(json.dumps(backends, indent=1) + "\n")
    return text
