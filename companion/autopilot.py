"""PX4 through MAVSDK 4.x (in-process, ``mavsdk.asyncio``): connect, watch
telemetry, command, and send offboard setpoints. The rest of the service sees
ENU; the conversion to NED happens here, once.

PX4's offboard rules (PX4 user guide, "Offboard Mode"): setpoints must already
stream (> 2 Hz, newer PX4 about 1 s) before the mode switch, and must keep
streaming or PX4 runs its offboard-loss failsafe after ``COM_OF_LOSS_T``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from dataclasses import dataclass, field

import numpy as np
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.offboard import OffboardAsync
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
from mavsdk.plugins.offboard import AccelerationNed, PositionNedYaw, VelocityNedYaw
from numpy.typing import NDArray

from companion.frames import enu_to_ned, ned_to_enu

FloatArray = NDArray[np.float64]
log = logging.getLogger("rota.autopilot")


_MAVSDK_LOG = logging.getLogger("rota.mavsdk")
_LEVELS = {0: logging.DEBUG, 1: logging.INFO, 2: logging.WARNING, 3: logging.ERROR}


def route_mavsdk_logs() -> None:
    """Send MAVSDK's own log lines to Python logging (logger ``rota.mavsdk``)
    instead of its coloured stdout output."""
    from mavsdk.logging import log_subscribe

    def handler(level: object, message: str, file: str | None, line: int) -> bool:
        _MAVSDK_LOG.log(_LEVELS.get(int(level), logging.INFO), "%s", message)
        return True

    log_subscribe(handler)


class AutopilotError(RuntimeError):
    """A command was refused or failed; the message says which and why."""


@dataclass
class Telemetry:
    """Latest telemetry (ENU), with the monotonic time it arrived."""

    position: FloatArray | None = None
    velocity: FloatArray | None = None
    armed: bool = False
    flight_mode: str = "UNKNOWN"
    landed_state: str = "UNKNOWN"
    healthy: bool = False
    position_std: FloatArray | None = None  # PX4's position std per axis (ENU), if reported
    yaw_ned_deg: float | None = None  # heading (NED yaw: from north, clockwise)
    position_time: float = 0.0
    seen: dict[str, float] = field(default_factory=dict)


class Autopilot:
    """One PX4 autopilot reached at a MAVSDK connection URL."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.telemetry = Telemetry()
        self._mavsdk: Mavsdk | None = None
        self._tel: TelemetryAsync | None = None
        self._action: ActionAsync | None = None
        self._offboard: OffboardAsync | None = None
        self._system = None
        self._tasks: list[asyncio.Task] = []

    # ---------------------------------------------------------------- connection
    async def connect(self, timeout_s: float) -> None:
        """Open the MAVLink connection and wait for an autopilot."""
        route_mavsdk_logs()
        self._mavsdk = Mavsdk(
            Configuration.create_with_component_type(ComponentType.COMPANION_COMPUTER))
        await self._mavsdk.add_any_connection(self.url)
        system = await self._mavsdk.first_autopilot(timeout_s)
        if system is None:
            raise AutopilotError(f"no autopilot on {self.url} within {timeout_s:.0f} s")
        self._system = system
        self._tel = TelemetryAsync(system)
        self._action = ActionAsync(system)
        self._offboard = OffboardAsync(system)
        self._tasks = [asyncio.create_task(self._watch(name, gen), name=f"telemetry-{name}")
                       for name, gen in (
                           ("position", self._tel.subscribe_position_velocity_ned()),
                           ("armed", self._tel.subscribe_armed()),
                           ("mode", self._tel.subscribe_flight_mode()),
                           ("landed", self._tel.subscribe_landed_state()),
                           ("health", self._tel.subscribe_health_all_ok()),
                           ("odometry", self._tel.subscribe_odometry()),
                           ("attitude", self._tel.subscribe_attitude_euler()))]
        self._tasks.append(asyncio.create_task(self._poll(), name="telemetry-poll"))

    async def _poll(self) -> None:
        """Once a second, read the slow-changing states directly: a subscription
        may only report changes, and one made after the first heartbeat would
        otherwise wait for the next change."""
        t = self.telemetry
        while True:
            with contextlib.suppress(Exception):
                t.flight_mode = _name(await self._tel.flight_mode())
                t.armed = bool(await self._tel.armed())
                t.landed_state = _name(await self._tel.landed_state())
                t.healthy = bool(await self._tel.health_all_ok())
            # (not the position: MAVSDK's getter returns the last value it has, which
            # would hide a link loss; freshness comes from the subscription alone)
            await asyncio.sleep(1.0)

    def _set_position(self, pv) -> None:  # noqa: ANN001
        p, v = pv.position, pv.velocity
        t = self.telemetry
        t.position = ned_to_enu([p.north_m, p.east_m, p.down_m])
        t.velocity = ned_to_enu([v.north_m_s, v.east_m_s, v.down_m_s])
        t.position_time = time.monotonic()

    async def _watch(self, name: str, gen) -> None:  # noqa: ANN001
        t = self.telemetry
        async for item in gen:
            now = time.monotonic()
            t.seen[name] = now
            if name == "position":
                self._set_position(item)
            elif name == "armed":
                t.armed = bool(item)
            elif name == "mode":
                t.flight_mode = _name(item)
            elif name == "landed":
                t.landed_state = _name(item)
            elif name == "health":
                t.healthy = bool(item)
            elif name == "attitude":
                t.yaw_ned_deg = float(item.yaw_deg)
            elif name == "odometry":
                # pose covariance: upper-right triangle of the 6x6 matrix, row-major;
                # x, y, z variances at 0, 6, 11 (NaN in the first entry: unknown)
                cov = list(getattr(item.pose_covariance, "covariance_matrix", None) or [])
                var = np.array([cov[i] for i in (0, 6, 11)]) if len(cov) >= 12 else None
                ok = var is not None and np.all(np.isfinite(var)) and np.all(var >= 0)
                t.position_std = ned_to_enu(np.sqrt(var)) if ok else None

    def link_ok(self, timeout_s: float) -> bool:
        """Telemetry arrived within ``timeout_s``."""
        return (self._tel is not None
                and time.monotonic() - self.telemetry.position_time <= timeout_s)

    async def close(self) -> None:
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        self._tasks = []
        for plugin in (self._offboard, self._action, self._tel):
            if plugin is not None:
                with contextlib.suppress(Exception):
                    plugin.destroy()
        if self._mavsdk is not None:
            with contextlib.suppress(Exception):
                self._mavsdk.destroy()
        self._mavsdk = self._tel = self._action = self._offboard = self._system = None

    # ------------------------------------------------------------------ commands
    async def _call(self, what: str, coro) -> None:  # noqa: ANN001
        try:
            await coro
        except Exception as exc:  # MAVSDK raises ActionError/OffboardError with the reason
            raise AutopilotError(f"{what} failed: {exc}") from None

    async def arm(self) -> None:
        await self._call("arm", self._action.arm())

    async def disarm(self) -> None:
        await self._call("disarm", self._action.disarm())

    async def takeoff(self, altitude_m: float) -> None:
        await self._call("set takeoff altitude", self._action.set_takeoff_altitude(altitude_m))
        await self._call("takeoff", self._action.takeoff())

    async def land(self) -> None:
        await self._call("land", self._action.land())

    async def hold(self) -> None:
        """PX4's own Hold mode (leaves offboard)."""
        await self._call("hold", self._action.hold())

    async def start_offboard(self) -> None:
        await self._call("offboard start", self._offboard.start())

    async def stop_offboard(self) -> None:
        await self._call("offboard stop", self._offboard.stop())

    async def stop_stream(self) -> None:
        """End MAVSDK's periodic re-sending of the last setpoint (it keeps sending at
        20 Hz once a setpoint was set, which would hide a dead service from PX4's
        offboard-loss failsafe): the plugin is replaced by a fresh one."""
        if self._offboard is None or self._system is None:
            return
        with contextlib.suppress(Exception):
            self._offboard.destroy()
        self._offboard = OffboardAsync(self._system)

    async def send(self, p_enu: FloatArray, v_enu: FloatArray, a_enu: FloatArray,
                   yaw_ned_deg: float) -> None:
        """One SET_POSITION_TARGET_LOCAL_NED with velocity/acceleration feed-forward."""
        p, v, a = enu_to_ned(p_enu), enu_to_ned(v_enu), enu_to_ned(a_enu)
        await self._offboard.set_position_velocity_acceleration_ned(
            PositionNedYaw(float(p[0]), float(p[1]), float(p[2]), float(yaw_ned_deg)),
            VelocityNedYaw(float(v[0]), float(v[1]), float(v[2]), float(yaw_ned_deg)),
            AccelerationNed(float(a[0]), float(a[1]), float(a[2])))


def _name(value: object) -> str:
    text = getattr(value, "name", None) or str(value)
    return text.split(".")[-1].upper()
