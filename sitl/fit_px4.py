"""Fit ROTA's deviation model (``s = max(m v_T + b, floor)``, memory ``T``) to the true
deviation of PX4's SIH vehicle from the commanded path, from the recorded flights
(``/work/shared/data/px4-sih/``: SIH's ground truth beside PX4's estimate and the setpoint).

What matters for a collision is the vehicle's **true** position across the commanded path:
the lag along the path is forgiven (a vehicle behind schedule is where the path was a moment
ago, which is collision-free), and the estimate's own error is included (the vehicle flies on
its estimate, so the truth is off by both). The deviation is measured as the service measures
its tracking error (the nearest point of the path commanded in the last second,
:func:`sitl.estimator_replay.path_deviation`), on the ground truth, per horizontal axis.

The fit is the estimator's own (:mod:`companion.uncertainty.estimator`, filterpy Kalman filters per
memory time) with a flat prior and no evidence rule: the maximum-likelihood line and memory
time. Its spread: the same fit on each quarter of every flight. The floor: the RMS per axis while
hovering (``06_hover_noise``).

Usage: ``python -m sitl.fit_px4 [DIR]`` prints the markdown that ``docs/estimator.md`` quotes.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from companion.uncertainty.estimator import EstimatorSettings
from rota.chance import UncertaintyModel
from sitl.estimator_replay import Flight, read, replay

DATA = Path("/work/shared/data/px4-sih")
#: The tracking flight (lines and circles at 1-3 m/s): paths a planner sends. The step
#: responses are left out: a setpoint that jumps is no path, its "deviation" is the jump.
FLIGHTS = ("04_tracking.csv",)
HOVER = "06_hover_noise.csv"
#: A flat prior and no evidence rule: the fit is the evidence's alone.
FLAT = EstimatorSettings(prior_std_m=10.0, prior_std_b=10.0, prior_weight_s=0.0,
                         min_samples=0, m_max=2.0, b_min=-1.0, b_max=2.0,
                         memory_evidence=0.0, forget_s=0.0)


def part(flight: Flight, sel: np.ndarray) -> Flight:
    return Flight(*(getattr(flight, f)[sel] for f in Flight.__dataclass_fields__))


def fit(flight: Flight) -> tuple[float, float, float, int]:
    """``(m, b, T, samples)`` of the true deviation off the path."""
    est = replay(flight, truth=True, prior=UncertaintyModel(m=0.0, b=0.3, memory_s=0.0),
                 settings=FLAT)
    best = min(est.fits(), key=lambda f: f.nll)
    return best.m, best.b, best.memory_s, est.samples


def run(data: Path) -> str:
    flights = {name: read(data / name) for name in FLIGHTS if (data / name).exists()}
    if not flights:
        raise ValueError(f"{data}: none of {', '.join(FLIGHTS)}")
    both = Flight(*(np.concatenate([getattr(f, k) for f in flights.values()])
                    for k in Flight.__dataclass_fields__))
    # (the second flight's times follow the first's, so the windows do not mix them)
    offset, ts = 0.0, []
    for f in flights.values():
        ts.append(f.t - f.t[0] + offset)
        offset = ts[-1][-1] + 100.0
    both = replace(both, t=np.concatenate(ts))
    m, b, memory, n = fit(both)
    lines = [f"Fit to the true deviation across the commanded path, {n} samples at 5 Hz from "
             f"{', '.join(flights)}: **m = {m:.3f} s, b = {b:.3f} m, T = {memory:g} s**.", "",
             "| part | samples | m (s) | b (m) | T (s) | std at 0.5 / 2 m/s (m) |",
             "|---|---|---|---|---|---|"]
    rows = []
    for name, f in flights.items():
        edges = np.linspace(f.t[0], f.t[-1] + 1e-9, 5)
        for q in range(4):
            sel = (f.t >= edges[q]) & (f.t < edges[q + 1])
            if sel.sum() < 50:
                continue
            pm, pb, pt, pn = fit(part(f, sel))
            rows.append((pm, pb))
            lines.append(f"| {name} quarter {q + 1} | {pn} | {pm:.3f} | {pb:.3f} | {pt:g} | "
                         f"{max(pm * 0.5 + pb, 0):.2f} / {max(pm * 2 + pb, 0):.2f} |")
    arr = np.array(rows)
    lines += ["", f"Spread over the {len(rows)} parts: m {arr[:, 0].min():.3f}-"
              f"{arr[:, 0].max():.3f} s, b {arr[:, 1].min():.3f}-{arr[:, 1].max():.3f} m."]
    if (data / HOVER).exists():
        try:
            hover = read(data / HOVER)
            floor = float(np.sqrt(np.mean(hover.truth**2)))
            lines.append(f"Hovering ({HOVER}, {len(hover.t)} samples): true deviation "
                         f"{floor:.3f} m RMS per axis (the floor).")
        except ValueError as exc:
            lines.append(f"Hovering: not used ({exc}).")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sitl.fit_px4",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("data", nargs="?", default=str(DATA))
    args = ap.parse_args(argv)
    try:
        print(run(Path(args.data)))
    except (OSError, ValueError, KeyError) as exc:
        print(f"fit_px4: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
