"""The protocol the service and the ground station share (``docs/protocol.md``): where
each message lives on Zenoh, the kinds of message the service sends, and the commands
it takes. Plain names only, no numerical libraries: the ground station imports this
module and nothing of the service beside it. Parsing and validation are the service's
(:mod:`companion.messages`)."""

from __future__ import annotations

#: Every key is ``<prefix>/<vehicle id>/<name>``, the prefix ``rota`` unless configured.
KEY_PREFIX = "rota"

#: The ``schema`` of each message the service sends.
STATUS = "rota/status"
TELEMETRY = "rota/telemetry"
REPLY = "rota/reply"
CONFIG = "rota/config"

#: The commands (``<prefix>/<vehicle>/cmd/<name>``), in the order of a flight.
COMMANDS = ("arm", "disarm", "takeoff", "start", "hold", "land", "abort")


def vehicle_key(prefix: str, vehicle_id: str, *parts: str) -> str:
    """A Zenoh key expression under one vehicle: ``rota/drone1/<parts>``."""
    return "/".join((prefix, vehicle_id, *parts))
