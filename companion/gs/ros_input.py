"""``rota-gs send --ros2`` and ``send-map --ros2``: a ROS message file read with the
service's ``[ros2]`` settings (changed by the flags) and published as a ROS node of
that layout would (docs/ros2.md)."""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

from companion.gs.client import GroundStation
from companion.ros2.send import RosMessage, RosPublisher, read_message
from companion.settings.config import Config, ConfigError, from_dict, load
from rota.errors import InputError

ROS_OPTIONS = ("config", "layout", "distro", "domain_id", "namespace", "topic", "bspline_type",
               "bspline_msg")


def read(args: argparse.Namespace, kind: str) -> tuple[RosMessage, Config]:
    """The ROS message in ``args.file`` for input ``kind`` and the configuration it was
    read with: ``--config`` (or the defaults), its ``[ros2]`` changed by the flags. The
    message is stamped now unless ``--keep-stamp``."""
    flags = {"layout": args.layout, "distro": args.distro, "domain_id": args.domain_id,
             "namespace": args.namespace, "bspline_type": args.bspline_type,
             "bspline_msg": args.bspline_msg, f"{kind}_topic": args.topic}
    try:
        cfg = from_dict({"ros2": {k: v for k, v in flags.items() if v is not None}},
                        base=load(args.config))
    except ConfigError as exc:
        raise InputError(args.config or "ROS options", str(exc)) from None
    stamp = None if args.keep_stamp else time.time()
    return read_message(args.file, kind, cfg.ros2, stamp), cfg


def refuse_options(args: argparse.Namespace) -> None:
    """A ROS option without ``--ros2`` is an error that names it."""
    given = [name for name in ROS_OPTIONS if getattr(args, name) is not None]
    if given:
        raise InputError("--" + given[0].replace("_", "-"), "only for a ROS message (--ros2)")


def sender(cfg: Config, ros: RosMessage) -> Callable[[GroundStation], None]:
    """Publish ``ros`` on the ground station's session as a ROS node of the layout would
    (its tokens stay declared while the session lives)."""
    def send(gs: GroundStation) -> None:
        RosPublisher(gs.session, cfg.ros2, ros.topic, ros.typename).put(ros.cdr)

    return send
