"""rota-gs: the ground station on the command line.

Watch and command a vehicle running the flight service over Zenoh, send it
trajectories and maps, replay its flight records, or serve the local web page
or the vehicle live to Foxglove.
Guide: docs/groundstation.md.

Exit status: 0 done; 1 refused by the service, or the state did not confirm a
command in time; 2 bad input (a file, an argument); 3 the service cannot be
reached (no Zenoh session, no reply, no status).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import shutil
import sys
import time
from pathlib import Path
from typing import Any

from companion.entry import package_version
from companion.gs.client import GroundStation, GroundStationError, list_vehicles
from companion.gs.view import NO_CONTACT_S, contact_age, render_status
from companion.protocol import COMMANDS, KEY_PREFIX
from rota.errors import InputError

EXIT_OK, EXIT_FAILED, EXIT_INPUT, EXIT_UNREACHABLE = 0, 1, 2, 3
DEFAULT_CONNECT = "tcp/127.0.0.1:7447"


class Unreachable(RuntimeError):
    """The service did not answer (exit status 3)."""


def _station(args: argparse.Namespace, vehicle: str | None = None) -> GroundStation:
    connect = args.connect or ([] if args.zenoh_config else [DEFAULT_CONNECT])
    try:
        return GroundStation(vehicle or args.vehicle, connect=connect,
                             config_file=args.zenoh_config, key_prefix=args.prefix,
                             wait_s=args.timeout)
    except GroundStationError as exc:
        raise Unreachable(str(exc)) from None


def _print_json(obj: Any) -> None:
    print(json.dumps(obj, indent=1))


# ------------------------------------------------------------------ commands
def cmd_list(args: argparse.Namespace) -> int:
    gs = _station(args)
    try:
        vehicles = list_vehicles(gs.session, args.prefix, timeout_s=args.timeout)
    finally:
        gs.close()
    if args.json:
        _print_json([{"prefix": v.prefix, "vehicle": v.id} for v in vehicles])
    elif not vehicles:
        print(f"no vehicle alive under {args.prefix}/ (is the service running and reachable?)")
    for v in vehicles if not args.json else []:
        print(f"{v.id}\t{v.prefix}/{v.id}/")
    return EXIT_OK


def cmd_status(args: argparse.Namespace) -> int:
    with _station(args) as gs:
        heard = _Heard(gs)
        status = _first_status(gs, args.timeout)
        _await(lambda: gs.telemetry or None, 0.5)  # (sent 5 times as often as status)
        if args.json:
            _print_json(status)
        else:
            v_max = None if "limits" in status else _v_max(gs)
            print(render_status(status, gs.telemetry, gs.retimed, width=_width(args),
                                v_max=v_max, ages=heard.ages()))
    return EXIT_OK


def _width(args: argparse.Namespace) -> int:
    """``--width``, else the terminal's width on a terminal, else 0 (whole lines)."""
    if args.width is not None:
        return max(args.width, 0)
    return shutil.get_terminal_size().columns if sys.stdout.isatty() else 0


class _Heard:
    """When the station last heard the service's status and telemetry (monotonic
    time), through its ``on_message`` hook."""

    def __init__(self, gs: GroundStation) -> None:
        self.at: dict[str, float] = {}
        gs.on_message = self._note
        for name in ("status", "telemetry"):  # (arrived while the station opened)
            if getattr(gs, name):
                self.at.setdefault(name, time.monotonic())

    def _note(self, name: str, obj: dict[str, Any]) -> None:  # noqa: ARG002
        self.at[name] = time.monotonic()

    def ages(self) -> dict[str, float | None]:
        now = time.monotonic()
        return {k: (now - self.at[k] if k in self.at else None)
                for k in ("status", "telemetry")}


def _first_status(gs: GroundStation, timeout_s: float) -> dict[str, Any]:
    try:
        return gs.wait_status(timeout_s)
    except GroundStationError as exc:
        raise Unreachable(str(exc)) from None


def cmd_watch(args: argparse.Namespace) -> int:
    """A live view, redrawn at 5 Hz (a tty) or printed once a second (a pipe) and at
    once when contact is lost or found; it says how long ago the service was heard,
    and "NO CONTACT" after :data:`~companion.gs.view.NO_CONTACT_S` of silence."""
    tty = sys.stdout.isatty()
    end = time.monotonic() + args.duration if args.duration > 0 else float("inf")
    events: list[str] = []
    with _station(args) as gs:
        heard = _Heard(gs)
        _first_status(gs, args.timeout)
        v_max = None if "limits" in gs.status else _v_max(gs)  # (a service without them)
        last: dict[str, Any] = {}
        silent, printed = False, 0.0
        try:
            while time.monotonic() < end:
                _collect_events(last, gs.status, events)
                last = gs.status
                ages = heard.ages()
                age = contact_age(ages)
                changed = (age is None or age > NO_CONTACT_S) != silent
                if changed:
                    silent = not silent
                    events.append(f"{time.strftime('%H:%M:%S')} "
                                  + ("NO CONTACT" if silent else "contact again"))
                if tty or changed or time.monotonic() - printed >= 1.0:
                    printed = time.monotonic()
                    screen = render_status(gs.status, gs.telemetry, gs.retimed, events[-8:],
                                           width=_width(args), v_max=v_max, ages=ages,
                                           ansi=tty)
                    sys.stdout.write("\x1b[H\x1b[2J" + screen + "\n" if tty
                                     else screen + "\n\n")
                    sys.stdout.flush()
                time.sleep(0.2)
        except KeyboardInterrupt:
            pass
    return EXIT_OK


def _v_max(gs: GroundStation) -> float | None:
    """The speed limit in force (None if the configuration cannot be read)."""
    try:
        return float(gs.config()["config"]["limits"]["v_max"])
    except (GroundStationError, KeyError, TypeError, ValueError):
        return None


def _collect_events(before: dict[str, Any], now: dict[str, Any], events: list[str]) -> None:
    """State changes, new errors and new warnings, as lines with a clock time."""
    clock = time.strftime("%H:%M:%S")
    if before.get("state") != now.get("state"):
        events.append(f"{clock} state {now.get('state')}")
    if before.get("trajectory_id") != now.get("trajectory_id") and now.get("trajectory_id"):
        events.append(f"{clock} flying {now['trajectory_id']}")
    err = now.get("last_error")
    if err and err != before.get("last_error"):
        events.append(f"{clock} ERROR {err.get('source')}: {err.get('message')}")
    old = before.get("warnings") or []
    for w in (now.get("warnings") or [])[len(old) if len(old) < 5 else 4:]:
        if w not in old[-1:]:
            events.append(f"{clock} warning: {w}")


def cmd_cmd(args: argparse.Namespace) -> int:
    from companion.gs.client import CONFIRM

    with _station(args) as gs:
        _first_status(gs, args.timeout)
        seen = gs.status_count
        reply = _query(gs.query, "cmd", args.name)
        if not reply.get("ok"):
            print(f"rota-gs: {args.name} refused: {reply.get('message')}", file=sys.stderr)
            return EXIT_FAILED
        if not args.no_wait:
            ok, wait, what = CONFIRM[args.name]
            try:
                asyncio.run(gs.wait_for(lambda s: gs.status_count > seen and ok(s),
                                        args.confirm_timeout or wait, what))
            except TimeoutError:
                print(f"rota-gs: {args.name}: accepted ({reply.get('message')}), but no "
                      f"{what} within {args.confirm_timeout or wait:g} s (state "
                      f"{gs.status.get('state')})", file=sys.stderr)
                return EXIT_FAILED
        state = gs.status.get("state", reply.get("state"))
    print(f"{args.name}: {reply.get('message') or 'ok'} (state {state})")
    return EXIT_OK


def _parse_assignment(text: str) -> tuple[str, str, Any]:
    if "=" not in text or "." not in text.split("=", 1)[0]:
        raise InputError("config set", f"expected SECTION.NAME=VALUE, got {text!r}")
    key, raw = text.split("=", 1)
    section, name = key.split(".", 1)
    try:
        value = json.loads(raw)
    except json.JSONDecodeError:
        value = raw  # a bare string
    return section, name, value


def cmd_config(args: argparse.Namespace) -> int:
    changes: dict[str, dict[str, Any]] | None = None
    if args.action == "set":
        if not args.items:
            raise InputError("config set", "give at least one SECTION.NAME=VALUE")
        changes = {}
        for item in args.items:
            section, name, value = _parse_assignment(item)
            changes.setdefault(section, {})[name] = value
    elif args.items and len(args.items) > 1:
        raise InputError("config get", "give at most one SECTION")
    with _station(args) as gs:
        reply = _query(gs.config, changes)
    if not reply.get("ok"):
        print(f"rota-gs: config refused: {reply.get('message')}", file=sys.stderr)
        return EXIT_FAILED
    cfg = reply.get("config", {})
    if args.action == "get" and args.items:
        if args.items[0] not in cfg:
            raise InputError("config get", f"no section {args.items[0]!r} (known: "
                             f"{', '.join(cfg)})")
        cfg = cfg[args.items[0]]
    if args.action == "set":
        print(reply.get("message") or "configuration updated")
        cfg = {s: cfg.get(s) for s in changes}
    _print_json(cfg)
    return EXIT_OK


def _query(fn, *a: Any) -> dict[str, Any]:  # noqa: ANN001
    try:
        return fn(*a)
    except GroundStationError as exc:
        raise Unreachable(str(exc)) from None


def cmd_estimator(args: argparse.Namespace) -> int:
    request: dict[str, Any] | None = None
    if args.action == "set":
        if args.m is None or args.b is None:
            raise InputError("estimator set", "give --m and --b")
        request = {"set": {"m": args.m, "b": args.b}}
    elif args.action == "reset":
        request = {"reset": True}
    elif args.action == "freeze":
        request = {"freeze": not args.thaw}
    with _station(args) as gs:
        reply = _query(gs.estimator, request)
    if not reply.get("ok"):
        print(f"rota-gs: estimator: {reply.get('message')}", file=sys.stderr)
        return EXIT_FAILED
    if reply.get("message"):
        print(reply["message"])
    _print_json(reply.get("estimator"))
    return EXIT_OK


def cmd_send(args: argparse.Namespace) -> int:
    from companion.gs import ros_input  # (the ROS types load only for a send)

    if args.ros2:
        ros, cfg = ros_input.read(args, args.ros2)
        ident = ros.id
        send = ros_input.sender(cfg, ros)
    else:
        from rota.schema import load, trajectory_from_dict

        ros_input.refuse_options(args)

        msg = load(args.file)
        parsed = trajectory_from_dict(msg)  # a bad file fails here, naming the field
        if not args.keep_stamp:
            msg["stamp"] = time.time()  # the service rejects stale stamps
        ident = msg.setdefault("id", parsed.id or Path(args.file).stem)

        def send(gs: GroundStation) -> None:
            gs.send_trajectory(msg)

    with _station(args) as gs:
        status = _first_status(gs, args.timeout)
        before = status.get("last_error")
        seen = len(gs.retimed)
        send(gs)
        outcome = _await(lambda: next((r for r in gs.retimed[seen:] if r.get("id") == ident),
                                      None) or _new_error(gs.status, before), args.timeout)
    if outcome is None:
        print(f"rota-gs: sent {ident!r}; no re-timed result within {args.timeout:g} s "
              "(the service re-times when flying or when the vehicle is ready)",
              file=sys.stderr)
        return EXIT_FAILED
    if "message" in outcome and "status" not in outcome:
        print(f"rota-gs: {ident!r} rejected: {outcome['message']}", file=sys.stderr)
        return EXIT_FAILED
    print(f"{ident}: {outcome['status']}, {outcome['input_duration']:.2f} s as planned -> "
          f"{outcome['duration']:.2f} s re-timed, {len(outcome.get('braking_zones', []))} "
          f"braking zone(s)" + (f" ({outcome['message']})" if outcome.get("message") else ""))
    return EXIT_OK if outcome["status"] != "rejected" else EXIT_FAILED


def _new_error(status: dict[str, Any], before: Any) -> dict[str, Any] | None:
    err = status.get("last_error")
    return err if err and err != before else None


def _await(probe, timeout_s: float) -> Any:  # noqa: ANN001
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        got = probe()
        if got is not None:
            return got
        time.sleep(0.05)
    return None


def cmd_send_map(args: argparse.Namespace) -> int:
    from companion.gs import ros_input  # (the ROS types load only for a send)

    if args.ros2:
        from companion.messages import Rejected
        from companion.ros2.send import decoded

        ros, cfg = ros_input.read(args, "pointcloud")
        try:
            vmap = decoded(ros, cfg)  # the voxel count the service will report
        except Rejected as exc:
            raise InputError(args.file, str(exc)) from None
        send = ros_input.sender(cfg, ros)
    else:
        from rota.cli import load_map

        ros_input.refuse_options(args)

        vmap = load_map(args.file, args.resolution)
        msg = vmap.to_dict() | {"stamp": time.time()}

        def send(gs: GroundStation) -> None:
            gs.send_map(msg)

    with _station(args) as gs:
        status = _first_status(gs, args.timeout)
        before = status.get("last_error")
        send(gs)
        outcome = _await(lambda: ({"voxels": gs.status["map_voxels"]}
                                  if gs.status.get("map_voxels") == len(vmap) else None)
                         or _new_error(gs.status, before), args.timeout)
    if outcome is None or "voxels" not in outcome:
        why = outcome["message"] if outcome else f"not confirmed within {args.timeout:g} s"
        print(f"rota-gs: map {args.file}: {why}", file=sys.stderr)
        return EXIT_FAILED
    print(f"map {args.file}: {len(vmap)} occupied voxels at {vmap.resolution:g} m in use")
    return EXIT_OK


def cmd_replay(args: argparse.Namespace) -> int:
    from companion.gs import replay

    flight = replay.load(args.files)  # InputError (exit 2) for what is no flight record
    figures = replay.stats(flight)
    if args.json:
        _print_json(figures)
    else:
        for k, v in figures.items():
            if k == "plans_rejected":
                print(f"{k}: {len(v)}")
                for plan in v:
                    print(f"  {plan['id'] or '(no id)'} rejected: {plan['reason']}")
            else:
                print(f"{k}: {v}")
    if args.plot:
        title = args.title or Path(args.files[0]).name
        print(f"plot: {replay.plot(flight, args.plot, title=title)}")
    return EXIT_OK


def cmd_web(args: argparse.Namespace) -> int:
    from companion.gs.web import serve

    serve(lambda vehicle: _station(args, vehicle), args.vehicle, args.host, args.port,
          tls_cert=args.tls_cert, tls_key=args.tls_key,
          token_file=Path(args.token_file) if args.token_file else None,
          names=tuple(args.name or ()))
    return EXIT_OK


def cmd_foxglove(args: argparse.Namespace) -> int:
    if args.layout:
        from companion.gs.foxglove import layout_json

        Path(args.layout).write_text(layout_json())
        print(f"layout: {args.layout}")
        return EXIT_OK
    if args.render:
        from companion.gs.foxglove_render import render

        if not args.files:
            raise InputError("foxglove --render", "give the record's MCAP file(s)")
        for f in args.files:
            if not Path(f).is_file():
                raise InputError("foxglove", f"{f}: no such file")
        try:
            out = render(args.files, args.render, title=args.title or Path(args.files[0]).name)
        except ValueError as exc:
            raise InputError("foxglove --render", str(exc)) from None
        print(f"scene: {out}")
        return EXIT_OK
    if args.files:
        raise InputError("foxglove", "record files only with --render (Foxglove opens "
                         "records itself)")
    from companion.gs.foxglove import serve
    from companion.gs.webauth import is_loopback

    if not is_loopback(args.host):
        raise InputError("foxglove --host", f"{args.host}: Foxglove's WebSocket protocol has no "
                         "authentication, so the vehicle's data is served on this machine's "
                         "loopback only; reach it from elsewhere through SSH "
                         f"(ssh -L {args.port}:127.0.0.1:{args.port} THIS-HOST)")
    serve(lambda vehicle: _station(args, vehicle), args.vehicle, args.host, args.port)
    return EXIT_OK


# ------------------------------------------------------------------ parser
def make_parser() -> argparse.ArgumentParser:
    doc = (__doc__ or "").split("\n\n")
    parser = argparse.ArgumentParser(prog="rota-gs", description=doc[1], epilog=doc[-1],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
    common = argparse.ArgumentParser(add_help=False)
    g = common.add_argument_group("connection")
    g.add_argument("-V", "--vehicle", default="drone1",
                   help="vehicle id ([service] vehicle_id; default drone1)")
    g.add_argument("--prefix", default=KEY_PREFIX, help=f"Zenoh key prefix (default {KEY_PREFIX})")
    g.add_argument("--connect", action="append", metavar="ENDPOINT",
                   help=f"Zenoh endpoint of the service or a router, e.g. tcp/HOST:7447 "
                   f"(repeatable; default {DEFAULT_CONNECT} without --zenoh-config)")
    g.add_argument("--zenoh-config", metavar="FILE",
                   help="a Zenoh JSON5 configuration (the fleet's: TLS, authentication)")
    g.add_argument("--timeout", type=float, default=5.0,
                   help="seconds to wait for the service (default 5)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def add(name: str, func, help: str,  # noqa: A002, ANN001
            parents: tuple[argparse.ArgumentParser, ...] = ()) -> argparse.ArgumentParser:
        p = sub.add_parser(name, parents=[common, *parents], help=help, description=help)
        p.set_defaults(func=func)
        return p

    p = add("list", cmd_list, "the vehicles alive (their services' liveliness tokens)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p = add("status", cmd_status, "the vehicle's status, once")
    p.add_argument("--json", action="store_true", help="print the rota/status message")
    p.add_argument("--width", type=int, default=None, help="wrap lines at this width "
                   "(default: the terminal's width; whole lines in a pipe)")
    p = add("watch", cmd_watch, "a live view: state, position, speed, plan, braking zones, "
            "errors and events (Ctrl-C ends)")
    p.add_argument("--duration", type=float, default=0.0,
                   help="stop after this many seconds (default: until Ctrl-C)")
    p.add_argument("--width", type=int, default=None, help="wrap lines at this width "
                   "(default: the terminal's width; whole lines in a pipe)")
    p = add("cmd", cmd_cmd, "send a command and wait for the state to confirm it")
    p.add_argument("name", choices=COMMANDS)
    p.add_argument("--no-wait", action="store_true", help="return on the reply, do not wait "
                   "for the state")
    p.add_argument("--confirm-timeout", type=float, default=None,
                   help="seconds to wait for the state (default per command: 10 to 90)")
    p = add("config", cmd_config, "read the configuration, or change limits, uncertainty "
            "and safety settings in flight")
    p.add_argument("action", choices=("get", "set"))
    p.add_argument("items", nargs="*", metavar="ITEM",
                   help="get: [SECTION]; set: SECTION.NAME=VALUE ... (VALUE as JSON, e.g. "
                   "limits.v_max=1.5 limits.a_max=[2,2,1])")
    p = add("estimator", cmd_estimator, "read or steer the in-flight uncertainty estimator")
    p.add_argument("action", choices=("get", "set", "reset", "freeze"))
    p.add_argument("--m", type=float, help="set: slope m of std = m * speed + b")
    p.add_argument("--b", type=float, help="set: offset b, m")
    p.add_argument("--thaw", action="store_true", help="freeze: resume learning instead")
    ros = argparse.ArgumentParser(add_help=False)
    g = ros.add_argument_group(
        "ROS 2 messages", "a ROS message as JSON or YAML in ROS field names (what `ros2 topic "
        "echo --once` prints) or as CDR bytes (.cdr), published as a ROS 2 node on the "
        "configured layout would; settings from [ros2] of --config, then these flags")
    g.add_argument("--config", metavar="FILE", help="the service's companion.toml")
    g.add_argument("--layout", choices=("rmw_zenoh", "ros2dds"),
                   help="rmw_zenoh (default) or ros2dds (zenoh-bridge-ros2dds)")
    g.add_argument("--distro", choices=("humble", "jazzy"), help="the ROS 2 of the service's "
                   "peers: jazzy (default; also Kilted, Rolling) or humble")
    g.add_argument("--domain-id", type=int, metavar="N", help="ROS_DOMAIN_ID (rmw_zenoh)")
    g.add_argument("--namespace", metavar="NS", help="node namespace (rmw_zenoh) or the "
                   "bridge's namespace (ros2dds)")
    g.add_argument("--topic", metavar="TOPIC", help="the topic (default: [ros2] <kind>_topic)")
    g.add_argument("--bspline-type", metavar="TYPE", help="traj_utils/msg/Bspline "
                   "(ego-planner-swarm, default), ego_planner/msg/Bspline (EGO-Planner) or "
                   "plan_manage/msg/Bspline (Fast-Planner)")
    g.add_argument("--bspline-msg", metavar="DEF", help="another layout: ego-planner, "
                   "ego-planner-swarm, fast-planner or the path of a Bspline.msg")
    p = add("send", cmd_send, "send a trajectory (rota/trajectory JSON, or a ROS message "
            "with --ros2) and show its re-time", (ros,))
    p.add_argument("file")
    p.add_argument("--ros2", choices=("bspline", "path", "multidof"), metavar="KIND",
                   help="FILE is a ROS message: bspline ([ros2] bspline_type), path "
                   "(nav_msgs/msg/Path) or multidof (trajectory_msgs/msg/"
                   "MultiDOFJointTrajectory)")
    p.add_argument("--keep-stamp", action="store_true",
                   help="keep the file's stamp (default: stamp it now; stale ones are rejected)")
    p = add("send-map", cmd_send_map, "send a map: rota/map JSON, a point cloud (.ply, .pcd, "
            ".npy, .csv), or a sensor_msgs/msg/PointCloud2 with --ros2", (ros,))
    p.add_argument("file")
    p.add_argument("--resolution", type=float, default=0.1,
                   help="voxel size for point clouds, m (default 0.1; ROS: [ros2] "
                   "cloud_resolution)")
    p.add_argument("--ros2", action="store_const", const="pointcloud",
                   help="FILE is a sensor_msgs/msg/PointCloud2")
    p.add_argument("--keep-stamp", action="store_true",
                   help="--ros2: keep the message's stamp (default: stamp it now)")
    p = sub.add_parser("replay", help="a flight record's figures and plot",
                       description="a flight record's figures and plot")
    p.set_defaults(func=cmd_replay)
    p.add_argument("files", nargs="+", metavar="FILE", help="MCAP record file(s) of one run")
    p.add_argument("--plot", metavar="OUT", help="draw the flight (PNG, SVG or PDF)")
    p.add_argument("--title", help="plot title (default: the file name)")
    p.add_argument("--json", action="store_true", help="print the figures as JSON")
    p = add("web", cmd_web, "serve the ground-station web page on this machine (a token "
            "per session; beyond loopback only over TLS)")
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (default "
                   "127.0.0.1: this machine only; any other needs --tls-cert and --tls-key)")
    p.add_argument("--port", type=int, default=8470, help="port (default 8470)")
    p.add_argument("--tls-cert", metavar="PEM", help="serve HTTPS with this certificate "
                   "(chain)")
    p.add_argument("--tls-key", metavar="PEM", help="the certificate's private key")
    p.add_argument("--token-file", metavar="FILE", help="write this session's token here, "
                   "mode 0600 (default $XDG_RUNTIME_DIR/rota-gs/web-PORT.token, else "
                   "~/.local/state/rota-gs/web-PORT.token)")
    p.add_argument("--name", action="append", metavar="HOST",
                   help="another host name the page answers to (how others reach it: "
                   "a DNS name, an address; repeatable)")
    p = add("foxglove", cmd_foxglove, "serve the vehicle live to Foxglove over its WebSocket "
            "protocol (ws://127.0.0.1:8765), or draw a record's Foxglove scene")
    p.add_argument("files", nargs="*", metavar="FILE", help="--render: MCAP record file(s)")
    p.add_argument("--host", default="127.0.0.1", help="loopback address to serve on (default "
                   "127.0.0.1; the protocol has no authentication, so nothing else)")
    p.add_argument("--port", type=int, default=8765, help="port (default 8765, Foxglove's)")
    p.add_argument("--render", metavar="OUT", help="draw the Foxglove channels of the record "
                   "FILE(s) to OUT (PNG, SVG or PDF) instead of serving")
    p.add_argument("--title", help="--render: title (default: the file name)")
    p.add_argument("--layout", metavar="OUT", help="write the Foxglove layout (JSON) to OUT")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = make_parser().parse_args(argv)
    try:
        return int(args.func(args))
    except InputError as exc:
        print(f"rota-gs {args.command}: bad input: {exc}", file=sys.stderr)
        return EXIT_INPUT
    except OSError as exc:
        print(f"rota-gs {args.command}: {exc}", file=sys.stderr)
        return EXIT_INPUT
    except Unreachable as exc:
        print(f"rota-gs {args.command}: {exc}", file=sys.stderr)
        return EXIT_UNREACHABLE
    except KeyboardInterrupt:
        print(f"rota-gs {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
