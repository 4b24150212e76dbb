"""rota-sitl: simulation experiments on the sitl stack, and the simulated flights
(demo, bench-stream, soak, fuzz: sitl/flights_cli.py).

Examples:
  rota-sitl demo                                                 # a flight through a forest
  rota-sitl experiment collision-rate                            # the full grid, 500 trials/cell
  rota-sitl experiment collision-rate --trials 4 --out /tmp/t1   # a quick check
  rota-sitl experiment memory-dose --seed 1 --trials 300         # the memory time's rule
  rota-sitl experiment px4 --px4 ../shared/px4-sitl              # ROTA and controls on PX4

Exit status: 0 the run finished (also when the hypothesis fails: the table says
whether it holds); 2 bad arguments; 130 interrupted (Ctrl-C).
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
from collections.abc import Sequence

from companion.cli import one_line
from companion.entry import package_version
from rota.chance import DEFAULT_MEMORY_S
from sitl.bench import add_bench_parser
from sitl.entry import FLIGHTS
from sitl.estimation import DRIFT, KINDS, EstimationErrorParams
from sitl.experiment import VEHICLES, ExperimentConfig, run_experiment
from sitl.experiment_px4 import Px4ExperimentConfig
from sitl.experiment_report import write_dose, write_outputs
from sitl.flights_cli import add_flight_commands
from sitl.flights_cli import main as flights_main
from sitl.px4 import PX4_ENV

#: The memory times of the dose-response (s).
DOSE_GRID = (0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0)


def _floats(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") \
            from None


def _kinds(text: str) -> tuple[str, ...]:
    kinds = tuple(x.strip() for x in text.split(","))
    bad = [k for k in kinds if k not in KINDS]
    if bad or len(set(kinds)) != len(kinds):
        raise argparse.ArgumentTypeError(f"expected distinct names from {', '.join(KINDS)}, "
                                         f"got {text!r}")
    return kinds


def _common(p: argparse.ArgumentParser, d: ExperimentConfig) -> None:
    e, dr = EstimationErrorParams(), DRIFT
    p.add_argument("--trials", type=int, default=d.trials, help="trials per cell")
    p.add_argument("--seed", type=int, default=d.seed, help="experiment seed")
    p.add_argument("--workers", type=int, default=d.workers, help="processes")
    p.add_argument("--chunk", type=int, default=d.chunk, help="trials per task")
    p.add_argument("--accel-ratio", type=float, default=d.accel_ratio,
                   help="a_max = RATIO * v_max")
    p.add_argument("--error-models", type=_kinds, default=tuple(x.kind for x in d.errors),
                   help=f"comma-separated error models ({', '.join(KINDS)})")
    p.add_argument("--error-slope", type=float, default=e.slope_s, help="m (s), both models")
    p.add_argument("--error-offset", type=float, default=e.offset_m, help="b (m), both models")
    p.add_argument("--error-tau", type=float, default=e.correlation_time_s,
                   help="correlated model: correlation time (s)")
    p.add_argument("--drift-tau", type=float, default=dr.correlation_time_s,
                   help="drift model: re-anchoring time (s)")
    p.add_argument("--vertical-scale", type=float, default=e.vertical_scale,
                   help="vertical error std as a share of the horizontal")
    p.add_argument("--vehicle", choices=tuple(VEHICLES), default=d.vehicle,
                   help="dynamics: calibrated to PX4's SIH quadrotor (default) or the idealised "
                        "point mass")
    p.add_argument("--d-th", type=float, default=None,
                   help="ROTA's braking zones by the paper's fixed threshold (m) instead of by "
                        "the risk (default) - sensitivity only")
    p.add_argument("--rejected", choices=("exclude", "fallback"), default=d.rejected,
                   help="trials whose path ROTA rejects: leave out of every arm (default) or "
                        "fly ROTA's fallback timing")
    p.add_argument("--clearance", type=float, default=d.clearance,
                   help="the reference planner's clearance beyond the robot's radius (m)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")


def _parser() -> argparse.ArgumentParser:
    doc = (__doc__ or "").split("\n\n")
    ap = argparse.ArgumentParser(prog="rota-sitl", description="Simulation experiments "
                                 "and flights.",
                                 epilog="\n\n".join(doc[1:]).strip(),
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
    sub = ap.add_subparsers(dest="group", required=True)
    add_flight_commands(sub)  # (run by sitl.flights_cli: the entry sends them there)
    add_bench_parser(sub)
    exp = sub.add_parser("experiment", help="run an experiment")
    which = exp.add_subparsers(dest="name", required=True)
    d = ExperimentConfig()
    cr = which.add_parser(
        "collision-rate",
        help="paper Table I with the controls: planner, ROTA, ROTA with error memory, and "
             "uniform slow-downs of the same duration (docs/table1.md)")
    _common(cr, d)
    cr.add_argument("--densities", type=_floats, default=d.densities,
                    help="comma-separated trees per m^2")
    cr.add_argument("--speeds", type=_floats, default=d.speeds, help="comma-separated v_max")
    cr.add_argument("--memory", type=float, default=DEFAULT_MEMORY_S,
                    help="memory time T of the error-memory arm (s)")
    cr.add_argument("--out", default="table1-out", help="output directory")
    dose = which.add_parser(
        "memory-dose",
        help="crash rate and flight time against ROTA's memory time in one cell, and the "
             "rule's pick of the default (docs/table1.md)")
    _common(dose, d)
    dose.add_argument("--density", type=float, default=0.063, help="trees per m^2")
    dose.add_argument("--speed", type=float, default=3.0, help="v_max (m/s)")
    dose.add_argument("--memories", type=_floats, default=DOSE_GRID,
                      help="comma-separated memory times (s)")
    dose.add_argument("--out", default="dose-out", help="output directory")
    p = Px4ExperimentConfig()
    px4 = which.add_parser(
        "px4", help="the planner's timing, ROTA and the equal-time uniform slow-down flown "
                    "on real PX4 SITL, judged on SIH's ground truth (docs/table1.md)")
    px4.add_argument("--px4", metavar="BUILD_DIR", default=os.environ.get(PX4_ENV),
                     help=f"the PX4 SITL build (default: ${PX4_ENV})")
    px4.add_argument("--trials", type=int, default=p.trials, help="forests, each flown per arm")
    px4.add_argument("--seed", type=int, default=p.seed, help="experiment seed")
    px4.add_argument("--workers", type=int, default=p.workers,
                     help="PX4 instances flying at once")
    px4.add_argument("--clearance", type=float, default=p.clearance,
                     help="the planner's clearance beyond the robot's radius (m)")
    px4.add_argument("--speed", type=float, default=p.speed, help="v_max (m/s)")
    px4.add_argument("--j-max", type=float, default=p.j_max,
                     help="also fly ROTA jerk-limited to this (m/s^3 per axis; PX4's "
                     "MPC_JERK_AUTO is 4) and measure every arm's RMS jerk (default 0: not)")
    px4.add_argument("--out", default="px4-out", help="output directory")
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``rota-sitl``; returns the exit status (0 also when the hypothesis
    fails: the run itself succeeded; the table says whether it holds)."""
    args = _parser().parse_args(argv)
    if args.group in FLIGHTS:
        return flights_main(argv)
    if args.group == "bench":  # (the peers are the bench extra's)
        return one_line("rota-sitl bench", lambda: args.func(args), [
            (ModuleNotFoundError, 1, lambda exc: f"needs {exc.name}, which is not installed "
             "(pip install 'rota-companion[bench]')"), (OSError, 1, str)])
    try:
        return _run(args, argv)
    except (ValueError, OSError) as exc:  # InputError too: the message names the field
        print(f"rota-sitl: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("rota-sitl: interrupted", file=sys.stderr)
        return 130


def _errors(args: argparse.Namespace) -> tuple[EstimationErrorParams, ...]:
    out = []
    for kind in args.error_models:
        tau = args.error_tau if kind == "correlated" else args.drift_tau
        out.append(EstimationErrorParams(slope_s=args.error_slope, offset_m=args.error_offset,
                                         correlation_time_s=tau, kind=kind,
                                         vertical_scale=args.vertical_scale))
    return tuple(out)


def _command(argv: Sequence[str] | None) -> str:
    shown = list(sys.argv[1:] if argv is None else argv)
    return "rota-sitl " + " ".join(shlex.quote(a) for a in shown)


def _run_px4(args: argparse.Namespace, argv: Sequence[str] | None) -> int:
    from sitl.experiment_px4 import run
    from sitl.experiment_px4_report import write

    if not args.px4:
        raise ValueError(f"--px4: name a PX4 SITL build directory (or set {PX4_ENV})")
    cfg = Px4ExperimentConfig(trials=args.trials, seed=args.seed, workers=args.workers,
                              clearance=args.clearance, speed=args.speed,
                              j_max=args.j_max)
    result = run(cfg, args.px4, lambda s: print(s, file=sys.stderr, flush=True))
    paths = write(result, args.out, _command(argv))
    print(paths["md"].read_text())
    print(f"wrote {paths['md']}, {paths['png']}, {paths['json']}")
    return 0


def _run(args: argparse.Namespace, argv: Sequence[str] | None) -> int:
    if args.name == "px4":
        return _run_px4(args, argv)
    for name in ("trials", "workers", "chunk"):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name}: must be at least 1, got {getattr(args, name)}")
    common = dict(accel_ratio=args.accel_ratio, trials=args.trials, seed=args.seed,
                  workers=args.workers, chunk=args.chunk, errors=_errors(args),
                  d_th=args.d_th, rejected=args.rejected, vehicle=args.vehicle,
                  clearance=args.clearance)
    if args.name == "collision-rate":
        memories = (0.0,) if args.memory == 0.0 else (0.0, args.memory)
        cfg = ExperimentConfig(densities=args.densities, speeds=args.speeds,
                               memories=memories, **common)
    else:
        cfg = ExperimentConfig(densities=(args.density,), speeds=(args.speed,),
                               memories=tuple(sorted(args.memories)), **common)
    progress = None if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True))
    result = run_experiment(cfg, progress)
    command = _command(argv)
    write = write_outputs if args.name == "collision-rate" else write_dose
    paths = write(result, args.out, command)
    with open(paths["md"]) as f:
        print(f.read())
    print(f"wrote {paths['md']}, {paths['png']}, {paths['json']}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
