"""``rota-sitl``: simulation experiments on the sitl stack.

Example::

    rota-sitl experiment collision-rate                      # the full grid, 500 trials/cell
    rota-sitl experiment collision-rate --trials 4 --out /tmp/t1   # a quick check
"""

from __future__ import annotations

import argparse
import shlex
import sys
from collections.abc import Sequence

from sitl.estimation import EstimationErrorParams
from sitl.experiment import ExperimentConfig, run_experiment, write_outputs


def _floats(text: str) -> tuple[float, ...]:
    return tuple(float(x) for x in text.split(","))


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="rota-sitl", description="Simulation experiments.")
    sub = ap.add_subparsers(dest="group", required=True)
    exp = sub.add_parser("experiment", help="run an experiment")
    which = exp.add_subparsers(dest="name", required=True)
    cr = which.add_parser(
        "collision-rate",
        help="paper Table I: collision rates with / without ROTA (docs/table1.md)",
    )
    d = ExperimentConfig()
    e = EstimationErrorParams()
    cr.add_argument("--trials", type=int, default=d.trials, help="trials per cell")
    cr.add_argument("--seed", type=int, default=d.seed, help="experiment seed")
    cr.add_argument("--workers", type=int, default=d.workers, help="processes")
    cr.add_argument("--chunk", type=int, default=d.chunk, help="trials per task")
    cr.add_argument("--densities", type=_floats, default=d.densities,
                    help="comma-separated trees per m^2")
    cr.add_argument("--speeds", type=_floats, default=d.speeds, help="comma-separated v_max")
    cr.add_argument("--accel-ratio", type=float, default=d.accel_ratio,
                    help="a_max = RATIO * v_max")
    cr.add_argument("--error-slope", type=float, default=e.slope_s, help="m (s)")
    cr.add_argument("--error-offset", type=float, default=e.offset_m, help="b (m)")
    cr.add_argument("--error-tau", type=float, default=e.correlation_time_s,
                    help="noise correlation time (s)")
    cr.add_argument("--d-th", type=float, default=None,
                    help="ROTA braking threshold (m; default: ROTA's 1 m) - sensitivity only")
    cr.add_argument("--rejected", choices=("exclude", "fallback"), default=d.rejected,
                    help="trials whose path ROTA rejects: leave out of both arms (default) or "
                         "count ROTA as flying its fallback timing")
    cr.add_argument("--out", default="table1-out", help="output directory")
    cr.add_argument("--quiet", action="store_true", help="no progress lines")
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``rota-sitl``; returns the exit status (0 also when the hypothesis
    fails: the run itself succeeded; the table says whether it holds)."""
    args = _parser().parse_args(argv)
    est = EstimationErrorParams(slope_s=args.error_slope, offset_m=args.error_offset,
                                correlation_time_s=args.error_tau)
    cfg = ExperimentConfig(densities=args.densities, speeds=args.speeds,
                           accel_ratio=args.accel_ratio, trials=args.trials, seed=args.seed,
                           workers=args.workers, chunk=args.chunk, estimation=est,
                           d_th=args.d_th, rejected=args.rejected)
    progress = None if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True))
    result = run_experiment(cfg, progress)
    shown = list(sys.argv[1:] if argv is None else argv)
    command = "rota-sitl " + " ".join(shlex.quote(a) for a in shown)
    paths = write_outputs(result, args.out, command)
    with open(paths["md"]) as f:
        print(f.read())
    print(f"wrote {paths['md']}, {paths['png']}, {paths['json']}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
