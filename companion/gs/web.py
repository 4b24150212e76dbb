"""``rota-gs web``: the ground station as a local web page.

A small HTTP server (the standard library's) on this machine: the page and its
assets come from the package (``companion/gs/static``; nothing is fetched from
the internet), live data reach the page as a stream of server-sent events, and
commands go back as POST requests. Who may use it (a token per session, checks of
``Host`` and ``Origin`` on every request, TLS beyond loopback):
:mod:`companion.gs.webauth`.

The page shows how old the newest status and telemetry are: the event stream
carries the ages as the ground station sees them (``ages``) with every batch and
twice a second, and the page counts on from there, so a silent service, a dead
ground station and a broken page connection all show as "no contact".
"""

from __future__ import annotations

import json
import logging
import socket
import ssl
import threading
import time
from collections.abc import Callable
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from companion.gs.client import GroundStation, GroundStationError
from companion.gs.webauth import (
    OWN_SITES,
    Access,
    access_for,
    check_bind,
    default_token_file,
    is_wildcard,
    new_token,
    tls_context,
    write_token,
)
from companion.protocol import COMMANDS
from rota.errors import InputError

log = logging.getLogger("rota.gs")

STATIC = {"/": ("index.html", "text/html; charset=utf-8"),
          "/app.js": ("app.js", "text/javascript; charset=utf-8"),
          "/style.css": ("style.css", "text/css; charset=utf-8")}
#: Telemetry is forwarded to the page at most this often (Hz).
PAGE_RATE_HZ = 10.0
#: The page hears the ages of status and telemetry at least this often (s).
AGES_EVERY_S = 0.5


def plan_view(result: dict[str, Any], samples: int = 300) -> dict[str, Any]:
    """What the page draws of a re-timed result: the planner's path, the re-timed
    path with its speed, the braking zones, the chance-constrained speed limits.
    A rejected result (its path passes through an obstacle; it is never flown) is
    the planner's path and the reason only: no speeds, zones or limits to draw."""
    from rota.schema import result_from_dict

    res, _ = result_from_dict(result)
    if result.get("status") == "rejected":
        tau_in = np.linspace(*res.trajectory.domain, samples)
        planned = np.round(res.trajectory.position(tau_in)[:, :2], 3).tolist()
        return {"id": result.get("id"), "status": "rejected", "message": result.get("message"),
                "duration": None, "planned": planned, "path": [], "speed": [], "t": [],
                "zones": [], "zone_times": [], "limit_t": [], "limits": []}
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
        "id": result.get("id"), "status": result.get("status"),
        "message": result.get("message"), "duration": res.duration,
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
    """A ground station feeding a :class:`Hub` for the page, and keeping when its
    newest status and telemetry arrived (monotonic time)."""

    def __init__(self, gs: GroundStation) -> None:
        self.gs = gs
        self.hub = Hub()
        self._last_tel = 0.0
        self.received: dict[str, float] = {}
        gs.on_message = self._on_message
        self._map_sub = gs.session.declare_subscriber(gs.key("map"), self._on_map)

    def ages(self) -> dict[str, float | None]:
        """Seconds since the newest status and telemetry (None: none yet)."""
        now = time.monotonic()
        return {k: (round(now - self.received[k], 3) if k in self.received else None)
                for k in ("status", "telemetry")}

    def _on_message(self, name: str, obj: dict[str, Any]) -> None:
        if name == "telemetry":
            now = self.received["telemetry"] = time.monotonic()
            if now - self._last_tel < 1.0 / PAGE_RATE_HZ:
                return
            self._last_tel = now
            self.hub.set("telemetry", obj)
        elif name == "status":
            self.received["status"] = time.monotonic()
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
        server: WebServer

        def log_message(self, fmt: str, *args: Any) -> None:
            log.debug("%s " + fmt, self.address_string(), *args)

        def _headers(self, code: int, ctype: str, length: int | None = None) -> None:
            self.send_response(code)
            self.send_header("Content-Type", ctype)
            if length is not None:
                self.send_header("Content-Length", str(length))
            self.send_header("Cache-Control", "no-store")
            self.send_header("Content-Security-Policy",
                             "default-src 'self'; connect-src 'self'; img-src 'self' data:; "
                             "frame-ancestors 'none'; form-action 'none'; base-uri 'none'")
            self.send_header("X-Content-Type-Options", "nosniff")
            self.send_header("Referrer-Policy", "no-referrer")
            self.send_header("Cross-Origin-Resource-Policy", "same-origin")
            self.send_header("X-Frame-Options", "DENY")
            if code == HTTPStatus.UNAUTHORIZED:
                self.send_header("WWW-Authenticate", 'Bearer realm="rota-gs"')
            self.end_headers()

        def _send(self, code: int, body: bytes, ctype: str) -> None:
            self._headers(code, ctype, len(body))
            self.wfile.write(body)

        def _json(self, obj: Any, code: int = 200) -> None:
            self._send(code, json.dumps(obj).encode(), "application/json")

        def _allowed(self, path: str) -> bool:
            """Host, Origin and Sec-Fetch-Site for every request; the token for
            ``/api/``. Answers a refusal itself (nothing of the vehicle in it)."""
            access = self.server.access
            host = self.headers.get("Host") or ""
            why = None
            if not access.host_ok(host):
                why = "forbidden: unknown Host"
            elif not access.origin_ok(self.headers.get("Origin"), host):
                why = "forbidden: foreign Origin"
            elif (self.headers.get("Sec-Fetch-Site") or "none") not in OWN_SITES and not (
                    path == "/" and self.headers.get("Sec-Fetch-Mode") == "navigate"):
                why = "forbidden: request from another site"
            if why is not None:
                self._json({"ok": False, "message": why}, HTTPStatus.FORBIDDEN)
            elif path.startswith("/api/") and not access.token_ok(
                    self.headers.get("Authorization")):
                why = "unauthorised: this page's token is needed (rota-gs web printed it)"
                self._json({"ok": False, "message": why}, HTTPStatus.UNAUTHORIZED)
            if why is not None:
                log.warning("web: refused %s %s from %s: %s", self.command, path[:80],
                            self.address_string(), why)
                self.close_connection = True
            return why is None

        def do_GET(self) -> None:  # noqa: N802
            path = self.path.split("?", 1)[0]
            if not self._allowed(path):
                return
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
            self.close_connection = True  # (a body, never read, cannot become a request)
            if not self._allowed(path):
                return
            name = path.removeprefix("/api/cmd/")
            if not path.startswith("/api/cmd/") or name not in COMMANDS:
                self._json({"ok": False, "message": f"unknown command {name[:40]!r}"}, 404)
                return
            log.info("web: command %s from %s", name, self.address_string())
            try:
                self._json(station.command(name))
            except GroundStationError as exc:
                self._json({"ok": False, "command": name, "message": str(exc)}, 504)

        def _events(self) -> None:
            self._headers(200, "text/event-stream")
            version, sent = 0, 0.0
            try:
                while not self.server.closing:
                    version, items = station.hub.since(version)
                    if items or time.monotonic() - sent >= AGES_EVERY_S:
                        sent = time.monotonic()
                        self.wfile.write(b"event: ages\ndata: "
                                         + json.dumps(station.ages()).encode() + b"\n\n")
                    for name, value in items.items():
                        data = json.dumps(value, allow_nan=False)
                        self.wfile.write(f"event: {name}\ndata: {data}\n\n".encode())
                    self.wfile.flush()
                    station.hub.wait(version, AGES_EVERY_S)
            except (BrokenPipeError, ConnectionResetError, OSError):
                pass
            self.close_connection = True

    return Handler


class WebServer(ThreadingHTTPServer):
    daemon_threads = True
    closing = False
    access: Access


def start(station: WebStation, vehicle: str, host: str = "127.0.0.1", port: int = 8470, *,
          token: str | None = None, tls: ssl.SSLContext | None = None,
          names: tuple[str, ...] = ()) -> WebServer:
    """Serve the page in a background thread; ``server.shutdown()`` stops it.
    ``token``: this session's (default: a new one, ``server.access.token``);
    ``tls``: serve HTTPS; ``names``: more host names the page answers to. The bind
    is not checked here (:func:`serve` does: loopback, or TLS)."""
    cls = WebServer
    if ":" in host.strip("[]"):
        cls = type("WebServer6", (WebServer,), {"address_family": socket.AF_INET6})
    server = cls((host.strip("[]"), port), _handler(station, vehicle))
    if tls is not None:
        server.socket = tls.wrap_socket(server.socket, server_side=True,
                                        do_handshake_on_connect=False)
    server.access = access_for(host, server.server_address[1], token or new_token(),
                               tls is not None, names)
    threading.Thread(target=server.serve_forever, name="rota-gs-web", daemon=True).start()
    return server


def stop(server: WebServer) -> None:
    server.closing = True
    server.shutdown()
    server.server_close()


def page_url(server: WebServer, host: str) -> str:
    """The address to open: the page with this session's token after ``#`` (a
    fragment: the browser keeps it, it is never sent to a server)."""
    a = server.access
    name = host if not is_wildcard(host) else socket.getfqdn()
    name = f"[{name.strip('[]')}]" if ":" in name.strip("[]") else name
    return f"{a.scheme}://{name}:{a.port}/#token={a.token}"


def serve(make_station: Callable[[str], GroundStation], vehicle: str, host: str, port: int,
          *, tls_cert: str | None = None, tls_key: str | None = None,
          token_file: Path | None = None, names: tuple[str, ...] = ()) -> None:
    """Serve until Ctrl-C (``rota-gs web``): refuse a bind beyond loopback without
    TLS, make this session's token, print the page's address with it and write it
    to ``token_file`` (0600), removed at the end."""
    if (tls_cert is None) != (tls_key is None):
        raise InputError("--tls-cert/--tls-key", "give both, or neither")
    check_bind(host, tls_cert is not None)
    tls = tls_context(tls_cert, tls_key) if tls_cert and tls_key else None
    station = WebStation(make_station(vehicle))
    server: WebServer | None = None
    path: Path | None = None
    # From here every way out, a Ctrl-C at any moment included, goes through the
    # ``finally``: the Zenoh session left open would hold the interpreter at its exit.
    try:
        try:
            server = start(station, vehicle, host, port, tls=tls, names=names)
        except OSError as exc:
            raise OSError(f"cannot serve on {host}:{port}: {exc.strerror}") from None
        path = token_file or default_token_file(server.access.port)
        try:
            write_token(path, server.access.token)
        except OSError as exc:
            tried, path = path, None  # (not written: nothing to remove)
            raise OSError(f"cannot write the token file {tried}: {exc.strerror}") from None
        where = "over HTTPS (TLS)" if tls else "on this machine's loopback only"
        print(f"rota-gs: ground station for vehicle {vehicle!r}, served {where}; every "
              f"request needs this session's token, in the address below and in {path} "
              f"(readable by you only); answers to host names "
              f"{', '.join(sorted(server.access.hosts))}. Ctrl-C stops. Open:\n"
              f"{page_url(server, host)}", flush=True)
        while True:
            # short sleeps: a Ctrl-C the kernel hands to another thread (Zenoh's, the
            # server's) only sets Python's flag, and the handler runs in this thread
            # when its sleep ends (an hour-long one kept a stopped rota-gs web running)
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        if path is not None:
            path.unlink(missing_ok=True)  # first: the token dies with the session
        if server is not None:
            stop(server)
        station.close()
