"""Simulated PX4-compatible multicopter speaking MAVLink 2 over UDP loopback.

``SimVehicle`` couples the point-mass model and cascaded controller of :mod:`sitl.dynamics`,
the speed-dependent estimation error of :mod:`sitl.estimation` and an optional world (for
collision checks) with a PX4-like commander state machine and a MAVLink 2 endpoint built with
pymavlink. Unmodified MAVSDK 4.x connects to it as to PX4 on its onboard (companion) link:

* the vehicle sends from ``127.0.0.1:<bind_port>`` to ``127.0.0.1:<port>`` (default 14540, so
  MAVSDK uses ``udpin://127.0.0.1:14540``) and answers every loopback peer that talks to it;
* two clocks: real time in a background thread (``with SimVehicle(...) as sim:`` or
  :meth:`SimVehicle.start`) for MAVSDK, or a simulated clock without any networking
  (:meth:`SimVehicle.step` / :meth:`SimVehicle.run_for`) for fast, deterministic experiments.

What PX4 behaviour is emulated (and what is not) is documented in docs/sitl.md. Frames: the
vehicle's local frame is NED with its origin at home; a world object is queried in ENU metres
(x east, y north, z up), with home at ``VehicleParams.home_enu_m``.
"""

from __future__ import annotations

import enum
import math
import select
import socket
import struct
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from sitl.dynamics import (
    ControllerParams,
    PositionController,
    QuadrotorModel,
    QuadrotorParams,
    QuadState,
    Setpoint,
    euler_from_rotation,
    quaternion_from_rotation,
    rotation_from_thrust_yaw,
)
from sitl.estimation import EstimationErrorParams, PositionErrorModel

LOOPBACK = "127.0.0.1"
DEFAULT_COMPANION_PORT = 14540
_EARTH_RADIUS_M = 6_378_137.0
_FORCE_MAGIC = 21196  # MAV_CMD_COMPONENT_ARM_DISARM param2: force (PX4 and ArduPilot)

# SET_POSITION_TARGET_*.type_mask bits (MAVLink POSITION_TARGET_TYPEMASK).
_IGNORE_X, _IGNORE_Y, _IGNORE_Z = 1, 2, 4
_IGNORE_VX, _IGNORE_VY, _IGNORE_VZ = 8, 16, 32
_IGNORE_AX, _IGNORE_AY, _IGNORE_AZ = 64, 128, 256
_FORCE_SET, _IGNORE_YAW, _IGNORE_YAW_RATE = 512, 1024, 2048

_M = mavlink2  # short alias for enum constants


class Px4Mode(enum.Enum):
    """PX4 flight modes as (main mode, sub mode) of PX4's MAVLink custom mode.

    PX4 packs ``custom_mode = (sub_mode << 24) | (main_mode << 16)`` into HEARTBEAT.custom_mode
    (PX4 source ``px4_custom_mode.h``; PX4 docs "MAVLink Messaging" / "Flight Modes").
    """

    MANUAL = (1, 0)
    ALTCTL = (2, 0)
    POSCTL = (3, 0)
    AUTO_READY = (4, 1)
    AUTO_TAKEOFF = (4, 2)
    AUTO_LOITER = (4, 3)  # "Hold"
    AUTO_MISSION = (4, 4)
    AUTO_RTL = (4, 5)
    AUTO_LAND = (4, 6)
    ACRO = (5, 0)
    OFFBOARD = (6, 0)
    STABILIZED = (7, 0)

    @property
    def main_mode(self) -> int:
        """PX4 main mode number."""
        return self.value[0]

    @property
    def sub_mode(self) -> int:
        """PX4 sub mode number (AUTO only, else 0)."""
        return self.value[1]

    @property
    def custom_mode(self) -> int:
        """The 32-bit HEARTBEAT.custom_mode value."""
        return (self.sub_mode << 24) | (self.main_mode << 16)

    @staticmethod
    def from_custom_mode(custom_mode: int) -> Px4Mode:
        """Decode HEARTBEAT.custom_mode (raises ValueError for unknown modes)."""
        key = ((custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF)
        return Px4Mode(key)

    @staticmethod
    def from_main_sub(main_mode: int, sub_mode: int) -> Px4Mode | None:
        """Mode for a DO_SET_MODE (param2, param3) pair, or None if unknown."""
        if main_mode == 4 and sub_mode == 0:
            sub_mode = 3  # AUTO without sub mode -> Hold
        if main_mode != 4:
            sub_mode = 0
        try:
            return Px4Mode((main_mode, sub_mode))
        except ValueError:
            return None


_MANUAL_MODES = {
    Px4Mode.MANUAL,
    Px4Mode.ALTCTL,
    Px4Mode.POSCTL,
    Px4Mode.ACRO,
    Px4Mode.STABILIZED,
}


class World(Protocol):
    """What the vehicle needs from a world: ENU signed distances and the robot radius."""

    robot_radius: float

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance (m) of ``(n, 3)`` ENU points to the nearest obstacle (<=0: inside)."""
        ...


#: Default telemetry rates (Hz), roughly PX4's onboard-link defaults (MAVLINK_MODE_ONBOARD):
#: position and attitude at 30-50 Hz, status messages at a few Hz, HOME_POSITION slowly.
DEFAULT_TELEMETRY_RATES_HZ: tuple[tuple[str, float], ...] = (
    ("HEARTBEAT", 1.0),
    ("SYS_STATUS", 5.0),
    ("EXTENDED_SYS_STATE", 5.0),
    ("LOCAL_POSITION_NED", 30.0),
    ("GLOBAL_POSITION_INT", 50.0),
    ("ATTITUDE", 20.0),
    ("ATTITUDE_QUATERNION", 50.0),
    ("ODOMETRY", 30.0),
    ("ESTIMATOR_STATUS", 2.0),
    ("GPS_RAW_INT", 5.0),
    ("BATTERY_STATUS", 1.0),
    ("HOME_POSITION", 0.5),
    ("SYSTEM_TIME", 1.0),
)


@dataclass(frozen=True)
class VehicleParams:
    """Commander / MAVLink parameters of the simulated vehicle (PX4 names in brackets).

    Attributes:
        system_id / component_id: MAVLink ids of the autopilot (PX4: 1 / 1).
        home_lat_deg / home_lon_deg / home_alt_m: fixed home (WGS-84, AMSL), PX4 SITL default.
        home_enu_m: position of home (the local NED origin) in the world's ENU frame.
        initial_yaw_deg: heading at start (0 = north).
        physics_dt_s: fixed integration / control step.
        com_of_loss_t_s: [COM_OF_LOSS_T] offboard setpoint timeout before the failsafe.
        offboard_min_rate_hz: setpoints must be received faster than this (PX4: > 2 Hz).
        offboard_min_stream_s: how long the stream must already run before OFFBOARD is
            accepted (0 = a single setpoint suffices, like old PX4).
        failsafe_hold_s: [COM_FAIL_ACT_T] hold time before the failsafe action (Land).
        takeoff_alt_m: [MIS_TAKEOFF_ALT] default takeoff altitude above home.
        takeoff_speed_m_s: [MPC_TKO_SPEED]; land_speed_m_s: [MPC_LAND_SPEED].
        auto_cruise_m_s: [MPC_XY_CRUISE] horizontal speed limit in Hold/RTL.
        brake_acc_m_s2: [MPC_ACC_HOR] deceleration assumed when entering Hold.
        disarm_land_s: [COM_DISARM_LAND] auto-disarm delay after landing (<= 0: never).
        disarm_preflight_s: [COM_DISARM_PRFLT] auto-disarm if armed but no takeoff (<= 0: never).
        takeoff_accept_m: altitude error at which Takeoff is complete and switches to Hold.
        collision_min_alt_m: collisions are ignored below this true altitude above the ground
            (None: the world's robot radius; the vehicle handles ground contact itself).
        battery_cells / battery_flight_time_s: simple linear battery model.
        flight_sw_version: reported PX4 version (major, minor, patch).
        telemetry_rates_hz: (message name, Hz) pairs; changeable with SET_MESSAGE_INTERVAL.
    """

    system_id: int = 1
    component_id: int = 1
    home_lat_deg: float = 47.397742
    home_lon_deg: float = 8.545594
    home_alt_m: float = 488.0
    home_enu_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    initial_yaw_deg: float = 0.0
    physics_dt_s: float = 0.004
    com_of_loss_t_s: float = 1.0
    offboard_min_rate_hz: float = 2.0
    offboard_min_stream_s: float = 1.0
    failsafe_hold_s: float = 5.0
    takeoff_alt_m: float = 2.5
    takeoff_speed_m_s: float = 1.5
    land_speed_m_s: float = 0.7
    auto_cruise_m_s: float = 5.0
    brake_acc_m_s2: float = 3.0
    disarm_land_s: float = 2.0
    disarm_preflight_s: float = 10.0
    takeoff_accept_m: float = 0.2
    collision_min_alt_m: float | None = None
    battery_cells: int = 4
    battery_flight_time_s: float = 1200.0
    flight_sw_version: tuple[int, int, int] = (1, 15, 0)
    telemetry_rates_hz: tuple[tuple[str, float], ...] = DEFAULT_TELEMETRY_RATES_HZ


@dataclass(frozen=True)
class Collision:
    """A recorded collision: sim time, true position (ENU world frame and local NED), distance."""

    time_s: float
    position_enu: np.ndarray
    position_ned: np.ndarray
    signed_distance_m: float


@dataclass(frozen=True)
class VehicleSnapshot:
    """Position/velocity snapshot in local NED (position also in the world ENU frame)."""

    time_s: float
    position_ned: np.ndarray
    velocity_ned: np.ndarray
    yaw_rad: float
    position_enu: np.ndarray


@dataclass
class History:
    """Per-step recording (enable with ``SimVehicle(record_history=True)``)."""

    time_s: list[float] = field(default_factory=list)
    true_position_ned: list[np.ndarray] = field(default_factory=list)
    estimated_position_ned: list[np.ndarray] = field(default_factory=list)
    velocity_ned: list[np.ndarray] = field(default_factory=list)
    error_std_m: list[np.ndarray] = field(default_factory=list)
    setpoint_position_ned: list[np.ndarray] = field(default_factory=list)
    mode: list[str] = field(default_factory=list)

    def arrays(self) -> dict[str, np.ndarray]:
        """The recording as numpy arrays (``(n,)`` or ``(n, 3)``)."""
        return {
            "time_s": np.asarray(self.time_s),
            "true_position_ned": np.asarray(self.true_position_ned).reshape(-1, 3),
            "estimated_position_ned": np.asarray(self.estimated_position_ned).reshape(-1, 3),
            "velocity_ned": np.asarray(self.velocity_ned).reshape(-1, 3),
            "error_std_m": np.asarray(self.error_std_m).reshape(-1, 3),
            "setpoint_position_ned": np.asarray(self.setpoint_position_ned).reshape(-1, 3),
            "mode": np.asarray(self.mode),
        }


def ned_to_enu(p: np.ndarray) -> np.ndarray:
    """Convert NED vectors ``(..., 3)`` to ENU: (e, n, u) = (y, x, -z)."""
    p = np.asarray(p, dtype=float)
    return np.stack((p[..., 1], p[..., 0], -p[..., 2]), axis=-1)


def enu_to_ned(p: np.ndarray) -> np.ndarray:
    """Convert ENU vectors ``(..., 3)`` to NED: (n, e, d) = (y, x, -z)."""
    p = np.asarray(p, dtype=float)
    return np.stack((p[..., 1], p[..., 0], -p[..., 2]), axis=-1)


class _Writer:
    """File-like sink for pymavlink: sends packed frames to every known loopback peer."""

    def __init__(self, vehicle: SimVehicle) -> None:
        self._vehicle = vehicle

    def write(self, buf: bytes) -> None:
        self._vehicle._send_bytes(buf)


# Parameters exposed over the MAVLink parameter protocol: name -> (VehicleParams field, type).
_PARAM_FIELDS: dict[str, tuple[str, int]] = {
    "COM_OF_LOSS_T": ("com_of_loss_t_s", _M.MAV_PARAM_TYPE_REAL32),
    "COM_FAIL_ACT_T": ("failsafe_hold_s", _M.MAV_PARAM_TYPE_REAL32),
    "MIS_TAKEOFF_ALT": ("takeoff_alt_m", _M.MAV_PARAM_TYPE_REAL32),
    "MPC_TKO_SPEED": ("takeoff_speed_m_s", _M.MAV_PARAM_TYPE_REAL32),
    "MPC_LAND_SPEED": ("land_speed_m_s", _M.MAV_PARAM_TYPE_REAL32),
    "MPC_XY_CRUISE": ("auto_cruise_m_s", _M.MAV_PARAM_TYPE_REAL32),
    "COM_DISARM_LAND": ("disarm_land_s", _M.MAV_PARAM_TYPE_REAL32),
    "COM_DISARM_PRFLT": ("disarm_preflight_s", _M.MAV_PARAM_TYPE_REAL32),
}
_PARAM_CONSTANTS: dict[str, tuple[float, int]] = {
    "SYS_HITL": (0, _M.MAV_PARAM_TYPE_INT32),
    "COM_RC_IN_MODE": (4, _M.MAV_PARAM_TYPE_INT32),  # 4: manual control disabled
    "CAL_GYRO0_ID": (1, _M.MAV_PARAM_TYPE_INT32),
    "CAL_ACC0_ID": (1, _M.MAV_PARAM_TYPE_INT32),
    "CAL_MAG0_ID": (1, _M.MAV_PARAM_TYPE_INT32),
    "RTL_RETURN_ALT": (30.0, _M.MAV_PARAM_TYPE_REAL32),
}

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


class SimVehicle:
    """A simulated PX4 multicopter (see module docstring).

    Args:
        params: commander / MAVLink parameters.
        quad: physical parameters; controller: controller gains and limits.
        estimation: estimation-error model parameters.
        world: optional object with ``signed_distance((n,3) ENU) -> (n,)`` and
            ``robot_radius``; a true position within ``robot_radius`` of an obstacle ends the
            flight (see :attr:`collisions`).
        seed: seed of the estimation-error generator (the only random source).
        port: UDP port of the companion (MAVSDK ``udpin://127.0.0.1:<port>``).
        bind_port: local UDP port of the vehicle (0: any free port; PX4 uses 14580).
        record_history: record true/estimated state every ``history_decimation`` steps.
    """

    def __init__(
        self,
        params: VehicleParams | None = None,
        *,
        quad: QuadrotorParams | None = None,
        controller: ControllerParams | None = None,
        estimation: EstimationErrorParams | None = None,
        world: World | None = None,
        seed: int = 0,
        port: int = DEFAULT_COMPANION_PORT,
        bind_port: int = 0,
        record_history: bool = False,
        history_decimation: int = 1,
    ) -> None:
        self.params = params if params is not None else VehicleParams()
        self.quad_params = quad if quad is not None else QuadrotorParams()
        self.controller_params = controller if controller is not None else ControllerParams()
        self.estimation_params = estimation if estimation is not None else EstimationErrorParams()
        self.world = world
        self.seed = seed
        self.port = int(port)
        self.bind_port = int(bind_port)

        p = self.params
        self._dt = p.physics_dt_s
        self._steps = 0
        self._lock = threading.RLock()
        state = QuadState(yaw=math.radians(p.initial_yaw_deg))
        self._model = QuadrotorModel(self.quad_params, state)
        self._ctrl = PositionController(self.controller_params, self.quad_params)
        self._err = PositionErrorModel(self.estimation_params, np.random.default_rng(seed))
        self._live: dict[str, float] = {
            name: float(getattr(p, attr)) for name, (attr, _) in _PARAM_FIELDS.items()
        }

        # Commander state.
        self.armed = False
        self.mode = Px4Mode.AUTO_LOITER
        self.crashed = False
        self.collisions: list[Collision] = []
        self.events: list[tuple[float, str]] = []
        self._armed_t = 0.0
        self._took_off = False
        self._ground_since: float | None = 0.0
        self._hold_sp: Setpoint | None = None
        self._takeoff_z = 0.0
        self._failsafe_t: float | None = None
        self._offboard_sp: Setpoint | None = None
        self._last_sp_t: float | None = None
        self._stream_start_t: float | None = None
        self.setpoints_received = 0
        self._active_sp = Setpoint()
        self._battery_used_s = 0.0

        # Recording.
        self._record = record_history
        self._decim = max(1, int(history_decimation))
        self.history = History()

        # Networking: the MAVLink codec always exists (without a socket frames are dropped).
        self._sock: socket.socket | None = None
        self._mav: Any = mavlink2.MAVLink(
            _Writer(self), srcSystem=self.params.system_id, srcComponent=self.params.component_id
        )
        self._mav.robust_parsing = True
        self._peers: list[tuple[str, int]] = []
        self._thread: threading.Thread | None = None
        self._stop_evt = threading.Event()
        self._default_rates: dict[int, float] = {
            getattr(_M, f"MAVLINK_MSG_ID_{name}"): rate
            for name, rate in self.params.telemetry_rates_hz
        }
        self._rates = dict(self._default_rates)
        self._next_send: dict[int, float] = {}
        self._last_reported_state: tuple[Any, ...] = ()
        self.link_blocked = False  #: test hook: drop all traffic in both directions
        self.received_message_counts: dict[str, int] = {}
        self.received_commands: list[int] = []
        self.thread_error: BaseException | None = None

    # ------------------------------------------------------------------ properties / readout

    @property
    def time_s(self) -> float:
        """Simulation time (s since start)."""
        return self._steps * self._dt

    @property
    def local_port(self) -> int | None:
        """The vehicle's bound UDP port while running, else None."""
        return self._sock.getsockname()[1] if self._sock is not None else None

    @property
    def running(self) -> bool:
        """True while the real-time thread runs."""
        return self._thread is not None and self._thread.is_alive()

    def param(self, name: str) -> float:
        """Current value of a PX4-named parameter (COM_OF_LOSS_T, MIS_TAKEOFF_ALT, ...)."""
        with self._lock:
            if name in self._live:
                return self._live[name]
            return float(_PARAM_CONSTANTS[name][0])

    def true_state(self) -> VehicleSnapshot:
        """Ground-truth state (what collisions are checked against)."""
        with self._lock:
            s = self._model.state
            return VehicleSnapshot(
                self.time_s,
                s.position.copy(),
                s.velocity.copy(),
                s.yaw,
                self._to_world_enu(s.position),
            )

    def estimated_state(self) -> VehicleSnapshot:
        """The autopilot's estimate (what it flies on and reports over MAVLink)."""
        with self._lock:
            s = self._model.state
            p_est = s.position + self._err.error
            return VehicleSnapshot(
                self.time_s, p_est, s.velocity.copy(), s.yaw, self._to_world_enu(p_est)
            )

    def estimation_error(self) -> np.ndarray:
        """Current estimate minus truth (NED, m)."""
        with self._lock:
            return self._err.error.copy()

    def estimation_std(self) -> np.ndarray:
        """Current per-axis standard deviation of the estimation error (NED, m)."""
        with self._lock:
            return self._err.std.copy()

    @property
    def landed_state(self) -> int:
        """MAV_LANDED_STATE of the vehicle."""
        s = self._model.state
        if s.on_ground or not self.armed:
            return _M.MAV_LANDED_STATE_ON_GROUND if s.on_ground else _M.MAV_LANDED_STATE_IN_AIR
        if self.mode is Px4Mode.AUTO_TAKEOFF:
            return _M.MAV_LANDED_STATE_TAKEOFF
        if self.mode is Px4Mode.AUTO_LAND:
            return _M.MAV_LANDED_STATE_LANDING
        return _M.MAV_LANDED_STATE_IN_AIR

    @property
    def last_setpoint_time_s(self) -> float | None:
        """Sim time of the last offboard setpoint received (None if none yet)."""
        return self._last_sp_t

    @property
    def failsafe_active(self) -> bool:
        """True while an offboard-loss failsafe is in progress (hold, then land)."""
        return self._failsafe_t is not None

    # ------------------------------------------------------------------ Python command API

    def arm(self, force: bool = False) -> int:
        """Arm (MAV_CMD_COMPONENT_ARM_DISARM); returns a MAV_RESULT."""
        return self.handle_command(
            _M.MAV_CMD_COMPONENT_ARM_DISARM, [1.0, _FORCE_MAGIC if force else 0.0]
        )

    def disarm(self, force: bool = False) -> int:
        """Disarm; refused in the air unless forced. Returns a MAV_RESULT."""
        return self.handle_command(
            _M.MAV_CMD_COMPONENT_ARM_DISARM, [0.0, _FORCE_MAGIC if force else 0.0]
        )

    def set_mode(self, mode: Px4Mode) -> int:
        """MAV_CMD_DO_SET_MODE with PX4 main/sub mode. Returns a MAV_RESULT."""
        return self.handle_command(
            _M.MAV_CMD_DO_SET_MODE,
            [_M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mode.main_mode, mode.sub_mode],
        )

    def takeoff(self, altitude_m: float | None = None) -> int:
        """MAV_CMD_NAV_TAKEOFF to ``altitude_m`` above home (default MIS_TAKEOFF_ALT)."""
        amsl = math.nan if altitude_m is None else self.params.home_alt_m + altitude_m
        return self.handle_command(_M.MAV_CMD_NAV_TAKEOFF, [math.nan] * 6 + [amsl])

    def land(self) -> int:
        """MAV_CMD_NAV_LAND at the current position."""
        return self.handle_command(_M.MAV_CMD_NAV_LAND, [math.nan] * 7)

    def hold(self) -> int:
        """Switch to Hold (AUTO_LOITER)."""
        return self.set_mode(Px4Mode.AUTO_LOITER)

    def set_position_target(self, setpoint: Setpoint) -> None:
        """Inject an offboard setpoint as if a SET_POSITION_TARGET_LOCAL_NED had arrived now."""
        with self._lock:
            self._on_offboard_setpoint(setpoint)

    def inject_message(self, msg: Any) -> None:
        """Process a decoded pymavlink message as if it had been received (any clock)."""
        with self._lock:
            self._on_message(msg)

    def handle_command(self, command: int, params: Sequence[float]) -> int:
        """Execute a MAV_CMD with up to 7 params (missing ones are NaN); returns MAV_RESULT."""
        pr = [float(x) for x in params] + [math.nan] * (7 - len(params))
        with self._lock:
            return self._handle_command(int(command), pr)[0]

    # ------------------------------------------------------------------ simulated clock

    def step(self, dt: float) -> None:
        """Advance the simulated clock by ``dt`` seconds (whole physics steps), no networking."""
        self._check_sim_clock()
        with self._lock:
            self._advance_to(self.time_s + dt)

    def run_for(
        self,
        seconds: float,
        setpoint_fn: Callable[[float], Setpoint] | None = None,
        setpoint_rate_hz: float = 20.0,
    ) -> None:
        """Advance the simulated clock by ``seconds``.

        If ``setpoint_fn`` is given it is called with the sim time at ``setpoint_rate_hz`` and its
        result injected as an offboard setpoint (like a companion streaming setpoints).
        """
        self._check_sim_clock()
        end = self.time_s + seconds
        with self._lock:
            if setpoint_fn is None:
                self._advance_to(end)
                return
            period = 1.0 / setpoint_rate_hz
            half = 0.5 * self._dt  # same whole-step criterion as _advance_to
            next_sp = self.time_s
            while self.time_s + half <= end:
                while self.time_s + half >= next_sp:
                    self._on_offboard_setpoint(setpoint_fn(self.time_s))
                    next_sp += period
                self._advance_to(min(end, next_sp))

    def _check_sim_clock(self) -> None:
        if self.running:
            raise RuntimeError("step()/run_for() are not available while the real-time loop runs")

    # ------------------------------------------------------------------ real time + network

    def start(self) -> SimVehicle:
        """Bind the UDP socket on 127.0.0.1 and start the real-time loop in a thread."""
        if self.running:
            return self
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.bind((LOOPBACK, self.bind_port))
        self._sock.setblocking(False)
        self._peers = [(LOOPBACK, self.port)]
        self._next_send = {mid: self.time_s for mid in self._rates}
        self._stop_evt.clear()
        self._thread = threading.Thread(target=self._loop, name="SimVehicle", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the real-time loop and close the socket."""
        self._stop_evt.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        self._thread = None
        if self._sock is not None:
            self._sock.close()
        self._sock = None

    def __enter__(self) -> SimVehicle:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _loop(self) -> None:
        tick = 0.005
        wall0 = time.monotonic()
        sim0 = self.time_s
        next_tick = wall0
        try:
            while not self._stop_evt.is_set():
                timeout = max(0.0, next_tick - time.monotonic())
                ready, _, _ = select.select([self._sock], [], [], timeout)
                if ready:
                    self._drain_socket()
                now = time.monotonic()
                if now >= next_tick:
                    with self._lock:
                        # Catch up at most 0.2 s per tick if the process was stalled.
                        target = sim0 + (now - wall0)
                        if target - self.time_s > 0.2:
                            sim0 += target - self.time_s - 0.2
                            target = sim0 + (now - wall0)
                        self._advance_to(target)
                        self._send_due_telemetry()
                    next_tick += tick
                    if next_tick < now:
                        next_tick = now + tick
        except BaseException as exc:  # pragma: no cover - surfaced to tests via thread_error
            self.thread_error = exc
            raise

    def _drain_socket(self) -> None:
        assert self._sock is not None
        while True:
            try:
                data, addr = self._sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                return
            except ConnectionRefusedError:
                continue  # ICMP "port unreachable" from an earlier send: nobody listens yet
            except OSError:
                return
            if addr[0] != LOOPBACK or self.link_blocked:
                continue
            if addr not in self._peers:
                self._peers.append(addr)
            with self._lock:
                try:
                    msgs = self._mav.parse_buffer(data) or []
                except Exception:  # noqa: BLE001 - malformed datagram: ignore like PX4
                    continue
                for msg in msgs:
                    self._on_message(msg)

    def _send_bytes(self, buf: bytes) -> None:
        if self._sock is None or self.link_blocked:
            return
        for addr in self._peers:
            try:
                self._sock.sendto(buf, addr)
            except OSError:
                pass

    def _send(self, msg: Any) -> None:
        if self._sock is not None:
            self._mav.send(msg)

    # ------------------------------------------------------------------ MAVLink input

    def _on_message(self, msg: Any) -> None:
        mtype = msg.get_type()
        if mtype == "BAD_DATA":
            return
        self.received_message_counts[mtype] = self.received_message_counts.get(mtype, 0) + 1
        if mtype == "COMMAND_LONG":
            if self._for_me(msg.target_system, msg.target_component):
                pr = [
                    msg.param1,
                    msg.param2,
                    msg.param3,
                    msg.param4,
                    msg.param5,
                    msg.param6,
                    msg.param7,
                ]
                self._command_from_mavlink(msg, msg.command, pr)
        elif mtype == "COMMAND_INT":
            if self._for_me(msg.target_system, msg.target_component):
                # x, y are degE7 in global frames; passed through scaled, z as is.
                pr = [
                    msg.param1,
                    msg.param2,
                    msg.param3,
                    msg.param4,
                    msg.x * 1e-7,
                    msg.y * 1e-7,
                    msg.z,
                ]
                self._command_from_mavlink(msg, msg.command, pr)
        elif mtype == "SET_POSITION_TARGET_LOCAL_NED":
            if self._for_me(msg.target_system, msg.target_component):
                sp = self._decode_local_target(msg)
                if sp is not None:
                    self._on_offboard_setpoint(sp)
        elif mtype == "PARAM_REQUEST_READ":
            if self._for_me(msg.target_system, msg.target_component):
                self._on_param_request_read(msg)
        elif mtype == "PARAM_REQUEST_LIST":
            if self._for_me(msg.target_system, msg.target_component):
                for i, name in enumerate(self._param_names()):
                    self._send_param(name, i)
        elif mtype == "PARAM_SET":
            if self._for_me(msg.target_system, msg.target_component):
                self._on_param_set(msg)
        elif mtype == "PING":
            if msg.target_system == 0 and msg.target_component == 0:
                # Ping protocol: answer a ping request addressed to everybody.
                self._send(
                    self._mav.ping_encode(
                        msg.time_usec, msg.seq, msg.get_srcSystem(), msg.get_srcComponent()
                    )
                )
        elif mtype == "TIMESYNC":
            if msg.tc1 == 0:
                self._send(self._mav.timesync_encode(int(self.time_s * 1e9) + 1, msg.ts1))

    def _for_me(self, target_system: int, target_component: int) -> bool:
        return target_system in (0, self.params.system_id) and target_component in (
            0,
            self.params.component_id,
        )

    def _command_from_mavlink(self, msg: Any, command: int, pr: list[float]) -> None:
        self.received_commands.append(int(command))
        result, after = self._handle_command(int(command), pr)
        self._send(
            self._mav.command_ack_encode(
                command,
                result,
                0,
                0,
                msg.get_srcSystem(),
                msg.get_srcComponent(),
            )
        )
        if after is not None:
            after()

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
            c, s = math.cos(self._model.state.yaw), math.sin(self._model.state.yaw)
            rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
            est = self._model.state.position + self._err.error
            pos = est + rot @ pos
            vel = rot @ vel
            acc = rot @ acc
        return Setpoint(position=pos, velocity=vel, acceleration=acc, yaw=yaw, yaw_rate=yaw_rate)

    # ------------------------------------------------------------------ parameters

    def _param_names(self) -> list[str]:
        return sorted(set(_PARAM_FIELDS) | set(_PARAM_CONSTANTS))

    def _send_param(self, name: str, index: int) -> None:
        names = self._param_names()
        if name in _PARAM_FIELDS:
            value, ptype = self._live[name], _PARAM_FIELDS[name][1]
        else:
            value, ptype = _PARAM_CONSTANTS[name]
        if ptype == _M.MAV_PARAM_TYPE_INT32:
            # PX4 uses byte-wise encoding: the int32 bits travel in the float field.
            wire = struct.unpack("<f", struct.pack("<i", int(value)))[0]
        else:
            wire = float(value)
        self._send(self._mav.param_value_encode(name.encode(), wire, ptype, len(names), index))

    def _on_param_request_read(self, msg: Any) -> None:
        names = self._param_names()
        name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode()
        name = name.rstrip("\x00")
        if msg.param_index >= 0:
            if msg.param_index < len(names):
                self._send_param(names[msg.param_index], msg.param_index)
        elif name in names:
            self._send_param(name, names.index(name))

    def _on_param_set(self, msg: Any) -> None:
        names = self._param_names()
        name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode()
        name = name.rstrip("\x00")
        if name not in names:
            return
        if name in _PARAM_FIELDS:
            self._live[name] = float(msg.param_value)
        self._send_param(name, names.index(name))

    # ------------------------------------------------------------------ commander

    def _event(self, text: str, severity: int = _M.MAV_SEVERITY_INFO) -> None:
        self.events.append((self.time_s, text))
        self._send(self._mav.statustext_encode(severity, text.encode()[:50]))

    def _stream_ok(self) -> bool:
        """PX4 offboard availability: setpoints > offboard_min_rate_hz for min_stream_s."""
        if self._last_sp_t is None or self._stream_start_t is None:
            return False
        t = self.time_s
        fresh = t - self._last_sp_t <= 1.0 / self.params.offboard_min_rate_hz
        long_enough = t - self._stream_start_t >= self.params.offboard_min_stream_s - 1e-9
        return fresh and long_enough

    def _on_offboard_setpoint(self, sp: Setpoint) -> None:
        t = self.time_s
        gap_max = 1.0 / self.params.offboard_min_rate_hz
        if self._last_sp_t is None or t - self._last_sp_t > gap_max:
            self._stream_start_t = t  # stream (re)starts
        self._last_sp_t = t
        self.setpoints_received += 1
        has_any = np.isfinite(np.concatenate((sp.position, sp.velocity, sp.acceleration))).any()
        if has_any or self._offboard_sp is None:
            self._offboard_sp = sp

    def _handle_command(self, cmd: int, pr: list[float]) -> tuple[int, Callable[[], None] | None]:
        """Returns (MAV_RESULT, optional action to run after the ACK was sent)."""
        acc, rej = _M.MAV_RESULT_ACCEPTED, _M.MAV_RESULT_TEMPORARILY_REJECTED
        if cmd == _M.MAV_CMD_COMPONENT_ARM_DISARM:
            force = int(round(pr[1])) == _FORCE_MAGIC if math.isfinite(pr[1]) else False
            return (self._do_arm(force) if pr[0] > 0.5 else self._do_disarm(force)), None
        if cmd == _M.MAV_CMD_DO_SET_MODE:
            if not int(pr[0]) & _M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
                return _M.MAV_RESULT_UNSUPPORTED, None
            mode = Px4Mode.from_main_sub(int(pr[1]), int(pr[2]) if math.isfinite(pr[2]) else 0)
            if mode is None:
                return _M.MAV_RESULT_UNSUPPORTED, None
            return (acc if self._request_mode(mode) else rej), None
        if cmd == _M.MAV_CMD_NAV_TAKEOFF:
            alt = pr[6] - self.params.home_alt_m if math.isfinite(pr[6]) else None
            return (acc if self._start_takeoff(alt) else rej), None
        if cmd == _M.MAV_CMD_NAV_LAND:
            return (acc if self._request_mode(Px4Mode.AUTO_LAND) else rej), None
        if cmd == _M.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return (acc if self._request_mode(Px4Mode.AUTO_RTL) else rej), None
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

    def _do_arm(self, force: bool) -> int:
        if self.armed:
            return _M.MAV_RESULT_ACCEPTED
        if self.crashed and not force:
            self._event("Arming denied: vehicle crashed", _M.MAV_SEVERITY_CRITICAL)
            return _M.MAV_RESULT_TEMPORARILY_REJECTED
        if self.mode is Px4Mode.OFFBOARD and not self._stream_ok() and not force:
            self._event("Arming denied: no offboard setpoints", _M.MAV_SEVERITY_CRITICAL)
            return _M.MAV_RESULT_TEMPORARILY_REJECTED
        if self.mode in (Px4Mode.AUTO_LAND, Px4Mode.AUTO_RTL) and not force:
            return _M.MAV_RESULT_TEMPORARILY_REJECTED
        self.armed = True
        self._armed_t = self.time_s
        self._took_off = not self._model.state.on_ground
        self._ground_since = self.time_s if self._model.state.on_ground else None
        self._ctrl.reset()
        if self.mode is Px4Mode.AUTO_LOITER:
            self._hold_sp = None  # re-latched at the current position on the next step
        self._event("Armed by external command")
        return _M.MAV_RESULT_ACCEPTED

    def _do_disarm(self, force: bool) -> int:
        if not self.armed:
            return _M.MAV_RESULT_ACCEPTED
        if not self._model.state.on_ground and not force:
            self._event("Disarming denied: not landed", _M.MAV_SEVERITY_CRITICAL)
            return _M.MAV_RESULT_TEMPORARILY_REJECTED
        self._disarm("Disarmed by external command")
        return _M.MAV_RESULT_ACCEPTED

    def _disarm(self, text: str) -> None:
        self.armed = False
        self._failsafe_t = None
        self._ctrl.reset()
        if self.mode in (Px4Mode.AUTO_LAND, Px4Mode.AUTO_TAKEOFF, Px4Mode.AUTO_RTL):
            self.mode = Px4Mode.AUTO_LOITER
        self._hold_sp = None
        self._event(text)

    def _request_mode(self, mode: Px4Mode) -> bool:
        if self.crashed:
            return False
        if mode in _MANUAL_MODES:
            return False  # no RC / manual control input emulated (COM_RC_IN_MODE = 4)
        if mode in (Px4Mode.AUTO_MISSION, Px4Mode.AUTO_READY):
            return False  # no mission support
        if mode is Px4Mode.OFFBOARD:
            # PX4 docs "Offboard Mode": the vehicle must already receive a setpoint stream
            # (> 2 Hz) before the mode can be engaged; PX4 answers TEMPORARILY_REJECTED.
            if not self._stream_ok():
                self._event(
                    "Switching to Offboard is currently not available", _M.MAV_SEVERITY_CRITICAL
                )
                return False
        if mode is Px4Mode.AUTO_TAKEOFF:
            return self._start_takeoff(None)
        if mode in (Px4Mode.AUTO_LAND, Px4Mode.AUTO_RTL) and not self.armed:
            return False
        self._enter_mode(mode)
        self._failsafe_t = None  # an explicit mode change ends a failsafe (user override)
        return True

    def _enter_mode(self, mode: Px4Mode) -> None:
        if mode is not self.mode:
            self._event(f"Mode {mode.name}")
        self.mode = mode
        # Hold latches the braking point and RTL its target on the next step.
        self._hold_sp = None
        if mode is Px4Mode.AUTO_LAND:
            est = self._model.state.position + self._err.error
            self._hold_sp = Setpoint(
                position=np.array([est[0], est[1], math.nan]),
                velocity=np.array([0.0, 0.0, self._live["MPC_LAND_SPEED"]]),
                acceleration=np.zeros(3),
            )

    def _start_takeoff(self, altitude_m: float | None) -> bool:
        if not self.armed or self.crashed:
            return False
        alt = self._live["MIS_TAKEOFF_ALT"] if altitude_m is None else altitude_m
        est = self._model.state.position + self._err.error
        self._takeoff_z = -abs(alt)
        self._hold_sp = Setpoint.hold(np.array([est[0], est[1], self._takeoff_z]))
        self._failsafe_t = None
        if self.mode is not Px4Mode.AUTO_TAKEOFF:
            self._event("Mode AUTO_TAKEOFF")
        self.mode = Px4Mode.AUTO_TAKEOFF
        return True

    def _braking_hold(self) -> Setpoint:
        s = self._model.state
        est = s.position + self._err.error
        speed = float(np.linalg.norm(s.velocity))
        stop = est + s.velocity * speed / (2.0 * self.params.brake_acc_m_s2)
        if s.on_ground:
            stop[2] = max(stop[2], s.position[2] + self._err.error[2])
        return Setpoint.hold(stop, yaw=s.yaw)

    def _update_commander(self) -> None:
        """Mode logic evaluated every physics step (before the controller)."""
        t = self.time_s
        s = self._model.state
        if not self.armed:
            return
        # Offboard loss failsafe: PX4 docs "Offboard Mode" (COM_OF_LOSS_T) and "Safety" >
        # "Failsafe Actions": Hold for COM_FAIL_ACT_T seconds, then the action (Land).
        if self.mode is Px4Mode.OFFBOARD:
            if self._last_sp_t is None or t - self._last_sp_t > self._live["COM_OF_LOSS_T"]:
                self._event("Failsafe activated: no offboard", _M.MAV_SEVERITY_CRITICAL)
                self._enter_mode(Px4Mode.AUTO_LOITER)
                self._failsafe_t = t
        if self._failsafe_t is not None and self.mode is Px4Mode.AUTO_LOITER:
            if t - self._failsafe_t >= self._live["COM_FAIL_ACT_T"]:
                self._event("Failsafe action: Land", _M.MAV_SEVERITY_CRITICAL)
                self._enter_mode(Px4Mode.AUTO_LAND)
        # Takeoff complete -> Hold.
        if self.mode is Px4Mode.AUTO_TAKEOFF:
            est_z = s.position[2] + self._err.error[2]
            if abs(est_z - self._takeoff_z) < self.params.takeoff_accept_m:
                self._enter_mode(Px4Mode.AUTO_LOITER)
        # RTL: above home at the current altitude, then land.
        if self.mode is Px4Mode.AUTO_RTL:
            est = s.position + self._err.error
            if self._hold_sp is None:
                self._hold_sp = Setpoint.hold(np.array([0.0, 0.0, min(est[2], -1.0)]))
            if float(np.hypot(est[0], est[1])) < 0.5 and float(np.linalg.norm(s.velocity)) < 0.5:
                self._enter_mode(Px4Mode.AUTO_LAND)
        # Ground / auto-disarm logic (COM_DISARM_LAND, COM_DISARM_PRFLT).
        if s.on_ground:
            if self._ground_since is None:
                self._ground_since = t
                if self._took_off:
                    self._event("Landing detected")
            on_ground_for = t - self._ground_since
            land_t = self._live["COM_DISARM_LAND"]
            prflt_t = self._live["COM_DISARM_PRFLT"]
            if (self._took_off or self.mode is Px4Mode.AUTO_LAND) and land_t > 0.0:
                if on_ground_for >= land_t:
                    self._disarm("Disarmed by landing")
                    return
            elif not self._took_off and prflt_t > 0.0 and t - self._armed_t >= prflt_t:
                self._disarm("Disarmed by auto preflight disarming")
                return
        else:
            self._ground_since = None
            self._took_off = True

    def _current_setpoint(self) -> tuple[Setpoint | None, dict[str, float]]:
        """Setpoint for the controller in the current mode (None: idle / motors stopped)."""
        s = self._model.state
        if self.mode is Px4Mode.OFFBOARD:
            return self._offboard_sp, {}
        if self.mode is Px4Mode.AUTO_TAKEOFF:
            return self._hold_sp, {"vel_max_up_m_s": self._live["MPC_TKO_SPEED"]}
        if self.mode is Px4Mode.AUTO_LAND:
            if s.on_ground:
                return None, {}
            return self._hold_sp, {"vel_max_down_m_s": self._live["MPC_LAND_SPEED"]}
        if self.mode is Px4Mode.AUTO_RTL:
            return self._hold_sp, {"vel_max_xy_m_s": self._live["MPC_XY_CRUISE"]}
        # Hold: idle on the ground, otherwise hold the braking point.
        if s.on_ground:
            return None, {}
        if self._hold_sp is None:
            self._hold_sp = self._braking_hold()
        return self._hold_sp, {"vel_max_xy_m_s": self._live["MPC_XY_CRUISE"]}

    # ------------------------------------------------------------------ physics

    def _advance_to(self, t_end: float) -> None:
        """Run whole physics steps until the sim time reaches ``t_end`` (chunked collisions)."""
        chunk_positions: list[np.ndarray] = []
        chunk_steps: list[int] = []
        while self.time_s + 0.5 * self._dt <= t_end:
            self._physics_step()
            if self.world is not None and not self.crashed and self._collision_relevant():
                chunk_positions.append(self._model.state.position.copy())
                chunk_steps.append(self._steps)
            if len(chunk_positions) >= 25:
                self._check_collisions(chunk_positions, chunk_steps)
                chunk_positions, chunk_steps = [], []
        if chunk_positions:
            self._check_collisions(chunk_positions, chunk_steps)

    def _collision_relevant(self) -> bool:
        s = self._model.state
        if s.on_ground:
            return False
        min_alt = self.params.collision_min_alt_m
        if min_alt is None:
            min_alt = float(getattr(self.world, "robot_radius", 0.0))
        return -(s.position[2] - self.quad_params.ground_z_ned) >= min_alt

    def _to_world_enu(self, p_ned: np.ndarray) -> np.ndarray:
        return ned_to_enu(p_ned) + np.asarray(self.params.home_enu_m, dtype=float)

    def _check_collisions(self, positions: list[np.ndarray], steps: list[int]) -> None:
        assert self.world is not None
        ned = np.asarray(positions)
        enu = self._to_world_enu(ned)
        d = np.asarray(self.world.signed_distance(enu), dtype=float).reshape(-1)
        hit = np.nonzero(d < float(self.world.robot_radius))[0]
        if hit.size == 0:
            return
        k = int(hit[0])
        col = Collision(steps[k] * self._dt, enu[k].copy(), ned[k].copy(), float(d[k]))
        self.collisions.append(col)
        # End of flight: freeze at the collision point, disarm, refuse to re-arm.
        s = self._model.state
        s.position = ned[k].copy()
        s.velocity = np.zeros(3)
        s.acceleration = np.zeros(3)
        s.thrust = np.zeros(3)
        self.crashed = True
        self.armed = False
        self._failsafe_t = None
        self._event(
            f"Collision at t={col.time_s:.2f}s ENU=({enu[k][0]:.1f},{enu[k][1]:.1f},"
            f"{enu[k][2]:.1f})",
            _M.MAV_SEVERITY_EMERGENCY,
        )

    def _physics_step(self) -> None:
        dt = self._dt
        s = self._model.state
        self._update_commander()
        thrust_cmd = np.zeros(3)
        yaw_rate = 0.0
        sp: Setpoint | None = None
        if self.armed and not self.crashed:
            sp, limits = self._current_setpoint()
            if sp is None:
                # Idle (spinning, not lifting): minimum thrust straight up.
                c = self.controller_params
                thrust_cmd = np.array([0.0, 0.0, -c.thr_min * self.quad_params.gravity_m_s2])
                thrust_cmd /= c.thr_hover
                self._ctrl.reset()
            else:
                est = s.position + self._err.error
                thrust_cmd = self._ctrl.update(dt, est, s.velocity, s.acceleration, sp, **limits)
                yaw_rate = self._ctrl.yaw_rate_command(s.yaw, sp)
                if s.on_ground:
                    self._ctrl.reset()
            self._battery_used_s += dt
        if self.crashed:
            self._steps += 1
        else:
            self._model.step(dt, thrust_cmd, yaw_rate)
            self._steps += 1
            self._err.step(dt, self._model.state.velocity)
        self._active_sp = sp if sp is not None else Setpoint()
        if self._record and self._steps % self._decim == 0:
            h = self.history
            h.time_s.append(self.time_s)
            h.true_position_ned.append(self._model.state.position.copy())
            h.estimated_position_ned.append(self._model.state.position + self._err.error)
            h.velocity_ned.append(self._model.state.velocity.copy())
            h.error_std_m.append(self._err.std.copy())
            h.setpoint_position_ned.append(self._active_sp.position.copy())
            h.mode.append(self.mode.name)

    # ------------------------------------------------------------------ telemetry

    def _single_message_sender(self, msg_id: int) -> Callable[[], None] | None:
        senders: dict[int, Callable[[], None]] = {
            _M.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self._send_autopilot_version,
            _M.MAVLINK_MSG_ID_HOME_POSITION: self._send_home_position,
        }
        if msg_id in senders:
            return senders[msg_id]
        if msg_id in self._stream_senders():
            fn = self._stream_senders()[msg_id]
            return fn
        return None

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
        self._rates[msg_id] = rate
        self._next_send[msg_id] = self.time_s
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
        }

    def _send_due_telemetry(self) -> None:
        t = self.time_s
        senders = self._stream_senders()
        state = (self.armed, self.mode, self.landed_state, self.crashed)
        if state != self._last_reported_state:
            # Deviation from PX4 (1 Hz heartbeat only): report arming/mode/landed changes at
            # once so that clients see them without up to 1 s of extra latency.
            self._last_reported_state = state
            self._send_heartbeat()
            self._send_extended_sys_state()
        for msg_id, rate in self._rates.items():
            if rate <= 0.0:
                continue
            if t + 1e-9 >= self._next_send.get(msg_id, t):
                senders[msg_id]()
                nxt = self._next_send.get(msg_id, t) + 1.0 / rate
                self._next_send[msg_id] = nxt if nxt > t else t + 1.0 / rate

    def _time_boot_ms(self) -> int:
        return int(self.time_s * 1000.0) & 0xFFFFFFFF

    def _base_mode(self) -> int:
        flags = _M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | _M.MAV_MODE_FLAG_STABILIZE_ENABLED
        if self.armed:
            flags |= _M.MAV_MODE_FLAG_SAFETY_ARMED
        if self.mode.main_mode == 4:
            flags |= _M.MAV_MODE_FLAG_AUTO_ENABLED | _M.MAV_MODE_FLAG_GUIDED_ENABLED
        elif self.mode is Px4Mode.OFFBOARD:
            flags |= _M.MAV_MODE_FLAG_GUIDED_ENABLED
        return flags

    def _send_heartbeat(self) -> None:
        if self.crashed:
            status = _M.MAV_STATE_FLIGHT_TERMINATION
        elif self._failsafe_t is not None:
            status = _M.MAV_STATE_CRITICAL
        elif self.armed:
            status = _M.MAV_STATE_ACTIVE
        else:
            status = _M.MAV_STATE_STANDBY
        self._send(
            self._mav.heartbeat_encode(
                _M.MAV_TYPE_QUADROTOR,
                _M.MAV_AUTOPILOT_PX4,
                self._base_mode(),
                self.mode.custom_mode,
                status,
            )
        )

    def _battery(self) -> tuple[float, int, int]:
        """(voltage V, current cA, remaining %)."""
        frac = max(0.0, 1.0 - self._battery_used_s / self.params.battery_flight_time_s)
        cell = 3.5 + 0.7 * frac
        current = 1500 if self.armed else 50
        return cell * self.params.battery_cells, current, int(round(100 * frac))

    def _send_sys_status(self) -> None:
        volt, cur, rem = self._battery()
        health = _HEALTH_BITS
        present = _HEALTH_BITS | _M.MAV_SYS_STATUS_PREARM_CHECK
        if not self.crashed:
            health |= _M.MAV_SYS_STATUS_PREARM_CHECK  # "can arm" (MAVSDK health.is_armable)
        self._send(
            self._mav.sys_status_encode(
                present, present, health, 200, int(volt * 1000), cur, rem, 0, 0, 0, 0, 0, 0
            )
        )

    def _send_extended_sys_state(self) -> None:
        self._send(
            self._mav.extended_sys_state_encode(_M.MAV_VTOL_STATE_UNDEFINED, self.landed_state)
        )

    def _est(self) -> tuple[np.ndarray, np.ndarray]:
        s = self._model.state
        return s.position + self._err.error, s.velocity

    def _send_local_position(self) -> None:
        p, v = self._est()
        self._send(
            self._mav.local_position_ned_encode(
                self._time_boot_ms(), p[0], p[1], p[2], v[0], v[1], v[2]
            )
        )

    def _latlon(self, p: np.ndarray) -> tuple[int, int, float]:
        lat0 = math.radians(self.params.home_lat_deg)
        lat = self.params.home_lat_deg + math.degrees(p[0] / _EARTH_RADIUS_M)
        lon = self.params.home_lon_deg + math.degrees(p[1] / (_EARTH_RADIUS_M * math.cos(lat0)))
        return int(round(lat * 1e7)), int(round(lon * 1e7)), self.params.home_alt_m - p[2]

    def _send_global_position(self) -> None:
        p, v = self._est()
        lat, lon, alt = self._latlon(p)
        hdg = int(round(math.degrees(self._model.state.yaw) % 360.0 * 100)) % 36000
        self._send(
            self._mav.global_position_int_encode(
                self._time_boot_ms(),
                lat,
                lon,
                int(round(alt * 1000)),
                int(round(-p[2] * 1000)),
                int(round(v[0] * 100)),
                int(round(v[1] * 100)),
                int(round(v[2] * 100)),
                hdg,
            )
        )

    def _rotation(self) -> np.ndarray:
        s = self._model.state
        return rotation_from_thrust_yaw(s.thrust, s.yaw, self.quad_params.gravity_m_s2)

    def _send_attitude(self) -> None:
        roll, pitch, yaw = euler_from_rotation(self._rotation())
        self._send(
            self._mav.attitude_encode(
                self._time_boot_ms(), roll, pitch, yaw, 0.0, 0.0, self._model.state.yaw_rate
            )
        )

    def _send_attitude_quaternion(self) -> None:
        q = quaternion_from_rotation(self._rotation())
        self._send(
            self._mav.attitude_quaternion_encode(
                self._time_boot_ms(), q[0], q[1], q[2], q[3], 0.0, 0.0, self._model.state.yaw_rate
            )
        )

    def _send_odometry(self) -> None:
        p, v = self._est()
        r = self._rotation()
        q = quaternion_from_rotation(r)
        v_body = r.T @ v  # PX4 sends the ODOMETRY velocity in the body (FRD) frame
        var = self._err.std**2
        # Upper-right triangle of the 6x6 pose covariance (x, y, z, roll, pitch, yaw), row-major.
        pose_cov = [0.0] * 21
        pose_cov[0], pose_cov[6], pose_cov[11] = var[0], var[1], var[2]
        pose_cov[15] = pose_cov[18] = pose_cov[20] = 1e-4
        vel_cov = [0.0] * 21
        vel_cov[0] = vel_cov[6] = vel_cov[11] = 1e-4
        vel_cov[15] = vel_cov[18] = vel_cov[20] = 1e-4
        self._send(
            self._mav.odometry_encode(
                int(self.time_s * 1e6),
                _M.MAV_FRAME_LOCAL_NED,
                _M.MAV_FRAME_BODY_FRD,
                p[0],
                p[1],
                p[2],
                list(q),
                v_body[0],
                v_body[1],
                v_body[2],
                0.0,
                0.0,
                self._model.state.yaw_rate,
                pose_cov,
                vel_cov,
                0,
                _M.MAV_ESTIMATOR_TYPE_AUTOPILOT,
                100,
            )
        )

    def _send_estimator_status(self) -> None:
        std = self._err.std
        flags = (
            _M.ESTIMATOR_ATTITUDE
            | _M.ESTIMATOR_VELOCITY_HORIZ
            | _M.ESTIMATOR_VELOCITY_VERT
            | _M.ESTIMATOR_POS_HORIZ_REL
            | _M.ESTIMATOR_POS_HORIZ_ABS
            | _M.ESTIMATOR_POS_VERT_ABS
            | _M.ESTIMATOR_PRED_POS_HORIZ_REL
            | _M.ESTIMATOR_PRED_POS_HORIZ_ABS
        )
        self._send(
            self._mav.estimator_status_encode(
                int(self.time_s * 1e6),
                flags,
                0.1,
                0.1,
                0.1,
                0.1,
                0.0,
                0.0,
                float(math.hypot(std[0], std[1])),
                float(std[2]),
            )
        )

    def _send_gps_raw(self) -> None:
        p, v = self._est()
        lat, lon, alt = self._latlon(p)
        vel = int(round(math.hypot(v[0], v[1]) * 100))
        cog = int(round(math.degrees(math.atan2(v[1], v[0])) % 360.0 * 100)) % 36000
        self._send(
            self._mav.gps_raw_int_encode(
                int(self.time_s * 1e6),
                _M.GPS_FIX_TYPE_3D_FIX,
                lat,
                lon,
                int(round(alt * 1000)),
                80,
                120,
                vel,
                cog,
                12,
            )
        )

    def _send_battery_status(self) -> None:
        volt, cur, rem = self._battery()
        cell_mv = int(volt * 1000 / self.params.battery_cells)
        cells = [cell_mv] * self.params.battery_cells + [0xFFFF] * (10 - self.params.battery_cells)
        used_mah = int(self._battery_used_s / 3600.0 * 15000)
        self._send(
            self._mav.battery_status_encode(
                0,
                _M.MAV_BATTERY_FUNCTION_ALL,
                _M.MAV_BATTERY_TYPE_LIPO,
                0x7FFF,
                cells,
                cur,
                used_mah,
                -1,
                rem,
            )
        )

    def _send_home_position(self) -> None:
        p = self.params
        self._send(
            self._mav.home_position_encode(
                int(round(p.home_lat_deg * 1e7)),
                int(round(p.home_lon_deg * 1e7)),
                int(round(p.home_alt_m * 1000)),
                0.0,
                0.0,
                0.0,
                [1.0, 0.0, 0.0, 0.0],
                0.0,
                0.0,
                0.0,
                int(self.time_s * 1e6),
            )
        )

    def _send_system_time(self) -> None:
        self._send(self._mav.system_time_encode(int(time.time() * 1e6), self._time_boot_ms()))

    def _send_autopilot_version(self) -> None:
        major, minor, patch = self.params.flight_sw_version
        caps = (
            _M.MAV_PROTOCOL_CAPABILITY_MAVLINK2
            | _M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
            | _M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
            | _M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
        )
        # PX4 encodes versions as major<<24 | minor<<16 | patch<<8 | type (255 = release).
        sw = (major << 24) | (minor << 16) | (patch << 8) | 255
        self._send(
            self._mav.autopilot_version_encode(
                caps,
                sw,
                sw,
                0,
                0,
                [0] * 8,
                [0] * 8,
                [0] * 8,
                0,
                0,
                0x5349_4D00_0000_0000 | (self.seed & 0xFFFF),
            )
        )
