"""rota-sim: run the simulated PX4 vehicle in real time for MAVSDK / a companion computer.

Examples:
  rota-sim --world forest --seed 3            # MAVSDK: udpin://127.0.0.1:14540
  rota-sim --world none --port 14550 --duration 60

Exit status: 0 done; 1 the simulation failed; 2 bad arguments (an unknown
world, a port out of range); 130 interrupted before it started.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from typing import Any

from companion.entry import package_version
from rota.errors import InputError
from sitl.estimation import EstimationErrorParams
from sitl.vehicle import DEFAULT_COMPANION_PORT, SimVehicle, VehicleParams


def load_world(name: str | None, seed: int) -> Any | None:
    """World hook: the obstacle world named ``name`` (None / "none": no world).

    ``sitl.world`` is imported lazily so that the vehicle works without it. It must provide
    ``get_world(name, seed)`` returning an object with ``signed_distance((n, 3) ENU points)``,
    ``robot_radius`` and (optionally) ``start`` (ENU, where the vehicle is placed).
    """
    if name is None or name.lower() == "none":
        return None
    try:
        from sitl import world as world_module  # lazy: written separately
    except ImportError as exc:  # pragma: no cover - depends on the checkout
        raise SystemExit(f"rota-sim: cannot load worlds ({exc}); use --world none") from exc
    get_world = getattr(world_module, "get_world", None)
    if get_world is None:  # pragma: no cover
        raise SystemExit("rota-sim: sitl.world has no get_world(name, seed)")
    return get_world(name, seed=seed)


def _parser() -> argparse.ArgumentParser:
    doc = (__doc__ or "").split("\n\n")
    ap = argparse.ArgumentParser(
        prog="rota-sim",
        description="Simulated PX4 multicopter speaking MAVLink 2 over UDP on 127.0.0.1.",
        epilog="\n\n".join(doc[1:]).strip(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
    ap.add_argument("--world", default="none", help="world name from sitl.world, or 'none'")
    ap.add_argument("--seed", type=int, default=0, help="seed of the world and estimation error")
    ap.add_argument(
        "--port",
        type=int,
        default=DEFAULT_COMPANION_PORT,
        help="companion UDP port the vehicle sends to (MAVSDK: udpin://127.0.0.1:PORT)",
    )
    ap.add_argument("--bind-port", type=int, default=0, help="vehicle's own UDP port (0: any)")
    ap.add_argument("--duration", type=float, default=0.0, help="stop after N s (0: run forever)")
    ap.add_argument("--error-slope", type=float, default=None,
                    help="m in sigma = m*|v| + b (s); any --error-* option replaces PX4's "
                    "estimate error by this model (defaults 0.2, -0.1, 1.0)")
    ap.add_argument("--error-offset", type=float, default=None, help="b in sigma = m*|v| + b (m)")
    ap.add_argument("--error-tau", type=float, default=None, help="error correlation time (s)")
    ap.add_argument("--of-loss-t", type=float, default=1.0, help="COM_OF_LOSS_T (s)")
    return ap



def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``rota-sim`` console script; returns the exit code."""
    args = _parser().parse_args(argv)
    try:
        return _run(args)
    except InputError as exc:
        print(f"rota-sim: bad argument: {exc.message}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"rota-sim: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("rota-sim: interrupted", file=sys.stderr)
        return 130


def _run(args: argparse.Namespace) -> int:
    if not 0 < args.port < 65536 or not 0 <= args.bind_port < 65536:
        raise InputError("--port", f"ports are 1..65535, got {args.port} / {args.bind_port}")
    world = load_world(args.world, args.seed)
    start = getattr(world, "start", None)
    home_enu = (float(start[0]), float(start[1]), 0.0) if start is not None else (0.0, 0.0, 0.0)
    params = VehicleParams(home_enu_m=home_enu, com_of_loss_t_s=args.of_loss_t)
    est = None  # the vehicle's default: PX4's EKF in SIH
    given = {k: v for k, v in (("slope_s", args.error_slope), ("offset_m", args.error_offset),
                               ("correlation_time_s", args.error_tau)) if v is not None}
    if given:
        est = EstimationErrorParams(**given)
    sim = SimVehicle(
        params,
        estimation=est,
        world=world,
        seed=args.seed,
        port=args.port,
        bind_port=args.bind_port,
    )
    with sim:
        print(
            f"rota-sim: vehicle on 127.0.0.1:{sim.local_port} -> companion 127.0.0.1:{args.port}"
            f" (MAVSDK: udpin://127.0.0.1:{args.port}); world={args.world} seed={args.seed}",
            flush=True,
        )
        t_end = time.monotonic() + args.duration if args.duration > 0 else float("inf")
        try:
            while time.monotonic() < t_end and sim.running:
                time.sleep(min(0.1, max(0.0, t_end - time.monotonic())))
        except KeyboardInterrupt:
            pass
    for col in sim.collisions:
        p = col.position_enu
        print(f"collision at t={col.time_s:.2f}s ENU=({p[0]:.2f}, {p[1]:.2f}, {p[2]:.2f})")
    if sim.thread_error is not None:
        print(f"rota-sim: simulation thread failed: {sim.thread_error!r}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
