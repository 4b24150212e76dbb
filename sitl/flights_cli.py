"""rota-sitl's flights: the simulated demo, and the flights that prove the service.

``rota-sitl demo`` flies the flight service (in this process) through a forest on the
simulated vehicle, or real PX4 SITL with ``--px4``; ``bench-stream`` measures the
setpoint stream's jitter while re-times run back to back; ``soak`` flies N minutes with
replans at 10 Hz (memory, errors, gaps, footprint); ``startup`` times the service's start
to ``READY=1``; ``fuzz`` sends hostile and
oversized messages on every input while flying; ``parity`` flies the demo N times on
each backend and tabulates the spread. They live here, not in
``rota-companion``: the flight service never imports the simulator.

Exit status: 0 success; 1 a failure at run time (the demo did not reach its goal, a
proving flight found a problem); 2 a bad option (it is named); 130 interrupted (Ctrl-C).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from companion.cli import RunError, UsageError, _positive, one_line, setup_logging


def cmd_demo(args: argparse.Namespace) -> int:
    from sitl.demo import run_demo

    setup_logging("WARNING" if not args.verbose else "INFO")
    try:
        summary = run_demo(out_dir=args.out, seed=args.seed, speed=args.speed,
                           px4_build=args.px4)
    except TimeoutError as exc:  # a step of the flight did not happen in time
        raise RunError(f"the demo did not complete: {exc}") from None
    return 0 if summary["reached_goal"] and not summary["collisions"] else 1


def cmd_bench_stream(args: argparse.Namespace) -> int:
    from sitl.bench_stream import run_bench_stream

    _positive(args, "seconds")
    setup_logging("WARNING")
    run_bench_stream(args.out, args.seconds)
    return 0


def cmd_soak(args: argparse.Namespace) -> int:
    from sitl.soak import run_soak

    _positive(args, "minutes")
    setup_logging("WARNING")
    figures = run_soak(args.minutes, seed=args.seed)
    print(figures.summary())
    for t, mb in figures.rss_mb:
        print(f"  RSS at {t:7.1f} s: {mb:.1f} MB")
    for e in figures.errors[:20]:
        print(f"  error: {e}")
    if figures.reaction_ms:
        r = figures.reaction_ms
        print(f"reaction, trajectory arrival to its first setpoint ({r['count']} replans): "
              f"p50 {r['p50']} ms, p99 {r['p99']} ms, max {r['max']} ms; parts p50 (p99): "
              + ", ".join(f"{k} {v} ({r['parts_p99'][k]})" for k, v in r["parts_p50"].items()))
    floor = figures.floor
    for what, usage in (("replanning at 10 Hz", figures.replanning),
                        ("holding, no replans", figures.holding)):
        if usage is not None:
            print(f"footprint of the service's process tree, {what}:\n{usage.table()}")
            if floor is not None and floor.cpu > 0:
                print(f"  = {usage.cpu / floor.cpu:.1f}x the floor's CPU and "
                      f"{usage.pss_mb / floor.pss_mb:.1f}x its PSS")
    if floor is not None:
        print(f"the floor (sitl/floor.py: the service's autopilot layer alone, 50 Hz "
              f"setpoints, same run):\n{floor.table()}")
    if args.out:
        from dataclasses import asdict

        Path(args.out).write_text(json.dumps(asdict(figures), indent=1, default=str) + "\n")
    print("OK" if not figures.problems else "PROBLEMS: " + "; ".join(figures.problems))
    return 0 if not figures.problems else 1


def cmd_fuzz(args: argparse.Namespace) -> int:
    from sitl.fuzz import run_fuzz
    from sitl.proving import Flight

    _positive(args, "examples")
    setup_logging("WARNING")
    flight = Flight(seed=args.seed)
    with flight:
        figures, window = run_fuzz(flight, args.examples, args.seed)
    stream = flight.figures(window, flight.sim.report.setpoints)
    print(figures.summary())
    print(f"vehicle side: {stream.summary()}")
    unsafe = stream.jumps + stream.outside_fence + stream.non_finite
    print(f"unsafe setpoints: {unsafe}; largest gap {stream.max_gap_s * 1e3:.1f} ms; "
          f"collisions: {len(flight.sim.report.collisions)}; service exit code "
          f"{flight.exit_code}")
    bad = figures.crashed or unsafe or stream.problems() or figures.replies < figures.queries
    return 1 if bad else 0


def cmd_parity(args: argparse.Namespace) -> int:
    from sitl.parity import run_parity

    _positive(args, "runs")
    setup_logging("WARNING")
    if args.tier_runs < 0:
        raise UsageError(f"--tier-runs: must be 0 or more, got {args.tier_runs}")
    if args.px4_from and not Path(args.px4_from).is_file():
        raise UsageError(f"--px4-from: no such file: {args.px4_from}")
    print(run_parity(args.runs, args.px4, args.out, args.tier_runs, args.px4_from))
    return 0


def cmd_startup(args: argparse.Namespace) -> int:
    from sitl.startup import run_startup

    _positive(args, "runs")
    setup_logging("WARNING")
    figures = run_startup(args.runs, cold=not args.no_cold)
    if args.out:
        Path(args.out).write_text(json.dumps(figures, indent=1) + "\n")
    return 0


def add_flight_commands(sub: argparse._SubParsersAction) -> None:
    """The flight commands, on ``rota-sitl``'s sub-command parser."""
    p = sub.add_parser("demo", help="simulated flight through a forest (no PX4 needed)")
    p.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    p.add_argument("--seed", type=int, default=3, help="world and noise seed (default 3)")
    p.add_argument("--speed", type=float, default=2.0, help="speed limit, m/s (default 2)")
    p.add_argument("-v", "--verbose", action="store_true", help="log the service's events")
    p.add_argument("--px4", metavar="BUILD_DIR", help="fly real PX4 SITL (the SIH quadrotor "
                   "of this PX4 build, e.g. PX4-Autopilot/build/px4_sitl_default) instead of "
                   "the sitl vehicle")
    p.set_defaults(func=cmd_demo)
    p = sub.add_parser("bench-stream", help="setpoint jitter while re-times run back to back")
    p.add_argument("--out", default=None, help="also write stream.json here")
    p.add_argument("--seconds", type=float, default=5.0,
                   help="how long to re-time back to back (default 5; the baseline is as long)")
    p.set_defaults(func=cmd_bench_stream)
    p = sub.add_parser("soak", help="fly N minutes with replans at 10 Hz; memory, errors, gaps")
    p.add_argument("--minutes", type=float, default=30.0, help="how long (default 30)")
    p.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    p.add_argument("--out", default=None, help="also write the figures as JSON here")
    p.set_defaults(func=cmd_soak)
    p = sub.add_parser("startup", help="the service's start to READY=1, the solver's cache "
                       "warm (after rota-companion warm-up) and empty")
    p.add_argument("--runs", type=int, default=5, help="starts on the warm cache (default 5)")
    p.add_argument("--no-cold", action="store_true", help="skip the start that compiles "
                   "(about a minute)")
    p.add_argument("--out", default=None, help="also write the figures as JSON here")
    p.set_defaults(func=cmd_startup)
    p = sub.add_parser("fuzz", help="hostile messages on every input while flying")
    p.add_argument("--examples", type=int, default=2000,
                   help="generated messages (default 2000), plus four oversized ones")
    p.add_argument("--seed", type=int, default=0, help="generator seed (default 0)")
    p.set_defaults(func=cmd_fuzz)
    p = sub.add_parser("parity", help="the demo flight (and the PX4 tier's flights) N times on "
                       "the sitl vehicle and on PX4 SITL, side by side (docs/sitl.md)")
    p.add_argument("--runs", type=int, default=10, help="demo flights per backend (default 10)")
    p.add_argument("--tier-runs", type=int, default=0, help="also fly the PX4 tier's "
                   "scenarios this many times per backend (default 0; about 3 min each)")
    p.add_argument("--px4", metavar="BUILD_DIR", help="also fly real PX4 SITL of this build")
    p.add_argument("--px4-from", metavar="JSON", help="take PX4's flights from this earlier "
                   "parity JSON instead of flying PX4 (after a change of the sitl vehicle)")
    p.add_argument("--out", default=None, help="write the Markdown table here (and JSON beside)")
    p.set_defaults(func=cmd_parity)


def make_parser() -> argparse.ArgumentParser:
    doc = (__doc__ or "").split("\n\n")
    parser = argparse.ArgumentParser(prog="rota-sitl", description=doc[1], epilog=doc[-1],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    add_flight_commands(parser.add_subparsers(dest="group", required=True, metavar="COMMAND"))
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = make_parser().parse_args(argv)
    if args.group == "demo":  # first contact: a word before the imports (seconds)
        print("demo: starting: loading the flight software ...", flush=True)
    # (fuzz needs the dev extra: hypothesis)
    return one_line(f"rota-sitl {args.group}", lambda: args.func(args), [
        (ModuleNotFoundError, 1, lambda exc: f"needs {exc.name}, which is not installed "
         "(pip install 'rota-companion[dev]')")])


if __name__ == "__main__":
    sys.exit(main())
