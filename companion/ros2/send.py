"""The planner's side, for tools that hold a ROS message (``rota-gs send --ros2``): read
it from a file as users have it, encode it with ``rosbags``, and publish it as a ROS 2
node of the configured layout would (liveliness tokens, key expression, attachment).

A file is either the message's CDR bytes with their encapsulation header (``.cdr``), or
the message in ROS field names as JSON (``.json``) or YAML (anything else; what ``ros2
topic echo --once`` prints, of which the first document is used).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zenoh
from ruamel.yaml import YAML, YAMLError

from companion.ros2.decode import message_id
from companion.ros2.encode import message_from_dict, ros_time
from companion.ros2.layout import Endpoint, make_layout
from companion.ros2.link import input_kinds
from companion.ros2.settings import Ros2Settings
from companion.ros2.types import typestore
from companion.settings.config import Config
from rota.errors import InputError

#: The ROS inputs of the service, by kind (the topic settings are ``[ros2] <kind>_topic``).
KINDS = ("bspline", "path", "multidof", "pointcloud")


@dataclass(frozen=True)
class RosMessage:
    """A ROS message ready to publish on the service's input ``kind``."""

    kind: str
    topic: str
    typename: str
    message: Any  # as rosbags holds it
    cdr: bytes
    id: str  # the id the service gives it (trajectories)
    stamp: float | None  # start_time (Bspline) or header.stamp, UNIX s; None: not stamped


def read_message(path: str | Path, kind: str, s: Ros2Settings,
                 stamp: float | None = None) -> RosMessage:
    """The message in ``path`` for input ``kind``, restamped with ``stamp`` (UNIX s) unless
    None. :class:`InputError` names the file and the field; ``OSError`` if it cannot be
    read."""
    path = Path(path)
    topic, typename, _ = input_kinds(s)[kind]
    if not topic:
        raise InputError(str(path), f"no topic for {kind} messages: set [ros2] {kind}_topic "
                         "or give one")
    raw = path.read_bytes()
    store = typestore(s.bspline_msg, s.bspline_type)
    cdr: bytes | None = None
    if path.suffix == ".cdr":
        try:
            msg = store.deserialize_cdr(raw, typename)
        except Exception as exc:  # noqa: BLE001 - rosbags raises several types for bad bytes
            raise InputError(str(path), f"not the CDR of a {typename} ({type(exc).__name__}: "
                             f"{' '.join(str(exc).split())})") from None
        cdr = raw
    else:
        data = _parse(raw, path)
        try:
            msg = message_from_dict(typename, data, s)
        except ValueError as exc:
            hint = (" (is [ros2] bspline_msg the planner's definition?)"
                    if kind == "bspline" and "not a field of" in str(exc) else "")
            raise InputError(str(path), f"{exc}{hint}") from None
    if stamp is not None:
        msg = _stamped(msg, kind, stamp, store.types)
        cdr = None
    if cdr is None:
        cdr = bytes(store.serialize_cdr(msg, typename))
    t = msg.start_time if kind == "bspline" else msg.header.stamp
    return RosMessage(kind, topic, typename, msg, cdr, message_id(kind, msg),
                      t.sec + t.nanosec * 1e-9 if (t.sec or t.nanosec) else None)


def _parse(raw: bytes, path: Path) -> Any:
    try:
        text = raw.decode()
    except UnicodeDecodeError:
        raise InputError(str(path), "not text (CDR bytes go in a .cdr file)") from None
    try:
        if path.suffix == ".json":
            return json.loads(text)
        return next((d for d in YAML(typ="safe", pure=True).load_all(text) if d is not None),
                    None)
    except (json.JSONDecodeError, YAMLError) as exc:
        kind = "JSON" if path.suffix == ".json" else "YAML"
        raise InputError(str(path), f"not valid {kind} ({' '.join(str(exc).split())})") from None


def _stamped(msg: Any, kind: str, stamp: float, types: dict[str, Any]) -> Any:
    if kind == "bspline":
        return dataclasses.replace(msg, start_time=ros_time(types, stamp))
    header = dataclasses.replace(msg.header, stamp=ros_time(types, stamp))
    return dataclasses.replace(msg, header=header)


def decoded(msg: RosMessage, cfg: Config) -> Any:
    """What the service's decoder makes of ``msg`` under ``cfg`` (a checked trajectory or a
    map), its age aside; raises :class:`companion.messages.Rejected`."""
    return input_kinds(cfg.ros2)[msg.kind][2](msg.cdr, cfg, now=msg.stamp)


class RosPublisher:
    """A ROS publisher on ``session`` as a node of the configured layout has one: the
    node's and its own liveliness tokens, the data key, and (rmw_zenoh) the attachment."""

    def __init__(self, session: zenoh.Session, s: Ros2Settings, topic: str, typename: str,
                 node_name: str = "rota_gs") -> None:
        self.layout = make_layout(dataclasses.replace(s, node_name=node_name),
                                  str(session.zid()))
        self.endpoint = Endpoint("MP", topic, typename)
        self.key = self.layout.key(self.endpoint)
        liveliness = session.liveliness()
        self._objs: list[Any] = [liveliness.declare_token(t)
                                 for t in self.layout.tokens([self.endpoint])]
        self._pub = session.declare_publisher(self.key, reliability=zenoh.Reliability.RELIABLE)
        self._seq = 0

    def put(self, cdr: bytes) -> None:
        self._seq += 1
        self._pub.put(cdr, **self.layout.put_options(self.endpoint, self._seq))

    def close(self) -> None:
        for obj in [self._pub, *self._objs]:
            try:
                obj.undeclare()
            except Exception:  # noqa: BLE001, S110 - closing anyway
                pass

    def __enter__(self) -> RosPublisher:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
