"""MAVLink 2 endpoint of the simulated vehicle (pymavlink, UDP on 127.0.0.1).

``MavlinkLink`` is PX4's onboard link as MAVSDK sees it: it decodes what arrives (commands,
offboard setpoints, parameter and message-interval requests, ping, timesync) and hands it to the
vehicle, and it sends the telemetry streams at their rates. It knows the vehicle through
:class:`LinkedVehicle`. The message set is documented in docs/sitl.md ("MAVLink interface").
"""

from __future__ import annotations

import math
import socket
import struct
import time
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2
from pymavlink.dialects.v20 import development as _DEV

from sitl.commander import Commander
from sitl.dynamics import Setpoint, euler_from_rotation, quaternion_from_rotation
from sitl.params import PX4_CONSTANTS, PX4_PARAMS, VehicleParams

LOOPBACK = "127.0.0.1"
_M = mavlink2
_EARTH_RADIUS_M = 6_378_137.0

# SET_POSITION_TARGET_*.type_mask bits (MAVLink POSITION_TARGET_TYPEMASK).
_IGNORE_X, _IGNORE_Y, _IGNORE_Z = 1, 2, 4
_IGNORE_VX, _IGNORE_VY, _IGNORE_VZ = 8, 16, 32
_IGNORE_AX, _IGNORE_AY, _IGNORE_AZ = 64, 128, 256
_FORCE_SET, _IGNORE_YAW, _IGNORE_YAW_RATE = 512, 1024, 2048

_HEALTH_BITS = (
    _M.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | _M.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | _M.MAV_SYS_STATUS_SENSOR_3D_MAG
    | _M.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | _M.MAV_SYS_STATUS_SENSOR_GPS
    | _M.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
    | _M.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
    | _M.MAV_SYS_STATUS_SENSOR_YAW_POSITION
    | _M.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
    | _M.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    | _M.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    | _M.MAV_SYS_STATUS_AHRS
    | _M.MAV_SYS_STATUS_SENSOR_BATTERY
)


class LinkedVehicle(Protocol):
    """What the link reads from and hands to the vehicle."""

    params: VehicleParams
    seed: int
    commander: Commander

    @property
    def time_s(self) -> float: ...

    def estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """Estimated position and velocity (NED)."""
        ...

    def true_state(self) -> Any:
        """Ground truth (``position_ned``, ``velocity_ned``)."""
        ...

    def attitude(self) -> tuple[np.ndarray, float, float]:
        """Body-to-NED rotation, yaw and yaw rate."""
        ...

    @property
    def battery_used_s(self) -> float: ...

    def reported_std(self) -> np.ndarray: ...

    def battery(self) -> tuple[float, int, int]: ...

    def set_position_target(self, setpoint: Setpoint, sent_ms: float = ...) -> None: ...


class _Writer:
    """File-like sink for pymavlink: sends packed frames to every known loopback peer."""

    def __init__(self, link: MavlinkLink) -> None:
        self._link = link

    def write(self, buf: bytes) -> None:
        self._link.send_bytes(buf)


class MavlinkLink:
    """The vehicle's MAVLink endpoint (see module docstring).

    Without an open socket (simulated clock) nothing is sent, but commands still work through
    :meth:`dispatch`.
    """

    def __init__(self, vehicle: LinkedVehicle) -> None:
        self.vehicle = vehicle
        p = vehicle.params
        self.mav: Any = mavlink2.MAVLink(_Writer(self), srcSystem=p.system_id,
                                         srcComponent=p.component_id)
        self.mav.robust_parsing = True
        self.sock: socket.socket | None = None
        self.peers: list[tuple[str, int]] = []
        self.blocked = False  #: test hook: drop all traffic in both directions
        self.received_message_counts: dict[str, int] = {}
        self.received_commands: list[int] = []
        self._default_rates: dict[int, float] = {
            getattr(_M, f"MAVLINK_MSG_ID_{name}"): rate for name, rate in p.telemetry_rates_hz
        }
        self.rates = dict(self._default_rates)
        self._next_send: dict[int, float] = {}
        self._last_reported_state: tuple[Any, ...] = ()
        self.captured: list[tuple[float, Any]] | None = None

    # ------------------------------------------------------------------ socket

    def open(self, port: int, bind_port: int) -> None:
        """Bind on 127.0.0.1 and send to the companion at ``port``."""
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((LOOPBACK, bind_port))
        self.sock.setblocking(False)
        self.peers = [(LOOPBACK, port)]
        self._next_send = {mid: self.vehicle.time_s for mid in self.rates}

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
        self.sock = None

    @property
    def local_port(self) -> int | None:
        return self.sock.getsockname()[1] if self.sock is not None else None

    def drain(self) -> None:
        """Read and dispatch every datagram waiting on the socket."""
        assert self.sock is not None
        while True:
            try:
                data, addr = self.sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                return
            except ConnectionRefusedError:
                continue  # ICMP "port unreachable" from an earlier send: nobody listens yet
            except OSError:
                return
            if addr[0] != LOOPBACK or self.blocked:
                continue
            if addr not in self.peers:
                self.peers.append(addr)
            try:
                msgs = self.mav.parse_buffer(data) or []
            except Exception:  # noqa: BLE001 - malformed datagram: ignore like PX4
                continue
            for msg in msgs:
                self.dispatch(msg)

    def send_bytes(self, buf: bytes) -> None:
        if self.sock is None or self.blocked:
            return
        for addr in self.peers:
            try:
                self.sock.sendto(buf, addr)
            except OSError:
                pass

    def send(self, msg: Any) -> None:
        if self.sock is not None:
            self.mav.send(msg)
        elif self.captured is not None:
            self.captured.append((self.vehicle.time_s, msg))

    def capture(self) -> list[tuple[float, Any]]:
        """Without a socket (simulated clock), keep every message the link would send as
        ``(sim time, message)`` in the returned list (the vehicle then sends its telemetry
        streams every physics step)."""
        self.captured = []
        self._next_send = {mid: self.vehicle.time_s for mid in self.rates}
        return self.captured

    def statustext(self, text: str, severity: int) -> None:
        self.send(self.mav.statustext_encode(severity, text.encode()[:50]))

    # ------------------------------------------------------------------ input

    def dispatch(self, msg: Any) -> None:
        """Process one decoded message (from the socket or injected)."""
        mtype = msg.get_type()
        if mtype == "BAD_DATA":
            return
        self.received_message_counts[mtype] = self.received_message_counts.get(mtype, 0) + 1
        targeted = hasattr(msg, "target_system") and self._for_me(msg)
        if mtype == "COMMAND_LONG" and targeted:
            self._command(msg, msg.command, [msg.param1, msg.param2, msg.param3, msg.param4,
                                             msg.param5, msg.param6, msg.param7])
        elif mtype == "COMMAND_INT" and targeted:
            # x, y are degE7 in global frames; passed through scaled, z as is.
            self._command(msg, msg.command, [msg.param1, msg.param2, msg.param3, msg.param4,
                                             msg.x * 1e-7, msg.y * 1e-7, msg.z])
        elif mtype == "SET_POSITION_TARGET_LOCAL_NED" and targeted:
            sp = self._decode_local_target(msg)
            if sp is not None:
                self.vehicle.set_position_target(sp, float(msg.time_boot_ms))
        elif mtype == "PARAM_REQUEST_READ" and targeted:
            self._on_param_request_read(msg)
        elif mtype == "PARAM_REQUEST_LIST" and targeted:
            for i, name in enumerate(self._param_names()):
                self._send_param(name, i)
        elif mtype == "PARAM_SET" and targeted:
            self._on_param_set(msg)
        elif mtype == "PING":
            if msg.target_system == 0 and msg.target_component == 0:
                # Ping protocol: answer a ping request addressed to everybody.
                self.send(self.mav.ping_encode(msg.time_usec, msg.seq, msg.get_srcSystem(),
                                               msg.get_srcComponent()))
        elif mtype == "TIMESYNC":
            if msg.tc1 == 0:
                self.send(self.mav.timesync_encode(int(self.vehicle.time_s * 1e9) + 1, msg.ts1))

    def _for_me(self, msg: Any) -> bool:
        p = self.vehicle.params
        return (msg.target_system in (0, p.system_id)
                and msg.target_component in (0, p.component_id))

    def _command(self, msg: Any, command: int, pr: list[float]) -> None:
        self.received_commands.append(int(command))
        result, after = self.handle_command(int(command), pr)
        self.send(self.mav.command_ack_encode(command, result, 0, 0, msg.get_srcSystem(),
                                              msg.get_srcComponent()))
        if after is not None:
            after()

    def handle_command(self, cmd: int, pr: list[float]
                       ) -> tuple[int, Callable[[], None] | None]:
        """(MAV_RESULT, optional action to run after the ACK was sent) for a MAV_CMD."""
        result = self.vehicle.commander.handle_command(cmd, pr)
        if result is not None:
            return result, None
        acc = _M.MAV_RESULT_ACCEPTED
        if cmd == _M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            return acc, self._send_autopilot_version
        if cmd == _M.MAV_CMD_GET_HOME_POSITION:
            return acc, self._send_home_position
        if cmd == _M.MAV_CMD_REQUEST_MESSAGE:
            msg_id = int(pr[0]) if math.isfinite(pr[0]) else -1
            sender = self._single_message_sender(msg_id)
            return (acc, sender) if sender is not None else (_M.MAV_RESULT_UNSUPPORTED, None)
        if cmd == _M.MAV_CMD_SET_MESSAGE_INTERVAL:
            return self._set_message_interval(pr), None
        return _M.MAV_RESULT_UNSUPPORTED, None

    def _decode_local_target(self, msg: Any) -> Setpoint | None:
        """SET_POSITION_TARGET_LOCAL_NED -> Setpoint honouring the type_mask bits."""
        frame = msg.coordinate_frame
        mask = msg.type_mask
        if frame not in (_M.MAV_FRAME_LOCAL_NED, _M.MAV_FRAME_BODY_NED):
            return None  # PX4 only accepts LOCAL_NED and BODY_NED (docs "Offboard Mode")

        def pick(vals: Sequence[float], bits: Sequence[int]) -> np.ndarray:
            out = [math.nan if mask & b else float(v) for v, b in zip(vals, bits, strict=True)]
            return np.array(out)

        pos = pick((msg.x, msg.y, msg.z), (_IGNORE_X, _IGNORE_Y, _IGNORE_Z))
        vel = pick((msg.vx, msg.vy, msg.vz), (_IGNORE_VX, _IGNORE_VY, _IGNORE_VZ))
        acc = pick((msg.afx, msg.afy, msg.afz), (_IGNORE_AX, _IGNORE_AY, _IGNORE_AZ))
        if mask & _FORCE_SET:
            acc[:] = math.nan  # force setpoints are not supported by PX4 multicopters
        yaw = math.nan if mask & _IGNORE_YAW else float(msg.yaw)
        yaw_rate = math.nan if mask & _IGNORE_YAW_RATE else float(msg.yaw_rate)
        if frame == _M.MAV_FRAME_BODY_NED:
            # Body-NED: velocity/acceleration rotated by the heading; position relative to the
            # vehicle (like PX4's handling of MAV_FRAME_BODY_NED in offboard).
            _, heading, _ = self.vehicle.attitude()
            c, s = math.cos(heading), math.sin(heading)
            rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
            est, _ = self.vehicle.estimate()
            pos = est + rot @ pos
            vel = rot @ vel
            acc = rot @ acc
        return Setpoint(position=pos, velocity=vel, acceleration=acc, yaw=yaw, yaw_rate=yaw_rate)

    # ------------------------------------------------------------------ parameters

    def _param_names(self) -> list[str]:
        return sorted(set(PX4_PARAMS) | set(PX4_CONSTANTS))

    def _send_param(self, name: str, index: int) -> None:
        names = self._param_names()
        if name in PX4_PARAMS:
            value, ptype = self.vehicle.commander.live[name], PX4_PARAMS[name][1]
        else:
            value, ptype = PX4_CONSTANTS[name]
        if ptype == _M.MAV_PARAM_TYPE_INT32:
            # PX4 uses byte-wise encoding: the int32 bits travel in the float field.
            wire = struct.unpack("<f", struct.pack("<i", int(value)))[0]
        else:
            wire = float(value)
        self.send(self.mav.param_value_encode(name.encode(), wire, ptype, len(names), index))

    @staticmethod
    def _param_id(msg: Any) -> str:
        name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode()
        return name.rstrip("\x00")

    def _on_param_request_read(self, msg: Any) -> None:
        names = self._param_names()
        name = self._param_id(msg)
        if msg.param_index >= 0:
            if msg.param_index < len(names):
                self._send_param(names[msg.param_index], msg.param_index)
        elif name in names:
            self._send_param(name, names.index(name))

    def _on_param_set(self, msg: Any) -> None:
        names = self._param_names()
        name = self._param_id(msg)
        if name not in names:
            return
        if name in PX4_PARAMS:
            self.vehicle.commander.live[name] = float(msg.param_value)
        self._send_param(name, names.index(name))

    # ------------------------------------------------------------------ telemetry

    def _single_message_sender(self, msg_id: int) -> Callable[[], None] | None:
        senders: dict[int, Callable[[], None]] = {
            _M.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self._send_autopilot_version,
            _M.MAVLINK_MSG_ID_HOME_POSITION: self._send_home_position,
        }
        return senders.get(msg_id, self._stream_senders().get(msg_id))

    def _set_message_interval(self, pr: list[float]) -> int:
        msg_id = int(pr[0]) if math.isfinite(pr[0]) else -1
        if msg_id not in self._stream_senders():
            return _M.MAV_RESULT_UNSUPPORTED
        interval_us = pr[1]
        if interval_us == 0 or not math.isfinite(interval_us):
            rate = self._default_rates.get(msg_id, 0.0)
        elif interval_us < 0:
            rate = 0.0
        else:
            rate = 1e6 / interval_us
        self.rates[msg_id] = rate
        self._next_send[msg_id] = self.vehicle.time_s
        return _M.MAV_RESULT_ACCEPTED

    def _stream_senders(self) -> dict[int, Callable[[], None]]:
        return {
            _M.MAVLINK_MSG_ID_HEARTBEAT: self._send_heartbeat,
            _M.MAVLINK_MSG_ID_SYS_STATUS: self._send_sys_status,
            _M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self._send_extended_sys_state,
            _M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: self._send_local_position,
            _M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self._send_global_position,
            _M.MAVLINK_MSG_ID_ATTITUDE: self._send_attitude,
            _M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: self._send_attitude_quaternion,
            _M.MAVLINK_MSG_ID_ODOMETRY: self._send_odometry,
            _M.MAVLINK_MSG_ID_ESTIMATOR_STATUS: self._send_estimator_status,
            _M.MAVLINK_MSG_ID_GPS_RAW_INT: self._send_gps_raw,
            _M.MAVLINK_MSG_ID_BATTERY_STATUS: self._send_battery_status,
            _M.MAVLINK_MSG_ID_HOME_POSITION: self._send_home_position,
            _M.MAVLINK_MSG_ID_SYSTEM_TIME: self._send_system_time,
            _M.MAVLINK_MSG_ID_HIL_STATE_QUATERNION: self._send_hil_state_quaternion,
            _DEV.MAVLINK_MSG_ID_CURRENT_MODE: self._send_current_mode,
        }

    def send_due_telemetry(self) -> None:
        """Send every stream whose next time has come (called by the real-time loop)."""
        t = self.vehicle.time_s
        senders = self._stream_senders()
        c = self.vehicle.commander
        state = (c.armed, c.mode, c.landed_state(), c.crashed)
        if state != self._last_reported_state and self.vehicle.params.instant_state_reports:
            # Idealised option (PX4 sends HEARTBEAT at 1 Hz only): report arming/mode/landed
            # changes at once.
            self._last_reported_state = state
            self._send_heartbeat()
            self._send_extended_sys_state()
        for msg_id, rate in self.rates.items():
            if rate <= 0.0:
                continue
            if t + 1e-9 >= self._next_send.get(msg_id, t):
                senders[msg_id]()
                nxt = self._next_send.get(msg_id, t) + 1.0 / rate
                self._next_send[msg_id] = nxt if nxt > t else t + 1.0 / rate

    def _time_boot_ms(self) -> int:
        return int(self.vehicle.time_s * 1000.0) & 0xFFFFFFFF

    def _base_mode(self) -> int:
        c = self.vehicle.commander
        flags = _M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | _M.MAV_MODE_FLAG_STABILIZE_ENABLED
        if c.armed:
            flags |= _M.MAV_MODE_FLAG_SAFETY_ARMED
        if c.mode.main_mode == 4:
            flags |= _M.MAV_MODE_FLAG_AUTO_ENABLED | _M.MAV_MODE_FLAG_GUIDED_ENABLED
        elif c.mode.main_mode == 6:
            flags |= _M.MAV_MODE_FLAG_GUIDED_ENABLED
        return flags

    def _send_heartbeat(self) -> None:
        c = self.vehicle.commander
        if c.crashed:
            status = _M.MAV_STATE_FLIGHT_TERMINATION
        elif c.failsafe_active:
            status = _M.MAV_STATE_CRITICAL
        elif c.armed:
            status = _M.MAV_STATE_ACTIVE
        else:
            status = _M.MAV_STATE_STANDBY
        self.send(self.mav.heartbeat_encode(_M.MAV_TYPE_QUADROTOR, _M.MAV_AUTOPILOT_PX4,
                                            self._base_mode(), c.mode.custom_mode, status))

    def _send_sys_status(self) -> None:
        volt, cur, rem = self.vehicle.battery()
        health = _HEALTH_BITS
        present = _HEALTH_BITS | _M.MAV_SYS_STATUS_PREARM_CHECK
        if not self.vehicle.commander.crashed:
            health |= _M.MAV_SYS_STATUS_PREARM_CHECK  # "can arm" (MAVSDK health.is_armable)
        self.send(self.mav.sys_status_encode(present, present, health, 200, int(volt * 1000),
                                             cur, rem, 0, 0, 0, 0, 0, 0))

    def _send_extended_sys_state(self) -> None:
        self.send(self.mav.extended_sys_state_encode(
            _M.MAV_VTOL_STATE_UNDEFINED, self.vehicle.commander.landed_state()))

    def _send_local_position(self) -> None:
        p, v = self.vehicle.estimate()
        self.send(self.mav.local_position_ned_encode(self._time_boot_ms(), p[0], p[1], p[2],
                                                     v[0], v[1], v[2]))

    def _latlon(self, p: np.ndarray) -> tuple[int, int, float]:
        prm = self.vehicle.params
        lat0 = math.radians(prm.home_lat_deg)
        lat = prm.home_lat_deg + math.degrees(p[0] / _EARTH_RADIUS_M)
        lon = prm.home_lon_deg + math.degrees(p[1] / (_EARTH_RADIUS_M * math.cos(lat0)))
        return int(round(lat * 1e7)), int(round(lon * 1e7)), prm.home_alt_m - p[2]

    def _send_global_position(self) -> None:
        p, v = self.vehicle.estimate()
        lat, lon, alt = self._latlon(p)
        _, yaw, _ = self.vehicle.attitude()
        hdg = int(round(math.degrees(yaw) % 360.0 * 100)) % 36000
        self.send(self.mav.global_position_int_encode(
            self._time_boot_ms(), lat, lon, int(round(alt * 1000)),
            int(round((self.vehicle.commander.home[2] - p[2]) * 1000)),
            int(round(v[0] * 100)), int(round(v[1] * 100)), int(round(v[2] * 100)), hdg))

    def _send_attitude(self) -> None:
        r, _, yaw_rate = self.vehicle.attitude()
        roll, pitch, yaw = euler_from_rotation(r)
        self.send(self.mav.attitude_encode(self._time_boot_ms(), roll, pitch, yaw, 0.0, 0.0,
                                           yaw_rate))

    def _send_attitude_quaternion(self) -> None:
        r, _, yaw_rate = self.vehicle.attitude()
        q = quaternion_from_rotation(r)
        self.send(self.mav.attitude_quaternion_encode(self._time_boot_ms(), q[0], q[1], q[2],
                                                      q[3], 0.0, 0.0, yaw_rate))

    def _send_odometry(self) -> None:
        p, v = self.vehicle.estimate()
        r, _, yaw_rate = self.vehicle.attitude()
        q = quaternion_from_rotation(r)
        v_body = r.T @ v  # PX4 sends the ODOMETRY velocity in the body (FRD) frame
        var = self.vehicle.reported_std() ** 2
        # Upper-right triangle of the 6x6 pose covariance (x, y, z, roll, pitch, yaw), row-major.
        pose_cov = [0.0] * 21
        pose_cov[0], pose_cov[6], pose_cov[11] = var[0], var[1], var[2]
        pose_cov[15] = pose_cov[18] = pose_cov[20] = 1e-4
        vel_cov = [0.0] * 21
        vel_cov[0] = vel_cov[6] = vel_cov[11] = 1e-4
        vel_cov[15] = vel_cov[18] = vel_cov[20] = 1e-4
        self.send(self.mav.odometry_encode(
            int(self.vehicle.time_s * 1e6), _M.MAV_FRAME_LOCAL_NED, _M.MAV_FRAME_BODY_FRD,
            p[0], p[1], p[2], list(q), v_body[0], v_body[1], v_body[2], 0.0, 0.0, yaw_rate,
            pose_cov, vel_cov, 0, _M.MAV_ESTIMATOR_TYPE_AUTOPILOT, 100))

    def _send_estimator_status(self) -> None:
        std = self.vehicle.reported_std()
        flags = (_M.ESTIMATOR_ATTITUDE | _M.ESTIMATOR_VELOCITY_HORIZ | _M.ESTIMATOR_VELOCITY_VERT
                 | _M.ESTIMATOR_POS_HORIZ_REL | _M.ESTIMATOR_POS_HORIZ_ABS
                 | _M.ESTIMATOR_POS_VERT_ABS | _M.ESTIMATOR_PRED_POS_HORIZ_REL
                 | _M.ESTIMATOR_PRED_POS_HORIZ_ABS)
        self.send(self.mav.estimator_status_encode(
            int(self.vehicle.time_s * 1e6), flags, 0.1, 0.1, 0.1, 0.1, 0.0, 0.0,
            float(math.hypot(std[0], std[1])), float(std[2])))

    def _send_gps_raw(self) -> None:
        p, v = self.vehicle.estimate()
        lat, lon, alt = self._latlon(p)
        vel = int(round(math.hypot(v[0], v[1]) * 100))
        cog = int(round(math.degrees(math.atan2(v[1], v[0])) % 360.0 * 100)) % 36000
        self.send(self.mav.gps_raw_int_encode(int(self.vehicle.time_s * 1e6),
                                              _M.GPS_FIX_TYPE_3D_FIX, lat, lon,
                                              int(round(alt * 1000)), 80, 120, vel, cog, 12))

    def _send_battery_status(self) -> None:
        volt, cur, rem = self.vehicle.battery()
        n = self.vehicle.params.battery_cells
        cell_mv = int(volt * 1000 / n)
        cells = [cell_mv] * n + [0xFFFF] * (10 - n)
        used_mah = int(self.vehicle.battery_used_s / 3600.0 * 15000)
        self.send(self.mav.battery_status_encode(0, _M.MAV_BATTERY_FUNCTION_ALL,
                                                 _M.MAV_BATTERY_TYPE_LIPO, 0x7FFF, cells, cur,
                                                 used_mah, -1, rem))

    def _send_home_position(self) -> None:
        home = self.vehicle.commander.home  # set at arming, like PX4
        lat, lon, alt = self._latlon(home)
        self.send(self.mav.home_position_encode(
            lat, lon, int(round(alt * 1000)), float(home[0]), float(home[1]), float(home[2]),
            [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, int(self.vehicle.time_s * 1e6)))

    def _send_hil_state_quaternion(self) -> None:
        """The ground truth, as PX4's SIH sends it on its display link (off unless asked for
        with SET_MESSAGE_INTERVAL)."""
        truth = self.vehicle.true_state()
        p, v = truth.position_ned, truth.velocity_ned
        r, yaw_rate = self.vehicle.attitude()[0], self.vehicle.attitude()[2]
        q = quaternion_from_rotation(r)
        lat, lon, alt = self._latlon(p)
        self.send(self.mav.hil_state_quaternion_encode(
            int(self.vehicle.time_s * 1e6), list(q), 0.0, 0.0, yaw_rate, lat, lon,
            int(round(alt * 1000)), int(round(v[0] * 100)), int(round(v[1] * 100)),
            int(round(v[2] * 100)), 0, 0, 0, 0, 0))

    def _send_current_mode(self) -> None:
        """CURRENT_MODE (MAVLink's development set, as PX4 sends it; off unless asked for)."""
        mode = self.vehicle.commander.mode.custom_mode
        self.send(_DEV.MAVLink_current_mode_message(0, mode, mode))

    def _send_system_time(self) -> None:
        self.send(self.mav.system_time_encode(int(time.time() * 1e6), self._time_boot_ms()))

    def _send_autopilot_version(self) -> None:
        major, minor, patch = self.vehicle.params.flight_sw_version
        caps = (_M.MAV_PROTOCOL_CAPABILITY_MAVLINK2
                | _M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
                | _M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | _M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE)
        # PX4 encodes versions as major<<24 | minor<<16 | patch<<8 | type (255 = release).
        sw = (major << 24) | (minor << 16) | (patch << 8) | 255
        self.send(self.mav.autopilot_version_encode(
            caps, sw, sw, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0,
            0x5349_4D00_0000_0000 | (self.vehicle.seed & 0xFFFF)))
