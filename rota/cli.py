"""The ``rota`` command line.

Commands (``rota COMMAND --help`` for each):

* ``rota retime IN.json -o OUT.json [--plot OUT.png]``: re-time a trajectory
  message (``docs/protocol.md``) and write a result message.
* ``rota example [-o FILE]``: write the bundled example trajectory.
* ``rota demo [--out DIR]``: re-time the bundled example and plot it.
* ``rota bench [--out DIR] [--quick] [--repeats N]``: the paper's Table II with
  peers (``docs/benchmarks.md``).

Exit status: 0 when the optimal re-time was found, 3 when the result is the
fallback (the result is still written, its ``message`` says why), 4 when the
path is rejected as unsafe (it passes through an obstacle of ``--map``), 2 for
bad input (the error names the offending field).
"""

from __future__ import annotations

import argparse
import json
import sys
from importlib import resources
from pathlib import Path

import numpy as np

from rota.bench import add_bench_parser
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

EXIT_OK, EXIT_INPUT, EXIT_FALLBACK, EXIT_REJECTED = 0, 2, 3, 4


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
    g.add_argument("--d-th", type=float, default=1.0,
                   help="braking-zone distance threshold, m (default 1.0)")


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
        braking=BrakingParams(d_th=args.d_th),
    )


def build_input(args: argparse.Namespace, trajectory: Trajectory) -> RetimeInput:
    a_max = args.a_max[0] if len(args.a_max) == 1 else tuple(args.a_max)
    return RetimeInput(trajectory=trajectory, limits=Limits(args.v_max, a_max),
                       smoothness=args.smoothness, dtau=args.dtau,
                       start_velocity=np.asarray(args.start_velocity),
                       safety=build_safety(args))


def cmd_retime(args: argparse.Namespace) -> int:
    msg = trajectory_from_dict(load(args.input))
    inp = build_input(args, msg.trajectory)
    result = retime(inp)
    dump(result_to_dict(result, msg, rate_hz=args.rate), args.output)
    print(f"{msg.id or args.input}: {result.status}; duration {msg.trajectory.duration:.3f} s "
          f"-> {result.duration:.3f} s" + (f" ({result.message})" if result.message else ""))
    for w in result.warnings:
        print(f"warning: {w}")
    zones = result.extras.get("intervals", ())
    if inp.safety is not None:
        print(f"braking zones (trajectory time): {[tuple(round(x, 2) for x in z) for z in zones]}")
    if args.plot:
        from rota.plot import plot_result

        obstacles = None if inp.safety is None else inp.safety.map.occupied
        print(f"plot: {plot_result(result, inp.limits, args.plot, obstacles, title=msg.id)}")
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


def make_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="rota", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("retime", help="re-time a trajectory message (JSON)")
    p.add_argument("input", help="rota/trajectory JSON file")
    p.add_argument("-o", "--output", required=True, help="where to write the rota/result JSON")
    p.add_argument("--plot", help="also write a plot (PNG/SVG/PDF)")
    p.add_argument("--rate", type=float, default=None,
                   help="also write setpoints sampled at this rate (Hz)")
    add_retime_options(p)
    add_safety_options(p)
    p.set_defaults(func=cmd_retime)

    p = sub.add_parser("example", help="write the bundled example trajectory")
    p.add_argument("-o", "--output", default="-", help="file, or - for stdout (default)")
    p.set_defaults(func=cmd_example)

    p = sub.add_parser("demo", help="re-time the bundled example and plot it")
    p.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    p.set_defaults(func=cmd_demo)

    add_bench_parser(sub)
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


if __name__ == "__main__":
    sys.exit(main())
