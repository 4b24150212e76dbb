"""Everything that arrives from Zenoh: the ``trajectory`` and ``map``
subscriptions and the ``cmd/*``, ``config`` and ``estimator`` queryables.

Zenoh calls back on its own threads. There, each input gets only constant-time
checks: its byte size against the configured cap and a rate limit; what fails
is dropped (a put) or refused at once (a query), and counted. What passes is
handed to the event loop as bytes, and from there to the decoder's worker
process; nothing is decoded on the loop, and replies leave from the service's
sending thread (:mod:`companion.network.outbox`). Every input is put on record with the
peer that sent it (:mod:`companion.network.actors`): each query and each refusal in the
log, each accepted put in the flight record's ``log`` channel. Puts are decoded one at a time per
kind, in arrival order; only the newest few of each kind wait (:data:`BACKLOG`),
so a flood supersedes itself. Every query gets a reply, whatever happens to it.
"""

from __future__ import annotations

import asyncio
import json
import logging
import threading
import time
from collections import Counter, deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, replace
from typing import Any

import zenoh

from companion import memory
from companion import messages as msgs
from companion.flight.reaction import Timing
from companion.network.actors import Actor, Peers
from companion.network.decoder import DecodeFn, Decoder
from companion.network.outbox import Send, send_now
from companion.settings.config import Config, short
from companion.status import Reporter

log = logging.getLogger("rota.companion")

#: Larger puts are recorded by size only (the flight record's writer is a thread).
RECORD_MAX_BYTES = 1_000_000
#: An input at least this large leaves memory to give back (:mod:`companion.memory`).
LARGE_BYTES = 1_000_000
#: After a large input, free memory is returned this often, s, until ...
TRIM_EVERY_S = 5.0
#: ... this long after the last large input, s.
TRIM_FOR_S = 15.0
#: Puts of each kind waiting for the decoder; older ones are dropped (counted).
BACKLOG = {"trajectory": 4, "map": 1}

#: A subscription handler: the decoded, validated input, on the event loop; it
#: raises :class:`companion.messages.Rejected` to refuse it.
PutHandler = Callable[[Any], None]
#: A query handler: (name, decoded payload or None, the asking peer) -> the reply's
#: JSON bytes. The peer is the :class:`~companion.network.actors.Actor` in words; the
#: fleet's access control decides who may ask at all.
QueryHandler = Callable[[str, Any, str], Awaitable[bytes]]
#: An input from an unknown sender (a ROS 2 message: rmw_zenoh declares no source).
NOBODY = Actor(None)


@dataclass(frozen=True)
class Handlers:
    trajectory: PutHandler
    map: PutHandler
    command: QueryHandler
    config: QueryHandler
    estimator: QueryHandler


class RateLimit:
    """A token bucket (thread-safe): ``rate`` per second, bursts of ``burst``."""

    def __init__(self, rate: float, burst: float | None = None) -> None:
        self.rate = rate
        self.burst = burst if burst is not None else max(1.0, rate)
        self._tokens = self.burst
        self._t = time.monotonic()
        self._lock = threading.Lock()

    def allow(self) -> bool:
        with self._lock:
            now = time.monotonic()
            self._tokens = min(self.burst, self._tokens + (now - self._t) * self.rate)
            self._t = now
            if self._tokens >= 1.0:
                self._tokens -= 1.0
                return True
            return False


class Inputs:
    """Declares the service's Zenoh inputs under ``key`` and dispatches them."""

    def __init__(self, session: zenoh.Session, cfg: Callable[[], Config],
                 loop: asyncio.AbstractEventLoop, handlers: Handlers, decoder: Decoder,
                 report: Reporter, send: Send = send_now,
                 record: Callable[[str, Any], None] | None = None) -> None:
        self._cfg = cfg
        self._send = send
        self._loop = loop
        self._h = handlers
        self._decoder = decoder
        self.report = report
        key = cfg().key
        self._key = key
        self._limits: dict[str, RateLimit] = {}
        self._drops: Counter[str] = Counter()  # (input: reason) -> count since the last report
        self._drops_lock = threading.Lock()
        self.dropped: Counter[str] = Counter()  # all time, per input
        self._pending: dict[str, deque[tuple[bytes, DecodeFn | None, Actor]]] = {}
        self._seen: set[tuple[str, str | None, str | None]] = set()  # (input, zid, name)
        self._wake: dict[str, asyncio.Event] = {}
        self._background: set[asyncio.Task] = set()
        #: the flight record: every put as received (``record(channel, payload)``)
        self.record: Callable[[str, Any], None] = record or (lambda channel, payload: None)
        self.peers = Peers(session)
        self._last_large = self._last_trim = -1e9  # monotonic times
        self._objs: list[Any] = [
            session.declare_subscriber(key("trajectory"), self._put("trajectory")),
            session.declare_subscriber(key("map"), self._put("map")),
            session.declare_queryable(key("cmd", "*"), self._query("cmd", handlers.command)),
            session.declare_queryable(key("config"), self._query("config", handlers.config)),
            session.declare_queryable(key("estimator"),
                                      self._query("estimator", handlers.estimator)),
        ]

    # ------------------------------------------------------------ Zenoh threads
    def _limit(self, name: str, rate: float) -> RateLimit:
        lim = self._limits.get(name)
        if lim is None or lim.rate != rate:
            lim = self._limits[name] = RateLimit(rate)
        return lim

    def _drop(self, what: str, reason: str) -> None:
        with self._drops_lock:
            self._drops[f"{what}: {reason}"] += 1
            self.dropped[what] += 1

    def admit(self, what: str, size: int, cap: int, rate: float,
              actor: Actor = NOBODY) -> bool:
        """The constant-time checks of an input of ``size`` bytes (any thread)."""
        sender = "" if actor is NOBODY else f" (from {actor})"
        if size >= LARGE_BYTES:  # (reassembled by Zenoh, refused or not: memory to give back)
            self._last_large = time.monotonic()
        if size > cap:
            self._drop(what, f"over the {cap}-byte cap{sender}")
            return False
        if not self._limit(what, rate).allow():
            self._drop(what, f"over {rate:g} per second{sender}")
            return False
        return True

    def deliver(self, what: str, payload: bytes, fn: DecodeFn | None = None,
                actor: Actor = NOBODY) -> None:
        """Hand an admitted put to the loop (any thread); ``fn`` decodes it."""
        self._loop.call_soon_threadsafe(self._arrived, what, payload, fn, actor,
                                        time.monotonic())

    def _caps(self, what: str) -> tuple[int, float]:
        """The byte cap and the rate limit of a trajectory or map input."""
        i = self._cfg().inputs
        return (i.max_map_bytes, i.max_maps_per_s) if what == "map" else \
            (i.max_trajectory_bytes, i.max_messages_per_s)

    def _put(self, what: str) -> Callable[[zenoh.Sample], None]:
        def callback(sample: zenoh.Sample) -> None:
            actor = self.peers.actor(sample.source_info)
            if self.admit(what, len(sample.payload), *self._caps(what), actor):
                self.deliver(what, sample.payload.to_bytes(), None, actor)

        return callback

    def put_ros2(self, kind: str, decode: DecodeFn, payload: bytes) -> None:
        """A ROS message, on Zenoh's thread (``companion.ros2``): the same byte cap and
        rate limit as the service's own trajectory and map inputs, then the decoding
        worker with the ROS decoder ``decode``."""
        what = "map" if kind == "pointcloud" else "trajectory"
        if self.admit(f"ros2 {kind}", len(payload), *self._caps(what)):
            self.deliver(what, payload, decode)

    def _query(self, what: str, handler: QueryHandler) -> Callable[[zenoh.Query], None]:
        def callback(query: zenoh.Query) -> None:
            name = str(query.key_expr).rsplit("/", 1)[-1] if what == "cmd" else what
            i = self._cfg().inputs
            size = 0 if query.payload is None else len(query.payload)
            # (unknown command names share one bucket: a flood of made-up names must
            # not grow the table of limits)
            label = (f"cmd/{name}" if name in msgs.COMMANDS else "cmd/unknown") \
                if what == "cmd" else what
            actor = self.peers.actor(query.source_info)
            if not self.admit(label, size, i.max_query_bytes, i.max_queries_per_s, actor):
                self._refuse(query, what, name, f"refused: over {i.max_queries_per_s:g} "
                             f"queries per second or {i.max_query_bytes} bytes")
                return
            payload = query.payload.to_bytes() if size else None
            self._loop.call_soon_threadsafe(self._answer, handler, query, what, name, payload,
                                            actor)

        return callback

    def _reply_key(self, what: str, name: str) -> str:
        """A concrete key that intersects the query's (which may hold wildcards)."""
        if what != "cmd":
            return self._key(what)
        plain = name and not any(c in name for c in "*$?#")
        return self._key("cmd", name if plain else "unknown")

    def _refuse(self, query: zenoh.Query, what: str, name: str, message: str) -> None:
        body = msgs.envelope(msgs.REPLY, command=name, ok=False, message=message)
        reply(query, self._reply_key(what, name), json.dumps(body).encode())

    # -------------------------------------------------------------- event loop
    def _arrived(self, what: str, payload: bytes, fn: DecodeFn | None, actor: Actor,
                 arrived: float) -> None:
        self.record(what, payload if len(payload) <= RECORD_MAX_BYTES else
                    {"bytes": len(payload), "not_recorded": "larger than "
                     f"{RECORD_MAX_BYTES} bytes"})
        queue = self._pending.setdefault(what, deque())
        if len(queue) >= BACKLOG.get(what, 1):
            queue.popleft()
            self._drop(what, "superseded by newer ones before it was decoded")
        queue.append((payload, fn, actor, arrived))
        self._wake.setdefault(what, asyncio.Event()).set()

    async def consume(self, what: str) -> None:
        """Decode and hand over the newest ``what`` input, one at a time (a task)."""
        wake = self._wake.setdefault(what, asyncio.Event())
        handler = self._h.map if what == "map" else self._h.trajectory
        queue = self._pending.setdefault(what, deque())
        while True:
            if not queue:
                wake.clear()
                await wake.wait()
                continue
            payload, fn, actor, arrived = queue.popleft()
            size = len(payload)
            try:
                obj = await self._decoder.decode(what, payload, fn)
            except msgs.Rejected as exc:
                self.report.error(what, f"{exc} (from {actor})")
                continue
            finally:
                payload = None  # (not held while this task waits for the next: up to the cap)
            if isinstance(obj, msgs.Incoming):  # (its way to the vehicle is timed)
                obj = replace(obj, timing=Timing(arrived, time.monotonic()))
            try:
                handler(obj)
            except msgs.Rejected as exc:
                self.report.error(what, f"{exc} (from {actor})")
                continue
            self._accepted(what, obj, size, actor)

    def _accepted(self, what: str, obj: Any, size: int, actor: Actor) -> None:
        """An accepted put on record: in the flight record's ``log`` channel every
        time, in the log the first time each peer sends each kind."""
        ident = getattr(obj, "id", None)
        message = f"{what}{f' {short(ident)!r}' if ident else ''} ({size} bytes) from {actor}"
        key = (what, actor.zid, actor.name)
        if key not in self._seen and len(self._seen) < 1000:  # (made-up ids: bounded)
            self._seen.add(key)
            log.info("first %s", message)
        self.record("log", {"level": "INFO", "logger": "rota.companion.inputs",
                            "message": message, "actor": actor.to_dict()})

    def kinds(self) -> list[str]:
        """The put inputs that need a :meth:`consume` task."""
        return ["trajectory", "map"]

    def _answer(self, handler: QueryHandler, query: zenoh.Query, what: str, name: str,
                payload: bytes | None, actor: Actor) -> None:
        async def answer() -> None:
            body = None
            try:
                request = None
                if payload and what != "cmd":
                    request = await self._decoder.decode("query", payload)
                body = await handler(name, request, str(actor))
            except msgs.Rejected as exc:
                self.report.error(what, str(exc))
                body = json.dumps(msgs.envelope(msgs.REPLY, command=name, ok=False,
                                                message=str(exc))).encode()
            except Exception as exc:  # noqa: BLE001 - every query gets a reply
                log.exception("answering %s %s", what, name)
                message = f"internal error: {type(exc).__name__}: {exc}"
                self.report.error(what, message)
                body = json.dumps(msgs.envelope(msgs.REPLY, command=name, ok=False,
                                                message=message)).encode()
            finally:
                if body is None:  # cancelled (shutdown): still answer
                    body = json.dumps(msgs.envelope(msgs.REPLY, command=name, ok=False,
                                                    message="service stopping")).encode()
                self._on_record(what, name, body, actor)
                # (a reply may wait for room on the asker's link: never on the loop)
                self._send(reply, query, self._reply_key(what, name), body)

        task = asyncio.ensure_future(answer())
        self._background.add(task)
        task.add_done_callback(self._background.discard)

    def _on_record(self, what: str, name: str, body: bytes, actor: Actor) -> None:
        """A query and its answer in the log (and so the flight record), with the
        asker: every command, configuration and estimator request, accepted or not."""
        try:
            answer = json.loads(body)
            ok, words = bool(answer.get("ok")), str(answer.get("message") or "")
        except (ValueError, AttributeError):
            ok, words = False, "unreadable reply"
        request = f"cmd/{short(name)}" if what == "cmd" else what
        log.log(logging.INFO if ok else logging.WARNING, "%s from %s: %s%s", request, actor,
                "done" if ok else "refused", f": {short(words, 300)}" if words else "")

    async def report_drops(self) -> None:
        """Once a second: what was dropped or refused, in one error (a task); and
        after a large input, free memory returned to the system (in a thread:
        ``malloc_trim`` takes each allocator arena's lock in turn)."""
        loop = asyncio.get_running_loop()
        while True:
            await asyncio.sleep(1.0)
            now = time.monotonic()
            if now - self._last_large < TRIM_FOR_S and now - self._last_trim >= TRIM_EVERY_S:
                self._last_trim = now
                await loop.run_in_executor(None, memory.trim)
            with self._drops_lock:
                drops, self._drops = self._drops, Counter()
            # a newer message superseding an older one is how a fast planner works;
            # a message refused for its size or rate is an error
            superseded = {r: n for r, n in drops.items() if "superseded" in r}
            refused = {r: n for r, n in drops.items() if r not in superseded}
            if refused:
                self.report.error("inputs", "dropped: " + "; ".join(
                    f"{n} x {reason}" for reason, n in sorted(refused.items())))
            if superseded:
                self.report.warn("inputs: " + "; ".join(
                    f"{n} x {reason}" for reason, n in sorted(superseded.items())), "inputs")

    def close(self) -> None:
        self.peers.close()
        for obj in self._objs:
            try:
                obj.undeclare()
            except Exception:  # noqa: BLE001, S110 - closing anyway
                pass


def reply(query: zenoh.Query, key: str, payload: bytes) -> None:
    """Answer a Zenoh query with JSON and finalise it."""
    try:
        query.reply(key, payload, encoding=zenoh.Encoding.APPLICATION_JSON)
    except Exception as exc:  # noqa: BLE001 - the asker may be gone
        log.debug("reply failed: %s", exc)
    finally:
        query.drop()
