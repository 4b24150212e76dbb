"""PX4 through MAVSDK 4.x (in-process, ``mavsdk.asyncio``): connect, watch
telemetry, command, and send offboard setpoints. The rest of the service sees
ENU; the conversion to NED happens here, once.

PX4's offboard rules (PX4 user guide, "Offboard Mode"): setpoints must already
stream (> 2 Hz, newer PX4 about 1 s) before the mode switch, and must keep
streaming or PX4 runs its offboard-loss failsafe after ``COM_OF_LOSS_T``.

Setpoints go out as single SET_POSITION_TARGET_LOCAL_NED messages from the
setpoint sender process (:mod:`companion.flight.sender`), through a loopback link of this
MAVSDK with forwarding on; not through MAVSDK's offboard plugin: that plugin
re-sends the last setpoint at 20 Hz from its own thread, so PX4 would not see a
stalled service, and after a stall longer than ``COM_OF_LOSS_T`` that stale
re-sending would take PX4 back into OFFBOARD (real PX4 returns to OFFBOARD by
itself when setpoints resume). Here the vehicle receives exactly what the
setpoint loop computes, nothing else. Commands (COMMAND_LONG) go through MAVSDK's
MAVLink-direct plugin.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.mavlink_direct import MavlinkDirectAsync
from mavsdk.asyncio.plugins.param import ParamAsync
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
from mavsdk.enums import ForwardingOption
from mavsdk.plugins.mavlink_direct import MavlinkDirectResult, MavlinkMessage
from numpy.typing import NDArray

from companion.flight.sender import (
    COMPONENT_ID,
    MAV_FRAME_LOCAL_NED,
    TYPE_MASK_PVA_YAW,
    SenderError,
    Sent,
    SetpointSender,
    shifted,
)
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


# MAVLink constants (common.xml) and PX4's custom mode for OFFBOARD (px4_custom_mode.h)
_MAV_CMD_DO_SET_MODE = 176
_DIRECT_SUCCESS = MavlinkDirectResult.SUCCESS.value
_MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
_PX4_MAIN_MODE_OFFBOARD = 6
_MAV_RESULTS = {0: "accepted", 1: "temporarily rejected", 2: "denied", 3: "unsupported",
                4: "failed", 5: "in progress", 6: "cancelled"}


#: Position telemetry asked of PX4 (its silence ends the setpoint stream within 0.8 s).
POSITION_RATE_HZ = 30.0
#: ODOMETRY (for PX4's position covariance, used by the estimator at 5 Hz). MAVSDK 4.1's
#: odometry subscription keeps about 180 bytes per message it delivers (measured: a bare
#: MAVSDK script subscribed to it alone grew 0.32 MB/min at PX4's 30 Hz, flat without it),
#: so the service asks for no more than it uses.
ODOMETRY_RATE_HZ = 5.0
#: ATTITUDE, for the heading held at start only. Every message MAVSDK delivers is a
#: callback into Python that wakes the event loop (PX4's onboard link sends attitude
#: at 20-50 Hz); the service asks for what it uses.
ATTITUDE_RATE_HZ = 2.0


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

    def __init__(self, url: str, on_error: Callable[[str], None] | None = None,
                 on_status_text: Callable[[str, str], None] | None = None) -> None:
        self.url = url
        self.telemetry = Telemetry()
        self._mavsdk: Mavsdk | None = None
        self._tel: TelemetryAsync | None = None
        self._action: ActionAsync | None = None
        self._direct: MavlinkDirectAsync | None = None
        self._system = None
        self._target = (1, 1)  # the autopilot's MAVLink system and component id
        self._sender: SetpointSender | None = None  # the setpoint sender process
        self._sender_link = None  # MAVSDK's handle of the link to it
        self._direct_sent: list[Sent] = []  # sent from here while the sender restarted
        #: (at, not_after, max_shift, values) handed while the sender restarted, not yet due
        self._direct_wait: deque[tuple[float, float, float, tuple[float, ...]]] = deque()
        self._tasks: list[asyncio.Task] = []
        self._boot = time.monotonic()
        #: PX4's COM_OF_LOSS_T, read at connection (None until read)
        self.offboard_loss_timeout_s: float | None = None
        #: called with a line of text when the link to the vehicle has a fault
        self.on_error: Callable[[str], None] = on_error or (lambda text: log.error("%s", text))
        #: called with (severity name, text) for every STATUSTEXT from the autopilot
        self.on_status_text: Callable[[str, str], None] = (
            on_status_text or (lambda severity, text: None))

    # ---------------------------------------------------------------- connection
    async def connect(self, timeout_s: float) -> None:
        """Open the MAVLink connection and wait for an autopilot."""
        route_mavsdk_logs()
        config = Configuration.create_with_component_type(ComponentType.COMPANION_COMPUTER)
        self._own_id = int(config.system_id)
        self._mavsdk = Mavsdk(config)
        # forwarding on: what the setpoint sender sends on its link goes on to PX4
        await self._mavsdk.add_any_connection(self.url, ForwardingOption.ON)
        system = await self._mavsdk.first_autopilot(timeout_s)
        if system is None:
            raise AutopilotError(f"no autopilot on {self.url} within {timeout_s:.0f} s")
        self._system = system
        self._tel = TelemetryAsync(system)
        with contextlib.suppress(Exception):  # the stream stops when positions stop coming
            await asyncio.wait_for(self._tel.set_rate_position_velocity_ned(POSITION_RATE_HZ),
                                   5.0)
        for name, rate, call in (("ODOMETRY", ODOMETRY_RATE_HZ, self._tel.set_rate_odometry),
                                 ("ATTITUDE", ATTITUDE_RATE_HZ,
                                  self._tel.set_rate_attitude_euler)):
            try:
                await asyncio.wait_for(call(rate), 5.0)
            except Exception as exc:  # noqa: BLE001 - MAVSDK raises TelemetryError; PX4's rate stays
                log.warning("could not set PX4's %s rate to %g Hz: %s", name, rate, exc)
        self._action = ActionAsync(system)
        self._direct = MavlinkDirectAsync(system)
        sysid = int(system._system.get_system_id())
        self._target = (sysid, 1)  # MAV_COMP_ID_AUTOPILOT1
        self._tasks = [asyncio.create_task(self._watch(name, gen), name=f"telemetry-{name}")
                       for name, gen in (
                           ("position", self._tel.subscribe_position_velocity_ned()),
                           ("armed", self._tel.subscribe_armed()),
                           ("mode", self._tel.subscribe_flight_mode()),
                           ("landed", self._tel.subscribe_landed_state()),
                           ("health", self._tel.subscribe_health_all_ok()),
                           ("odometry", self._tel.subscribe_odometry()),
                           ("attitude", self._tel.subscribe_attitude_euler()),
                           ("statustext", self._tel.subscribe_status_text()))]
        self._tasks.append(asyncio.create_task(self._poll(), name="telemetry-poll"))
        await self._start_sender()
        self._tasks.append(asyncio.create_task(self._watch_sender(), name="setpoint-sender"))
        param = ParamAsync(system)
        try:
            self.offboard_loss_timeout_s = float(
                await asyncio.wait_for(param.get_param_float("COM_OF_LOSS_T"), 5.0))
        except Exception as exc:  # noqa: BLE001 - the configured value is used instead
            log.warning("could not read PX4's COM_OF_LOSS_T: %s", exc)
        finally:
            with contextlib.suppress(Exception):
                param.destroy()

    async def _start_sender(self) -> None:
        """Start the setpoint sender process and MAVSDK's forwarding link to it."""
        sender = await asyncio.to_thread(SetpointSender.spawn, self._boot,
                                         (self._own_id, COMPONENT_ID), self._target)
        try:
            link = await self._mavsdk.add_any_connection(f"udpout://127.0.0.1:{sender.port}",
                                                         ForwardingOption.ON)
            await asyncio.to_thread(sender.wait_ready)
        except BaseException:
            sender.close()
            raise
        old, self._sender, self._sender_link = self._sender_link, sender, link
        if old is not None:
            with contextlib.suppress(Exception):
                await self._mavsdk.remove_connection(old)

    async def _watch_sender(self) -> None:
        """Restart the sender process if it ends (meanwhile :meth:`send` sends from the
        stream's thread); every death is reported."""
        while True:
            await asyncio.sleep(0.1)
            if self._sender is None or self._sender.alive:
                continue
            dead = self._sender
            self.on_error(f"{dead.exit_reason()}; setpoints go out through MAVSDK from "
                          "the stream's thread until it is restarted")
            dead.close(0.1)
            try:
                await self._start_sender()
            except Exception as exc:  # noqa: BLE001 - tried again at the next check
                self.on_error(f"the setpoint sender did not restart: {exc}")
                await asyncio.sleep(1.0)
            else:
                log.warning("setpoint sender restarted")

    async def _poll(self) -> None:
        """Once a second, read the slow-changing states directly: a subscription
        may only report changes, and one made after the first heartbeat would
        otherwise wait for the next change."""
        t = self.telemetry
        reads = (("mode", "flight_mode", lambda: self._tel.flight_mode(), _name),
                 ("armed", "armed", lambda: self._tel.armed(), bool),
                 ("landed", "landed_state", lambda: self._tel.landed_state(), _name),
                 ("health", "healthy", lambda: self._tel.health_all_ok(), bool))
        while True:
            for name, attr, read, convert in reads:
                asked = time.monotonic()
                with contextlib.suppress(Exception):
                    value = convert(await read())
                    # a subscription update that came in meanwhile is newer: keep it
                    if t.seen.get(name, 0.0) < asked:
                        setattr(t, attr, value)
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
            elif name == "statustext":
                self.on_status_text(_name(item.type).lower(), str(item.text))
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
        for plugin in (self._direct, self._action, self._tel):
            if plugin is not None:
                with contextlib.suppress(Exception):
                    plugin.destroy()
        if self._mavsdk is not None:
            with contextlib.suppress(Exception):
                self._mavsdk.destroy()
        self._mavsdk = self._tel = self._action = self._direct = self._system = None
        if self._sender is not None:
            self._sender.close()
        self._sender = self._sender_link = None

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
        """Switch PX4 to OFFBOARD (MAV_CMD_DO_SET_MODE with PX4's custom main mode 6);
        the setpoint stream must already run."""
        await self._command(_MAV_CMD_DO_SET_MODE, "offboard start",
                            _MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, _PX4_MAIN_MODE_OFFBOARD, 0)

    async def _command(self, command: int, what: str, *params: float) -> None:
        if self._direct is None:
            raise AutopilotError(f"{what} failed: not connected")
        fields = {"target_system": self._target[0], "target_component": self._target[1],
                  "command": command, "confirmation": 0}
        fields.update({f"param{i + 1}": float(x) for i, x in
                       enumerate((*params, *(0.0,) * (7 - len(params))))})
        message = MavlinkMessage("COMMAND_LONG", 0, 0, *self._target, json.dumps(fields))
        try:
            ack = await self._direct.send_command(message)
            result = int(json.loads(ack.fields_json or "{}").get("result", -1))
        except Exception as exc:  # noqa: BLE001 - MAVSDK raises MavlinkDirectError
            raise AutopilotError(f"{what} failed: {exc}") from None
        if result != 0:
            raise AutopilotError(f"{what} failed: PX4 answered "
                                 f"{_MAV_RESULTS.get(result, f'no acknowledgement ({result})')}")

    def send(self, p_enu: FloatArray, v_enu: FloatArray, a_enu: FloatArray,
             yaw_ned_deg: float, at: float, not_after: float = math.inf,
             max_silence: float = math.inf, max_shift: float = 0.0) -> bool:
        """One SET_POSITION_TARGET_LOCAL_NED (position, velocity and acceleration
        feed-forward, yaw), to go out at the monotonic time ``at`` (stamped with the
        moment it does), and not at all after ``not_after`` nor ``max_silence`` after
        the last setpoint that went out (moved on by up to ``max_shift`` if it goes out
        late: :func:`companion.flight.sender.shifted`): handed to the sender process (one
        pipe write, :mod:`companion.flight.sender`). While the sender is dead and being
        restarted, sent from here through MAVSDK's MAVLink-direct plugin instead
        (:meth:`_send_direct`); what waits here when the new sender is up is handed to it
        first, deadlines unchanged. True unless it was dropped at once (past
        ``not_after``)."""
        if self._direct is None:
            raise AutopilotError("not connected")
        p, v, a = enu_to_ned(p_enu), enu_to_ned(v_enu), enu_to_ned(a_enu)
        values = (*map(float, p), *map(float, v), *map(float, a), math.radians(yaw_ned_deg))
        if self._sender is not None:
            try:
                while self._direct_wait:
                    first, until, shift, waiting = self._direct_wait[0]
                    self._sender.put(first, until, max_silence, shift, waiting)
                    self._direct_wait.popleft()
                self._sender.put(at, not_after, max_silence, max_shift, values)
                return True
            except SenderError:
                pass  # reported and restarted by _watch_sender
        self._direct_wait.append((at, not_after, max_shift, values))
        self._send_direct()
        return not any(s.at == at and s.sent_at is None for s in self._direct_sent)

    def _send_direct(self) -> None:
        """The stand-in while the sender restarts, called once a tick of the stream:
        sends one setpoint at once through MAVSDK's MAVLink-direct plugin. The setpoint
        whose deadline has come if there is one (the latest of them, moved on to now by
        up to its ``max_shift``: a late tick); else, as a filler for the setpoints the dead
        sender took with it, a copy of the next one moved back along its velocity to now
        (by at most the stream's lead), which still goes out at its own deadline. Never
        after a setpoint's ``not_after``. It never waits: the stream's thread calls it
        holding the stream's lock."""
        now = time.monotonic()
        wait = self._direct_wait
        while wait and now > wait[0][1]:
            self._direct_sent.append(Sent(wait.popleft()[0], None, "computed before a stall"))
        if not wait:
            return
        due = None
        while wait and wait[0][0] <= now:
            if due is not None:
                self._direct_sent.append(Sent(due[0], None, "superseded: a late tick"))
            due = wait.popleft()
        at, not_after, max_shift, values = due if due is not None else wait[0]
        values = shifted(values, max(-max_shift, min(now - at, max_shift)))
        keys = ("x", "y", "z", "vx", "vy", "vz", "afx", "afy", "afz", "yaw")
        fields = {"time_boot_ms": int(round((now - self._boot) * 1e3)) & 0xFFFFFFFF,
                  "target_system": self._target[0], "target_component": self._target[1],
                  "coordinate_frame": MAV_FRAME_LOCAL_NED, "type_mask": TYPE_MASK_PVA_YAW,
                  **dict(zip(keys, values, strict=True)), "yaw_rate": 0.0}
        message = MavlinkMessage("SET_POSITION_TARGET_LOCAL_NED", 0, 0, *self._target,
                                 json.dumps(fields))
        # everything is built before the deadline is checked: only the C call (MAVSDK
        # packs and sends the datagram in it) lies between the check and the send
        plugin = self._direct._plugin
        handle, c_message = plugin._require_handle(), message.to_c_struct()
        if time.monotonic() > not_after:
            if due is not None:
                self._direct_sent.append(Sent(at, None, "computed before a stall"))
            return
        code = plugin._lib.mavsdk_mavlink_direct_send_message(handle, c_message)
        if code != _DIRECT_SUCCESS:
            raise AutopilotError(f"setpoint not sent: MAVSDK answered "
                                 f"{MavlinkDirectResult(code).name}")
        if due is not None:  # (a filler is no report: its setpoint is still to go out)
            self._direct_sent.append(Sent(at, now))

    def cancel_sends(self) -> None:
        """Drop the setpoints handed over and not yet sent (the stream stopped)."""
        self._direct_wait.clear()
        if self._sender is not None:
            with contextlib.suppress(SenderError):
                self._sender.cancel()

    def sent(self) -> list[Sent]:
        """What became of the setpoints handed over since the last call."""
        direct, self._direct_sent = self._direct_sent, []
        return direct + ([] if self._sender is None else self._sender.reports())


def _name(value: object) -> str:
    text = getattr(value, "name", None) or str(value)
    return text.split(".")[-1].upper()
