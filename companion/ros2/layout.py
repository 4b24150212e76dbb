"""Where ROS 2 topics live on Zenoh: key expressions, liveliness tokens and
attachments of the two layouts (sources in ``docs/ros2.md``).

``rmw_zenoh`` (ros2/rmw_zenoh, ``docs/design.md``):

* data: ``<domain>/<fully qualified topic, no leading />/<DDS type>/<RIHS01 hash>``
  (Humble: ``TypeHashNotSupported`` in place of the hash, ros2/rmw_zenoh PR 388; the
  tokens, QoS and attachment of rmw_zenoh 0.1.2+ on Humble are Jazzy's);
* tokens: ``@ros2_lv/<domain>/<zid>/<node id>/<node id>/NN/<enclave>/<namespace>/<node>``
  for the node and ``@ros2_lv/<domain>/<zid>/<node id>/<entity id>/<MP|MS>/<enclave>/
  <namespace>/<node>/<topic>/<DDS type>/<hash>/<qos>`` per publisher and subscription,
  names "mangled" (``/`` -> ``%``, empty -> ``%``);
* every put carries an attachment: int64 sequence number, int64 source time (ns since
  the UNIX epoch), both little-endian, and the 16-byte publisher GID with its length
  (rmw_zenoh from Jazzy 0.2.4 on; earlier releases put a string key before each);
* an entity's GID is the XXH3-128 hash of its liveliness token (``liveliness_utils.cpp``),
  the low 64 bits first, each half little-endian.

``zenoh-bridge-ros2dds`` (eclipse-zenoh/zenoh-plugin-ros2dds):

* data: ``[<bridge namespace>/]<topic, no leading />``, payload CDR as DDS has it;
* tokens: ``@/<zid>/@ros2_lv`` for the bridge, ``@/<zid>/@ros2_lv/<MP|MS>/<key>/<ROS
  type>/<qos>`` per route (``/`` -> ``§``); a bridge that sees an ``MP`` token
  creates a DDS writer for it, so ROS tools see the topic;
* no attachment.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import xxhash
import zenoh
from zenoh import ext

from companion.ros2.settings import Ros2Settings
from companion.ros2.types import dds_type_name, type_hash

DEPTH = 10  # KEEP_LAST depth announced for every endpoint (rclcpp's usual QoS(10))


@dataclass(frozen=True)
class Endpoint:
    """A ROS publisher (``MP``) or subscription (``MS``) of the service."""

    kind: str
    topic: str
    typename: str


def resolve(topic: str, namespace: str) -> str:
    """The fully qualified name: relative names go under ``namespace``."""
    if topic.startswith("/"):
        return topic
    return "/".join(("", *namespace.strip("/").split("/"), topic)).replace("//", "/")


def mangle(name: str) -> str:
    """rmw_zenoh's liveliness form of a name: ``/`` -> ``%``; empty -> ``%``."""
    return name.replace("/", "%") if name not in ("", "/") else "%"


def rmw_qos(depth: int = DEPTH) -> str:
    """rmw_zenoh's compact QoS for RELIABLE, VOLATILE, KEEP_LAST(depth): settings at
    rmw_zenoh's defaults are left empty (its default depth is 42)."""
    return f"::,{'' if depth == 42 else depth}:,:,:,,"


def dds_qos(typehash: str, depth: int = DEPTH) -> str:
    """The bridge's compact QoS of a keyless topic: RELIABLE (1), VOLATILE (0),
    KEEP_LAST (0) with ``depth``, and the USER_DATA ROS 2 (Iron and later) carries."""
    return f":1:0:0,{depth}:typehash={typehash};"


def attachment(seq: int, gid: bytes, stamp_ns: int | None = None) -> bytes:
    """rmw_zenoh's attachment, serialised with zenoh-ext's serializer."""
    ts = time.time_ns() if stamp_ns is None else stamp_ns
    return ext.z_serialize((ext.Int64(seq), ext.Int64(ts),
                            [ext.UInt8(b) for b in gid])).to_bytes()


def rmw_gid(token: str) -> bytes:
    """rmw_zenoh's GID of the entity with liveliness token ``token``: XXH3-128 (seed 0)
    of the token, low 64 bits then high 64 bits, each little-endian."""
    return xxhash.xxh3_128_intdigest(token.encode()).to_bytes(16, "little")


def parse_attachment(raw: bytes) -> tuple[int, int, bytes]:
    """(sequence number, source time ns, GID) from an rmw_zenoh attachment."""
    seq, ts, gid = ext.z_deserialize(tuple[ext.Int64, ext.Int64, list[ext.UInt8]],
                                     zenoh.ZBytes(raw))
    return int(seq), int(ts), bytes(int(b) for b in gid)


class RmwZenoh:
    """Keys and tokens of a node ``namespace/node_name`` in ``domain_id``."""

    name = "rmw_zenoh"
    NODE_ID = 0

    def __init__(self, s: Ros2Settings, zid: str) -> None:
        self.s = s
        self.zid = zid
        ns = "/" + s.namespace.strip("/") if s.namespace.strip("/") else ""
        self._node = (f"@ros2_lv/{s.domain_id}/{zid}/{self.NODE_ID}/{{eid}}/{{kind}}/%/"
                      f"{mangle(ns)}/{s.node_name}")
        self._ns = ns
        self._ids: dict[Endpoint, int] = {}

    def hash(self, ep: Endpoint) -> str:
        """The type hash in keys and tokens: RIHS01, or Humble's ``TypeHashNotSupported``."""
        return type_hash(ep.typename, self.s.bspline_msg, self.s.bspline_type, self.s.distro)

    def fq(self, ep: Endpoint) -> str:
        return resolve(ep.topic, self._ns)

    def key(self, ep: Endpoint) -> str:
        return (f"{self.s.domain_id}/{self.fq(ep).strip('/')}/{dds_type_name(ep.typename)}/"
                f"{self.hash(ep)}")

    def sub_key(self, ep: Endpoint) -> str:
        """Any type hash: a publisher with another definition of the type gets a clear
        error on status (see :func:`hash_in`) instead of silence."""
        return self.key(ep).rsplit("/", 1)[0] + "/*"

    @staticmethod
    def hash_in(key: str) -> str | None:
        return key.rsplit("/", 1)[-1]

    def watch_key(self, ep: Endpoint) -> tuple[str, str]:
        """(topic, DDS type) as a peer's token of the same topic writes them."""
        return mangle(self.fq(ep)), dds_type_name(ep.typename)

    def node_token(self) -> str:
        return self._node.format(eid=self.NODE_ID, kind="NN")

    def token(self, ep: Endpoint, entity_id: int | None = None) -> str:
        """The entity's token; ids count from 1 in declaration order (0 is the node)."""
        eid = self._ids.setdefault(ep, len(self._ids) + 1) if entity_id is None else entity_id
        return (self._node.format(eid=eid, kind=ep.kind)
                + f"/{mangle(self.fq(ep))}/{dds_type_name(ep.typename)}/{self.hash(ep)}/"
                + rmw_qos())

    def tokens(self, endpoints: list[Endpoint]) -> list[str]:
        return [self.node_token(), *(self.token(ep) for ep in endpoints)]

    def gid(self, ep: Endpoint) -> bytes:
        """The publisher's GID, derived from its token as rmw_zenoh derives it, so the
        GID in the attachment is the one ROS tools see in the graph."""
        return rmw_gid(self.token(ep))

    def put_options(self, ep: Endpoint, seq: int) -> dict[str, bytes]:
        """What the ``seq``-th put on ``ep`` carries: the attachment."""
        return {"attachment": attachment(seq, self.gid(ep))}


class Ros2Dds:
    """Keys and tokens as a ``zenoh-bridge-ros2dds`` with ``namespace`` announces them."""

    name = "ros2dds"
    SLASH = "§"

    def __init__(self, s: Ros2Settings, zid: str) -> None:
        self.s = s
        self.zid = zid

    def key(self, ep: Endpoint) -> str:
        return "/".join(p for p in (self.s.namespace.strip("/"), ep.topic.strip("/")) if p)

    sub_key = key

    @staticmethod
    def hash_in(key: str) -> str | None:  # the bridge's keys carry no type
        return None

    def node_token(self) -> str:
        return f"@/{self.zid}/@ros2_lv"

    def token(self, ep: Endpoint) -> str:
        h = type_hash(ep.typename, self.s.bspline_msg, self.s.bspline_type)
        return (f"{self.node_token()}/{ep.kind}/{self.key(ep).replace('/', self.SLASH)}/"
                f"{ep.typename.replace('/', self.SLASH)}/{dds_qos(h)}")

    def tokens(self, endpoints: list[Endpoint]) -> list[str]:
        return [self.node_token(), *(self.token(ep) for ep in endpoints)]

    @staticmethod
    def put_options(ep: Endpoint, seq: int) -> dict[str, bytes]:
        """The bridge's puts carry no attachment."""
        return {}


def make_layout(s: Ros2Settings, zid: str) -> RmwZenoh | Ros2Dds:
    return RmwZenoh(s, zid) if s.layout == "rmw_zenoh" else Ros2Dds(s, zid)
