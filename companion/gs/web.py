"""``rota-gs web``: the ground station as a local web page.

A small HTTP server (the standard library's) on this machine: the page and its
assets come from the package (``companion/gs/static``; nothing is fetched from
the internet), live data reach the page as server-sent events, and commands go
back as POST requests, which must carry the ``X-Rota-GS`` header and come to the
host name the page was served from, so another web site open in the same
browser cannot command the vehicle.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Callable
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Any

import numpy as np

from companion.gs.client import COMMANDS, GroundStation, GroundStationError

log = logging.getLogger("rota.gs")

STATIC = {"/": ("index.html", "text/html; charset=utf-8"),
          "/app.js": ("app.js", "text/javascript; charset=utf-8"),
          "/style.css": ("style.css", "text/css; charset=utf-8")}
#: Telemetry is forwarded to the page at most this often (Hz).
PAGE_RATE_HZ = 10.0


def plan_view(result: dict[str, Any], samples: int = 300) -> dict[str, Any]:
    """What the page draws of a re-timed result: the planner's path, the re-timed
    path with its speed, the braking zones, the chance-constrained speed limits."""
    from rota.schema import result_from_dict

    res, _ = result_from_dict(result)
    t = np.linspace(0.0, res.duration, samples)
    s = res.sample(t)
    tau_in = np.linspace(*res.trajectory.domain, samples)
    planned = res.trajectory.position(tau_in)
    zones = []
    for a, b in result.get("braking_zones", []):
        tau = np.linspace(a, b, 12)
        zones.append(np.round(res.trajectory.position(tau)[:, :2], 3).tolist())
    tau_n, t_n = np.asarray(result["tau"]), np.asarray(result["t"])
    return {
        "id": result.get("id"), "status": result.get("status"), "duration": res.duration,
        "planned": np.round(planned[:, :2], 3).tolist(),
        "path": np.round(s.position[:, :2], 3).tolist(),
        "speed": np.round(np.linalg.norm(s.velocity, axis=1), 3).tolist(),
        "t": np.round(t, 3).tolist(),
        "zones": zones,
        "zone_times": [[float(np.interp(a, tau_n, t_n)), float(np.interp(b, tau_n, t_n))]
                       for a, b in result.get("braking_zones", [])],
        "limit_t": np.round(t_n, 3).tolist(),
        "limits": result.get("speed_limits", []),
    }


def map_view(vmap: dict[str, Any], band: tuple[float, float] = (0.2, 4.0)) -> dict[str, Any]:
    """Occupied map cells seen from above (voxels within the altitude band)."""
    occ = np.asarray(vmap.get("occupied") or [], dtype=float).reshape(-1, 3)
    occ = occ[(occ[:, 2] >= band[0]) & (occ[:, 2] <= band[1])]
    res = float(vmap.get("resolution", 0.1))
    origin = np.asarray(vmap.get("origin", (0.0, 0.0, 0.0)), dtype=float)[:2]
    ij = np.unique(np.floor((occ[:, :2] - origin) / res + 1e-6).astype(int), axis=0)
    cells = origin + (ij + 0.5) * res
    return {"resolution": res, "cells": np.round(cells, 3).tolist()}


class Hub:
    """The newest of everything, shared between Zenoh's threads and the page's
    event streams; ``version`` counts changes."""

    def __init__(self) -> None:
        self.cond = threading.Condition()
        self.version = 0
        self.items: dict[str, tuple[int, Any]] = {}

    def set(self, name: str, value: Any) -> None:
        with self.cond:
            self.version += 1
            self.items[name] = (self.version, value)
            self.cond.notify_all()

    def since(self, version: int) -> tuple[int, dict[str, Any]]:
        with self.cond:
            return self.version, {k: v for k, (n, v) in self.items.items() if n > version}

    def wait(self, version: int, timeout: float) -> None:
        with self.cond:
            if self.version == version:
                self.cond.wait(timeout)


class WebStation:
    """A ground station feeding a :class:`Hub` for the page."""

    def __init__(self, gs: GroundStation) -> None:
        self.gs = gs
        self.hub = Hub()
        self._last_tel = 0.0
        gs.on_message = self._on_message
        self._map_sub = gs.session.declare_subscriber(gs.key("map"), self._on_map)
        self.refresh_config()

    def refresh_config(self) -> None:
        try:
            self.hub.set("config", self.gs.config()["config"])
        except (GroundStationError, KeyError):
            pass

    def _on_message(self, name: str, obj: dict[str, Any]) -> None:
        if name == "telemetry":
            now = time.monotonic()
            if now - self._last_tel < 1.0 / PAGE_RATE_HZ:
                return
            self._last_tel = now
            self.hub.set("telemetry", obj)
        elif name == "status":
            self.hub.set("status", obj)
        elif name == "retimed":
            try:
                self.hub.set("plan", plan_view(obj))
            except Exception as exc:  # noqa: BLE001 - a bad result must not stop the page
                log.warning("cannot draw result %s: %s", obj.get("id"), exc)

    def _on_map(self, sample: Any) -> None:
        try:
            self.hub.set("map", map_view(json.loads(sample.payload.to_bytes())))
        except Exception as exc:  # noqa: BLE001
            log.warning("cannot draw the map: %s", exc)

    def command(self, name: str) -> dict[str, Any]:
        reply = self.gs.query("cmd", name)
        self.hub.set("reply", reply)
        return reply

    def close(self) -> None:
        self._map_sub.undeclare()
        self.gs.close()


def _handler(station: WebStation, vehicle: str) -> type[BaseHTTPRequestHandler]:
    static = resources.files("companion.gs") / "static"

    class Handler(BaseHTTPRequestHandler):
        server_version = "rota-gs"
        protocol_version = "HTTP/1.1"

        def log_message(self, fmt: str, *args: Any) -> None:
            log.debug("%s " + fmt, self.address_string(), *args)

        def _send(self, code: int, body: bytes, ctype: str) -> None:
            self.send_response(code)
            self.send_header("Content-Type", ctype)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.send_header("Content-Security-Policy",
                             "default-src 'self'; connect-src 'self'; img-src 'self' data:")
            self.end_headers()
            self.wfile.write(body)

        def _json(self, obj: Any, code: int = 200) -> None:
            self._send(code, json.dumps(obj).encode(), "application/json")

        def do_GET(self) -> None:  # noqa: N802
            path = self.path.split("?", 1)[0]
            if path in STATIC:
                name, ctype = STATIC[path]
                self._send(200, (static / name).read_bytes(), ctype)
            elif path == "/api/events":
                self._events()
            elif path == "/api/info":
                self._json({"vehicle": vehicle, "commands": list(COMMANDS)})
            else:
                self._send(404, b"not found", "text/plain")

        def do_POST(self) -> None:  # noqa: N802
            path = self.path.split("?", 1)[0]
            host = (self.headers.get("Host") or "").rsplit(":", 1)[0]
            if self.headers.get("X-Rota-GS") != "1" or host not in self.server.allowed_hosts:
                self._json({"ok": False, "message": "forbidden"}, HTTPStatus.FORBIDDEN)
                return
            name = path.removeprefix("/api/cmd/")
            if not path.startswith("/api/cmd/") or name not in COMMANDS:
                self._json({"ok": False, "message": f"unknown command {name!r}"}, 404)
                return
            try:
                self._json(station.command(name))
            except GroundStationError as exc:
                self._json({"ok": False, "command": name, "message": str(exc)}, 504)

        def _events(self) -> None:
            self.send_response(200)
            self.send_header("Content-Type", "text/event-stream")
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            version, keepalive = 0, time.monotonic()
            try:
                while not self.server.closing:
                    version, items = station.hub.since(version)
                    for name, value in items.items():
                        data = json.dumps(value, allow_nan=False)
                        self.wfile.write(f"event: {name}\ndata: {data}\n\n".encode())
                    if items or time.monotonic() - keepalive > 10:
                        if not items:
                            self.wfile.write(b": keepalive\n\n")
                        self.wfile.flush()
                        keepalive = time.monotonic()
                    station.hub.wait(version, 0.5)
            except (BrokenPipeError, ConnectionResetError):
                pass
            self.close_connection = True

    return Handler


class WebServer(ThreadingHTTPServer):
    daemon_threads = True
    closing = False
    allowed_hosts: set[str] = set()


def start(station: WebStation, vehicle: str, host: str = "127.0.0.1",
          port: int = 8470) -> WebServer:
    """Serve the page in a background thread; ``server.shutdown()`` stops it."""
    server = WebServer((host, port), _handler(station, vehicle))
    server.allowed_hosts = {host, "localhost", "127.0.0.1", "[::1]"}
    threading.Thread(target=server.serve_forever, name="rota-gs-web", daemon=True).start()
    return server


def stop(server: WebServer) -> None:
    server.closing = True
    server.shutdown()
    server.server_close()


def serve(make_station: Callable[[str], GroundStation], vehicle: str, host: str,
          port: int) -> None:
    """Serve until Ctrl-C (``rota-gs web``)."""
    station = WebStation(make_station(vehicle))
    try:
        server = start(station, vehicle, host, port)
    except OSError as exc:
        station.close()
        raise OSError(f"cannot serve on {host}:{port}: {exc.strerror}") from None
    print(f"rota-gs: ground station for vehicle {vehicle!r} on http://{host}:{port}/ "
          "(Ctrl-C stops)", flush=True)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        stop(server)
        station.close()
