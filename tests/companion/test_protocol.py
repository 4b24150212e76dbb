"""One protocol, shared: the service and the ground station take their keys, message
kinds and commands from companion/protocol.py, and the ground station's client imports
nothing else of the service."""

from __future__ import annotations

import ast
from pathlib import Path

from companion import protocol
from companion.gs.client import CONFIRM, GroundStation
from companion.settings.config import from_dict

ROOT = Path(__file__).resolve().parents[2]


def test_the_ground_station_confirms_every_command_of_the_protocol():
    assert set(CONFIRM) == set(protocol.COMMANDS) and len(CONFIRM) == len(protocol.COMMANDS)


def test_service_and_ground_station_build_the_same_keys():
    cfg = from_dict({"service": {"vehicle_id": "d7", "key_prefix": "fleet"}})
    gs = GroundStation.__new__(GroundStation)  # (no session: only its key layout)
    gs.vehicle, gs.key_prefix = "d7", "fleet"
    for parts in (("status",), ("cmd", "land"), ("trajectory",)):
        assert cfg.key(*parts) == gs.key(*parts) == "/".join(("fleet", "d7", *parts))
    assert from_dict({}).service.key_prefix == protocol.KEY_PREFIX


def test_the_client_imports_of_the_service_only_the_protocol():
    tree = ast.parse((ROOT / "companion" / "gs" / "client.py").read_text())
    used = {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)
            and node.module and node.module.startswith("companion")}
    assert used == {"companion.protocol"}
