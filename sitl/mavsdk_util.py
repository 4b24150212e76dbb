"""Small helpers to talk to a (simulated or real) PX4 through MAVSDK 4.x (``mavsdk.asyncio``).

Example::

    with SimVehicle(port=port, seed=3) as sim:
        async def fly() -> None:
            async with connect(port) as link:
                await wait_health_ok(link)
                await link.action.arm()
        asyncio.run(fly())
"""

from __future__ import annotations

import asyncio
import json
import socket
from collections.abc import AsyncIterator, Awaitable, Callable
from contextlib import asynccontextmanager
from dataclasses import dataclass
from typing import Any

from mavsdk.asyncio import ComponentType, Configuration, Mavsdk, System
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.mavlink_direct import MavlinkDirectAsync
from mavsdk.asyncio.plugins.offboard import OffboardAsync
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
from mavsdk.plugins.mavlink_direct import MavlinkMessage


def free_udp_port() -> int:
    """A currently free UDP port on 127.0.0.1 (for parallel tests)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class Link:
    """A connected MAVSDK instance with the plugins the project uses."""

    mavsdk: Mavsdk
    system: System
    telemetry: TelemetryAsync
    action: ActionAsync
    offboard: OffboardAsync
    direct: MavlinkDirectAsync


@asynccontextmanager
async def connect(
    port: int, timeout_s: float = 10.0, host: str = "127.0.0.1"
) -> AsyncIterator[Link]:
    """Connect MAVSDK as a companion computer on ``udpin://host:port``; yields a :class:`Link`.

    Raises:
        TimeoutError: if no autopilot is discovered within ``timeout_s``.
    """
    mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.COMPANION_COMPUTER))
    plugins: list[Any] = []
    try:
        await mavsdk.add_any_connection(f"udpin://{host}:{port}")
        system = await mavsdk.first_autopilot(timeout_s)
        if system is None:
            raise TimeoutError(f"no autopilot on udpin://{host}:{port} within {timeout_s} s")
        plugins = [
            TelemetryAsync(system),
            ActionAsync(system),
            OffboardAsync(system),
            MavlinkDirectAsync(system),
        ]
        yield Link(mavsdk, system, *plugins)
    finally:
        for plugin in reversed(plugins):
            plugin.destroy()
        mavsdk.destroy()


async def wait_until(
    predicate: Callable[[], Awaitable[bool]], timeout_s: float, interval_s: float = 0.05
) -> bool:
    """Poll an async predicate until it is true (returns True) or the timeout ends (False)."""
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout_s
    while True:
        if await predicate():
            return True
        if loop.time() >= end:
            return False
        await asyncio.sleep(interval_s)


async def wait_health_ok(link: Link, timeout_s: float = 10.0) -> bool:
    """Wait until MAVSDK reports ``health_all_ok`` (sensors, positions, home, armable)."""
    return await wait_until(link.telemetry.health_all_ok, timeout_s, 0.1)


async def send_command_long(
    link: Link, command: int, params: list[float], target: tuple[int, int] = (1, 1)
) -> int:
    """Send a raw COMMAND_LONG through MAVSDK's MavlinkDirect; returns the ACK's MAV_RESULT."""
    fields: dict[str, Any] = {
        "target_system": target[0],
        "target_component": target[1],
        "command": command,
        "confirmation": 0,
    }
    padded = list(params) + [0.0] * (7 - len(params))
    fields.update({f"param{i + 1}": float(v) for i, v in enumerate(padded)})
    msg = MavlinkMessage("COMMAND_LONG", 0, 0, target[0], target[1], json.dumps(fields))
    ack = await link.direct.send_command(msg)
    return int(json.loads(ack.fields_json)["result"])
