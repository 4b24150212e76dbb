"""Statistics, table and plot of the PX4 experiment (:mod:`sitl.experiment_px4`).

Compared are the trials every arm flew. Per arm: collisions (SIH's truth within the robot's
radius of a trunk) with the 95 % Wilson interval, the closest approach (truth, robot radius
subtracted) and the commanded duration. Paired, ROTA against each control: the exact McNemar
test on collisions (:func:`sitl.experiment_stats.mcnemar`) and the closest approach's paired
difference (mean with its 95 % t interval, and the two-sided Wilcoxon signed-rank test).

With the jerk-limited arm (``j_max``): over the trials both ROTA arms flew, the RMS jerk of
each arm as flown (SIH's truth) and as commanded, and, paired, the jerk-limited arm's RMS jerk
and duration as ratios to ROTA's (geometric means with 95 % t intervals on the log ratios,
Wilcoxon signed-rank p).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from sitl.experiment_px4 import ARMS, JERK_ARM
from sitl.experiment_stats import mcnemar, wilson

LABELS = {"planned": "planner's timing", "rota": "ROTA (shipped model)",
          "uniform": "uniform slow-down, = ROTA time", JERK_ARM: "ROTA, jerk-limited"}


def paired_difference(x: np.ndarray, y: np.ndarray) -> dict[str, float]:
    """Mean of ``x - y`` with its 95 % t interval, and the Wilcoxon signed-rank p."""
    d = np.asarray(x, float) - np.asarray(y, float)
    n = len(d)
    mean = float(d.mean()) if n else math.nan
    half = (float(stats.t.ppf(0.975, n - 1) * d.std(ddof=1) / math.sqrt(n)) if n > 1
            else math.nan)
    p = float(stats.wilcoxon(d).pvalue) if n > 0 and np.any(d != 0) else 1.0
    return {"mean": mean, "lo": mean - half, "hi": mean + half, "p": p, "n": n}


def summarise(run: dict[str, Any]) -> dict[str, Any]:
    """Per-arm figures and the paired tests over the trials every arm flew."""
    trials = run["trials"]
    both = [t for t in trials if all(a in t["arms"] for a in ARMS)]
    n = len(both)
    out: dict[str, Any] = {
        "n": n, "trials": len(trials),
        "no_plan": sum(t["status"] == "no-plan" for t in trials),
        "rejected": sum(t["status"] == "rejected" for t in trials),
        "fitted_rejected": sum(t["fitted_status"] == "rejected" for t in trials
                               if t["status"] != "no-plan"),
        "errors": [f"trial {t['trial']}: {t['error']}" for t in trials if t.get("error")],
        "braking_fraction": float(np.mean([t["braking_fraction"] for t in both])) if n else 0,
        "path_clearance": [float(min(t["path_clearance"] for t in both)) if n else math.nan,
                           float(np.median([t["path_clearance"] for t in both])) if n
                           else math.nan],
        "arms": {}, "pairs": {}}
    col = {a: np.array([t["arms"][a]["collided"] for t in both], bool) for a in ARMS}
    close = {a: np.array([t["arms"][a]["closest_truth"] for t in both]) for a in ARMS}
    for a in ARMS:
        k = int(col[a].sum())
        out["arms"][a] = {
            "collisions": k, "rate": k / n if n else math.nan, "ci95": wilson(k, n),
            "closest_median": float(np.median(close[a])) if n else math.nan,
            "closest_p10": float(np.percentile(close[a], 10)) if n else math.nan,
            "closest_min": float(close[a].min()) if n else math.nan,
            "duration": float(np.mean([t["durations"][a] for t in both])) if n else math.nan,
            "estimate_minus_truth": float(np.median(
                [t["arms"][a]["closest_estimate"] - t["arms"][a]["closest_truth"]
                 for t in both])) if n else math.nan}
    for other in ("planned", "uniform"):
        b, c, p = mcnemar(col["rota"], col[other])
        out["pairs"][other] = {"only_rota": b, "only_other": c, "p": p,
                               "closest": paired_difference(close["rota"], close[other])}
    out["jerk"] = jerk_summary(trials)
    return out


def ratio(x: np.ndarray, y: np.ndarray) -> dict[str, float]:
    """The paired ratio ``x / y``: geometric mean with its 95 % t interval, Wilcoxon p."""
    d = paired_difference(np.log(x), np.log(y))
    return {"ratio": math.exp(d["mean"]), "lo": math.exp(d["lo"]) if d["n"] > 1 else math.nan,
            "hi": math.exp(d["hi"]) if d["n"] > 1 else math.nan, "p": d["p"], "n": d["n"]}


def jerk_summary(trials: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The jerk-limited arm against ROTA's, over the trials both flew (None: no such arm)."""
    both = [t for t in trials if {"rota", JERK_ARM} <= set(t["arms"])
            and all(math.isfinite(t["arms"][a]["rms_jerk_truth"]) for a in ("rota", JERK_ARM))]
    if not both:
        return None

    def col(arm: str, key: str) -> np.ndarray:
        return np.array([t["arms"][arm][key] if key in t["arms"][arm] else t["durations"][arm]
                         for t in both], float)

    flown = [a for a in (*ARMS, JERK_ARM)  # (the controls too, where they flew)
             if all(a in t["arms"] and "rms_jerk_truth" in t["arms"][a] for t in both)]
    arms = {a: {"rms_jerk_truth": float(np.mean(col(a, "rms_jerk_truth"))),
                "rms_jerk_commanded": float(np.mean(col(a, "rms_jerk_commanded"))),
                "duration": float(np.mean(col(a, "duration"))),
                "collisions": int(sum(t["arms"][a]["collided"] for t in both))} for a in flown}
    return {"n": len(both), "arms": arms,
            "jerk_truth": ratio(col(JERK_ARM, "rms_jerk_truth"), col("rota", "rms_jerk_truth")),
            "jerk_commanded": ratio(col(JERK_ARM, "rms_jerk_commanded"),
                                    col("rota", "rms_jerk_commanded")),
            "duration": ratio(col(JERK_ARM, "duration"), col("rota", "duration"))}


def jerk_markdown(j: dict[str, Any], j_max: float) -> list[str]:
    """The jerk-limited arm's table (:func:`jerk_summary`)."""
    lines = ["", f"Jerk-limited ROTA (j_max {j_max:g} m/s^3 per axis) against ROTA, the "
             f"{j['n']} trials both flew (every arm's mean over them); RMS jerk of the "
             "velocity (Savitzky-Golay, sitl.experiment_px4.rms_jerk), as flown (SIH's truth) "
             "and as commanded:", "",
             "| arm | RMS jerk flown (m/s^3) | RMS jerk commanded (m/s^3) | duration (s) | "
             "collisions |", "|---|---|---|---|---|"]
    for a, r in j["arms"].items():
        lines.append(f"| {LABELS[a]} | {r['rms_jerk_truth']:.2f} | "
                     f"{r['rms_jerk_commanded']:.2f} | {r['duration']:.2f} | "
                     f"{r['collisions']} of {j['n']} |")
    lines += ["", "| jerk-limited / ROTA, paired | ratio (95 % CI) | Wilcoxon p |",
              "|---|---|---|"]
    for key, what in (("jerk_truth", "RMS jerk flown"), ("jerk_commanded",
                                                          "RMS jerk commanded"),
                      ("duration", "flight time")):
        r = j[key]
        lines.append(f"| {what} | {r['ratio']:.3f} ({r['lo']:.3f} to {r['hi']:.3f}) | "
                     f"{r['p']:.3g} |")
    return lines


def _ci(lo_hi: tuple[float, float]) -> str:
    return f"{100 * lo_hi[0]:.1f}-{100 * lo_hi[1]:.1f} %"


def markdown(run: dict[str, Any], s: dict[str, Any], command: str) -> str:
    cfg = run["config"]
    fitted = run["fitted_model"]
    lines = [
        "# ROTA on real PX4 SITL (SIH): planner's timing, ROTA and the equal-time slow-down",
        "", f"Command: `{command}` ({run['wall_time_s']:.0f} s wall).", "",
        f"{s['trials']} forests of {cfg['density']} trees per m^2 (seed {cfg['seed']}); the "
        f"reference planner at {cfg['clearance']} m clearance beyond the robot's radius, "
        f"{cfg['speed']} m/s, {cfg['a_max']} m/s^2, {cfg['altitude']} m altitude; ROTA with the "
        f"shipped model (memory {cfg['memory_s']:g} s, Delta 1e-4, 0.3 m robot). Flown on "
        f"real PX4 (SIH), truth from SIH. Compared: the **{s['n']}** trials every arm flew "
        f"(no plan: {s['no_plan']}, rejected by ROTA: {s['rejected']}, lost to a fault: "
        f"{len(s['errors'])}). The paths' clearance: min {s['path_clearance'][0]:.2f} m, "
        f"median {s['path_clearance'][1]:.2f} m; ROTA put {100 * s['braking_fraction']:.0f} % "
        "of the nodes in braking zones.", "",
        "| arm | collisions | rate (95 % Wilson) | closest approach, median / 10th pct / min "
        "(m) | commanded duration (s) | PX4's estimate minus truth, closest (m) |",
        "|---|---|---|---|---|---|"]
    for a in ARMS:
        r = s["arms"][a]
        lines.append(f"| {LABELS[a]} | {r['collisions']} of {s['n']} | "
                     f"{100 * r['rate']:.1f} % ({_ci(r['ci95'])}) | {r['closest_median']:.2f} / "
                     f"{r['closest_p10']:.2f} / {r['closest_min']:.2f} | {r['duration']:.2f} | "
                     f"{r['estimate_minus_truth']:+.2f} |")
    lines += ["", "| ROTA against | collisions only ROTA / only the other | McNemar p | "
              "closest approach, ROTA minus other: mean (95 % CI) | Wilcoxon p |",
              "|---|---|---|---|---|"]
    for other, pr in s["pairs"].items():
        d = pr["closest"]
        lines.append(f"| {LABELS[other]} | {pr['only_rota']} / {pr['only_other']} | "
                     f"{pr['p']:.3g} | {d['mean']:+.3f} m ({d['lo']:+.3f} to {d['hi']:+.3f}) | "
                     f"{d['p']:.3g} |")
    lines += ["", f"ROTA with the model fitted to PX4 (m {fitted['m']:g}, b {fitted['b']:g} m) "
              f"rejected {s['fitted_rejected']} of {s['trials'] - s['no_plan']} planned paths "
              "(no speed meets Delta there; docs/estimator.md)."]
    if s.get("jerk"):
        lines += jerk_markdown(s["jerk"], cfg.get("j_max", 0.0))
    if s["errors"]:
        lines += ["", "Faults: " + "; ".join(s["errors"])]
    return "\n".join(lines) + "\n"


def plot(run: dict[str, Any], path: Path) -> Path:
    """The closest approach per trial and arm, paired trials joined."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    both = [t for t in run["trials"] if all(a in t["arms"] for a in ARMS)]
    fig, ax = plt.subplots(figsize=(6.5, 4))
    xs = np.arange(len(ARMS))
    for t in both:
        ax.plot(xs, [t["arms"][a]["closest_truth"] for a in ARMS], "-o", color="0.6",
                lw=0.7, ms=3)
    ax.axhline(0.0, color="r", lw=1, label="collision (robot radius)")
    ax.set_xticks(xs, [LABELS[a] for a in ARMS], fontsize=8)
    ax.set_ylabel("closest approach to a trunk, truth (m)")
    ax.set_title("PX4 SITL (SIH): each line one forest, flown three ways", fontsize=10)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write(run: dict[str, Any], out: str, command: str) -> dict[str, Path]:
    d = Path(out)
    d.mkdir(parents=True, exist_ok=True)
    s = summarise(run)
    paths = {"md": d / "px4.md", "json": d / "px4.json", "png": d / "px4.png"}
    paths["md"].write_text(markdown(run, s, command))
    paths["json"].write_text(json.dumps({**run, "summary": s}, indent=1, default=str) + "\n")
    plot(run, paths["png"])
    return paths
