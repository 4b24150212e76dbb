"""rota-companion: the flight service's command line.

Run the flight service (under systemd: Type=notify), check a configuration,
compile the solver into its cache ahead of the first start (warm-up), or make a
fleet's certificates and Zenoh configurations (fleet). The simulated
demo and the proving flights are rota-sitl commands (sitl/flights_cli.py).

Exit status: 0 success; 1 a failure at run time (Zenoh or MAVLink could not be
opened); 2 a bad configuration (the error names the setting); 130 interrupted
(Ctrl-C).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import os
import re
import signal
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from companion.entry import package_version

if TYPE_CHECKING:  # imported where used: the CLI starts (and the demo speaks) sooner
    from companion.settings.config import Config

_SYSLOG = {logging.DEBUG: 7, logging.INFO: 6, logging.WARNING: 4, logging.ERROR: 3,
           logging.CRITICAL: 2}


class _JournalFormatter(logging.Formatter):
    """``<priority>logger: message`` lines; journald reads the priority prefix and
    adds its own time stamps."""

    def format(self, record: logging.LogRecord) -> str:
        prio = _SYSLOG.get(record.levelno, 6)
        return f"<{prio}>{record.name}: {record.getMessage()}"


def setup_logging(level: str) -> None:
    """Log at ``level`` to stdout; events (INFO) always reach the flight record."""
    handler = logging.StreamHandler(sys.stdout)
    handler.setLevel(level.upper())
    if os.environ.get("JOURNAL_STREAM") or os.environ.get("INVOCATION_ID"):
        handler.setFormatter(_JournalFormatter())
    else:
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    logging.basicConfig(level=min(logging.INFO, logging.getLevelName(level.upper())),
                        handlers=[handler], force=True)
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


#: MAVSDK connection URLs: udp/tcp with host and port, or a serial device.
_MAVLINK_URL = re.compile(r"^((udp|udpin|udpout|tcp|tcpin|tcpout)://[^/:\s]*:\d{1,5}"
                          r"|(serial|serial_flowcontrol):///[^\s:]+(:\d+)?)$")


def check_directory(path: str, setting: str) -> None:
    """``path`` is a directory this user can write, or can be created (its nearest
    existing parent is writable); a ConfigError naming ``setting`` otherwise."""
    from companion.settings.config import ConfigError

    target = Path(path).absolute()
    probe = target
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if not probe.is_dir():
        raise ConfigError(f"{setting}: {path}: cannot be created ({probe} is not a directory)")
    if not os.access(probe, os.W_OK | os.X_OK):
        who = f"user {_user()}"
        what = "not writable" if probe == target else f"cannot be created ({probe} is not " \
            "writable)"
        raise ConfigError(f"{setting}: {path}: {what} by {who} (the systemd unit creates it "
                          "with StateDirectory=; to run by hand, set it to a directory you "
                          "can write)")


def _user() -> str:
    import pwd

    try:
        return pwd.getpwuid(os.getuid()).pw_name
    except KeyError:
        return str(os.getuid())


def check_environment(cfg: Config) -> None:
    """Checks beyond the file's own: the Zenoh configuration file loads, the
    MAVLink URL is one MAVSDK understands, the state and record directories can be
    written by this user. Raises ConfigError naming the setting."""
    from companion.settings.config import ConfigError

    if not _MAVLINK_URL.match(cfg.mavlink.url):
        raise ConfigError(f"[mavlink] url: {cfg.mavlink.url!r} is not a MAVSDK connection URL "
                          "(udpin://HOST:PORT, tcpout://HOST:PORT, serial:///dev/ttyAMA0:921600)")
    if cfg.zenoh.config_file:

        path = cfg.zenoh.config_file
        if not os.path.isfile(path):
            raise ConfigError(f"[zenoh] config_file: {path}: no such file")
    check_directory(cfg.service.state_dir, "[service] state_dir")
    if cfg.record.enabled:
        where = "[record] dir" if cfg.record.dir else "[record] dir (<state_dir>/records)"
        check_directory(cfg.record.dir or os.path.join(cfg.service.state_dir, "records"), where)
    from companion.network.security import check_exposure, zenoh_config

    for problem in check_exposure(cfg, zenoh_config(cfg)):  # refuses unless insecure
        print(f"rota-companion: warning: INSECURE: {problem}", file=sys.stderr)


def cmd_run(args: argparse.Namespace) -> int:
    from companion.worker import start_fork_server

    # records, logs and the estimator's state are the operator's alone (files 0600,
    # folders 0700), under systemd (UMask=0027) or not; a stricter umask stays
    os.umask(os.umask(0o077) | 0o077)
    start_fork_server()  # (it imports the workers' code while this process imports its own)
    from companion.settings.config import load

    cfg = load(args.config)
    check_environment(cfg)
    if access_control(cfg):  # its denials are in Zenoh's own log only: into ours
        import zenoh

        from companion.network import zenoh_log

        zenoh_log.forward(zenoh)
    setup_logging(cfg.service.log_level)
    try:
        asyncio.run(_serve(cfg))
    except Exception as exc:
        if type(exc).__module__.startswith("zenoh"):
            endpoints = ", ".join(cfg.zenoh.listen) if not cfg.zenoh.config_file else \
                cfg.zenoh.config_file
            raise RunError(f"cannot open Zenoh ({endpoints}): {str(exc).split(' at ')[0]} "
                           "(is the port in use? zenohd listens on 7447 too)") from None
        if isinstance(exc, OSError) and exc.filename:
            raise RunError(f"{exc.filename}: {exc.strerror}") from None
        raise
    return 0


def access_control(cfg: Config) -> bool:
    """Whether the Zenoh configuration turns access control on."""
    from companion.network.security import zenoh_config

    try:
        return json.loads(zenoh_config(cfg).get_json("access_control/enabled")) is True
    except Exception:  # noqa: BLE001 - unset
        return False


class RunError(RuntimeError):
    """A failure at run time, said in one line (exit status 1)."""


class UsageError(ValueError):
    """A bad option value, said in one line (exit status 2)."""


def _positive(args: argparse.Namespace, *names: str) -> None:
    for name in names:
        if not getattr(args, name) > 0:
            raise UsageError(f"--{name}: must be positive, got {getattr(args, name)}")


def cmd_check(args: argparse.Namespace) -> int:
    from companion.settings.config import load

    cfg = load(args.config)
    check_environment(cfg)
    print(json.dumps(cfg.to_dict(), indent=1))
    print(f"{args.config}: OK", file=sys.stderr)
    return 0


def cmd_warm_up(args: argparse.Namespace) -> int:
    """Compile (or load) the solver's kernels into the cache the service will load them
    from, so that no start waits for a compile (docs/deploy.md)."""
    from rota import warm_up
    from rota.jitcache import resolve_cache_dir

    where = resolve_cache_dir(args.cache_dir)
    if where is None or (args.cache_dir and where != Path(args.cache_dir)):
        raise RunError(f"{args.cache_dir or 'no cache directory'}: cannot write there (the "
                       "service's user must own it: docs/deploy.md)")
    seconds = warm_up(where)
    print(f"solver compiled or loaded in {seconds:.1f} s; cache {where}")
    return 0


def cmd_fleet(args: argparse.Namespace) -> int:
    from companion.network.fleet import Fleet, FleetError, FleetNameError, make_fleet

    if any("=" not in h for h in args.host):
        raise UsageError("--host takes VEHICLE=HOST, e.g. --host drone1=10.0.0.11")
    hosts = dict(h.split("=", 1) for h in args.host)
    fleet = Fleet(vehicles=tuple(args.vehicles.split(",")),
                  ground_stations=tuple(args.ground_stations.split(",")), hosts=hosts,
                  days=args.days)
    try:
        written = make_fleet(fleet, args.dir, args.install_dir)
    except FleetNameError as exc:
        raise UsageError(str(exc)) from None
    except FleetError as exc:
        raise RunError(str(exc)) from None
    for path in written:
        print(path)
    print(f"fleet in {args.dir}: keep ca/ca.key offline; copy each member's directory to its "
          "computer (docs/security.md)")
    return 0


def make_parser() -> argparse.ArgumentParser:
    doc = (__doc__ or "").split("\n\n")
    parser = argparse.ArgumentParser(prog="rota-companion", description=doc[1], epilog=doc[2],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    p = sub.add_parser("run", help="run the flight service")
    p.add_argument("--config", help="TOML configuration (default: built-in defaults)")
    p.set_defaults(func=cmd_run)
    p = sub.add_parser("check-config", help="validate a configuration file")
    p.add_argument("config")
    p.set_defaults(func=cmd_check)
    p = sub.add_parser("warm-up", help="compile the solver into its cache now (at install "
                       "time), so that no start of the service waits for a compile")
    p.add_argument("--cache-dir", default=None,
                   help="the cache (default: as the service finds it: $ROTA_CACHE_DIR, "
                   "systemd's $CACHE_DIRECTORY, ~/.cache/rota)")
    p.set_defaults(func=cmd_warm_up)
    p = sub.add_parser("fleet", help="certificates and Zenoh configs of a fleet (mutual TLS, "
                       "access control)")
    p.add_argument("dir", help="where to make (or extend) the fleet")
    p.add_argument("--vehicles", required=True, help="vehicle ids, comma-separated")
    p.add_argument("--ground-stations", default="gs",
                   help="ground-station names, comma-separated (default gs)")
    p.add_argument("--host", action="append", default=[], metavar="VEHICLE=HOST",
                   help="where a vehicle is reached (default VEHICLE.local); repeat")
    p.add_argument("--install-dir", default=None,
                   help="where each member's directory will live on its computer (default: "
                   "where it is made), e.g. /etc/rota-companion/fleet")
    p.add_argument("--days", type=int, default=825, help="certificate validity (default 825)")
    p.set_defaults(func=cmd_fleet)
    return parser


def one_line(prog: str, fn: Callable[[], int],
             extra: Sequence[tuple[type[BaseException], int, Callable[[Any], str]]] = (),
             ) -> int:
    """``fn()``'s exit status, or one line for a failure it raised: ``extra``
    (exception type, exit status, its words) first, then RunError (1), UsageError (2)
    and Ctrl-C (130)."""
    handlers = [*extra, (RunError, 1, str), (UsageError, 2, str)]
    try:
        return int(fn())
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except tuple(t for t, _, _ in handlers) as exc:
        code, say = next((c, w) for t, c, w in handlers if isinstance(exc, t))
        print(f"{prog}: {say(exc)}", file=sys.stderr)
        return code


def main(argv: list[str] | None = None) -> int:
    args = make_parser().parse_args(argv)
    from companion.settings.config import ConfigError

    return one_line(f"rota-companion {args.command}", lambda: args.func(args),
                    [(ConfigError, 2, lambda exc: f"configuration error: {exc}")])


if __name__ == "__main__":
    sys.exit(main())
