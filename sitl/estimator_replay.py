"""Replay a recorded PX4 flight through the in-flight estimator and compare what it learns
with the deviation measured against the simulator's ground truth (docs/estimator.md).

The recording is a 50 Hz table of PX4 SIH flights (the project's reference data, columns as in
its README: ``t_s``, ``mode``, PX4's estimate ``x y z vx vy vz``, the ODOMETRY variances
``var_x var_y var_z`` on every 10th row, the setpoint on the wire ``sp_x sp_y sp_z`` and SIH's
ground truth ``gt_x gt_y gt_z``). The rows with variances (5 Hz, the service's learning rate)
in OFFBOARD are replayed. The deviation is measured as the service measures its tracking
error: from the commanded path of the last second (:func:`path_deviation`), so PX4's lag
along the path is forgiven and what is left is how far the vehicle is off the path:

* **learned**: the estimator fed what the companion has: PX4's speed, its estimate's deviation
  from the path and its reported std, horizontally;
* **truth-fed**: the same estimator fed the true deviation (ground truth off the path) and no
  reported std: what it would learn if it could see the truth.

Usage: ``python -m sitl.estimator_replay [CSV] [--plot PNG]``.
"""

from __future__ import annotations

import argparse
import csv
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from companion.uncertainty.estimator import EstimatorSettings, UncertaintyEstimator
from rota.chance import UncertaintyModel

#: The reference recording, where the project keeps it, and the extract shipped for the tests.
RECORDING = Path("/work/shared/data/px4-sih/04_tracking.csv")
EXTRACT = Path(__file__).resolve().parent / "data" / "px4_sih_tracking_5hz.csv"
COLUMNS = ("t_s", "mode", "x", "y", "z", "vx", "vy", "vz", "var_x", "var_y", "var_z",
           "sp_x", "sp_y", "sp_z", "gt_x", "gt_y", "gt_z")
#: Speed bins of the comparison (m/s).
BINS = (0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.5)
#: The service measures its tracking error against the setpoints of the last second
#: ([safety] tracking_lag_s).
LAG_S = 1.0


def path_deviation(t: np.ndarray, pos: np.ndarray, sp_t: np.ndarray, sp: np.ndarray,
                   lag_s: float = LAG_S) -> np.ndarray:
    """``pos[k]`` minus the nearest point of the commanded path of the last ``lag_s``: the
    polyline through the setpoints ``sp`` sent at ``sp_t`` in ``[t[k] - lag_s, t[k]]`` (the
    last one before, if none), as the service's tracking error (which takes the nearest of
    the setpoints it sent then)."""
    out = np.empty_like(pos)
    for k, (tk, p) in enumerate(zip(t, pos, strict=True)):
        sel = np.flatnonzero((sp_t >= tk - lag_s) & (sp_t <= tk))
        if not len(sel):
            sel = np.flatnonzero(sp_t <= tk)[-1:]
        pts = sp[sel]
        if len(pts) == 1:
            out[k] = p - pts[0]
            continue
        a, d = pts[:-1], np.diff(pts, axis=0)
        den = np.einsum("ij,ij->i", d, d)
        u = np.clip(np.einsum("ij,ij->i", p - a, d) / np.where(den > 0, den, 1.0), 0.0, 1.0)
        near = a + u[:, None] * d
        off = p - near
        out[k] = off[int(np.argmin(np.einsum("ij,ij->i", off, off)))]
    return out


@dataclass(frozen=True, eq=False)
class Flight:
    """The 5 Hz offboard samples of a recording (NED, SI)."""

    t: np.ndarray
    speed: np.ndarray
    track: np.ndarray  # (n, 2) estimate off the path of the last second, horizontal
    reported: np.ndarray  # (n, 2) PX4's position std, horizontal
    truth: np.ndarray  # (n, 2) ground truth off that path, horizontal
    est_error: np.ndarray  # (n, 2) estimate - ground truth, horizontal
    lagged: np.ndarray  # (n, 2) ground truth - the setpoint at the same time (lag included)


def read(path: Path) -> Flight:
    """The rows with ODOMETRY variances in OFFBOARD mode."""
    with open(path, newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["mode"] == "OFFBOARD" and r["var_x"]
                and r["gt_x"] and r["sp_x"]]
    if not rows:
        raise ValueError(f"{path}: no OFFBOARD rows with variances, setpoints and ground truth")

    def col(*names: str) -> np.ndarray:
        return np.array([[float(r[n]) for n in names] for r in rows])

    t = col("t_s")[:, 0]
    est, sp, gt = col("x", "y"), col("sp_x", "sp_y"), col("gt_x", "gt_y")
    return Flight(t, np.linalg.norm(col("vx", "vy", "vz"), axis=1),
                  path_deviation(t, est, t, sp), np.sqrt(col("var_x", "var_y")),
                  path_deviation(t, gt, t, sp), est - gt, gt - sp)


def extract(src: Path, dst: Path) -> int:
    """Write the replayed rows of ``src`` with the needed columns to ``dst``; their count."""
    with open(src, newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["mode"] == "OFFBOARD" and r["var_x"]
                and r["gt_x"] and r["sp_x"]]
    dst.parent.mkdir(parents=True, exist_ok=True)
    with open(dst, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        for r in rows:
            w.writerow([r[c] for c in COLUMNS])
    return len(rows)


def replay(flight: Flight, truth: bool = False, prior: UncertaintyModel | None = None,
           settings: EstimatorSettings | None = None) -> UncertaintyEstimator:
    """Feed the flight to a fresh estimator: what the companion sees, or (``truth``) the true
    deviation without a reported std."""
    est = UncertaintyEstimator(prior or UncertaintyModel(), settings or EstimatorSettings())
    for k in range(len(flight.t)):
        if truth:
            est.observe(float(flight.speed[k]), flight.truth[k], None, t=float(flight.t[k]))
        else:
            est.observe(float(flight.speed[k]), flight.track[k], flight.reported[k],
                        t=float(flight.t[k]))
    return est


def window_speed(flight: Flight, memory_s: float) -> np.ndarray:
    """Largest speed over the last ``memory_s`` seconds at every sample."""
    out = np.empty_like(flight.speed)
    for k, t in enumerate(flight.t):
        out[k] = flight.speed[(flight.t >= t - memory_s - 1e-9) & (flight.t <= t)].max()
    return out


def compare(flight: Flight) -> tuple[UncertaintyEstimator, UncertaintyEstimator, list[dict]]:
    """Both estimators and, per speed bin of the learned model's window speed, the RMS per
    axis of the true deviation, of what the companion sees, and the learned model's std."""
    learned, truth = replay(flight), replay(flight, truth=True)
    model = learned.estimate()
    v_t = window_speed(flight, model.memory_s)
    seen = np.sqrt(flight.track**2 + flight.reported**2)
    rows = []
    for lo, hi in zip(BINS, BINS[1:], strict=False):
        sel = (v_t >= lo) & (v_t < hi)
        if not sel.any():
            continue
        def rms(a: np.ndarray, sel: np.ndarray = sel) -> float:
            return float(np.sqrt(np.mean(a[sel] ** 2)))

        v = float(v_t[sel].mean())
        rows.append({"bin": (lo, hi), "n": int(sel.sum()), "speed": v,
                     "truth": rms(flight.truth), "seen": rms(seen),
                     "track": rms(flight.track), "est_error": rms(flight.est_error),
                     "reported": rms(flight.reported), "lagged": rms(flight.lagged),
                     "learned": max(model.m * v + model.b, 0.0)})
    return learned, truth, rows


def markdown(learned: UncertaintyEstimator, truth: UncertaintyEstimator,
             rows: list[dict]) -> str:
    a, b = learned.estimate(), truth.estimate()
    lines = [
        f"Learned from what the companion sees: m = {a.m:.3f} s, b = {a.b:.3f} m, "
        f"T = {a.memory_s:g} s ({learned.samples} samples).",
        f"Learned from the true deviation: m = {b.m:.3f} s, b = {b.b:.3f} m, "
        f"T = {b.memory_s:g} s.", "",
        "Per horizontal axis, binned by the largest speed of the last T s (RMS, m):", "",
        "| speed (m/s) | samples | true deviation from the setpoint, lag included | true "
        "deviation from the path | estimate's deviation from the path | PX4's std | estimate "
        "- truth | seen: deviation + PX4's std | learned model |",
        "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['bin'][0]:g}-{r['bin'][1]:g} | {r['n']} | {r['lagged']:.2f} | "
                     f"{r['truth']:.2f} | {r['track']:.2f} | {r['reported']:.2f} | "
                     f"{r['est_error']:.2f} | {r['seen']:.2f} | {r['learned']:.2f} |")
    lines += ["", "Log-likelihood per memory time (learned, relative to its best; truth-fed "
              "likewise):", "",
              "| T (s) | " + " | ".join(f"{f.memory_s:g}" for f in learned.fits()) + " |",
              "|---|" + "---|" * len(learned.fits())]
    for name, est in (("learned", learned), ("truth-fed", truth)):
        best = min(f.nll for f in est.fits())
        lines.append(f"| {name} | " + " | ".join(f"{best - f.nll:.1f}" for f in est.fits())
                     + " |")
    return "\n".join(lines) + "\n"


def plot(flight: Flight, learned: UncertaintyEstimator, truth: UncertaintyEstimator,
         rows: list[dict], path: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    v = np.linspace(0.0, 3.2, 50)
    for est, colour, label in ((learned, "tab:blue", "learned (what the companion sees)"),
                               (truth, "tab:red", "learned from the true deviation")):
        m = est.estimate()
        ax.plot(v, np.maximum(m.m * v + m.b, 0.0), color=colour,
                label=f"{label}: {m.m:.2f} v + {m.b:.2f}, T = {m.memory_s:g} s")
    sp = [r["speed"] for r in rows]
    ax.plot(sp, [r["truth"] for r in rows], "o", color="tab:red",
            label="true deviation from the path (RMS)")
    ax.plot(sp, [r["lagged"] for r in rows], "x", color="tab:red",
            label="true deviation from the setpoint, lag included (RMS)")
    ax.plot(sp, [r["seen"] for r in rows], "s", color="tab:blue", mfc="none",
            label="estimate's deviation + PX4's std (RMS)")
    ax.plot(sp, [r["est_error"] for r in rows], "^", color="grey",
            label="PX4's estimate - truth (RMS)")
    ax.set_xlabel("largest speed of the last T s (m/s)")
    ax.set_ylabel("per-axis deviation (m)")
    ax.legend(fontsize=7)
    for est, colour, name in ((learned, "tab:blue", "learned"), (truth, "tab:red", "truth")):
        fits = est.fits()
        best = min(f.nll for f in fits)
        ax2.plot([f.memory_s for f in fits], [best - f.nll for f in fits], "-o", color=colour,
                 label=name)
    ax2.set_xlabel("memory time T (s)")
    ax2.set_ylabel("log-likelihood - best (weighted samples)")
    ax2.legend(fontsize=8)
    fig.suptitle(f"PX4 SIH tracking flight replayed through the estimator ({len(flight.t)} "
                 "samples at 5 Hz)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sitl.estimator_replay",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("csv", nargs="?", default=str(RECORDING if RECORDING.exists() else EXTRACT))
    ap.add_argument("--plot", help="write the comparison plot here")
    args = ap.parse_args(argv)
    try:
        flight = read(Path(args.csv))
    except (OSError, ValueError, KeyError) as exc:
        print(f"estimator_replay: {exc}", file=sys.stderr)
        return 2
    learned, truth, rows = compare(flight)
    print(markdown(learned, truth, rows))
    if args.plot:
        plot(flight, learned, truth, rows, args.plot)
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
