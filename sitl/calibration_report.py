"""Side-by-side figures of PX4 (recorded) and the ``sitl`` vehicle (replayed), as a table and a
plot for docs/sitl.md.

    python -m sitl.calibration_report --png docs/sitl-calibration.png   # prints the tables

:func:`compare` computes everything :mod:`sitl.calibration` measures, for PX4 and for the
vehicle over a few noise seeds (the vehicle's figures are the means over the seeds);
tests/sitl/test_sitl_calibration.py checks them against stated tolerances.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from sitl import calibration as cal
from sitl.px4_reference import load, phase_span

GROUPS = tuple((f"lines {v} m/s", (f"line_v{v}_out", f"line_v{v}_back")) for v in (1, 2, 3)) + \
    tuple((f"circle {v} m/s", (f"circle_v{v}",)) for v in (1, 2, 3))


def compare(seeds: Sequence[int] = (1, 2, 3), arm_trials: int = 100) -> dict[str, Any]:
    """PX4's and the vehicle's figures (see module docstring)."""
    ref = load()
    kinds = dict(cal.RUNS)
    px4_track = cal.reference(ref, "tracking")
    sim_track = [cal.replay(ref, "tracking", seed=s) for s in seeds]
    runs = {phase: (cal.tracking_metrics(ref, px4_track, phase, kind),
                    cal.TrackingMetrics.mean([cal.tracking_metrics(ref, f, phase, kind)
                                              for f in sim_track]))
            for phase, kind in cal.RUNS}
    groups = {name: tuple(cal.TrackingMetrics.mean([runs[p][i] for p in phases])
                          for i in (0, 1)) for name, phases in GROUPS}
    steps_px4 = cal.reference(ref, "steps")
    steps_sim = [cal.replay(ref, "steps", seed=s) for s in seeds]
    step_names = [str(n) for n in ref["steps/phase_names"] if str(n).startswith("step")]
    steps = {n: (cal.step_metrics(ref, steps_px4, n),
                 _mean_dicts([cal.step_metrics(ref, f, n) for f in steps_sim]))
             for n in step_names}
    hover_sim = [cal.hover_stats(ref, cal.replay(ref, "hover", seed=s)) for s in seeds]
    loss_sim = cal.replay(ref, "loss", seed=seeds[0])
    arm = ref["arm/hb_latency"]
    return {
        "seeds": tuple(seeds), "runs": runs, "groups": groups, "steps": steps, "kinds": kinds,
        "hover": (cal.hover_stats(ref, cal.reference(ref, "hover")), _mean_dicts(hover_sim)),
        "takeoff": (cal.px4_takeoff(ref), _mean_dicts([cal.sim_takeoff(seed=s)
                                                       for s in seeds])),
        "loss": (cal.loss_timing(ref, cal.reference(ref, "loss")),
                 cal.loss_timing(ref, loss_sim)),
        "arm": (arm[np.isfinite(arm)], cal.arm_latency(arm_trials)),
        "flights": {"tracking": (px4_track, sim_track[0]), "loss": loss_sim}, "ref": ref,
    }


def _mean_dicts(items: list[dict[str, Any]]) -> dict[str, Any]:
    return {k: np.nanmean(np.array([d[k] for d in items], dtype=float), axis=0)
            for k in items[0] if not isinstance(items[0][k], str)}


def _f(x: float, nd: int = 2) -> str:
    return "n/a" if not math.isfinite(float(x)) else f"{float(x):.{nd}f}"


def markdown(res: dict[str, Any]) -> str:
    """The tables of docs/sitl.md ("Calibration")."""
    out = [f"Vehicle: mean over noise seeds {', '.join(map(str, res['seeds']))}.", "",
           "| run | lag (s) PX4 / sitl | RMS error (m) | max error (m) | overshoot after end (m) "
           "| mean distance 0-2 s after end (m) | residual 3-4 s after end (m) "
           "| settled to 0.5 m after (s) |", "|---|---|---|---|---|---|---|---|"]
    fields = ("lag_s", "rms_m", "max_m", "overshoot_m", "mean_after_m", "residual_m",
              "settle_s")
    for name, (a, b) in list(res["runs"].items()) + list(res["groups"].items()):
        bold = "**" if name in res["groups"] else ""
        cells = [f"{_f(getattr(a, k))} / {_f(getattr(b, k))}" for k in fields]
        out.append(f"| {bold}{name}{bold} | " + " | ".join(cells) + " |")
    out += ["", "| position step | size (m) PX4 / sitl | delay to 10 % (s) | rise 10-90 % (s) "
            "| overshoot (%) | peak speed (m/s) |", "|---|---|---|---|---|---|"]
    for name, (a, b) in res["steps"].items():
        cells = [f"{_f(a[k], 1 if k == 'overshoot_pct' else 2)} / "
                 f"{_f(b[k], 1 if k == 'overshoot_pct' else 2)}"
                 for k in ("size_m", "delay_s", "rise_s", "overshoot_pct", "peak_speed_m_s")]
        out.append(f"| {name} | " + " | ".join(cells) + " |")
    hp, hs = res["hover"]
    tp, ts = res["takeoff"]
    lp, ls = res["loss"]
    ap, asim = res["arm"]

    def trio(v: np.ndarray) -> str:
        return " / ".join(f"{x:.2f}" for x in v)

    out += ["", "| hover, takeoff, offboard loss, arming | PX4 | sitl |", "|---|---|---|",
            f"| hover: std of the estimate x / y / z (m) | {trio(hp['std_m'])} | "
            f"{trio(hs['std_m'])} |",
            f"| hover: std of the velocity x / y / z (m/s) | {trio(hp['vel_std_m_s'])} | "
            f"{trio(hs['vel_std_m_s'])} |",
            f"| hover: largest distance from the setpoint in 30 s (m) | {hp['max_m']:.2f} | "
            f"{hs['max_m']:.2f} |",
            f"| hover: estimate - truth, std x / y / z (m) | "
            f"{trio(hp['est_minus_truth_std_m'])} | {trio(hs['est_minus_truth_std_m'])} |"]
    for key, label in (("t_0.5m_s", "takeoff: command -> 0.5 m above home (s)"),
                       ("t_hold_s", "takeoff: command -> Hold (s)"),
                       ("alt_at_hold_m", "takeoff: altitude at Hold (m; target 2.0)"),
                       ("t_1.8m_s", "takeoff: command -> 1.8 m (s)"),
                       ("alt_4s_after_hold_m", "takeoff: altitude 4-5 s after Hold (m)"),
                       ("max_alt_m", "takeoff: highest until then (m)")):
        out.append(f"| {label} | {tp[key]:.2f} | {ts[key]:.2f} |")
    out += [f"| offboard loss: last setpoint -> {lp[0]['failsafe_mode']} (s; 50 Hz samples) | "
            f"{', '.join(_f(x['loss_to_mode_s']) for x in lp)} | "
            f"{', '.join(_f(x['loss_to_mode_s']) for x in ls)} |",
            f"| offboard loss: failsafe mode | {', '.join(x['failsafe_mode'] for x in lp)} | "
            f"{', '.join(x['failsafe_mode'] for x in ls)} |",
            "| setpoints back -> OFFBOARD without a mode command (s; 50 Hz samples) | "
            f"{', '.join(_f(x['resume_to_offboard_s'], 3) for x in lp)} | "
            f"{', '.join(_f(x['resume_to_offboard_s'], 3) for x in ls)} |",
            f"| arm -> first armed HEARTBEAT (s), median / max (trials) | "
            f"{np.median(ap):.2f} / {ap.max():.2f} ({ap.size}) | "
            f"{np.median(asim):.2f} / {asim.max():.2f} ({asim.size}) |"]
    return "\n".join(out) + "\n"


def plot(res: dict[str, Any], path: str) -> None:
    """Four panels: a line and a circle at 2 m/s, the takeoff, an offboard loss."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ref = res["ref"]
    px4, sim = res["flights"]["tracking"]
    fig, axes = plt.subplots(2, 2, figsize=(11, 8))
    t0, t1 = phase_span(ref, "tracking", "line_v2_out")
    _, t2 = phase_span(ref, "tracking", "line_v2_out_hold")
    ax = axes[0, 0]
    for name, fl, style in (("PX4", px4, "-"), ("sitl", sim, "--")):
        m = (fl.t >= t0 - 1) & (fl.t <= t2)
        ax.plot(fl.t[m] - t0, fl.pos[m, 0], style, label=f"{name} estimate x")
    tt = np.linspace(t0 - 1, t2, 400)
    ax.plot(tt - t0, cal.setpoint_position(ref, "tracking", tt)[:, 0], "k:", label="setpoint")
    ax.axvline(t1 - t0, color="grey", lw=0.5)
    ax.set(title="10 m line, peak 2 m/s", xlabel="s", ylabel="x north (m)")
    ax.legend(fontsize=8)
    ax = axes[0, 1]
    t0, t1 = phase_span(ref, "tracking", "circle_v2")
    for name, fl, style in (("PX4", px4, "-"), ("sitl", sim, "--")):
        m = (fl.t >= t0) & (fl.t <= t1)
        ax.plot(fl.pos[m, 1], fl.pos[m, 0], style, label=name)
    tt = np.linspace(t0, t1, 800)
    p = cal.setpoint_position(ref, "tracking", tt)
    ax.plot(p[:, 1], p[:, 0], "k:", label="setpoint")
    ax.set(title="circle r = 3 m, 2 m/s", xlabel="y east (m)", ylabel="x north (m)",
           aspect="equal")
    ax.legend(fontsize=8)
    ax = axes[1, 0]
    t, z = ref["takeoff/t"], ref["takeoff/z"]
    home = float(np.mean(z[(t > -1) & (t < 0)]))
    ax.plot(t, home - z, label="PX4")
    sim_t, sim_alt, _ = cal.sim_takeoff_trace(seed=1)
    ax.plot(sim_t, sim_alt, "--", label="sitl")
    ax.axhline(2.0, color="k", ls=":", lw=0.8)
    ax.set(title="takeoff to 2 m (action.takeoff)", xlabel="s after the command",
           ylabel="altitude above home (m)", xlim=(-0.5, 12))
    ax.legend(fontsize=8)
    ax = axes[1, 1]
    loss = cal.reference(ref, "loss")
    sp_t = ref["loss/sp_t"]
    g = int(np.flatnonzero(np.diff(sp_t) > 0.5)[0])
    ta = float(sp_t[g])
    for name, fl, style in (("PX4", loss, "-"), ("sitl", res["flights"]["loss"], "--")):
        m = (fl.t >= ta - 2) & (fl.t <= ta + 6)
        ax.plot(fl.t[m] - ta, -fl.pos[m, 2], style, label=f"{name} altitude")
        rtl = m & (fl.mode == "AUTO_RTL")
        ax.plot(fl.t[rtl] - ta, np.full(rtl.sum(), 1.0 if name == "PX4" else 0.9), ".",
                ms=2, label=f"{name} in Return")
    ax.axvline(0.0, color="grey", lw=0.5)
    ax.axvline(float(sp_t[g + 1]) - ta, color="grey", lw=0.5)
    ax.set(title="offboard loss at 2 m/s, setpoints back after 3 s", xlabel="s after the last "
           "setpoint", ylabel="m")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sitl.calibration_report")
    ap.add_argument("--png", default="docs/sitl-calibration.png")
    ap.add_argument("--seeds", type=int, default=3)
    args = ap.parse_args(argv)
    res = compare(tuple(range(1, args.seeds + 1)))
    plot(res, args.png)
    print(markdown(res))
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
