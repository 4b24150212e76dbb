"""``rota-sitl parity``: the demo flight and the PX4 tier's flights, N times on each
vehicle backend, side by side.

The demo: the same forest, seed and speed as ``rota-sitl demo``, flown ``runs`` times on
the ``sitl`` vehicle and, with ``--px4 BUILD``, on real PX4 SITL (SIH), each run from a
fresh state folder (the estimator learns nothing between runs), holding HOLD_S at the
goal before it lands. Its tracking is measured on the flight record as
:mod:`sitl.calibration` measures PX4's recorded runs (:func:`tracking_figures`).

The tier (``tier_runs``): the scenarios of :mod:`sitl.tier_scenarios` (forest flight,
hold, offboard loss, SIGTERM, land) flown in that order on one fresh vehicle per run.

Per backend and figure: mean, standard deviation, min and max; written as Markdown tables
(docs/sitl.md, "Parity with PX4") and as JSON beside them. Closest approach is from each
simulator's ground truth (``sitl``: its true position; PX4: SIH's
``HIL_STATE_QUATERNION``), the robot's radius subtracted. A run that does not complete
(a timeout, the vehicle not reaching the goal) is counted and its error kept; it is not
retried.
"""

from __future__ import annotations

import asyncio
import json
import math
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from companion.gs import replay
from sitl.calibration import SETTLE_M, best_lag, settle_time

#: How long the demo holds at the goal before it lands (s): the window of its overshoot
#: and settling, as the recorded PX4 runs hold 4 s after each line (sitl/calibration.py)
HOLD_S = 5.0
#: Overshoot and settling are measured over this long after the last plan setpoint (s)
AFTER_S = 4.0

#: The figures compared: (summary key, label, unit).
FIGURES = (
    ("flight_time_s", "flight time to the goal", "s"),
    ("lag_s", "lag behind the setpoints", "s"),
    ("rms_tracking_error_m", "RMS tracking error", "m"),
    ("max_tracking_error_m", "max tracking error (the service's)", "m"),
    ("overshoot_m", "overshoot after the end", "m"),
    ("settle_s", f"settled within {SETTLE_M} m after the end", "s"),
    ("closest_approach_m", "closest approach to a trunk (truth)", "m"),
    ("max_speed_m_s", "max speed flown", "m/s"),
    ("braking_zones", "braking zones", ""),
    ("setpoint_jitter_p99_ms", "setpoint jitter p99", "ms"),
)


#: The tier's figures: (key, label, unit).
TIER_FIGURES = (
    ("forest_time_s", "forest flight, start to goal", "s"),
    ("forest_clearance_m", "forest flight, closest approach (truth)", "m"),
    ("rest_miss_m", "rest point from the goal (10 s mean)", "m"),
    ("hold_brake_m", "hold: the setpoint's brake", "m"),
    ("hold_settle_m", "hold: vehicle at rest from the hold setpoint", "m"),
    ("hold_lag_m", "hold: vehicle behind its setpoint at the command", "m"),
    ("failsafe_after_s", "offboard loss: PX4's failsafe after the freeze", "s"),
    ("offboard_back_s", "offboard loss: OFFBOARD again after 'start'", "s"),
    ("sigterm_hold_s", "SIGTERM: PX4 in Hold after", "s"),
    ("land_s", "land: disarmed after 'land'", "s"),
    ("tier_clearance_m", "closest approach, whole tier (truth)", "m"),
)


def tracking_figures(f: replay.Flight) -> dict[str, float]:
    """The plans' tracking on a flight record, measured as :mod:`sitl.calibration`
    measures PX4's recorded runs: the lag (the time shift of the setpoints that minimises
    the RMS error), the RMS error without shift (the reported position against the
    setpoints interpolated in time), and after the last plan setpoint the overshoot past
    it along the direction of travel and when the vehicle stays within SETTLE_M of it
    (NaN: not within AFTER_S)."""
    plans = [p[0] for p in f.plans()]
    flown = np.flatnonzero(np.isin(np.asarray(f.sp_source), plans))
    a, b = int(flown[0]), int(flown[-1])
    sp_t, sp_p = f.sp_t[a:b + 1], f.sp_p[a:b + 1]

    def at(t: np.ndarray) -> np.ndarray:
        return np.column_stack([np.interp(t, sp_t, sp_p[:, k]) for k in range(3)])

    inside = (f.tel_t >= sp_t[0]) & (f.tel_t <= sp_t[-1])
    tt, pp = f.tel_t[inside], f.position[inside]
    lag, _ = best_lag(tt, pp, at, np.arange(-0.3, 1.5, 0.01))
    end = sp_p[-1]
    way = end - at(np.array([sp_t[-1] - 1.0]))[0]  # the last second of travel
    u = way / max(float(np.linalg.norm(way)), 1e-9)
    after = (f.tel_t > sp_t[-1]) & (f.tel_t <= sp_t[-1] + AFTER_S)
    settle = settle_time(f.tel_t[after], np.linalg.norm(f.position[after] - end, axis=1),
                         sp_t[-1])
    return {"lag_s": round(lag, 2),
            "rms_tracking_error_m": round(math.sqrt(float(np.mean(
                np.sum((pp - at(tt)) ** 2, axis=1)))), 3),
            "overshoot_m": round(max(0.0, float(((f.position[after] - end) @ u).max())), 3)
            if after.any() else None,
            "settle_s": None if math.isnan(settle) else round(settle, 2)}


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
                # each `sitl` run draws its own noise (estimation error, wander), as
                # each PX4 run does: one draw for all runs hid the spread
                summary = run_demo(out_dir=tmp, seed=seed, speed=speed, px4_build=px4_build,
                                   hold_s=HOLD_S, vehicle_seed=100 + k)
                summary.update(tracking_figures(replay.load(summary.pop("record"))))
            except Exception as exc:  # noqa: BLE001 - counted and said, the next run goes on
                out["failed"].append(f"run {k + 1}: {type(exc).__name__}: {exc}")
                continue
        summary["wall_s"] = round(time.monotonic() - t0, 1)
        out["runs"].append(summary)
    return out


async def _tier_run(f: Any) -> dict[str, Any]:
    from sitl import tier_scenarios as sc

    t0 = time.monotonic()
    forest = await sc.forest_flight(f)
    held = await sc.hold(f)
    loss = await sc.offboard_loss(f)
    term = await sc.sigterm(f)
    landing = await sc.land(f)
    return {"forest_time_s": round(forest.t1 - forest.t0, 2),
            "forest_clearance_m": round(forest.clearance_m, 3),
            "rest_miss_m": round(forest.miss_m, 3),
            "hold_brake_m": round(held.brake_m, 3), "hold_settle_m": round(held.settle_m, 3),
            "hold_lag_m": round(held.lag_m, 3),
            "failsafe_after_s": round(loss.failsafe_after_s, 3),
            "failsafe_mode": loss.failsafe[1] if loss.failsafe else None,
            "offboard_back_s": round(loss.t_back - loss.t_start, 3),
            "sigterm_hold_s": round(term.t_hold - term.t0, 3),
            "land_s": round(landing.t_down - landing.t0, 2),
            "tier_clearance_m": round(f.true_clearance(t0), 3),
            "retries": list(f.retries)}


def fly_tier(runs: int, px4_build: str | None) -> dict[str, Any]:
    """``runs`` tier flights (:func:`_tier_run`) on one backend, each on a fresh vehicle."""
    from sitl.tier import TierFlight

    backend = "px4" if px4_build else "sitl"
    out: dict[str, Any] = {"backend": backend, "runs": [], "failed": []}
    for k in range(runs):
        try:
            with TierFlight(backend, Path(px4_build) if px4_build else None,
                            noise_seed=100 + k) as f:
                out["runs"].append(asyncio.run(_tier_run(f)))
        except Exception as exc:  # noqa: BLE001 - counted and said, the next run goes on
            out["failed"].append(f"run {k + 1}: {type(exc).__name__}: {str(exc)[:300]}")
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


#: A `sitl` figure matches PX4 when its mean lies within this many of PX4's run-to-run
#: standard deviations of PX4's mean: closer than that, a reviewer could not tell the
#: `sitl` mean from the mean of another set of PX4 runs of the same size (two sd of one run
#: is a wide band for a mean of ten; the band is stated, not hidden: docs/sitl.md)
MATCH_SD = 2.0


def _values(b: dict[str, Any], key: str) -> list[float]:
    return [r[key] for r in b["runs"] if r.get(key) is not None and math.isfinite(r[key])]


def match(sitl: list[float], px4: list[float]) -> tuple[float, float, bool] | None:
    """(`sitl` mean - PX4 mean, the band MATCH_SD x PX4's sd, whether within it); None
    without two PX4 values and one `sitl` value."""
    a, b = spread(sitl), spread(px4)
    if a.get("n", 0) < 1 or b.get("n", 0) < 2:
        return None
    diff, band = a["mean"] - b["mean"], MATCH_SD * b["sd"]
    return diff, band, abs(diff) <= band


def table(backends: list[dict[str, Any]], figures: tuple = FIGURES,
          reached: bool = True) -> str:
    """The Markdown table: one row per figure, one column per backend (``reached``: and
    how many runs reached the goal without a collision); with a `sitl` and a `px4`
    column, also the difference of the means and whether it is within MATCH_SD of PX4's
    standard deviations (:func:`match`)."""
    both = [b["backend"] for b in backends] == ["sitl", "px4"]
    head = ["figure"] + [f"`{b['backend']}` ({len(b['runs'])} of "
                         f"{len(b['runs']) + len(b['failed'])} runs)" for b in backends]
    if both:
        head += ["`sitl` - PX4", f"within {MATCH_SD:g} sd of PX4"]
    rows = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for key, label, unit in figures:
        cells = []
        for b in backends:
            values = _values(b, key)
            missing = len(b["runs"]) - len(values)  # (e.g. not settled within the window)
            cells.append(_cell(spread(values)) + (f" [{missing} without]" if missing else ""))
        if both:
            m = match(_values(backends[0], key), _values(backends[1], key))
            cells += ["-", "-"] if m is None else [f"{m[0]:+.3g}",
                                                   f"{'yes' if m[2] else 'no'} (±{m[1]:.3g})"]
        rows.append(f"| {label}{f' ({unit})' if unit else ''} | " + " | ".join(cells) + " |")
    if not reached:
        return "\n".join(rows) + "\n"

    def clean(b: dict[str, Any]) -> int:
        return sum(bool(r.get("reached_goal")) and not r.get("collisions") for r in b["runs"])

    reached_cells = [f"{clean(b)} of {len(b['runs']) + len(b['failed'])}" for b in backends]
    rows.append("| reached the goal without a collision | " + " | ".join(reached_cells)
                + (" | | |" if both else " |"))
    return "\n".join(rows) + "\n"


def _failures(backends: list[dict[str, Any]]) -> str:
    return "".join(f"\n* `{b['backend']}` {f}" for b in backends for f in b["failed"])


def render(demo: list[dict[str, Any]], tier: list[dict[str, Any]], day: str) -> str:
    """The tables of :func:`run_parity` from its flights (as its JSON holds them)."""
    runs = max(len(b["runs"]) + len(b["failed"]) for b in demo)
    text = (f"Demo flight (forest seed 3, 2 m/s, {HOLD_S:g} s held at the goal), {runs} runs "
            f"per backend; mean ± sd (min-max); measured {day}.\n\n" + table(demo)
            + _failures(demo))
    if tier:
        n = max(len(b["runs"]) + len(b["failed"]) for b in tier)
        text += (f"\n\nThe PX4 tier's flights (forest flight, hold, offboard loss, SIGTERM, "
                 f"land; one fresh vehicle per run), {n} runs per backend; mean ± sd "
                 f"(min-max); measured {day}.\n\n" + table(tier, TIER_FIGURES, reached=False)
                 + _failures(tier))
    return text


def with_px4_from(earlier: dict[str, Any], demo: list[dict[str, Any]],
                  tier: list[dict[str, Any]], day: str
                  ) -> tuple[list[dict[str, Any]], list[dict[str, Any]], str]:
    """The ``sitl`` flights just flown beside PX4's from an ``earlier`` parity JSON."""
    def px4(backends: list[dict[str, Any]]) -> list[dict[str, Any]]:
        return [b for b in backends if b["backend"] == "px4"]

    if not px4(earlier["demo"]) or (tier and not px4(earlier["tier"])):
        raise ValueError("the earlier parity JSON has no PX4 flights of that kind")
    return (demo + px4(earlier["demo"]), tier + px4(earlier["tier"]) if tier else [],
            f"{day} (PX4's flights: {earlier['measured']})")


def run_parity(runs: int, px4_build: str | None, out: str | None, tier_runs: int = 0,
               px4_from: str | None = None) -> str:
    """Fly, print and (with ``out``) write the tables and their JSON beside them.

    ``px4_from``: take PX4's flights from this earlier JSON instead of flying PX4 again
    (after a change of the ``sitl`` vehicle alone); the tables say when they were flown."""
    builds = [None, px4_build] if px4_build and not px4_from else [None]
    demo = [fly(runs, b) for b in builds]
    tier = [fly_tier(tier_runs, b) for b in builds] if tier_runs > 0 else []
    day = time.strftime("%Y-%m-%d", time.gmtime())
    if px4_from:
        demo, tier, day = with_px4_from(json.loads(Path(px4_from).read_text()), demo, tier,
                                        day)
    text = render(demo, tier, day)
    if out:
        Path(out).write_text(text + "\n")
        Path(out).with_suffix(".json").write_text(
            json.dumps({"measured": day, "demo": demo, "tier": tier}, indent=1) + "\n")
    return text
