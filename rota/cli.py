"""rota: re-time planner trajectories with ROTA (Robust Optimal Time Allocation).

Re-time a trajectory message (docs/protocol.md) into a result message, write the
bundled example, or re-time and plot the example (the paper's Table II with peers
is "rota-sitl bench": docs/benchmarks.md). "rota COMMAND --help" describes each
command.

Exit status: 0 the optimal re-time was found; 1 the command cannot run here (a
missing optional dependency); 2 bad input (the error names the offending field
or option); 3 the result is the fallback (still written; its message says why);
4 the path is rejected as unsafe (it passes through an obstacle of --map);
130 interrupted (Ctrl-C).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import threading
import time
from importlib import resources
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import numpy as np

from rota.braking import BrakingParams
from rota.chance import ChanceParams, UncertaintyModel
from rota.errors import InputError
from rota.problem import Limits, RetimeInput
from rota.result import REJECTED
from rota.retime import retime
from rota.robust import Safety
from rota.schema import dump, load, result_to_dict, trajectory_from_dict
from rota.trajectory import Trajectory
from rota.voxelmap import VoxelMap

EXIT_OK, EXIT_UNAVAILABLE, EXIT_INPUT, EXIT_FALLBACK, EXIT_REJECTED = 0, 1, 2, 3, 4
#: Default cap on the size of a re-time: trajectory points, grid nodes
#: (duration / dtau) and setpoints written (duration x rate); --max-points overrides.
MAX_POINTS = 100_000
#: Coordinates beyond this (m) are taken for a unit mix-up.
MAX_COORDINATE_M = 1e6
#: Re-times with more grid nodes than this print a progress line.
PROGRESS_NODES = 3000
PLOT_FORMATS = (".png", ".svg", ".pdf")


def _floats(text: str) -> list[float]:
    try:
        return [float(x) for x in text.split(",")]
    except ValueError:
        msg = f"expected comma-separated numbers, got {text!r}"
        raise argparse.ArgumentTypeError(msg) from None


def _vec3(text: str) -> list[float]:
    values = _floats(text)
    if len(values) != 3:
        raise argparse.ArgumentTypeError(f"expected x,y,z, got {text!r}")
    return values


def add_retime_options(p: argparse.ArgumentParser) -> None:
    """Options shared by every command that re-times."""
    g = p.add_argument_group("re-timing")
    g.add_argument("--v-max", type=float, default=2.0, help="speed limit, m/s (default 2.0)")
    g.add_argument("--a-max", type=_floats, default=[3.0],
                   help="acceleration limit per axis, m/s^2: one value or ax,ay,az (default 3)")
    g.add_argument("--j-max", type=_floats, default=None,
                   help="jerk limit per axis, m/s^3: one value or jx,jy,jz (default none; "
                        "PX4's MPC_JERK_AUTO is 4)")
    g.add_argument("--lambda", dest="smoothness", type=float, default=0.5,
                   help="smoothness weight lambda (paper Eq. 10; default 0.5, 0 = time-optimal)")
    g.add_argument("--dtau", type=float, default=0.1,
                   help="trajectory-time grid step, s (default 0.1)")
    g.add_argument("--start-velocity", type=_vec3, default=[0.0, 0.0, 0.0],
                   help="vehicle velocity at the start, x,y,z m/s (default rest)")


def add_safety_options(p: argparse.ArgumentParser) -> None:
    """Map and uncertainty options (paper Sec. III-B/C); without --map none apply."""
    g = p.add_argument_group("robustness (with --map)")
    g.add_argument("--map", help="occupancy map: rota/map JSON, or a point cloud "
                   "(.ply, .pcd, .npy, .csv) voxelised at --map-resolution")
    g.add_argument("--map-resolution", type=float, default=0.1,
                   help="voxel size for point-cloud maps, m (default 0.1)")
    g.add_argument("--inflate", type=float, default=0.0,
                   help="inflate the map by this radius, m (default 0: the robot "
                   "ellipsoid --semi-axes accounts for the robot's size)")
    g.add_argument("--m", type=float, default=0.2,
                   help="uncertainty slope: std = m * speed + b (default 0.2)")
    g.add_argument("--b", type=float, default=-0.1, help="uncertainty offset, m (default -0.1)")
    g.add_argument("--per-axis", action="store_true",
                   help="use the per-axis velocity in the uncertainty model (paper's "
                   "literal Eq. 15; frame-dependent) instead of the speed")
    g.add_argument("--delta", type=float, default=1e-4,
                   help="collision probability bound per sample (default 1e-4 = 0.01 %%)")
    g.add_argument("--semi-axes", type=_floats, default=[0.3],
                   help="robot safety ellipsoid semi-axes, m: one value or a,b,c (default 0.3)")
    g.add_argument("--obstacle-std", type=float, default=0.03,
                   help="obstacle position std, m (default 0.03)")
    g.add_argument("--v-floor", type=float, default=0.5,
                   help="lowest speed limit the chance constraint imposes, m/s (default 0.5)")
    g.add_argument("--d-th", type=float, default=0.0,
                   help="also brake for every obstacle within this distance, m (default 0: "
                        "braking zones follow the risk alone)")
    g.add_argument("--paper-zones", action="store_true",
                   help="braking zones by the paper's fixed threshold --d-th alone (Eq. 6), "
                        "not by the risk")


def load_map(path: str, resolution: float) -> VoxelMap:
    if path.lower().endswith(".json"):
        return VoxelMap.from_dict(load(path))
    return VoxelMap.from_file(path, resolution)


def build_safety(args: argparse.Namespace) -> Safety | None:
    if not args.map:
        return None
    vmap = load_map(args.map, args.map_resolution)
    if args.inflate > 0:
        vmap = vmap.inflated(args.inflate)
    axes = args.semi_axes * 3 if len(args.semi_axes) == 1 else args.semi_axes
    return Safety(
        map=vmap,
        uncertainty=UncertaintyModel(m=args.m, b=args.b, per_axis=args.per_axis),
        chance=ChanceParams(delta=args.delta, semi_axes=tuple(axes),
                            obstacle_std=(args.obstacle_std,) * 3,
                            v_floor=min(args.v_floor, args.v_max), v_max=args.v_max),
        braking=BrakingParams(d_th=args.d_th, risk=not args.paper_zones),
    )


def build_input(args: argparse.Namespace, trajectory: Trajectory) -> RetimeInput:
    a_max = args.a_max[0] if len(args.a_max) == 1 else tuple(args.a_max)
    j = getattr(args, "j_max", None)
    j_max = None if j is None else (j[0] if len(j) == 1 else tuple(j))
    return RetimeInput(trajectory=trajectory, limits=Limits(args.v_max, a_max, j_max),
                       smoothness=args.smoothness, dtau=args.dtau,
                       start_velocity=np.asarray(args.start_velocity),
                       safety=build_safety(args))


def _size(trajectory: Trajectory) -> int:
    """Points of a trajectory: control points, samples or polynomial segments."""
    from rota.trajectory import Window

    base = trajectory.base if isinstance(trajectory, Window) else trajectory
    for name in ("control_points", "t", "durations"):
        if hasattr(base, name):
            return len(getattr(base, name))
    return 0


def check_retime_args(args: argparse.Namespace, trajectory: Trajectory) -> None:
    """Caps and checks before any work: every error names the option."""
    cap = args.max_points
    if args.rate is not None and not (math.isfinite(args.rate) and args.rate > 0):
        raise InputError("--rate", f"must be a positive number of Hz, got {args.rate:g}")
    if args.plot and Path(args.plot).suffix.lower() not in PLOT_FORMATS:
        raise InputError("--plot", f"{args.plot}: use a .png, .svg or .pdf file name")
    if not (math.isfinite(args.dtau) and args.dtau > 0):
        raise InputError("--dtau", f"must be positive, got {args.dtau:g}")
    points = _size(trajectory)
    if points > cap:
        raise InputError("trajectory", f"{points} points is over the cap of {cap} "
                         "(--max-points N to allow more; memory and time grow with it)")
    lo, hi = trajectory.domain
    p = trajectory.position(np.linspace(lo, hi, 201))
    if not np.all(np.isfinite(p)) or np.abs(p).max() > MAX_COORDINATE_M:
        raise InputError("trajectory", f"positions beyond {MAX_COORDINATE_M:g} m (or not "
                         "finite): wrong units?")
    nodes = (hi - lo) / args.dtau
    if nodes > cap:
        raise InputError("--dtau", f"{nodes:.0f} grid nodes (duration {hi - lo:.1f} s / dtau "
                         f"{args.dtau:g} s) is over the cap of {cap} (--max-points N to allow "
                         "more)")
    if args.rate is not None:
        # the re-timed duration is not known yet: assume up to 10x the planned one
        samples = 10 * (hi - lo) * args.rate
        if samples > cap:
            raise InputError("--rate", f"up to {samples:.0f} setpoints at {args.rate:g} Hz is "
                             f"over the cap of {cap} (--max-points N to allow more)")


class Progress:
    """A line on stderr while a long re-time runs: what it is and the time spent."""

    def __init__(self, what: str) -> None:
        self.what, self._stop = what, threading.Event()
        self._t0 = time.monotonic()
        self._tty = sys.stderr.isatty()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        every = 1.0 if self._tty else 10.0
        while not self._stop.wait(every):
            line = f"rota retime: {self.what}: {time.monotonic() - self._t0:.0f} s"
            print(("\r" + line) if self._tty else line, end="" if self._tty else "\n",
                  file=sys.stderr, flush=True)

    def __enter__(self) -> Progress:
        print(f"rota retime: {self.what} ...", file=sys.stderr, flush=True)
        self._thread.start()
        return self

    def __exit__(self, kind: type | None, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        end = "\n" if self._tty else ""
        if kind is None:
            print(f"{end}rota retime: {self.what}: done in {time.monotonic() - self._t0:.1f} s",
                  file=sys.stderr, flush=True)
        elif end:
            print(file=sys.stderr, flush=True)


class CtrlC:
    """While a re-time runs. Ctrl-C takes effect when the compiled step that runs
    returns (:mod:`rota.interrupt`), which on a long solve may take a while: if it
    has not within half a second, say so; a second Ctrl-C stops at once (exit
    130: nothing has been written yet). Watches the signal through Python's
    wakeup fd, which the C-level handler writes while the main thread computes."""

    def __enter__(self) -> CtrlC:
        self._done, self._thread, self._old = threading.Event(), None, None
        self._r, self._w = os.pipe()
        os.set_blocking(self._w, False)
        try:
            self._old = signal.set_wakeup_fd(self._w, warn_on_full_buffer=False)
        except ValueError:  # not the main thread
            return self
        self._thread = threading.Thread(target=self._watch, daemon=True)
        self._thread.start()
        return self

    def _watch(self) -> None:
        seen = 0
        while data := os.read(self._r, 64):
            seen += data.count(signal.SIGINT)
            if seen >= 2:
                print("rota retime: interrupted", file=sys.stderr, flush=True)
                os._exit(130)
            if seen == 1 and not self._done.wait(0.5):
                print("rota retime: Ctrl-C: stopping when the running solver step returns "
                      "(Ctrl-C again: now)", file=sys.stderr, flush=True)

    def __exit__(self, *exc: object) -> None:
        self._done.set()
        if self._old is not None:
            signal.set_wakeup_fd(self._old)
        os.close(self._w)  # the watcher reads the end of the pipe and returns
        if self._thread is not None:
            self._thread.join()
        os.close(self._r)


def check_setpoints(args: argparse.Namespace, duration: float) -> None:
    """The cap on setpoints, now that the re-timed duration is known."""
    if args.rate is None:
        return
    count = math.floor(duration * args.rate + 1e-9) + 2 if math.isfinite(duration) else math.inf
    if count > args.max_points:
        raise InputError("--rate", f"{count:.0f} setpoints ({duration:.1f} s re-timed at "
                         f"{args.rate:g} Hz) is over the cap of {args.max_points} "
                         "(--max-points N to allow more, or a lower --rate); nothing written")


def cmd_retime(args: argparse.Namespace) -> int:
    msg = trajectory_from_dict(load(args.input))
    check_retime_args(args, msg.trajectory)
    inp = build_input(args, msg.trajectory)
    lo, hi = msg.trajectory.domain
    nodes = int((hi - lo) / args.dtau)
    with CtrlC():
        if nodes > PROGRESS_NODES:
            with Progress(f"re-timing {_size(msg.trajectory)} points on {nodes} grid nodes"):
                result = retime(inp)
        else:
            result = retime(inp)
    check_setpoints(args, result.duration)
    out = result_to_dict(result, msg, rate_hz=args.rate)
    try:
        text = json.dumps(out, indent=1, allow_nan=False) + "\n"
    except ValueError:  # NaN or inf in the result: never write invalid JSON
        raise InputError("trajectory", "the re-timed result is not finite (values too "
                         "large?); nothing written") from None
    # with -o - the result is standard output; what is said about it goes to stderr
    say = sys.stderr if args.output == "-" else sys.stdout
    if args.output == "-":
        sys.stdout.write(text)
        sys.stdout.flush()
    else:
        Path(args.output).write_text(text)
    if result.status == REJECTED:  # its time mapping is a stand-in, never to be flown
        print(f"{msg.id or args.input}: rejected, not to be flown: {result.message}", file=say)
    else:
        print(f"{msg.id or args.input}: {result.status}; duration "
              f"{msg.trajectory.duration:.3f} s -> {result.duration:.3f} s"
              + (f" ({result.message})" if result.message else ""), file=say)
    for w in result.warnings:
        print(f"warning: {w}", file=say)
    zones = result.diagnostics.intervals
    if inp.safety is not None:
        shown = ", ".join(f"{float(a):.2f}-{float(b):.2f}" for a, b in zones) or "none"
        print(f"braking zones (trajectory time, s): {shown}", file=say)
    if args.plot:
        from rota.plot import plot_result

        obstacles = None if inp.safety is None else inp.safety.map.occupied
        print(f"plot: {plot_result(result, inp.limits, args.plot, obstacles, title=msg.id)}",
              file=say)
    if result.status == REJECTED:
        return EXIT_REJECTED
    return EXIT_OK if result.ok else EXIT_FALLBACK


def example_path() -> Path:
    return Path(str(resources.files("rota") / "data" / "example_trajectory.json"))


def cmd_example(args: argparse.Namespace) -> int:
    text = example_path().read_text()
    if args.output == "-":
        sys.stdout.write(text)
    else:
        Path(args.output).write_text(text)
        print(f"wrote {args.output}")
    return EXIT_OK


def cmd_demo(args: argparse.Namespace) -> int:
    """Re-time the bundled example (paper sample trajectory 1 limits) and plot it."""
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    msg = trajectory_from_dict(json.loads(example_path().read_text()))
    limits = Limits(1.0, 3.0)
    result = retime(RetimeInput(trajectory=msg.trajectory, limits=limits))
    dump(result_to_dict(result, msg, rate_hz=50.0), out / "example_result.json")
    from rota.plot import plot_result

    png = plot_result(result, limits, out / "example_retime.png",
                      title="Example: planned at 1 m/s, 3 m/s² - re-timed with ROTA")
    print(f"example trajectory: {msg.trajectory.duration:.2f} s as planned -> "
          f"{result.duration:.2f} s re-timed ({result.status}) {result.message}")
    print(f"wrote {out / 'example_result.json'} and {png}")
    return EXIT_OK if result.ok else EXIT_FALLBACK


def package_version() -> str:
    """(companion.entry has the same for the other CLIs: the library cannot import it)"""
    try:
        return version("rota-companion")
    except PackageNotFoundError:  # pragma: no cover - a source tree
        return "unknown"


def make_parser() -> argparse.ArgumentParser:
    doc = (__doc__ or "").split("\n\n")
    parser = argparse.ArgumentParser(prog="rota", description=doc[1], epilog=doc[2],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("retime", help="re-time a trajectory message (JSON)")
    p.add_argument("input", help="rota/trajectory JSON file")
    p.add_argument("-o", "--output", required=True,
                   help="where to write the rota/result JSON (- for standard output)")
    p.add_argument("--plot", help="also write a plot (PNG/SVG/PDF)")
    p.add_argument("--rate", type=float, default=None,
                   help="also write setpoints sampled at this rate (Hz)")
    p.add_argument("--max-points", type=int, default=MAX_POINTS,
                   help=f"refuse larger work: trajectory points, grid nodes (duration / "
                   f"dtau) or setpoints (re-timed duration x rate; checked again after "
                   f"the solve) (default {MAX_POINTS})")
    add_retime_options(p)
    add_safety_options(p)
    p.set_defaults(func=cmd_retime)

    p = sub.add_parser("example", help="write the bundled example trajectory")
    p.add_argument("-o", "--output", default="-", help="file, or - for stdout (default)")
    p.set_defaults(func=cmd_example)

    p = sub.add_parser("demo", help="re-time the bundled example and plot it")
    p.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    p.set_defaults(func=cmd_demo)

    return parser


def main(argv: list[str] | None = None) -> int:
    parser = make_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except InputError as exc:
        print(f"rota {args.command}: bad input: {exc}", file=sys.stderr)
        return EXIT_INPUT
    except OSError as exc:
        print(f"rota {args.command}: {exc}", file=sys.stderr)
        return EXIT_INPUT
    except ModuleNotFoundError as exc:
        print(f"rota {args.command}: needs {exc.name}, which is not installed",
              file=sys.stderr)
        return EXIT_UNAVAILABLE
    except KeyboardInterrupt:
        print(f"rota {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
