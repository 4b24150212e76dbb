"""Proving the service under faults, hostile input and time: a harness that flies
the ``sitl`` vehicle with the service running as systemd runs it (its own
process, so it can be stopped, killed and measured), a ground station on Zenoh,
and the vehicle's own record of every setpoint it received.

Used by the fault-injection and fuzz tests and by ``rota-sitl soak`` and
``rota-sitl fuzz``. Everything stays on 127.0.0.1.
"""

from __future__ import annotations

import asyncio
import json
import math
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from companion.flight.plan import blend_speed
from companion.gs import GroundStation
from companion.settings.config import Config, to_toml
from sitl.demo import demo_config, free_tcp_port, map_message, start_holding
from sitl.mavsdk_util import free_udp_port
from sitl.process import SimProcess
from sitl.stream_checks import StreamFigures, check_stream
from sitl.world import get_world

#: The proving route: a circle through the take-off point, bending past the
#: pillar of the ``pillar`` world (1.5 m from its surface).
CIRCLE_RADIUS_M = 3.6


#: A deliberate defect a test may build into the service (to show that its assertions
#: catch one): "frame", setpoints sent to the autopilot without ENU->NED's x/y swap (z
#: still flipped, so the take-off works).
DEFECTS = {"frame": "import numpy as _np, companion.flight.autopilot as _a\n"
                    "_a.enu_to_ned = lambda v: _np.asarray(v, dtype=float) * [1.0, 1.0, -1.0]\n"}


class ServiceProcess:
    """``rota-companion run`` in a child process, its output in ``log_path``.

    ``notify_socket``: systemd's notification socket to hand the service (:class:`Notes`);
    ``defect``: one of :data:`DEFECTS`, built in before the service's modules load.
    """

    def __init__(self, cfg: Config, workdir: Path, notify_socket: Path | None = None,
                 defect: str | None = None) -> None:
        if defect is not None and defect not in DEFECTS:
            raise ValueError(f"defect {defect!r}: one of {sorted(DEFECTS)}")
        self.cfg_path = workdir / "companion.toml"
        self.cfg_path.write_text(to_toml(cfg))
        self.log_path = workdir / "service.log"
        self.notify_socket, self.defect = notify_socket, defect
        self.proc: subprocess.Popen | None = None

    def start(self) -> ServiceProcess:
        args = ["run", "--config", str(self.cfg_path)]
        if self.defect is None:
            command = [sys.executable, "-m", "companion.cli", *args]
        else:
            command = [sys.executable, "-c", DEFECTS[self.defect]
                       + "import sys; from companion.cli import main; sys.exit(main())", *args]
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        if self.notify_socket is not None:
            env["NOTIFY_SOCKET"] = str(self.notify_socket)
        log = self.log_path.open("w")
        self.proc = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, env=env)
        log.close()
        return self

    @property
    def pid(self) -> int:
        assert self.proc is not None
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def signal(self, sig: int) -> None:
        os.kill(self.pid, sig)

    def rss_mb(self) -> float:
        """Resident memory of the service process (not its workers), MB."""
        for line in Path(f"/proc/{self.pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
        return math.nan

    def output(self) -> str:
        return self.log_path.read_text(errors="replace")

    def stop(self, timeout_s: float = 20.0) -> int:
        """SIGTERM, as systemd stops it; the exit code."""
        if self.proc is None:
            return 0
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        return int(self.proc.returncode)


class Notes:
    """systemd's notification socket, read all the time as systemd does: ``with Notes(path)
    as notes:``, then :meth:`seen` (READY=1, WATCHDOG=1, STATUS=..., STOPPING=1)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._notes: set[str] = set()
        self._lock = threading.Lock()
        self._done = threading.Event()

    def __enter__(self) -> Notes:
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self._sock.bind(str(self.path))
        self._sock.settimeout(0.2)
        self._thread = threading.Thread(target=self._listen, daemon=True,
                                        name="systemd-notify")
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._done.set()
        self._thread.join()
        self._sock.close()

    def _listen(self) -> None:
        while not self._done.is_set():
            try:
                data = self._sock.recv(4096)
            except (TimeoutError, OSError):
                continue
            with self._lock:
                self._notes.update(data.decode(errors="replace").split("\n"))

    def seen(self) -> set[str]:
        with self._lock:
            return set(self._notes)

    def clear(self) -> None:
        with self._lock:
            self._notes.clear()


def circle_message(center: np.ndarray, radius: float, angle: float, speed: float,
                   duration_s: float, ident: str, dt: float = 0.1) -> dict[str, Any]:
    """A ``samples`` trajectory (local ENU) along a horizontal circle, counter-
    clockwise from ``angle`` (rad) at ``speed`` for ``duration_s``."""
    t = np.arange(0.0, duration_s + 1e-9, dt)
    w = speed / radius
    th = angle + w * t
    c, s = np.cos(th), np.sin(th)
    z = np.full_like(t, center[2])
    p = np.stack([center[0] + radius * c, center[1] + radius * s, z], axis=1)
    v = np.stack([-speed * s, speed * c, 0 * t], axis=1)
    a = np.stack([-speed * w * c, -speed * w * s, 0 * t], axis=1)
    return {"schema": "rota/trajectory", "version": 1, "id": ident, "frame": "ENU",
            "stamp": time.time(), "type": "samples", "t": t.tolist(), "p": p.tolist(),
            "v": v.tolist(), "a": a.tolist()}


class Flight:
    """The sitl vehicle, the service in its own process and a ground station.

    ``with Flight(...) as f:`` then ``asyncio.run(...)`` of coroutines that use
    :meth:`take_off`, :meth:`circle` and :attr:`gs`; :meth:`figures` checks the
    setpoints the vehicle received.
    """

    def __init__(self, speed: float = 2.0, seed: int = 0, world: str = "pillar",
                 workdir: str | None = None, sim_params: dict[str, Any] | None = None,
                 gs_config: str | None = None, **overrides: dict[str, Any]) -> None:
        self.world = get_world(world, seed=seed)
        self.speed = speed
        self.seed = seed
        self._tmp = tempfile.TemporaryDirectory(prefix="rota-proving-") if workdir is None \
            else None
        self.workdir = Path(workdir or self._tmp.name)
        self.workdir.mkdir(parents=True, exist_ok=True)
        self.mav_port, self.zenoh_port = free_udp_port(), free_tcp_port()
        self.cfg = demo_config(self.mav_port, self.zenoh_port, speed, str(self.workdir),
                               **{"stream": {"takeoff_altitude_m": 2.0}} | overrides)
        self.sim = SimProcess(port=self.mav_port, world=world, seed=seed, params=sim_params)
        self.service = ServiceProcess(self.cfg, self.workdir)
        self.gs: GroundStation | None = None
        self.gs_config = gs_config  # a Zenoh config file for the ground station (the fleet's)
        self.center = np.zeros(3)
        self.pauses: list[tuple[float, float]] = []  # the service was stopped on purpose

    def __enter__(self) -> Flight:
        self.sim.__enter__()
        self.service.start()
        if self.gs_config:
            self.gs = GroundStation(self.cfg.service.vehicle_id, config_file=self.gs_config,
                                    key_prefix=self.cfg.service.key_prefix, wait_s=30.0)
        else:
            self.gs = GroundStation.for_service(self.cfg, f"tcp/127.0.0.1:{self.zenoh_port}",
                                                wait_s=30.0)
        return self

    def __exit__(self, *exc: object) -> None:
        if self.gs is not None:
            self.gs.close()
        self.exit_code = self.service.stop()
        self.log = self.service.output()
        self.sim.__exit__(*exc)
        if self._tmp is not None:
            self._tmp.cleanup()

    @property
    def allowed_speed(self) -> float:
        """The fastest any setpoint may move (the stream's own bound)."""
        return allowed_speed(self.cfg)

    async def command(self, name: str) -> dict[str, Any]:
        reply = await self.gs.command(name)
        if not reply["ok"]:
            raise RuntimeError(f"{name}: {reply['message']}")
        return reply

    async def take_off(self) -> None:
        """Wait for a healthy vehicle, send the map, arm, take off, wait until
        PX4's takeoff has finished (every step confirmed by the service)."""
        gs = self.gs
        await gs.wait_for(lambda s: s["state"] == "ready", 90, "the vehicle to be ready")
        gs.publish("map", map_message(self.world, self.sim.home_enu))
        await gs.wait_for(lambda s: s.get("map_voxels"), 20, "the map to arrive")
        await self.command("arm")
        await self.command("takeoff")
        await gs.wait_for(lambda s: s["state"] == "airborne", 60, "the takeoff to end")

    async def circle(self, ident: str = "circle-0", duration_s: float = 60.0) -> None:
        """Start offboard and fly the proving circle from where the vehicle holds."""
        gs = self.gs
        here = await start_holding(gs)
        self.center = here + [CIRCLE_RADIUS_M, 0.0, 0.0]
        # sent again every 5 s, as a planner re-sends (one sent while the service's first
        # re-time still loads on a busy machine is not lost; it may not fly fresh)
        end = time.monotonic() + 60.0
        while True:
            gs.publish("trajectory", circle_message(self.center, CIRCLE_RADIUS_M, math.pi,
                                                    self.speed, duration_s, ident))
            try:
                await gs.wait_for(lambda s: s.get("trajectory_id") == ident, 5,
                                  "the circle to begin")
                return
            except TimeoutError:
                if time.monotonic() > end:
                    raise

    def replan(self, ident: str, duration_s: float = 20.0) -> None:
        """A new circle trajectory from the commanded position (a planner's replan)."""
        sp = self.gs.telemetry.get("setpoint")
        if sp is None:
            return
        here = np.asarray(sp["position"])
        d = here - self.center
        d[2] = 0.0
        # the circle through the commanded position (it left the old one after a hold)
        self.center = here - CIRCLE_RADIUS_M * d / max(float(np.linalg.norm(d)), 1e-6)
        self.gs.publish("trajectory", circle_message(
            self.center, CIRCLE_RADIUS_M, math.atan2(d[1], d[0]), self.speed, duration_s,
            ident))

    def figures(self, window: tuple[float, float] | None = None,
                setpoints: dict[str, np.ndarray] | None = None) -> StreamFigures:
        """The setpoints the vehicle received (so far, or from the final report)."""
        return stream_figures(self.cfg, self.sim, window, setpoints, self.pauses)


def allowed_speed(cfg: Config) -> float:
    """The fastest any setpoint may move (the stream's own bound)."""
    return cfg.limits.v_max + blend_speed(cfg.safety.stitch_tolerance_m)


def stream_figures(cfg: Config, sim: SimProcess, window: tuple[float, float] | None = None,
                   setpoints: dict[str, np.ndarray] | None = None,
                   pauses: Sequence[tuple[float, float]] = ()) -> StreamFigures:
    """Gaps, jumps, limits and the geofence of the setpoints ``sim`` received (so far, or
    ``setpoints`` from its final report) under the service's ``cfg``."""
    sp = setpoints if setpoints is not None else sim.setpoints()
    fence = (cfg.safety.geofence_min, cfg.safety.geofence_max)
    return check_stream(sp, allowed_speed(cfg), fence, sim.home_enu, window, pauses,
                        sim.steal_monitor.samples(), cfg.stream.stall_budget_s)


def statuses_errors(statuses: Any) -> list[str]:
    """Every error the status messages carried (status coalesces them into its
    event log)."""
    return sorted({e["message"] for s in statuses for e in s.get("events", ())
                   if e["level"] == "error"})


async def until(predicate, timeout_s: float, what: str, period_s: float = 0.05) -> None:  # noqa: ANN001
    """Wait until ``predicate()`` holds."""
    end = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > end:
            raise TimeoutError(f"timed out waiting for {what}")
        await asyncio.sleep(period_s)


def dumps(obj: Any) -> str:
    return json.dumps(obj, indent=1, default=float)


FLOOD_KEYS = ("cmd/arm", "cmd/disarm", "cmd/takeoff", "cmd/start", "cmd/bogus", "config",
              "estimator")


def _flood(endpoint: str, prefix: str, rate: float, seconds: float, conn: Any) -> None:
    """In a child process: ``rate * seconds`` queries, round the service's
    queryables, at ``rate`` per second (on absolute deadlines: behind them, it
    catches up at once; on a busy machine it may take longer); sends (sent,
    replied, refused, seconds taken) back through ``conn``."""
    import threading

    import zenoh

    z = zenoh.Config()
    z.insert_json5("mode", '"peer"')
    z.insert_json5("scouting/multicast/enabled", "false")
    z.insert_json5("connect/endpoints", json.dumps([endpoint]))
    session = zenoh.open(z)
    lock = threading.Lock()
    counts = {"replied": 0, "refused": 0}

    def on_reply(reply: Any) -> None:
        with lock:
            counts["replied"] += 1
            if reply.ok is not None and b'"ok": false' in reply.ok.payload.to_bytes():
                counts["refused"] += 1

    sent, batch, total = 0, max(1, int(rate / 100)), int(rate * seconds)
    start = time.monotonic()
    while sent < total:
        due = min(total, int((time.monotonic() - start) * rate))
        while sent < due:
            session.get(f"{prefix}/{FLOOD_KEYS[sent % len(FLOOD_KEYS)]}", on_reply,
                        timeout=10.0)
            sent += 1
        time.sleep(batch / rate)
    took = time.monotonic() - start
    end = time.monotonic() + 12.0
    while time.monotonic() < end and counts["replied"] < sent:
        time.sleep(0.05)
    session.close()
    conn.send((sent, counts["replied"], counts["refused"], took))


def flood(flight: Flight, rate: float = 1000.0, seconds: float = 5.0) -> Any:
    """Start a query flood from another process (another Zenoh peer); returns a
    function that waits for it and gives (sent, replied, refused, seconds taken)."""
    import multiprocessing

    ctx = multiprocessing.get_context("spawn")
    parent, child = ctx.Pipe()
    proc = ctx.Process(target=_flood, args=(f"tcp/127.0.0.1:{flight.zenoh_port}",
                                            flight.cfg.key(), rate, seconds, child),
                       daemon=True)
    proc.start()

    def result(timeout_s: float = 60.0) -> tuple[int, int, int, float]:
        if not parent.poll(timeout_s):
            proc.kill()
            raise TimeoutError("the flood did not finish")
        out = parent.recv()
        proc.join(5)
        return out

    return result
