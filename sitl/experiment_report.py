"""Tables, plots and JSON of the collision experiment (:mod:`sitl.experiment`): the paper's
Table I layout with the control arms, the detailed per-cell statistics, and the memory time's
dose-response with the rule that picks the default memory time."""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable
from dataclasses import asdict

import numpy as np

from sitl.experiment import ExperimentResult
from sitl.experiment_stats import (
    CLAIM_P,
    CLAIM_RATE,
    CellResult,
    claim_memory,
    mcnemar,
    rota_arm,
    uniform_arm,
)

#: The paper's Table I (collision rate in %, with / without time allocation, 50 trials).
PAPER_TABLE1: dict[float, dict[float, tuple[float, float]]] = {
    0.025: {1.0: (0.0, 0.0), 2.0: (0.0, 0.0), 3.0: (0.0, 2.0)},
    0.043: {1.0: (0.0, 2.0), 2.0: (2.0, 8.0), 3.0: (4.0, 10.0)},
    0.063: {1.0: (0.0, 6.0), 2.0: (2.0, 12.0), 3.0: (2.0, 14.0)},
}
DENSITY_NAMES = {0.025: "Low", 0.043: "Mid", 0.063: "High"}
MODEL_TEXT = {"correlated": "correlated error (amplitude follows the speed)",
              "drift": "drift error (speed drives the increments)"}


def arm_label(arm: str) -> str:
    if arm == "planned":
        return "planner's timing"
    kind, t = arm.split(":")
    if kind == "rota":
        return "ROTA (paper)" if float(t) == 0 else f"ROTA + memory {t} s"
    return "uniform, = ROTA time" if float(t) == 0 else f"uniform, = ROTA + memory {t} s time"


def _pct(x: float) -> str:
    return f"{100 * x:.1f} %"


def _p(p: float) -> str:
    return f"{p:.2g}"


def _errors_text(result: ExperimentResult) -> str:
    parts = []
    for e in result.config.errors:
        parts.append(f"{e.kind}: sigma = max({e.slope_s:g} |v| + ({e.offset_m:g}), "
                     f"{e.min_std_m:g}) m per horizontal axis, vertical x {e.vertical_scale:g}, "
                     f"tau = {e.correlation_time_s:g} s")
    return "; ".join(parts)


def markdown_table(result: ExperimentResult, command: str | None = None) -> str:
    """Per error model: the paper's layout (ROTA / planner, memory / uniform control) and the
    detailed statistics of every cell."""
    cfg = result.config
    t_mem = claim_memory(cfg)
    mem = rota_arm(t_mem) if t_mem is not None else None
    lines = [f"Command: `{command}`", ""] if command else []
    lines += [
        f"Seed {cfg.seed}, {cfg.trials} trials per cell, vehicle {cfg.vehicle}, "
        f"a_max = {cfg.accel_ratio:g} * v_max, planner clearance {cfg.clearance:g} m, "
        f"memory times {', '.join(f'{t:g}' for t in cfg.memories)} s; error models: "
        f"{_errors_text(result)}"
        + ("" if cfg.d_th is None else f"; ROTA braking threshold d_th = {cfg.d_th:g} m")
        + f"; paths ROTA rejects: {cfg.rejected}. A crash is a tree collision (any altitude) "
        "or a ground strike; rates are crash rates.",
    ]
    for kind, cells in result.cells.items():
        lines += ["", f"### {MODEL_TEXT.get(kind, kind)}", ""]
        head = "ROTA / planner's timing"
        if mem is not None:
            head += f" | ROTA + memory {t_mem:g} s / uniform at its time"
        lines += [f"Crash rate, paper layout ({head}; paper's collision rates in brackets, "
                  "with / without, 50 trials there):", "",
                  "| density | " + " | ".join(f"v = {v:g} m/s" for v in cfg.speeds) + " |",
                  "|---|" + "---|" * len(cfg.speeds)]
        for d in cfg.densities:
            row = [f"{DENSITY_NAMES.get(d, '')} ({d:g}/m^2)".strip()]
            for v in cfg.speeds:
                c = result.cell(kind, d, v)
                paper = PAPER_TABLE1.get(d, {}).get(v)
                text = f"{_pct(c.rate[rota_arm(0.0)])} / {_pct(c.rate['planned'])}" \
                    if rota_arm(0.0) in c.arms else _pct(c.rate["planned"])
                if paper:
                    text += f" ({paper[0]:g} / {paper[1]:g} %)"
                if mem is not None:
                    text += (f" \\| **{_pct(c.rate[mem])}** / "
                             f"{_pct(c.rate[uniform_arm(t_mem)])}")
                row.append(text)
            lines.append("| " + " | ".join(row) + " |")
        lines += ["", *detail_table(cells)]
    if t_mem is not None:
        lines += ["", f"Claim (ROTA + memory {t_mem:g} s crashes less than the uniform "
                  f"slow-down of the same duration, exact two-sided McNemar p < {CLAIM_P:g}, "
                  f"in every cell where the planner's timing crashes more than "
                  f"{100 * CLAIM_RATE:g} %, under every error model): "
                  f"**{'holds' if result.claim_holds else 'does not hold'}**"
                  + _claim_summary(result) + "."]
    return "\n".join(lines) + "\n"


def _claim_summary(result: ExperimentResult) -> str:
    fails = [f"{c.kind} {c.density:g}/m^2 {c.v_max:g} m/s" for cs in result.cells.values()
             for c in cs if c.claim == "fails"]
    applies = sum(c.claim != "n/a" for cs in result.cells.values() for c in cs)
    return f" ({applies} cells apply" + (f"; fails in {', '.join(fails)})" if fails else ")")


def detail_table(cells: list[CellResult]) -> list[str]:
    """Two tables: every arm's crash rate with its interval, (trees + ground) and mean flight
    time per cell; then the paired tests per cell and the claim."""
    arms = cells[0].arms
    pairs = [(p.first, p.second) for p in cells[0].pairs]
    lines = [
        "Crash rate [95 % Wilson interval] (tree collisions + ground strikes), mean flight "
        "time; n: trials in the comparison:",
        "",
        "| density | v | n | " + " | ".join(arm_label(a) for a in arms) + " |",
        "|---|---|---|" + "---|" * len(arms),
    ]
    for c in cells:
        lines.append(f"| {c.density:g} | {c.v_max:g} | {c.n} | " + " | ".join(
            f"{_pct(c.rate[a])} [{100 * c.ci95[a][0]:.1f}, {100 * c.ci95[a][1]:.1f}] "
            f"({c.collisions[a]} + {c.ground[a]}), {c.mean_duration[a]:.2f} s" for a in arms)
            + " |")
    lines += [
        "",
        "Paired tests (exact two-sided McNemar on crashes; b / c = trials where only the first "
        "/ only the second arm crashed):",
        "",
        "| density | v | " + " | ".join(f"{arm_label(a)} vs {arm_label(b)}" for a, b in pairs)
        + " | claim |",
        "|---|---|" + "---|" * (len(pairs) + 1),
    ]
    for c in cells:
        lines.append(f"| {c.density:g} | {c.v_max:g} | " + " | ".join(
            f"{p.only_first} / {p.only_second}, p = {_p(p.p)}" for p in c.pairs)
            + f" | {c.claim} |")
    status = "; ".join(
        f"{c.density:g}/{c.v_max:g}: " + ", ".join(f"{k} {v}" for k, v in c.retime_status.items())
        + (f" ({c.rejected_planned_crashes} rejected paths crashed with the planner's timing)"
           if c.retime_status.get("rejected") else "")
        + (f", no plan {c.plan_failures}" if c.plan_failures else "")
        for c in cells)
    return lines + ["", f"ROTA status per cell: {status}."]


def plot(result: ExperimentResult, path: str) -> None:
    """Crash rates with 95 % intervals per arm and cell, one row per error model."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cfg = result.config
    kinds = list(result.cells)
    nd = len(cfg.densities)
    arms = cfg.arms
    colours = {"planned": "tab:red"}
    palette = iter(["tab:blue", "tab:green", "tab:purple", "tab:brown", "tab:olive"])
    for a in arms:
        if a.startswith("rota"):
            colours[a] = next(palette)
    fig, axes = plt.subplots(len(kinds), nd, figsize=(4.6 * nd, 3.8 * len(kinds)),
                             squeeze=False)
    width = 0.8 / len(arms)
    for i, kind in enumerate(kinds):
        for j, d in enumerate(cfg.densities):
            ax = axes[i, j]
            x = np.arange(len(cfg.speeds))
            for k, arm in enumerate(arms):
                cells = [result.cell(kind, d, v) for v in cfg.speeds]
                rate = np.array([100 * c.rate[arm] for c in cells])
                lo = np.array([100 * c.ci95[arm][0] for c in cells])
                hi = np.array([100 * c.ci95[arm][1] for c in cells])
                colour = colours.get(arm, colours.get(arm.replace("uniform", "rota"), "grey"))
                ax.bar(x + (k - (len(arms) - 1) / 2) * width, rate, width, color=colour,
                       alpha=0.45 if arm.startswith("uniform") else 0.9,
                       hatch="//" if arm.startswith("uniform") else None, label=arm_label(arm),
                       yerr=np.maximum(np.vstack([rate - lo, hi - rate]), 0.0), capsize=2)
                paper = [PAPER_TABLE1.get(d, {}).get(v) for v in cfg.speeds]
                col = {"planned": 1, rota_arm(0.0): 0}.get(arm)
                if col is not None and all(p is not None for p in paper):
                    ax.plot(x + (k - (len(arms) - 1) / 2) * width, [p[col] for p in paper],
                            "k_", ms=10, mew=2,
                            label="paper (50 trials)" if arm == "planned" else None)
            ax.set_xticks(x, [f"{v:g} m/s" for v in cfg.speeds])
            ax.set_title(f"{kind} error, {d:g} trees/m^2", fontsize=10)
            ax.set_ylabel("crash rate (%)")
            if i == 0 and j == 0:
                ax.legend(fontsize=7)
    fig.suptitle(f"Crash rates per arm ({cfg.trials} trials per cell, seed {cfg.seed}; "
                 "hatched: uniform slow-down of the same duration; black: the paper's "
                 "collision rates)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _rounded(value: object) -> object:
    """Per-trial floats to 0.1 mm / 0.1 ms (keeps the JSON small); seeds stay exact."""
    if isinstance(value, float):
        return round(value, 4) if math.isfinite(value) else value
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_rounded(v) for v in value]
    return value


def _compact(data: dict) -> dict:
    """Per-trial data for the JSON: outcomes as 0/1, closest approach to the millimetre,
    flight end times left out (the durations are kept)."""
    out = {k: v for k, v in data.items() if k != "flights"}
    out["flights"] = {kind: {arm: {"collided": [int(x) for x in f["collided"]],
                                   "ground": [int(x) for x in f["ground"]],
                                   "closest": [round(x, 3) if math.isfinite(x) else x
                                               for x in f["closest"]]}
                             for arm, f in arms.items()}
                      for kind, arms in data.get("flights", {}).items()}
    return _rounded(out)  # type: ignore[return-value]


def to_json(result: ExperimentResult) -> dict:
    """JSON-friendly dict of the run (configuration, cell statistics, per-trial data)."""
    cfg = result.config
    trials = {f"{cfg.densities[di]:g}/{cfg.speeds[vi]:g}": _compact(data)
              for (di, vi), data in result.trials.items()}
    return {"schema": "rota/table1", "version": 2, "config": asdict(cfg),
            "cells": {k: [asdict(c) for c in cs] for k, cs in result.cells.items()},
            "claim_holds": result.claim_holds, "wall_time_s": result.wall_time_s,
            "prep_time_s": result.prep_time_s, "sim_time_s": result.sim_time_s,
            "trials": trials}


def _timing(result: ExperimentResult) -> str:
    return (f"\nRun time: {result.wall_time_s:.1f} s wall with {result.config.workers} "
            f"worker(s) (planning + re-timing {result.prep_time_s:.1f} s, flights "
            f"{result.sim_time_s:.1f} s, summed over workers).\n")


def _write(result: ExperimentResult, out_dir: str, name: str, text: str,
           draw: Callable[[ExperimentResult, str], None]) -> dict:
    """Write ``<name>.md`` (``text`` and the run time), ``<name>.png`` (``draw``) and
    ``<name>.json`` into ``out_dir``; their paths."""
    os.makedirs(out_dir, exist_ok=True)
    paths = {k: os.path.join(out_dir, f"{name}.{k}") for k in ("md", "png", "json")}
    with open(paths["md"], "w") as f:
        f.write(text + _timing(result))
    draw(result, paths["png"])
    with open(paths["json"], "w") as f:
        json.dump(to_json(result), f, allow_nan=True)
    return paths


def write_outputs(result: ExperimentResult, out_dir: str, command: str | None = None) -> dict:
    """Write ``table1.md``, ``table1.png`` and ``table1.json`` into ``out_dir``."""
    return _write(result, out_dir, "table1", markdown_table(result, command), plot)


# ---------------------------------------------------------------------- dose-response
def memory_rule(result: ExperimentResult, kind: str, p_stop: float = 0.05) -> float:
    """The rule that picks the memory time (docs/table1.md, "Memory time"), for one error
    model on a one-cell run over a grid of memory times: the smallest T for which the next
    T on the grid does not lower the crash rate significantly (exact two-sided McNemar
    p >= ``p_stop``, or no fewer crashes), i.e. where more memory stops buying safety that
    the paired flights can measure. The largest T if every step still helps."""
    cfg = result.config
    grid = sorted(cfg.memories)
    data = result.trials[(0, 0)]
    keep = _kept(cfg, data)
    crash = {t: _crashed(data, kind, rota_arm(t))[keep] for t in grid}
    for t, nxt in zip(grid, grid[1:], strict=False):
        b, cc, p = mcnemar(crash[t], crash[nxt])
        if not (b > cc and p < p_stop):
            return t
    return grid[-1]


def _kept(cfg, data: dict) -> np.ndarray:
    planned = np.array(data["planned"], dtype=bool)
    rejected = planned & np.any([np.array(s) == "rejected" for s in data["status"].values()],
                                axis=0)
    return planned & ~rejected if cfg.rejected == "exclude" else planned


def _crashed(data: dict, kind: str, arm: str) -> np.ndarray:
    f = data["flights"][kind][arm]
    return np.array(f["collided"], dtype=bool) | np.array(f["ground"], dtype=bool)


def dose_markdown(result: ExperimentResult, command: str | None = None) -> str:
    """The dose-response table (crash rate and flight time per memory time, per error model)
    and the rule's pick."""
    cfg = result.config
    d, v = cfg.densities[0], cfg.speeds[0]
    lines = [f"Command: `{command}`", ""] if command else []
    lines += [f"Memory time dose-response at {d:g} trees/m^2, v_max = {v:g} m/s, seed "
              f"{cfg.seed}, {cfg.trials} trials, vehicle {cfg.vehicle}; error models: "
              f"{_errors_text(result)}.", ""]
    picks = {}
    for kind, cells in result.cells.items():
        c = cells[0]
        picks[kind] = memory_rule(result, kind)
        lines += [f"### {MODEL_TEXT.get(kind, kind)} (n = {c.n})", "",
                  "| T (s) | ROTA + memory: crash rate [95 %] | flight time | uniform at that "
                  "time: crash rate | uniform vs ROTA: b / c, p | T vs next T: b / c, p |",
                  "|---|---|---|---|---|---|"]
        grid = sorted(cfg.memories)
        keep = _kept(cfg, result.trials[(0, 0)])
        for t, nxt in zip(grid, [*grid[1:], None], strict=True):
            a = rota_arm(t)
            uni = (f"{_pct(c.rate[uniform_arm(t)])}" if cfg.uniform else "-")
            test = c.pair(uniform_arm(t), a) if cfg.uniform else None
            step = "-"
            if nxt is not None:
                data = result.trials[(0, 0)]
                b, cc, p = mcnemar(_crashed(data, kind, a)[keep],
                                   _crashed(data, kind, rota_arm(nxt))[keep])
                step = f"{b} / {cc}, {_p(p)}"
            lines.append(f"| {t:g} | {_pct(c.rate[a])} [{100 * c.ci95[a][0]:.1f}, "
                         f"{100 * c.ci95[a][1]:.1f}] | {c.mean_duration[a]:.2f} s | {uni} | "
                         + (f"{test.only_first} / {test.only_second}, {_p(test.p)}"
                            if test else "-") + f" | {step} |")
        lines += ["", f"Planner's timing: {_pct(c.rate['planned'])}, "
                  f"{c.mean_duration['planned']:.2f} s. Rule's pick for this model: "
                  f"**T = {picks[kind]:g} s**.", ""]
    lines += [f"Rule (the larger pick of the error models): **T = {max(picks.values()):g} s**."]
    return "\n".join(lines) + "\n"


def dose_plot(result: ExperimentResult, path: str) -> None:
    """Crash rate (with 95 % intervals) and flight time against the memory time, per error
    model; the uniform slow-down of the same duration beside it."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cfg = result.config
    grid = sorted(cfg.memories)
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    for kind, colour in zip(result.cells, ("tab:blue", "tab:green"), strict=False):
        c = result.cells[kind][0]
        for arm_of, ls, label in ((rota_arm, "-o", "ROTA + memory"),
                                  (uniform_arm, "--s", "uniform, same time")):
            if arm_of is uniform_arm and not cfg.uniform:
                continue
            r = np.array([100 * c.rate[arm_of(t)] for t in grid])
            lo = np.array([100 * c.ci95[arm_of(t)][0] for t in grid])
            hi = np.array([100 * c.ci95[arm_of(t)][1] for t in grid])
            ax.errorbar(grid, r, yerr=np.vstack([r - lo, hi - r]), fmt=ls, color=colour,
                        alpha=1.0 if arm_of is rota_arm else 0.5, capsize=3,
                        label=f"{label} ({kind})")
        ax.axhline(100 * c.rate["planned"], color=colour, lw=0.8, ls=":",
                   label=f"planner's timing ({kind})")
        ax2.plot(grid, [c.mean_duration[rota_arm(t)] for t in grid], "-o", color=colour,
                 label=kind)
    ax.set_xlabel("memory time T (s)")
    ax.set_ylabel("crash rate (%)")
    ax.legend(fontsize=7)
    ax2.set_xlabel("memory time T (s)")
    ax2.set_ylabel("mean flight time (s)")
    ax2.legend(fontsize=8)
    fig.suptitle(f"Memory time: {cfg.densities[0]:g} trees/m^2, {cfg.speeds[0]:g} m/s, "
                 f"{cfg.trials} trials, seed {cfg.seed}")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def write_dose(result: ExperimentResult, out_dir: str, command: str | None = None) -> dict:
    """Write ``dose.md``, ``dose.png`` and ``dose.json`` into ``out_dir``."""
    return _write(result, out_dir, "dose", dose_markdown(result, command), dose_plot)
