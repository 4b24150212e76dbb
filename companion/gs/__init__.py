"""The ground station: a Zenoh client library (:class:`GroundStation`), the
``rota-gs`` command line, a local web page and the flight-record replay plot.
Guide: ``docs/groundstation.md``."""

from companion.gs.client import (
    GroundStation,
    GroundStationError,
    Vehicle,
    list_vehicles,
    open_session,
    zenoh_config,
)
from companion.protocol import COMMANDS

__all__ = ["COMMANDS", "GroundStation", "GroundStationError", "Vehicle", "list_vehicles",
           "open_session", "zenoh_config"]
