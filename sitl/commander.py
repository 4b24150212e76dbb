"""PX4-like commander of the simulated vehicle: arming, flight modes, offboard rules, failsafes.

``Commander`` decides, every physics step, which setpoint the position controller flies
(offboard setpoint, takeoff, hold, land, return) and when the vehicle arms, disarms and changes
mode. It knows the vehicle only through :class:`Host` (time, estimated state, ground contact),
so it can be read and tested without MAVLink. The behaviour follows PX4 (main, SIH quadrotor,
no RC) as recorded in docs/sitl.md ("Calibration"):

* arming and mode commands take effect at once (PX4 ACKs within 2-16 ms); what telemetry shows
  of them is the link's business (1 Hz HEARTBEAT);
* OFFBOARD needs offboard setpoints younger than COM_OF_LOSS_T (one is enough);
* offboard loss (no setpoint for COM_OF_LOSS_T + ~0.07 s) without RC runs NAV_RCL_ACT
  (Return by default) at once; when setpoints come back during the failsafe, the vehicle returns
  to OFFBOARD by itself (~0.02 s after the first one), as PX4 does: the user's mode is still
  OFFBOARD. An explicit mode command ends the failsafe;
* Takeoff spools up, climbs on a ramp and hands over to Hold NAV_MC_ALT_RAD below the target;
  Hold finishes the climb. Home is set at arming (the position estimate then);
* Return brakes, climbs to RTL_RETURN_ALT, flies home, descends to RTL_DESCEND_ALT, lands.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from sitl.auto import AutoLimits, AutoReference
from sitl.dynamics import Setpoint
from sitl.params import VehicleParams, live_params

_M = mavlink2
FORCE_MAGIC = 21196  # MAV_CMD_COMPONENT_ARM_DISARM param2: force (PX4 and ArduPilot)


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


_MANUAL_MODES = {Px4Mode.MANUAL, Px4Mode.ALTCTL, Px4Mode.POSCTL, Px4Mode.ACRO,
                 Px4Mode.STABILIZED}


class Host(Protocol):
    """What the commander needs from the vehicle."""

    @property
    def time_s(self) -> float: ...

    def estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """Estimated position and velocity (NED)."""
        ...

    @property
    def on_ground(self) -> bool: ...

    @property
    def height_m(self) -> float:
        """True height above the ground (SIH's distance sensor)."""
        ...

    @property
    def yaw(self) -> float: ...

    def reset_controller(self) -> None: ...


#: PX4 reports the TAKEOFF landed state this long after the takeoff command, still on the
#: ground (measured 1.65-1.8 s).
TAKEOFF_STATE_DELAY_S = 1.8
_FAILSAFE_ACTIONS = {1: Px4Mode.AUTO_LOITER, 2: Px4Mode.AUTO_RTL, 3: Px4Mode.AUTO_LAND}


class Commander:
    """Modes, arming and failsafes (see module docstring).

    Args:
        params: vehicle parameters (the PX4 ones are copied into :attr:`live`, which the
            MAVLink parameter protocol may change).
        host: the vehicle (time, estimated state, ground contact, controller reset).
        notify: called with ``(text, MAV_SEVERITY)`` for every event (sent as STATUSTEXT).
    """

    def __init__(self, params: VehicleParams, host: Host,
                 notify: Callable[[str, int], None] | None = None) -> None:
        self.params = params
        self.host = host
        self._notify = notify
        self.live: dict[str, float] = live_params(params)
        self.armed = False
        self.mode = Px4Mode.AUTO_LOITER
        self.crashed = False
        self.events: list[tuple[float, str]] = []
        #: home (NED), set to the position estimate at arming like PX4
        self.home = np.zeros(3)
        self._armed_t = 0.0
        self._took_off = False
        self._ground_since: float | None = 0.0
        self._detected = False  # "Landing detected" said since the touchdown
        self._land_v = 0.0  # Land's descent speed now (m/s) and its rate (m/s^2)
        self._land_acc = 0.0
        self._ref: AutoReference | None = None
        self._target = np.zeros(3)
        self._takeoff_t = 0.0
        self._rtl_phase = ""
        self._failsafe_t: float | None = None
        self._offboard_sp: Setpoint | None = None
        self._last_sp_t: float | None = None
        self._stream_start_t: float | None = None
        self.setpoints_received = 0

    # ------------------------------------------------------------------ readout

    @property
    def failsafe_active(self) -> bool:
        """True while an offboard-loss failsafe is in progress."""
        return self._failsafe_t is not None

    @property
    def last_setpoint_time_s(self) -> float | None:
        """Sim time of the last offboard setpoint received (None if none yet)."""
        return self._last_sp_t

    def landed_state(self) -> int:
        """MAV_LANDED_STATE of the vehicle."""
        on_ground = self.host.on_ground
        takeoff = self.armed and self.mode is Px4Mode.AUTO_TAKEOFF
        if takeoff and (not on_ground
                        or self.host.time_s - self._takeoff_t >= TAKEOFF_STATE_DELAY_S):
            return _M.MAV_LANDED_STATE_TAKEOFF
        if self.landed() or not self.armed:
            return _M.MAV_LANDED_STATE_ON_GROUND if on_ground else _M.MAV_LANDED_STATE_IN_AIR
        if self.mode is Px4Mode.AUTO_LAND or self._rtl_phase == "land":
            return _M.MAV_LANDED_STATE_LANDING
        return _M.MAV_LANDED_STATE_IN_AIR

    # ------------------------------------------------------------------ events

    def event(self, text: str, severity: int = _M.MAV_SEVERITY_INFO) -> None:
        """Record an event (and send it as STATUSTEXT through ``notify``)."""
        self.events.append((self.host.time_s, text))
        if self._notify is not None:
            self._notify(text, severity)

    # ------------------------------------------------------------------ input

    def stream_ok(self) -> bool:
        """PX4's offboard availability: the last setpoint is younger than COM_OF_LOSS_T (and
        the stream has run for offboard_min_stream_s)."""
        if self._last_sp_t is None or self._stream_start_t is None:
            return False
        t = self.host.time_s
        fresh = t - self._last_sp_t <= self.live["COM_OF_LOSS_T"]
        long_enough = t - self._stream_start_t >= self.params.offboard_min_stream_s - 1e-9
        return fresh and long_enough

    def on_offboard_setpoint(self, sp: Setpoint) -> None:
        """An offboard setpoint arrived (SET_POSITION_TARGET_LOCAL_NED)."""
        t = self.host.time_s
        if self._last_sp_t is None or t - self._last_sp_t > self.live["COM_OF_LOSS_T"]:
            self._stream_start_t = t  # stream (re)starts
        self._last_sp_t = t
        self.setpoints_received += 1
        has_any = np.isfinite(np.concatenate((sp.position, sp.velocity, sp.acceleration))).any()
        if has_any or self._offboard_sp is None:
            self._offboard_sp = sp

    def handle_command(self, cmd: int, pr: list[float]) -> int | None:
        """Execute a commander MAV_CMD (arm, mode, takeoff, land, RTL): its MAV_RESULT, or
        None if the command is not the commander's."""
        acc, rej = _M.MAV_RESULT_ACCEPTED, _M.MAV_RESULT_TEMPORARILY_REJECTED
        if cmd == _M.MAV_CMD_COMPONENT_ARM_DISARM:
            force = int(round(pr[1])) == FORCE_MAGIC if math.isfinite(pr[1]) else False
            return self._do_arm(force) if pr[0] > 0.5 else self._do_disarm(force)
        if cmd == _M.MAV_CMD_DO_SET_MODE:
            if not int(pr[0]) & _M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
                return _M.MAV_RESULT_UNSUPPORTED
            mode = Px4Mode.from_main_sub(int(pr[1]), int(pr[2]) if math.isfinite(pr[2]) else 0)
            if mode is None:
                return _M.MAV_RESULT_UNSUPPORTED
            return acc if self._request_mode(mode) else rej
        if cmd == _M.MAV_CMD_NAV_TAKEOFF:
            z = -(pr[6] - self.params.home_alt_m) if math.isfinite(pr[6]) else None
            return acc if self._start_takeoff(z) else rej
        if cmd == _M.MAV_CMD_NAV_LAND:
            return acc if self._request_mode(Px4Mode.AUTO_LAND) else rej
        if cmd == _M.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return acc if self._request_mode(Px4Mode.AUTO_RTL) else rej
        return None

    def crash(self) -> None:
        """The vehicle hit an obstacle: disarmed for good (refuses to arm or change mode)."""
        self.crashed = True
        self.armed = False
        self._failsafe_t = None

    # ------------------------------------------------------------------ arming

    def _do_arm(self, force: bool) -> int:
        if self.armed:
            return _M.MAV_RESULT_ACCEPTED
        if self.crashed and not force:
            self.event("Arming denied: vehicle crashed", _M.MAV_SEVERITY_CRITICAL)
            return _M.MAV_RESULT_TEMPORARILY_REJECTED
        if self.mode is Px4Mode.OFFBOARD and not self.stream_ok() and not force:
            self.event("Arming denied: no offboard setpoints", _M.MAV_SEVERITY_CRITICAL)
            return _M.MAV_RESULT_TEMPORARILY_REJECTED
        if self.mode in (Px4Mode.AUTO_LAND, Px4Mode.AUTO_RTL) and not force:
            return _M.MAV_RESULT_TEMPORARILY_REJECTED
        self.armed = True
        self._armed_t = self.host.time_s
        on_ground = self.host.on_ground
        self._took_off = not on_ground
        self._ground_since = self.host.time_s if on_ground else None
        self.home = self.host.estimate()[0].copy()
        self.host.reset_controller()
        self._ref = None  # Hold re-latches at the current position
        self.event("Armed by external command")
        return _M.MAV_RESULT_ACCEPTED

    def _do_disarm(self, force: bool) -> int:
        if not self.armed:
            return _M.MAV_RESULT_ACCEPTED
        if not self.landed() and not force:
            self.event("Disarming denied: not landed", _M.MAV_SEVERITY_CRITICAL)
            return _M.MAV_RESULT_TEMPORARILY_REJECTED
        self._disarm("Disarmed by external command")
        return _M.MAV_RESULT_ACCEPTED

    def _disarm(self, text: str) -> None:
        self.armed = False
        self._failsafe_t = None
        self.host.reset_controller()
        if self.mode in (Px4Mode.AUTO_LAND, Px4Mode.AUTO_TAKEOFF, Px4Mode.AUTO_RTL):
            self.mode = Px4Mode.AUTO_LOITER
        self._ref = None
        self._rtl_phase = ""
        self.event(text)

    # ------------------------------------------------------------------ modes

    def _limits(self, speed_up: float | None = None) -> AutoLimits:
        lv = self.live
        return AutoLimits(speed_xy=lv["MPC_XY_CRUISE"],
                          speed_up=lv["MPC_Z_V_AUTO_UP"] if speed_up is None else speed_up,
                          speed_down=lv["MPC_Z_V_AUTO_DN"], acc_xy=lv["MPC_ACC_HOR"])

    def _request_mode(self, mode: Px4Mode) -> bool:
        if self.crashed:
            return False
        if mode in _MANUAL_MODES:
            return False  # no RC / manual control input emulated (COM_RC_IN_MODE = 4)
        if mode in (Px4Mode.AUTO_MISSION, Px4Mode.AUTO_READY):
            return False  # no mission support
        if mode is Px4Mode.OFFBOARD and not self.stream_ok():
            # PX4 docs "Offboard Mode": the vehicle must already receive setpoints before the
            # mode can be engaged; PX4 answers TEMPORARILY_REJECTED.
            self.event("Switching to Offboard is currently not available",
                       _M.MAV_SEVERITY_CRITICAL)
            return False
        if mode is Px4Mode.AUTO_TAKEOFF:
            return self._start_takeoff(None)
        if mode in (Px4Mode.AUTO_LAND, Px4Mode.AUTO_RTL) and not self.armed:
            return False
        self._failsafe_t = None  # an explicit mode change ends a failsafe (user override)
        self._enter_mode(mode)
        return True

    def _enter_mode(self, mode: Px4Mode, keep_target: bool = False) -> None:
        """Switch mode; the automatic modes' reference continues from where it is (or starts
        at the estimate) towards the stopping point, or the old target with ``keep_target``
        (Takeoff's hand-over to Hold)."""
        previous = self.mode
        if mode is not previous:
            self.event(f"Mode {mode.name}")
        self.mode = mode
        self._rtl_phase = ""
        if mode is Px4Mode.OFFBOARD:
            return
        est, vel = self.host.estimate()
        self._land_v, self._land_acc = max(float(vel[2]), 0.0), 0.0  # Land starts from here
        if self._ref is None or previous is Px4Mode.OFFBOARD:
            self._ref = AutoReference(est, vel)
        if keep_target:
            return
        self._target = self._ref.stopping_point(self._limits())
        if self.host.on_ground:
            self._target[2] = est[2]
        if mode is Px4Mode.AUTO_RTL:
            self._rtl_phase = "brake"

    def _start_takeoff(self, z: float | None) -> bool:
        """Takeoff to NED height ``z`` (None: MIS_TAKEOFF_ALT above home)."""
        if not self.armed or self.crashed:
            return False
        est, vel = self.host.estimate()
        target_z = self.home[2] - abs(self.live["MIS_TAKEOFF_ALT"]) if z is None else z
        self._failsafe_t = None
        if self.mode is not Px4Mode.AUTO_TAKEOFF:
            self.event("Mode AUTO_TAKEOFF")
        self.mode = Px4Mode.AUTO_TAKEOFF
        self._rtl_phase = ""
        self._takeoff_t = self.host.time_s
        self._ref = None if self.host.on_ground else AutoReference(est, vel)
        self._target = np.array([est[0], est[1], target_z])
        return True

    def _failsafe_action(self) -> None:
        action = _FAILSAFE_ACTIONS.get(int(self.live["NAV_RCL_ACT"]), Px4Mode.AUTO_RTL)
        self.event(f"Failsafe action: {action.name}", _M.MAV_SEVERITY_CRITICAL)
        self._enter_mode(action)

    # ------------------------------------------------------------------ every step

    def update(self) -> None:
        """Mode logic evaluated every physics step (before the controller)."""
        t = self.host.time_s
        if not self.armed:
            return
        est, vel = self.host.estimate()
        lv = self.live
        if self.mode is Px4Mode.OFFBOARD and self._failsafe_t is None:
            loss_t = lv["COM_OF_LOSS_T"] + self.params.offboard_loss_reaction_s
            if self._last_sp_t is None or t - self._last_sp_t > loss_t:
                self.event("Failsafe activated: no offboard", _M.MAV_SEVERITY_CRITICAL)
                self._failsafe_t = t
                if self.params.failsafe_hold_s > 0.0:
                    self._enter_mode(Px4Mode.AUTO_LOITER)
                else:
                    self._failsafe_action()
        elif self._failsafe_t is not None:
            back = (self.stream_ok() and self._stream_start_t is not None
                    and self._stream_start_t > self._failsafe_t
                    and t - self._stream_start_t >= self.params.offboard_resume_s - 1e-9)
            if back:
                self._failsafe_t = None
                self.event("Offboard setpoints back: failsafe cleared")
                self._enter_mode(Px4Mode.OFFBOARD)
            elif (self.mode is Px4Mode.AUTO_LOITER and self.params.failsafe_hold_s > 0.0
                  and t - self._failsafe_t >= self.params.failsafe_hold_s):
                self._failsafe_action()
        if self.mode is Px4Mode.AUTO_TAKEOFF and not self.host.on_ground:
            if est[2] <= self._target[2] + lv["NAV_MC_ALT_RAD"]:
                self._enter_mode(Px4Mode.AUTO_LOITER, keep_target=True)  # Hold ends the climb
        if self.mode is Px4Mode.AUTO_RTL:
            self._rtl_progress(est, vel)
        self._ground_logic(t)

    def _rtl_progress(self, est: np.ndarray, vel: np.ndarray) -> None:
        """Return phases: brake, climb (to RTL_RETURN_ALT above home), return (home at that
        height), descend (to RTL_DESCEND_ALT), land."""
        lv = self.live
        near = np.abs(est - self._target)
        slow = float(np.linalg.norm(vel)) < 0.5
        if self._rtl_phase == "brake" and float(np.hypot(vel[0], vel[1])) < 0.5:
            self._rtl_phase = "climb"
            self._target[2] = min(self._target[2], self.home[2] - lv["RTL_RETURN_ALT"])
        elif self._rtl_phase == "climb" and near[2] < 0.5:
            self._rtl_phase = "return"
            self._target = np.array([self.home[0], self.home[1], self._target[2]])
        elif self._rtl_phase == "return" and max(near[0], near[1]) < 0.5 and slow:
            self._rtl_phase = "descend"
            self._target[2] = max(self._target[2], self.home[2] - lv["RTL_DESCEND_ALT"])
        elif self._rtl_phase == "descend" and near[2] < 0.3:
            self._rtl_phase = "land"
            self._land_v, self._land_acc = max(float(vel[2]), 0.0), 0.0

    def landed(self) -> bool:
        """PX4's land detector: on the ground and, armed after a flight, for
        ``land_detect_s`` since the touchdown."""
        if not self.host.on_ground:
            return False
        if not (self.armed and self._took_off):
            return True
        since = self._ground_since  # (None: touched down in this step)
        return since is not None and self.host.time_s - since >= self.params.land_detect_s

    def _ground_logic(self, t: float) -> None:
        """Landing detection and auto-disarm (COM_DISARM_LAND, COM_DISARM_PRFLT)."""
        if self.host.on_ground:
            detect = self.params.land_detect_s if self._took_off else 0.0
            if self._ground_since is None:
                self._ground_since = t
            on_ground_for = t - self._ground_since
            if self._took_off and not self._detected and on_ground_for >= detect:
                self._detected = True
                self.event("Landing detected")
            land_t = self.live["COM_DISARM_LAND"]
            prflt_t = self.live["COM_DISARM_PRFLT"]
            landing = self.mode is Px4Mode.AUTO_LAND or self._rtl_phase == "land"
            if (self._took_off or landing) and land_t > 0.0:
                if on_ground_for >= detect + land_t:
                    self._disarm("Disarmed by landing")
            elif not self._took_off and prflt_t > 0.0 and t - self._armed_t >= prflt_t:
                if self.mode is not Px4Mode.AUTO_TAKEOFF:
                    self._disarm("Disarmed by auto preflight disarming")
        else:
            self._ground_since = None
            self._took_off = True
            self._detected = False

    def _land_speed(self, dt: float) -> float:
        """Land's descent speed: MPC_LAND_SPEED, MPC_LAND_CRWL below MPC_LAND_ALT3 (by the
        distance sensor), reached with the jerk MPC_JERK_AUTO (from rest at the command)."""
        lv = self.live
        crawl = self.host.height_m < lv["MPC_LAND_ALT3"]
        target = lv["MPC_LAND_CRWL"] if crawl else lv["MPC_LAND_SPEED"]
        err = target - self._land_v
        jerk = max(lv["MPC_JERK_AUTO"], 1e-3)
        # accelerate with growing rate; ease in where the rate left would overshoot
        self._land_acc = min(self._land_acc + jerk * dt, math.sqrt(2.0 * jerk * abs(err)))
        self._land_v += math.copysign(min(self._land_acc * dt, abs(err)), err)
        return self._land_v

    def setpoint(self, dt: float) -> tuple[Setpoint | None, dict[str, Any]]:
        """Setpoint for the controller in the current mode (None: idle on the ground) and the
        mode's speed limits; advances the automatic modes' reference by ``dt``."""
        on_ground = self.host.on_ground
        lv = self.live
        if self.mode is Px4Mode.OFFBOARD:
            return self._offboard_sp, {}
        if self.mode is Px4Mode.AUTO_TAKEOFF:
            climb_t = self.host.time_s - self._takeoff_t - self.params.takeoff_spoolup_s
            if self._ref is None:
                if climb_t < 0.0:
                    return None, {}  # spool-up on the ground
                self._ref = AutoReference(self.host.estimate()[0])
            ramp_s = max(self.params.takeoff_ramp_s, 1e-3)
            ramp = lv["MPC_TKO_SPEED"] * min(1.0, max(climb_t, 0.0) / ramp_s)
            return self._ref.step(dt, self._target, self._limits(max(ramp, 0.05))), {}
        landing = self.mode is Px4Mode.AUTO_LAND or self._rtl_phase == "land"
        if on_ground and (landing or self.mode is Px4Mode.AUTO_LOITER):
            return None, {}
        if self._ref is None:
            est, vel = self.host.estimate()
            self._ref = AutoReference(est, vel)
            self._target = self._ref.stopping_point(self._limits())
        if landing:
            ref = self._ref.step(dt, np.array([self._target[0], self._target[1], math.nan]),
                                 self._limits())
            land_v = self._land_speed(dt)
            return Setpoint(np.array([ref.position[0], ref.position[1], math.nan]),
                            np.array([ref.velocity[0], ref.velocity[1], land_v]),
                            np.array([ref.acceleration[0], ref.acceleration[1], 0.0])), \
                {"vel_max_down_m_s": land_v}
        return self._ref.step(dt, self._target, self._limits()), {}
