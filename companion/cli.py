"""``rota-companion``: the flight service's command line.

* ``rota-companion run [--config FILE]``: run the service (systemd: Type=notify).
* ``rota-companion check-config FILE``: validate a configuration and print it.
* ``rota-companion demo [--out DIR] [--seed N]``: a simulated flight through a
  forest (the README's main job): no PX4 install, no Zenoh router needed.
* ``rota-companion bench-stream [--out DIR]``: setpoint-stream jitter at 50 Hz
  while 30 m, dtau = 0.01 s re-times run (``docs/benchmarks.md``).

Exit status: 0 success, 2 bad configuration, 1 other failure.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import os
import signal
import sys

from companion.config import ConfigError, load

_SYSLOG = {logging.DEBUG: 7, logging.INFO: 6, logging.WARNING: 4, logging.ERROR: 3,
           logging.CRITICAL: 2}


class _JournalFormatter(logging.Formatter):
    """``<priority>logger: message`` lines; journald reads the priority prefix and
    adds its own time stamps."""

    def format(self, record: logging.LogRecord) -> str:
        prio = _SYSLOG.get(record.levelno, 6)
        return f"<{prio}>{record.name}: {record.getMessage()}"


def setup_logging(level: str) -> None:
    handler = logging.StreamHandler(sys.stdout)
    if os.environ.get("JOURNAL_STREAM") or os.environ.get("INVOCATION_ID"):
        handler.setFormatter(_JournalFormatter())
    else:
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    logging.basicConfig(level=level.upper(), handlers=[handler], force=True)
    # MAVSDK's debug chatter only when asked for explicitly
    logging.getLogger("rota.mavsdk").setLevel(max(logging.INFO, logging.getLevelName(
        level.upper())))


async def _serve(cfg) -> None:  # noqa: ANN001
    from companion.service import Service

    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    await Service(cfg).run(stop)


def cmd_run(args: argparse.Namespace) -> int:
    cfg = load(args.config)
    setup_logging(cfg.service.log_level)
    asyncio.run(_serve(cfg))
    return 0


def cmd_check(args: argparse.Namespace) -> int:
    cfg = load(args.config)
    print(json.dumps(cfg.to_dict(), indent=1))
    print(f"{args.config}: OK", file=sys.stderr)
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from companion.demo import run_demo

    setup_logging("WARNING" if not args.verbose else "INFO")
    summary = run_demo(out_dir=args.out, seed=args.seed, speed=args.speed)
    return 0 if summary["reached_goal"] and not summary["collisions"] else 1


def cmd_bench_stream(args: argparse.Namespace) -> int:
    from companion.bench_stream import run_bench_stream

    setup_logging("WARNING")
    run_bench_stream(args.out, args.rounds)
    return 0


def make_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="rota-companion", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("run", help="run the flight service")
    p.add_argument("--config", help="TOML configuration (default: built-in defaults)")
    p.set_defaults(func=cmd_run)
    p = sub.add_parser("check-config", help="validate a configuration file")
    p.add_argument("config")
    p.set_defaults(func=cmd_check)
    p = sub.add_parser("demo", help="simulated flight through a forest (no PX4 needed)")
    p.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    p.add_argument("--seed", type=int, default=3, help="world and noise seed (default 3)")
    p.add_argument("--speed", type=float, default=2.0, help="speed limit, m/s (default 2)")
    p.add_argument("-v", "--verbose", action="store_true", help="log the service's events")
    p.set_defaults(func=cmd_demo)
    p = sub.add_parser("bench-stream", help="setpoint jitter while long re-times run")
    p.add_argument("--out", default=None, help="also write stream.json here")
    p.add_argument("--rounds", type=int, default=8, help="re-times to run (default 8)")
    p.set_defaults(func=cmd_bench_stream)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = make_parser().parse_args(argv)
    try:
        return int(args.func(args))
    except ConfigError as exc:
        print(f"rota-companion: configuration error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
