"""The service on the ROS 2 graph: subscriptions for the planner's topics, publishers
for status and the re-timed trajectory, and the liveliness tokens the layout
needs so ROS tools (and bridges) see them.

Zenoh callbacks only hand the raw payload on: ``deliver(kind, decode_fn, payload)``
with one of :mod:`companion.ros2.decode`'s functions. Decoding happens wherever
``deliver`` sends it (the service's decoding worker), never on Zenoh's thread.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Callable
from typing import Any

import zenoh

from companion.network.outbox import Send, send_now
from companion.ros2 import decode
from companion.ros2.encode import retimed_cdr_from_json, status_cdr
from companion.ros2.layout import Endpoint, RmwZenoh, make_layout
from companion.ros2.settings import Ros2Settings
from companion.ros2.types import HUMBLE_HASH, MULTIDOF, PATH, POINTCLOUD, STRING

log = logging.getLogger("rota.companion")

#: ``deliver(kind, decode_fn, payload)``: kind is bspline, path, multidof or pointcloud;
#: ``decode_fn(payload, cfg)`` returns a messages.Incoming or a VoxelMap, or raises
#: messages.Rejected.
Deliver = Callable[[str, Callable[..., Any], bytes], None]


def input_kinds(s: Ros2Settings) -> dict[str, tuple[str, str, Callable[..., Any]]]:
    """kind -> (topic, ROS type, decoder) of every ROS input, its topic "" when off."""
    return {"bspline": (s.bspline_topic, s.bspline_type, decode.decode_bspline),
            "path": (s.path_topic, PATH, decode.decode_path),
            "multidof": (s.multidof_topic, MULTIDOF, decode.decode_multidof),
            "pointcloud": (s.pointcloud_topic, POINTCLOUD, decode.decode_pointcloud)}


def inputs(s: Ros2Settings) -> list[tuple[str, Endpoint, Callable[..., Any]]]:
    """(kind, endpoint, decoder) of every configured input topic."""
    return [(kind, Endpoint("MS", topic, typename), fn)
            for kind, (topic, typename, fn) in input_kinds(s).items() if topic]


def outputs(s: Ros2Settings) -> dict[str, Endpoint]:
    table = {"status": (s.status_topic, STRING), "retimed": (s.retimed_topic, MULTIDOF)}
    return {name: Endpoint("MP", topic, typename)
            for name, (topic, typename) in table.items() if topic}


def _put(pub: Any, name: str, cdr: bytes, options: dict[str, Any]) -> None:
    try:
        pub.put(cdr, **options)
    except Exception as exc:  # noqa: BLE001 - never let publishing take the service down
        log.warning("publishing ROS %s failed: %s", name, exc)


class Ros2Link:
    """Declares everything on ``session``; ``close()`` undeclares it."""

    def __init__(self, session: zenoh.Session, settings: Ros2Settings,
                 deliver: Deliver, send: Send = send_now,
                 warn: Callable[[str, str], None] | None = None) -> None:
        self.settings = settings
        self._send = send
        self.layout = make_layout(settings, str(session.zid()))
        self._deliver = deliver
        self._objs: list[Any] = []
        ins = inputs(settings)
        outs = outputs(settings)
        for kind, ep, fn in ins:
            self._objs.append(session.declare_subscriber(self.layout.sub_key(ep),
                                                         self._callback(kind, ep, fn)))
        self._pubs = {name: session.declare_publisher(
            self.layout.key(ep), congestion_control=zenoh.CongestionControl.DROP,
            reliability=zenoh.Reliability.RELIABLE) for name, ep in outs.items()}
        self._endpoints = outs
        self._seq = dict.fromkeys(outs, 0)
        self.tokens = self.layout.tokens([ep for _, ep, _ in ins] + list(outs.values()))
        liveliness = session.liveliness()
        self._objs += [liveliness.declare_token(t) for t in self.tokens]
        #: ``warn(message, source)``: a ROS peer of the other distribution (status)
        self._warn = warn or (lambda message, source: log.warning("%s", message))
        self._warned: set[str] = set()
        if isinstance(self.layout, RmwZenoh):
            self._watch = {(kind, layout_topic, dds): ep for ep, kind, layout_topic, dds in (
                (ep, "MP" if ep.kind == "MS" else "MS", *self.layout.watch_key(ep))
                for ep in [ep for _, ep, _ in ins] + list(outs.values()))}
            self._objs.append(liveliness.declare_subscriber(
                f"@ros2_lv/{settings.domain_id}/**", self._on_token, history=True))
        else:  # a bridge announces each route it makes, with its ROS type
            self._own = f"@/{session.zid()}/"
            self._routes = {("MP" if ep.kind == "MS" else "MS", self.layout.key(ep)): ep
                            for ep in [ep for _, ep, _ in ins] + list(outs.values())}
            self._objs.append(liveliness.declare_subscriber(
                "@/*/@ros2_lv/**", self._on_route, history=True))
        log.info("ROS 2 (%s): in %s, out %s", self.layout.name,
                 ", ".join(self.layout.sub_key(ep) for _, ep, _ in ins) or "-",
                 ", ".join(self.layout.key(ep) for ep in outs.values()) or "-")

    def _callback(self, kind: str, ep: Endpoint,
                  fn: Callable[..., Any]) -> Callable[[zenoh.Sample], None]:
        deliver = self._deliver
        layout = self.layout
        want = layout.hash(ep) if isinstance(layout, RmwZenoh) else None
        what = f"{kind} {ep.topic}"

        def callback(sample: zenoh.Sample) -> None:
            payload = sample.payload.to_bytes()
            got = layout.hash_in(str(sample.key_expr))
            if got is not None and got != want:
                deliver(kind, functools.partial(decode.wrong_type, what=what, got=got,
                                                want=want), payload)
            else:
                deliver(kind, fn, payload)

        return callback

    def _on_token(self, sample: zenoh.Sample) -> None:
        """A ROS entity appeared: if it publishes one of the service's inputs or
        subscribes to one of its outputs in the other distribution's form, say so once
        (no data may ever flow to reveal it: a Humble subscriber gets nothing)."""
        token = str(sample.key_expr)
        if sample.kind != zenoh.SampleKind.PUT or token in self._warned:
            return
        parts = token.split("/")
        if len(parts) < 13:  # not a publisher's or subscription's token
            return
        kind, node, topic, dds, got = parts[5], parts[8], parts[9], parts[10], parts[11]
        ep = self._watch.get((kind, topic, dds))
        if ep is None:
            return
        want = self.layout.hash(ep)
        humble_peer = got == HUMBLE_HASH
        if humble_peer == (want == HUMBLE_HASH):
            return  # the same flavour (a differing definition shows when data arrives)
        self._warned.add(token)
        role = "publisher" if kind == "MP" else "subscriber"
        if humble_peer:
            fix, peer = 'set [ros2] distro = "humble"', "ROS 2 Humble"
        else:
            fix, peer = 'set [ros2] distro = "jazzy"', "ROS 2 Jazzy, Kilted or Rolling"
        self._warn(f"ROS 2: node {node} is a {peer} {role} of {ep.topic} and the service "
                   f"speaks {'Humble' if want == HUMBLE_HASH else 'Jazzy and later'}: they "
                   f"cannot exchange messages; {fix}", "ros2")

    def _on_route(self, sample: zenoh.Sample) -> None:
        """A bridge made a route: if it carries one of the service's inputs or outputs
        with another ROS type, say so once (the bridge keeps the first type it saw for
        a topic, so the two never exchange a message, and nothing else would tell)."""
        token = str(sample.key_expr)
        if (sample.kind != zenoh.SampleKind.PUT or token in self._warned
                or token.startswith(self._own)):
            return
        parts = token.split("/")  # @ / <zid> / @ros2_lv / <MP|MS> / <key> / <type> / ...
        if len(parts) < 6:
            return
        slash = self.layout.SLASH
        kind, key, got = parts[3], parts[4].replace(slash, "/"), parts[5].replace(slash, "/")
        ep = self._routes.get((kind, key))
        if ep is None or got == ep.typename:
            return
        self._warned.add(token)
        role = "publishes" if kind == "MP" else "subscribes to"
        fix = (f'set [ros2] bspline_type = "{got}"' if ep.typename == self.settings.bspline_type
               and ep.kind == "MS" else f"the service's is {ep.typename}")
        self._warn(f"ROS 2: a node behind zenoh-bridge-ros2dds {role} {ep.topic} as {got} and "
                   f"the service {'reads' if ep.kind == 'MS' else 'writes'} {ep.typename}: "
                   f"they cannot exchange messages; {fix}", "ros2")

    # ------------------------------------------------------------ outputs
    def put(self, name: str, cdr: bytes) -> None:
        """Publish CDR on output ``name`` (with rmw_zenoh's attachment)."""
        pub = self._pubs.get(name)
        if pub is None:
            return
        self._seq[name] += 1
        self._send(_put, pub, name, cdr,
                   self.layout.put_options(self._endpoints[name], self._seq[name]))

    def publish_status(self, status: dict[str, Any]) -> None:
        if "status" in self._pubs:
            self.put("status", status_cdr(status, self.settings))

    def publish_retimed(self, result_json: bytes) -> None:
        """The service's ``rota/result`` bytes, as a MultiDOFJointTrajectory."""
        if "retimed" not in self._pubs:
            return
        try:
            cdr = retimed_cdr_from_json(result_json, self.settings)
        except Exception as exc:  # noqa: BLE001 - a bad result must not stop the service
            log.warning("ROS re-timed trajectory not published: %s", exc)
            return
        self.put("retimed", cdr)

    def close(self) -> None:
        for obj in [*self._objs, *self._pubs.values()]:
            try:
                obj.undeclare()
            except Exception:  # noqa: BLE001, S110 - closing anyway
                pass
        self._objs.clear()
        self._pubs.clear()
