"""Simulated PX4-compatible multicopter speaking MAVLink 2 over UDP loopback.

``SimVehicle`` is the vehicle: it couples the point-mass model and cascaded controller of
:mod:`sitl.dynamics`, the estimation error of :mod:`sitl.estimation` and an optional world
(for collision checks) with the commander of :mod:`sitl.commander` (modes, failsafes) and the
MAVLink endpoint of :mod:`sitl.mavlink_link`. Unmodified MAVSDK 4.x connects to it as to PX4 on
its onboard (companion) link:

* the vehicle sends from ``127.0.0.1:<bind_port>`` to ``127.0.0.1:<port>`` (default 14540, so
  MAVSDK uses ``udpin://127.0.0.1:14540``) and answers every loopback peer that talks to it;
* a second endpoint like PX4's GCS link (:attr:`SimVehicle.gcs_port`, any free port) sends the
  same telemetry, at rates of its own, to whoever talks to it (a passive observer:
  :mod:`sitl.observer`); a link loss (:attr:`SimVehicle.link_blocked`) leaves it alone;
* two clocks: real time in a background thread (``with SimVehicle(...) as sim:`` or
  :meth:`SimVehicle.start`) for MAVSDK, or a simulated clock without any networking
  (:meth:`SimVehicle.step` / :meth:`SimVehicle.run_for`) for fast, deterministic experiments.

What PX4 behaviour is emulated (and what is not) is documented in docs/sitl.md. Frames: the
vehicle's local frame is NED with its origin at home; a world object is queried in ENU metres
(x east, y north, z up), with home at ``VehicleParams.home_enu_m``.
"""

from __future__ import annotations

import math
import select
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.frames import enu_to_ned, ned_to_enu
from sitl.commander import FORCE_MAGIC, Commander, Px4Mode
from sitl.dynamics import (
    PX4_SIH_QUAD,
    ControllerParams,
    PositionController,
    QuadrotorModel,
    QuadrotorParams,
    QuadState,
    Setpoint,
    rotation_from_thrust_yaw,
)
from sitl.estimation import PX4_SIH_ESTIMATION, EstimationErrorParams, PositionErrorModel
from sitl.mavlink_link import LOOPBACK, MavlinkLink
from sitl.params import PX4_CONSTANTS, VehicleParams

__all__ = ["DEFAULT_COMPANION_PORT", "LOOPBACK", "Collision", "History", "Px4Mode",
           "SimVehicle", "VehicleParams", "VehicleSnapshot", "World", "enu_to_ned",
           "ned_to_enu", "setpoint_arrays"]

DEFAULT_COMPANION_PORT = 14540
_M = mavlink2


class World(Protocol):
    """What the vehicle needs from a world: ENU signed distances and the robot radius."""

    robot_radius: float

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance (m) of ``(n, 3)`` ENU points to the nearest obstacle (<=0: inside)."""
        ...


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


def setpoint_arrays(log: list[tuple[Any, ...]]) -> dict[str, np.ndarray]:
    """:attr:`SimVehicle.setpoint_log` as arrays: ``wall_time`` (host monotonic s),
    ``time_s`` (sim), ``position_ned``, ``velocity_ned``, ``acceleration_ned`` (n, 3;
    NaN where the type mask ignores a field), ``mode`` (at arrival), ``sent_s``
    (the message's time_boot_ms in seconds: when the sender sent it, on its clock) and
    ``yaw_ned_rad`` (NaN if not set)."""
    rows = np.asarray([r[:11] for r in log], dtype=float).reshape(-1, 11)
    return {"wall_time": rows[:, 0], "time_s": rows[:, 1], "position_ned": rows[:, 2:5],
            "velocity_ned": rows[:, 5:8], "acceleration_ned": rows[:, 8:11],
            "mode": np.asarray([r[11] for r in log], dtype=str),
            "sent_s": np.asarray([r[12] for r in log], dtype=float) / 1e3,
            "yaw_ned_rad": np.asarray([r[13] for r in log], dtype=float)}


class SimVehicle:
    """A simulated PX4 multicopter (see module docstring).

    Args:
        params: commander / MAVLink parameters.
        quad: physical parameters (default: PX4's SIH quadrotor, ``PX4_SIH_QUAD``);
            controller: controller gains and limits (PX4's defaults).
        estimation: estimation error and hover wander (default: PX4's EKF in SIH,
            ``PX4_SIH_ESTIMATION``; ``sitl.estimation.IDEAL`` for none).
        world: optional object with ``signed_distance((n,3) ENU) -> (n,)`` and
            ``robot_radius``; a true position within ``robot_radius`` of an obstacle ends the
            flight (see :attr:`collisions`).
        seed: seed of the estimation-error generator (the only random source).
        port: UDP port of the companion (MAVSDK ``udpin://127.0.0.1:<port>``).
        bind_port: local UDP port of the vehicle (0: any free port; PX4 uses 14580).
        record_history: record true/estimated state every ``history_decimation`` steps, and
            every offboard setpoint received (:attr:`setpoint_log`).
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
        self.quad_params = quad if quad is not None else PX4_SIH_QUAD
        self.controller_params = controller if controller is not None else ControllerParams()
        self.estimation_params = estimation if estimation is not None else PX4_SIH_ESTIMATION
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
        self._err = PositionErrorModel(self.estimation_params, np.random.default_rng(seed),
                                       self._dt)
        self.collisions: list[Collision] = []
        #: every offboard setpoint received while recording: (host monotonic s, sim s,
        #: p, v, a NED (9 floats), mode name, the message's time_boot_ms (the sender's
        #: clock; NaN when injected)), for checks of what the vehicle was sent
        self.setpoint_log: list[tuple[Any, ...]] = []
        self._active_sp = Setpoint()
        self._battery_used_s = 0.0
        self._record = record_history
        self._decim = max(1, int(history_decimation))
        self.history = History()
        self.link = MavlinkLink(self)
        self.gcs_link = MavlinkLink(self)  # like PX4's GCS link: its own peers and rates
        self.commander = Commander(p, self, self._statustext)
        self._thread: threading.Thread | None = None
        self._stop_evt = threading.Event()
        self.thread_error: BaseException | None = None

    # ------------------------------------------------------------------ properties / readout

    @property
    def time_s(self) -> float:
        """Simulation time (s since start)."""
        return self._steps * self._dt

    @property
    def local_port(self) -> int | None:
        """The vehicle's bound UDP port while running, else None."""
        return self.link.local_port

    @property
    def gcs_port(self) -> int | None:
        """The bound UDP port of the GCS-like link while running, else None."""
        return self.gcs_link.local_port

    def _statustext(self, text: str, severity: int) -> None:
        self.link.statustext(text, severity)
        self.gcs_link.statustext(text, severity)

    @property
    def running(self) -> bool:
        """True while the real-time thread runs."""
        return self._thread is not None and self._thread.is_alive()

    @property
    def armed(self) -> bool:
        return self.commander.armed

    @property
    def mode(self) -> Px4Mode:
        return self.commander.mode

    @property
    def crashed(self) -> bool:
        return self.commander.crashed

    @property
    def events(self) -> list[tuple[float, str]]:
        """(sim time, text) of every commander event (also sent as STATUSTEXT)."""
        return self.commander.events

    @property
    def setpoints_received(self) -> int:
        return self.commander.setpoints_received

    @property
    def link_blocked(self) -> bool:
        """Test hook: drop all MAVLink traffic in both directions."""
        return self.link.blocked

    @link_blocked.setter
    def link_blocked(self, value: bool) -> None:
        self.link.blocked = bool(value)

    @property
    def received_message_counts(self) -> dict[str, int]:
        return self.link.received_message_counts

    @property
    def received_commands(self) -> list[int]:
        return self.link.received_commands

    def param(self, name: str) -> float:
        """Current value of a PX4-named parameter (COM_OF_LOSS_T, MIS_TAKEOFF_ALT, ...)."""
        with self._lock:
            if name in self.commander.live:
                return self.commander.live[name]
            return float(PX4_CONSTANTS[name][0])

    def true_state(self) -> VehicleSnapshot:
        """Ground-truth state (what collisions are checked against)."""
        with self._lock:
            s = self._model.state
            return VehicleSnapshot(self.time_s, s.position.copy(), s.velocity.copy(), s.yaw,
                                   self._to_world_enu(s.position))

    def estimated_state(self) -> VehicleSnapshot:
        """The autopilot's estimate (what it flies on and reports over MAVLink)."""
        with self._lock:
            s = self._model.state
            p_est = s.position + self._err.error
            return VehicleSnapshot(self.time_s, p_est, s.velocity.copy(), s.yaw,
                                   self._to_world_enu(p_est))

    def estimation_error(self) -> np.ndarray:
        """Current estimate minus truth (NED, m)."""
        with self._lock:
            return self._err.error.copy()

    def estimation_std(self) -> np.ndarray:
        """Current per-axis standard deviation of the estimation error (NED, m)."""
        with self._lock:
            return self._err.std.copy()

    def reported_std(self) -> np.ndarray:
        """The position uncertainty the vehicle reports (ODOMETRY covariance, NED, m)."""
        return self._err.reported_std.copy()

    @property
    def landed_state(self) -> int:
        """MAV_LANDED_STATE of the vehicle."""
        return self.commander.landed_state()

    @property
    def last_setpoint_time_s(self) -> float | None:
        """Sim time of the last offboard setpoint received (None if none yet)."""
        return self.commander.last_setpoint_time_s

    @property
    def failsafe_active(self) -> bool:
        """True while an offboard-loss failsafe is in progress."""
        return self.commander.failsafe_active

    # -------------------------------------------- what the commander and the link read

    def estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """Estimated position and velocity (NED)."""
        s = self._model.state
        return s.position + self._err.error, s.velocity

    @property
    def on_ground(self) -> bool:
        return self._model.state.on_ground

    @property
    def height_m(self) -> float:
        return self._model.params.ground_z_ned - float(self._model.state.position[2])

    @property
    def yaw(self) -> float:
        return self._model.state.yaw

    def reset_controller(self) -> None:
        self._ctrl.reset()

    def attitude(self) -> tuple[np.ndarray, float, float]:
        """Body-to-NED rotation (from the thrust direction and yaw), yaw and yaw rate."""
        s = self._model.state
        return rotation_from_thrust_yaw(s.thrust, s.yaw, self.quad_params.gravity_m_s2), \
            s.yaw, s.yaw_rate

    @property
    def battery_used_s(self) -> float:
        return self._battery_used_s

    def battery(self) -> tuple[float, int, int]:
        """(voltage V, current cA, remaining %) of a linear battery model."""
        frac = max(0.0, 1.0 - self._battery_used_s / self.params.battery_flight_time_s)
        cell = 3.5 + 0.7 * frac
        current = 1500 if self.armed else 50
        return cell * self.params.battery_cells, current, int(round(100 * frac))

    # ------------------------------------------------------------------ Python command API

    def arm(self, force: bool = False) -> int:
        """Arm (MAV_CMD_COMPONENT_ARM_DISARM); returns a MAV_RESULT."""
        return self.handle_command(_M.MAV_CMD_COMPONENT_ARM_DISARM,
                                   [1.0, FORCE_MAGIC if force else 0.0])

    def disarm(self, force: bool = False) -> int:
        """Disarm; refused in the air unless forced. Returns a MAV_RESULT."""
        return self.handle_command(_M.MAV_CMD_COMPONENT_ARM_DISARM,
                                   [0.0, FORCE_MAGIC if force else 0.0])

    def set_mode(self, mode: Px4Mode) -> int:
        """MAV_CMD_DO_SET_MODE with PX4 main/sub mode. Returns a MAV_RESULT."""
        return self.handle_command(_M.MAV_CMD_DO_SET_MODE, [
            _M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mode.main_mode, mode.sub_mode])

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

    def set_position_target(self, setpoint: Setpoint, sent_ms: float = math.nan) -> None:
        """Inject an offboard setpoint as if a SET_POSITION_TARGET_LOCAL_NED had arrived now
        (``sent_ms``: the message's time_boot_ms, the sender's clock; NaN when injected)."""
        with self._lock:
            if self._record:
                self.setpoint_log.append((time.monotonic(), self.time_s, *setpoint.position,
                                          *setpoint.velocity, *setpoint.acceleration,
                                          self.mode.name, sent_ms, setpoint.yaw))
            self.commander.on_offboard_setpoint(setpoint)

    def inject_message(self, msg: Any) -> None:
        """Process a decoded pymavlink message as if it had been received (any clock)."""
        with self._lock:
            self.link.dispatch(msg)

    def handle_command(self, command: int, params: Sequence[float]) -> int:
        """Execute a MAV_CMD with up to 7 params (missing ones are NaN); returns MAV_RESULT."""
        pr = [float(x) for x in params] + [math.nan] * (7 - len(params))
        with self._lock:
            return self.link.handle_command(int(command), pr)[0]

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
                    self.set_position_target(setpoint_fn(self.time_s))
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
        self.link.open(self.port, self.bind_port)
        self.gcs_link.open(0, 0)
        self.gcs_link.peers = []  # nobody until an observer talks to it
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
        self.link.close()
        self.gcs_link.close()

    def __enter__(self) -> SimVehicle:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _loop(self) -> None:
        tick = 0.005
        wall0 = time.monotonic()
        sim0 = self.time_s
        next_tick = wall0
        links = {self.link.sock: self.link, self.gcs_link.sock: self.gcs_link}
        try:
            while not self._stop_evt.is_set():
                timeout = max(0.0, next_tick - time.monotonic())
                ready, _, _ = select.select(list(links), [], [], timeout)
                for sock in ready:
                    with self._lock:
                        links[sock].drain()
                now = time.monotonic()
                if now >= next_tick:
                    with self._lock:
                        # Catch up at most 0.2 s per tick if the process was stalled.
                        target = sim0 + (now - wall0)
                        if target - self.time_s > 0.2:
                            sim0 += target - self.time_s - 0.2
                            target = sim0 + (now - wall0)
                        self._advance_to(target)
                        self.link.send_due_telemetry()
                        if self.gcs_link.peers:
                            self.gcs_link.send_due_telemetry()
                    next_tick += tick
                    if next_tick < now:
                        next_tick = now + tick
        except BaseException as exc:  # pragma: no cover - surfaced to tests via thread_error
            self.thread_error = exc
            raise

    # ------------------------------------------------------------------ physics

    def _advance_to(self, t_end: float) -> None:
        """Run whole physics steps until the sim time reaches ``t_end`` (chunked collisions)."""
        chunk_positions: list[np.ndarray] = []
        chunk_steps: list[int] = []
        capturing = self.link.captured is not None and not self.running
        while self.time_s + 0.5 * self._dt <= t_end:
            self._physics_step()
            if capturing:
                self.link.send_due_telemetry()
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
        self.commander.crash()
        self.commander.event(
            f"Collision at t={col.time_s:.2f}s ENU=({enu[k][0]:.1f},{enu[k][1]:.1f},"
            f"{enu[k][2]:.1f})", _M.MAV_SEVERITY_EMERGENCY)

    def _physics_step(self) -> None:
        dt = self._dt
        s = self._model.state
        self.commander.update()
        thrust_cmd = np.zeros(3)
        yaw_rate = 0.0
        sp: Setpoint | None = None
        if self.armed and not self.crashed:
            sp, limits = self.commander.setpoint(dt)
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
            self._model.step(dt, thrust_cmd, yaw_rate, self._err.disturbance)
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
