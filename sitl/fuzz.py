"""Hostile input, generated: ``rota-sitl fuzz`` (and a reduced run in the
tests) flies the proving circle while hypothesis-generated malformed and
hostile messages arrive on every input (trajectory, map, commands, config,
estimator), plus the oversized messages that once stalled the stream. Then it
prints what it tried and what the vehicle received: crashes, unsafe setpoints,
the largest gap, and the service's memory before and after.

Commands that are an operator's to give (hold, land, abort) are not fuzzed:
they work as commands; everything else is, including arm, disarm, takeoff and
start in flight, which the service must refuse.
"""

from __future__ import annotations

import asyncio
import json
import math
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sitl.proving import Flight, circle_message

SAFE_COMMANDS = ("arm", "disarm", "takeoff", "start")
#: Messages per second sent by the fuzzer (under the service's rate limits, so
#: that most messages are decoded rather than dropped unread).
PACE_HZ = 15.0

_numbers = st.one_of(
    st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=False, allow_infinity=False),
    st.sampled_from([0, -0.0, 1e308, -1e308, 5e-324, 2**53 + 1]))
_scalars = st.one_of(st.none(), st.booleans(), _numbers,
                     st.text(max_size=20), st.sampled_from(["NaN", "Infinity", "-Infinity"]))
_json = st.recursive(_scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=6), st.dictionaries(st.text(max_size=10), inner, max_size=6)),
    max_leaves=30)


@dataclass
class Hostile:
    """One hostile message: where it goes, and its bytes."""

    key: str  # "trajectory", "map", "cmd/<name>", "config", "estimator"
    payload: bytes | None
    kind: str  # what was done to it


def _mutate(message: dict[str, Any], data: st.DataObject) -> tuple[dict[str, Any], str]:
    """A valid message with one field broken."""
    msg = dict(message)
    keys = sorted(msg)
    action = data.draw(st.sampled_from(["set", "delete", "number", "nest", "stamp"]))
    key = data.draw(st.sampled_from(keys))
    if action == "set":
        msg[key] = data.draw(_json)
    elif action == "delete":
        del msg[key]
    elif action == "number":
        arr = [k for k in keys if isinstance(msg[k], list) and msg[k]]
        if arr:
            key = data.draw(st.sampled_from(arr))
            items = json.loads(json.dumps(msg[key]))
            i = data.draw(st.integers(0, len(items) - 1))
            bad = data.draw(st.sampled_from([float("nan"), float("inf"), 1e308, -1e308,
                                             "x", None, [], {}]))
            if isinstance(items[i], list) and items[i]:
                items[i][data.draw(st.integers(0, len(items[i]) - 1))] = bad
            else:
                items[i] = bad
            msg[key] = items
    elif action == "nest":
        depth = data.draw(st.integers(2, 100_000))
        return msg, f"nest:{depth}"  # built as bytes (json cannot write it)
    elif action == "stamp":
        msg["stamp"] = data.draw(st.sampled_from([None, 0, -1.0, time.time() - 3600,
                                                  time.time() + 3600, time.time() - 10]))
    return msg, f"{action}:{key}"


def _encode(msg: Any, kind: str, data: st.DataObject) -> bytes:
    if kind.startswith("nest:"):
        depth = int(kind[5:])
        return b'{"schema": ' + b"[" * depth + b"1" + b"]" * depth + b"}"
    text = json.dumps(msg, allow_nan=True).encode()
    how = data.draw(st.sampled_from(["plain"] * 6 + ["truncate", "bytes", "utf16"]))
    if how == "truncate":  # (a share, not an index: the text's length varies with the
        # time stamps, and hypothesis needs the same draws for the same choices)
        return text[: int(data.draw(st.floats(0.0, 1.0)) * len(text))]
    if how == "bytes":
        return data.draw(st.binary(max_size=200))
    if how == "utf16":
        return text.decode().encode("utf-16")
    return text


def hostile(flight: Flight, data: st.DataObject) -> Hostile:
    """A hostile message for ``flight``'s service, drawn by hypothesis."""
    where = data.draw(st.sampled_from(["trajectory", "map", "cmd", "config", "estimator"]))
    if where == "trajectory":
        valid = circle_message(flight.center, 3.6, 0.0, flight.speed, 10.0, "fuzz")
        msg, kind = _mutate(valid, data)
        return Hostile("trajectory", _encode(msg, kind, data), kind)
    if where == "map":
        valid = {"schema": "rota/map", "version": 1, "frame": "ENU", "resolution": 0.1,
                 "origin": [0, 0, 0], "occupied": [[20.05, 20.05, 1.05]], "stamp": time.time()}
        msg, kind = _mutate(valid, data)
        return Hostile("map", _encode(msg, kind, data), kind)
    if where == "cmd":
        name = data.draw(st.one_of(st.sampled_from(SAFE_COMMANDS),
                                   st.text(alphabet="abcdefgh_*$?-", min_size=1, max_size=12)))
        payload = data.draw(st.one_of(st.none(), st.binary(max_size=64)))
        return Hostile(f"cmd/{name}", payload, "command")
    body = data.draw(st.one_of(_json, st.fixed_dictionaries({"set": _json}), st.fixed_dictionaries(
        {"set": st.dictionaries(st.sampled_from(["limits", "safety", "uncertainty", "stream"]),
                                st.dictionaries(st.text(max_size=12), _json, max_size=3),
                                max_size=2)})))
    return Hostile(where, _encode(body, "query", data), "query")


def _trajectory_bytes(ident: str, kind: str, fields: str) -> bytes:
    return (f'{{"schema": "rota/trajectory", "version": 1, "id": "{ident}", "type": "{kind}", '
            f'"stamp": {time.time()}, {fields}}}').encode()


def oversized() -> list[Hostile]:
    """The messages that once stalled the stream for 0.5 to 4 s (built as text:
    the fuzzer need not hold them as Python lists)."""
    points = ", ".join(["[0.0, 0.0, 1.0]"] * 1_000_000)
    n = 2_000_000
    times = ", ".join(map(str, range(n)))
    samples = ", ".join(["[0.0, 0.0, 1.0]"] * n)
    coeffs = "[" + ", ".join(["0.0"] * 200_001) + "]"
    g = np.stack(np.meshgrid(np.arange(100), np.arange(100), np.arange(100)), -1).reshape(-1, 3)
    voxels = json.dumps((g * 0.1 + 10.05).round(2).tolist())
    return [
        Hostile("trajectory", _trajectory_bytes(
            "big", "bspline", f'"knot_span": 0.1, "control_points": [{points}]'),
            "1e6 control points"),
        Hostile("trajectory", _trajectory_bytes(
            "huge", "samples", f'"t": [{times}], "p": [{samples}]'), "2e6 samples"),
        Hostile("trajectory", _trajectory_bytes(
            "degree", "polynomial", f'"durations": [1.0], "coefficients": '
            f'[[{coeffs}, {coeffs}, {coeffs}]]'), "degree 200,000"),
        Hostile("map", (f'{{"schema": "rota/map", "version": 1, "frame": "ENU", "resolution": '
                        f'0.1, "origin": [0, 0, 0], "stamp": {time.time()}, "occupied": '
                        f'{voxels}}}').encode(), "1e6 voxels"),
    ]


@dataclass
class FuzzFigures:
    tried: Counter = field(default_factory=Counter)
    crashed: bool = False
    replies: int = 0
    queries: int = 0
    rss_before_mb: float = math.nan
    rss_after_mb: float = math.nan

    def summary(self) -> str:
        return (f"messages tried: {sum(self.tried.values())} ({dict(self.tried)}); "
                f"queries answered {self.replies}/{self.queries}; crashed: {self.crashed}; "
                f"service RSS {self.rss_before_mb:.0f} MB before, {self.rss_after_mb:.0f} MB "
                "after")


def send(flight: Flight, msg: Hostile, figures: FuzzFigures) -> None:
    """Put or query ``msg`` (queries are counted when answered)."""
    session, key = flight.gs.session, flight.cfg.key(msg.key)
    try:
        if msg.key in ("trajectory", "map"):
            session.put(key, msg.payload or b"")
        else:
            def on_reply(reply: Any) -> None:
                figures.replies += 1

            session.get(key, on_reply, payload=msg.payload, timeout=10.0)
            figures.queries += 1
    except Exception:  # noqa: BLE001 - Zenoh itself refuses to send it (a bad key)
        figures.tried["unsendable"] += 1
        return
    figures.tried[msg.key.split("/")[0]] += 1


def run_fuzz(flight: Flight, examples: int, seed: int = 0,
             big: bool = True) -> tuple[FuzzFigures, tuple[float, float]]:
    """Fuzz ``flight``'s service while it flies the proving circle. Returns the
    figures and the wall-clock window of the fuzzing."""
    figures = FuzzFigures()

    async def prepare() -> None:
        await flight.take_off()
        await flight.circle("fuzz-0", duration_s=600.0)

    asyncio.run(prepare())
    figures.rss_before_mb = flight.service.rss_mb()
    t0 = time.monotonic()

    @settings(max_examples=examples, deadline=None, database=None, derandomize=False,
              suppress_health_check=list(HealthCheck))
    @given(data=st.data())
    def one(data: st.DataObject) -> None:
        if not flight.service.alive():
            figures.crashed = True
            return
        send(flight, hostile(flight, data), figures)
        time.sleep(1.0 / PACE_HZ)

    import hypothesis

    hypothesis.seed(seed)(one)()
    if big:
        for msg in oversized():
            send(flight, msg, figures)
            time.sleep(1.0)
    deadline = time.monotonic() + 15.0
    while figures.replies < figures.queries and time.monotonic() < deadline:
        time.sleep(0.1)
    figures.crashed = figures.crashed or not flight.service.alive()
    if not figures.crashed:
        figures.rss_after_mb = flight.service.rss_mb()
    return figures, (t0, time.monotonic())
