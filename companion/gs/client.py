"""The ground-station client: one Zenoh session that watches a vehicle's
status, telemetry and re-timed results, sends trajectories, maps, commands and
configuration, and lists the vehicles alive. Message formats: ``docs/protocol.md``.

It works against the demo on loopback (``connect=["tcp/127.0.0.1:PORT"]``) and
against a service on another machine (its Zenoh endpoint, or the fleet's Zenoh
configuration file with its TLS and authentication settings).
"""

from __future__ import annotations

import asyncio
import json
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import zenoh

from companion.protocol import KEY_PREFIX, vehicle_key

#: The state each command leads to, as the status reports it (None: any), and
#: how long the vehicle may take to get there.
CONFIRM: dict[str, tuple[Callable[[dict[str, Any]], bool], float, str]] = {
    "arm": (lambda s: s.get("state") == "armed", 10.0, "state armed"),
    "disarm": (lambda s: s.get("state") in ("ready", "not_ready"), 10.0, "state ready"),
    "takeoff": (lambda s: s.get("state") == "airborne", 40.0, "state airborne"),
    "start": (lambda s: s.get("state") == "offboard", 15.0, "state offboard"),
    "hold": (lambda s: s.get("command") == "hold", 30.0, "a hold"),
    "abort": (lambda s: s.get("state") in ("airborne", "ready", "landing"), 10.0,
              "PX4's own mode (airborne)"),
    "land": (lambda s: s.get("state") in ("ready", "not_ready"), 90.0,
             "landed and disarmed (ready)"),
}


class GroundStationError(RuntimeError):
    """A query got no answer, the service refused, or a state was not confirmed."""


def zenoh_config(connect: Sequence[str] = (), config_file: str | None = None) -> zenoh.Config:
    """A Zenoh configuration for a ground station: the fleet's file when given
    (its mode, endpoints, TLS and authentication), else a Zenoh client of the
    service (or router) at ``connect``: it listens on no port and seeks nothing on
    the network (multicast scouting off); the service routes for it."""
    if config_file:
        z = zenoh.Config.from_file(config_file)
        if connect:
            z.insert_json5("connect/endpoints", json.dumps(list(connect)))
        return z
    z = zenoh.Config()
    z.insert_json5("mode", '"client"')
    z.insert_json5("scouting/multicast/enabled", "false")
    z.insert_json5("connect/endpoints", json.dumps(list(connect)))
    return z


def open_session(connect: Sequence[str] = (), config_file: str | None = None,
                 wait_s: float = 0.0) -> zenoh.Session:
    """Open a Zenoh session, trying again for up to ``wait_s`` while the service
    (or router) cannot be reached; then raise :class:`GroundStationError`."""
    where = config_file or ", ".join(connect) or "the default configuration"
    try:
        config = zenoh_config(connect, config_file)
    except (zenoh.ZError, OSError, ValueError) as exc:
        raise GroundStationError(f"Zenoh configuration {where}: {exc}") from None
    end = time.monotonic() + wait_s
    while True:
        try:
            return zenoh.open(config)
        except zenoh.ZError as exc:
            if time.monotonic() >= end:
                raise GroundStationError(f"cannot reach {where}: {str(exc).split('!')[0]} "
                                         "(is the service running, and is this its Zenoh "
                                         "endpoint?)") from None
        time.sleep(0.1)


@dataclass(frozen=True)
class Vehicle:
    """A vehicle whose service is alive (its Zenoh liveliness token) and answers
    (``zid``: the Zenoh id of the session that answered its ``config`` query)."""

    prefix: str
    id: str
    zid: str = ""


def list_vehicles(session: zenoh.Session, prefix: str = "*",
                  timeout_s: float = 2.0) -> list[Vehicle]:
    """The vehicles alive: the services' liveliness tokens ``<prefix>/<id>/alive``,
    each confirmed by a service answering ``<prefix>/<id>/config`` (Zenoh does not
    say who declared a token, so a token alone may be a ghost; Zenoh does say who
    answered a query)."""
    tokens = set()
    for reply in session.liveliness().get(f"{prefix}/*/alive", timeout=timeout_s):
        if reply.ok is not None:
            parts = str(reply.ok.key_expr).split("/")
            if len(parts) == 3:
                tokens.add((parts[0], parts[1]))
    asked = [(p, v, session.get(f"{p}/{v}/config", timeout=timeout_s)) for p, v in tokens]
    found = [Vehicle(p, v, _replier(replies)) for p, v, replies in asked]
    return sorted((v for v in found if v.zid), key=lambda v: (v.prefix, v.id))


def _replier(replies: Any) -> str:
    """The Zenoh id of the first session that answered (``""``: none did)."""
    for reply in replies:
        if reply.ok is not None and reply.replier_id is not None:
            return str(reply.replier_id.zid)
    return ""


class GroundStation:
    """A Zenoh client for one vehicle (``<key_prefix>/<vehicle>/...``).

    Keeps the newest ``status`` and ``telemetry``, every re-timed result
    (``retimed``), the status history (``statuses``) and the commanded positions
    (``setpoints``: (monotonic time, ENU position)). ``on_message(name, obj)`` is
    called from Zenoh's threads for every message received. ``wait_s``: how long
    to keep trying to reach the service at first.

    Only the vehicle speaks for the vehicle: a status, telemetry or re-timed
    message is taken only if its source (Zenoh's source info, which the service
    sets on each) is the session that answers the vehicle's ``config`` query
    (``vehicle_zid``, as Zenoh reports the replier); others are counted in
    ``ignored``. The source info is declared by the sender, so this stops a
    process that merely publishes on the vehicle's keys, not one that copies the
    vehicle's source; the fleet's access control on the vehicle stops both
    (``docs/security.md``).
    """

    def __init__(self, vehicle: str = "drone1", *, connect: Sequence[str] = (),
                 config_file: str | None = None, key_prefix: str = KEY_PREFIX,
                 session: zenoh.Session | None = None, history: int = 100000,
                 wait_s: float = 0.0,
                 on_message: Callable[[str, dict[str, Any]], None] | None = None) -> None:
        self.vehicle, self.key_prefix = vehicle, key_prefix
        self._own_session = session is None
        self.session = session or open_session(connect, config_file, wait_s)
        self.status: dict[str, Any] = {}
        self.status_count = 0  # statuses received
        self.telemetry: dict[str, Any] = {}
        self.retimed: list[dict[str, Any]] = []
        self.statuses: deque[dict[str, Any]] = deque(maxlen=history)
        self.setpoints: deque[tuple[float, list[float]]] = deque(maxlen=history)
        self.on_message = on_message
        self._changed = threading.Condition()
        self._sn = 0
        self.vehicle_zid: str | None = None  # the session that answers as the vehicle
        self.ignored = 0  # outputs from any other session
        self._asked, self._ask_every = -1e9, 1.0
        self.identify()
        self._subs = [self.session.declare_subscriber(self.key(name), self._on(name))
                      for name in ("status", "telemetry", "retimed")]

    @classmethod
    def for_service(cls, cfg: Any, endpoint: str, **kwargs: Any) -> GroundStation:
        """A ground station for the service configured by ``cfg`` (a
        :class:`companion.settings.config.Config`), connecting to ``endpoint``."""
        return cls(cfg.service.vehicle_id, key_prefix=cfg.service.key_prefix,
                   connect=[endpoint], **kwargs)

    def key(self, *parts: str) -> str:
        return vehicle_key(self.key_prefix, self.vehicle, *parts)

    # ------------------------------------------------------------ receiving
    def identify(self) -> None:
        """Ask (without waiting) which session answers the vehicle's ``config``
        query; it becomes :attr:`vehicle_zid` (a restarted service is a new
        session: asked again when another source speaks, at most once a second, and
        less often while no one answers)."""
        now = time.monotonic()
        if now - self._asked < self._ask_every:
            return
        self._asked = now
        self._ask_every = min(self._ask_every * 2, 30.0)
        answered = threading.Event()

        def on_reply(reply: zenoh.Reply) -> None:
            rid = reply.replier_id
            if reply.ok is not None and rid is not None and not answered.is_set():
                answered.set()
                self.vehicle_zid, self._ask_every = str(rid.zid), 1.0

        try:
            self.session.get(self.key("config"), on_reply, timeout=5.0)
        except zenoh.ZError:
            pass

    def _from_vehicle(self, sample: zenoh.Sample) -> bool:
        source = sample.source_info
        zid = None if source is None else str(source.source_id.zid)
        if zid is not None and zid == self.vehicle_zid:
            return True
        if zid is not None:
            self.identify()
            if self.vehicle_zid is None:
                return True  # not known yet: any session that names itself
        self.ignored += 1
        return False

    def _on(self, name: str) -> Callable[[zenoh.Sample], None]:
        def callback(sample: zenoh.Sample) -> None:
            if not self._from_vehicle(sample):
                return
            try:
                obj = json.loads(sample.payload.to_bytes())
            except (UnicodeDecodeError, json.JSONDecodeError):
                return
            if name == "status":
                self.status = obj
                self.statuses.append(obj)
                self.status_count += 1
            elif name == "telemetry":
                self.telemetry = obj
                sp = obj.get("setpoint")
                if sp is not None:
                    self.setpoints.append((time.monotonic(), sp["position"]))
            else:
                self.retimed.append(obj)
            if self.on_message is not None:
                self.on_message(name, obj)
            with self._changed:
                self._changed.notify_all()

        return callback

    # ------------------------------------------------------------ sending
    def publish(self, name: str, obj: dict[str, Any] | bytes) -> None:
        """Put a JSON message on ``<prefix>/<vehicle>/<name>`` (trajectory, map);
        ``obj`` a dict, or its JSON already encoded (``bytes``).

        With congestion control *block*, not Zenoh's default for a put (*drop*): a
        map of a megabyte goes out in many fragments, and with *drop* a full send
        queue (a busy machine) loses it without a word on either side, as a map once
        was in a test on a loaded machine. Waiting for room is what an operator wants
        of a map or a trajectory."""
        payload = obj if isinstance(obj, bytes) else json.dumps(obj, allow_nan=False).encode()
        self._sn += 1  # who sent it: the service's record names this session's Zenoh id
        self.session.put(self.key(name), payload, encoding=zenoh.Encoding.APPLICATION_JSON,
                         congestion_control=zenoh.CongestionControl.BLOCK,
                         source_info=zenoh.SourceInfo(self.session.id, self._sn))

    def send_trajectory(self, obj: dict[str, Any]) -> None:
        self.publish("trajectory", obj)

    def send_map(self, obj: dict[str, Any]) -> None:
        self.publish("map", obj)

    def query(self, *parts: str, payload: dict[str, Any] | None = None,
              timeout_s: float = 15.0) -> dict[str, Any]:
        """A Zenoh query to the service; its JSON reply (blocking)."""
        key = self.key(*parts)
        body = None if payload is None else json.dumps(payload, allow_nan=False).encode()
        self._sn += 1  # who asks: the service's audit log names this session's Zenoh id
        source = zenoh.SourceInfo(self.session.id, self._sn)
        for reply in self.session.get(key, payload=body, timeout=timeout_s, source_info=source):
            if reply.ok is not None:
                return json.loads(reply.ok.payload.to_bytes())
        raise GroundStationError(f"no reply from {key} within {timeout_s:g} s (is the "
                                 f"service for vehicle {self.vehicle!r} running and reachable?)")

    async def command(self, name: str, timeout_s: float = 15.0) -> dict[str, Any]:
        """Send a command (``cmd/<name>``) and return the reply (``rota/reply``)."""
        return await asyncio.get_running_loop().run_in_executor(
            None, lambda: self.query("cmd", name, timeout_s=timeout_s))

    async def command_confirmed(self, name: str, timeout_s: float | None = None) -> dict[str, Any]:
        """Send a command, then wait until the status confirms the state it leads
        to; raises :class:`GroundStationError` if refused or not confirmed."""
        reply = await self.command(name)
        if not reply.get("ok"):
            raise GroundStationError(f"{name} refused: {reply.get('message')}")
        if name in CONFIRM:
            ok, wait, what = CONFIRM[name]
            await self.wait_for(ok, timeout_s or wait, what, fresh=True)
        return reply

    def config(self, changes: dict[str, Any] | None = None) -> dict[str, Any]:
        """Read the configuration, or change run-time settings (``rota/config``)."""
        return self.query("config", payload=None if changes is None else {"set": changes})

    def estimator(self, request: dict[str, Any] | None = None) -> dict[str, Any]:
        """Read or steer the in-flight uncertainty estimator (``rota/estimator``)."""
        return self.query("estimator", payload=request)

    # ------------------------------------------------------------ waiting
    async def wait_for(self, predicate: Callable[[dict[str, Any]], bool], timeout_s: float,
                       what: str, fresh: bool = False) -> dict[str, Any]:
        """Wait until a status satisfies ``predicate`` (with ``fresh``: a status
        received after this call); return it, or raise TimeoutError."""
        since = self.status_count if fresh else 0
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            s = self.status
            if s and self.status_count > since and predicate(s):
                return s
            await asyncio.sleep(0.02)
        s = self.status or {}
        said = [f"{e.get('source')}: {e.get('message')}" if isinstance(e, dict) else e
                for e in s.get("events", [])[-5:]]
        raise TimeoutError(f"timed out after {timeout_s:g} s waiting for {what}; state "
                           f"{s.get('state')!r}, last words on status: {said}; status: "
                           f"{json.dumps(s)[:400]}")

    def wait_status(self, timeout_s: float) -> dict[str, Any]:
        """The newest status, waiting up to ``timeout_s`` for the first (blocking)."""
        end = time.monotonic() + timeout_s
        with self._changed:
            while not self.status and time.monotonic() < end:
                self._changed.wait(max(end - time.monotonic(), 0.0))
        if not self.status:
            raise GroundStationError(f"no status from {self.key('status')} within "
                                     f"{timeout_s:g} s (is the service running and reachable?)")
        return self.status

    def close(self) -> None:
        for s in self._subs:
            try:
                s.undeclare()
            except Exception:  # noqa: BLE001, S110 - closing anyway
                pass
        if self._own_session:
            self.session.close()

    def __enter__(self) -> GroundStation:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
