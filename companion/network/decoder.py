"""Decoding network input off the event loop: every trajectory, map and query
payload is parsed and validated in a worker process (:mod:`companion.worker`),
so a large, deep or hostile message costs the setpoint stream nothing. What
comes back is small and validated (an :class:`~companion.messages.Incoming`, a
:class:`~rota.voxelmap.VoxelMap`, or a query's JSON object); any failure,
including RecursionError, MemoryError, a timeout or the death of the worker,
comes back as :class:`~companion.messages.Rejected` naming the input.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from typing import Any

from companion import memory
from companion import messages as msgs
from companion.settings.config import Config
from companion.worker import Worker, WorkerDied

log = logging.getLogger("rota.companion")

#: A payload at least this large leaves memory to give back (:mod:`companion.memory`).
LARGE_BYTES = 1_000_000
#: How long (s) a new decode worker may take to start (its imports): generous, a busy
#: 2-core machine took over 5 s; a decode's own budget starts after it.
WARM_UP_S = 60.0
#: Values a query (command, config, estimator) may hold.
MAX_QUERY_ITEMS = 1000

#: A decoder of one input kind: (payload, config, arrival UNIX time) -> object;
#: module-level, so that it can be sent to the worker.
DecodeFn = Callable[[bytes, Config, float], Any]


def decode_query(payload: bytes, cfg: Config, now: float) -> Any:  # noqa: ARG001
    return msgs.decode(payload, "query", cfg.inputs.max_json_depth, MAX_QUERY_ITEMS)


#: The service's own JSON inputs.
DECODERS: dict[str, DecodeFn] = {
    "trajectory": msgs.parse_trajectory,
    "map": msgs.parse_map,
    "query": decode_query,
}


def _run(fn: DecodeFn, what: str, payload: bytes, cfg: Config, now: float) -> Any:
    """In the worker: ``fn``, with every failure turned into Rejected; after a large
    payload, the memory it took is given back."""
    try:
        return fn(payload, cfg, now)
    except msgs.Rejected:
        raise
    except RecursionError:
        raise msgs.Rejected(f"{what}: nested too deeply") from None
    except MemoryError:
        raise msgs.Rejected(f"{what}: too large to decode (out of memory)") from None
    except Exception as exc:  # noqa: BLE001 - any decoder failure is the message's fault
        raise msgs.Rejected(f"{what}: could not be decoded ({type(exc).__name__}: "
                            f"{str(exc)[:200]})") from None
    finally:
        if len(payload) >= LARGE_BYTES:  # (the payload itself is mapped: freed by its owner)
            memory.trim()


class Decoder:
    """Decodes payloads in worker processes (two: a large map does not hold up a
    trajectory).

    A decode's budget (``inputs.decode_timeout_s``) is for decoding only: a worker
    process that is new (at start, or after one died) is warmed first, its imports
    timed by :data:`WARM_UP_S`. Timed by the decode budget, a fresh worker still
    importing on a busy machine was killed as "too slow", and its successor too, and
    the service refused trajectories until one imported within 5 s.
    """

    def __init__(self, cfg: Callable[[], Config]) -> None:
        self._cfg = cfg
        self.worker = Worker("decode", workers=2)
        self.ready = False  # warmed once: the service is past its start
        self._warming = asyncio.Lock()

    async def start(self) -> None:
        """Spawn every worker now (imports take a second, many on a busy machine),
        not within a message's decode budget: one call each, at once."""
        async with self._warming:
            cfg = self._cfg()
            await asyncio.gather(*(
                self.worker.call(WARM_UP_S, _run, decode_query, "warm-up", b"{}", cfg,
                                 time.time())
                for _ in range(self.worker.workers)))
        self.ready = True

    async def _warm(self) -> None:
        """Warm the workers if they are new (after a warm-up under way, if one is)."""
        async with self._warming:
            cold = self.worker.cold
        if cold:
            await self.start()

    async def decode(self, what: str, payload: bytes, fn: DecodeFn | None = None) -> Any:
        """``payload`` decoded by ``fn`` (default: the decoder named ``what``)."""
        if not self.ready:
            # (a decode's budget is not meant for a worker still importing: timed out,
            # it would kill the worker that start-up is waiting for)
            raise msgs.Rejected(f"{what}: the service is starting (its decoders are not "
                                "ready yet); try again in a few seconds")
        cfg = self._cfg()
        fn = fn or DECODERS[what]
        for attempt in (1, 2):
            try:
                await self._warm()
            except (TimeoutError, WorkerDied) as exc:
                raise msgs.Rejected(f"{what}: no decode worker came up ({exc})") from None
            try:
                return await self.worker.call(cfg.inputs.decode_timeout_s, _run, fn, what,
                                              payload, cfg, time.time())
            except WorkerDied as exc:
                # the worker died (killed, out of memory): once more in a fresh one, so
                # nothing is lost to a death the message did not cause
                if attempt == 2:
                    raise msgs.Rejected(f"{what}: {exc} (twice; the message is refused)") \
                        from None
                log.warning("%s: %s; decoding it again", what, exc)
            except TimeoutError as exc:
                raise msgs.Rejected(f"{what}: {exc}") from None
        raise AssertionError("unreachable")  # pragma: no cover

    def close(self) -> None:
        self.worker.close()
