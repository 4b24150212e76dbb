"""Parameters of the simulated vehicle and the PX4 parameters it exposes over MAVLink.

``VehicleParams`` holds what the commander, the MAVLink link and the vehicle share (PX4
parameter names in the docstring). ``PX4_PARAMS`` maps the PX4 names that can be read and
written over the MAVLink parameter protocol to ``VehicleParams`` fields; ``PX4_CONSTANTS`` are
read-only values a client may ask for.
"""

from __future__ import annotations

from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink2

_M = mavlink2

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

    The defaults are PX4's (main, SIH quadrotor, no RC) as recorded in docs/sitl.md; the timing
    figures without a PX4 name were measured there.

    Attributes:
        system_id / component_id: MAVLink ids of the autopilot (PX4: 1 / 1).
        home_lat_deg / home_lon_deg / home_alt_m: the local origin (WGS-84, AMSL).
        home_enu_m: position of the local NED origin in the world's ENU frame.
        initial_yaw_deg: heading at start (0 = north).
        physics_dt_s: fixed integration / control step.
        com_of_loss_t_s: [COM_OF_LOSS_T] offboard setpoints count as lost this long after the
            last one (and OFFBOARD can be entered while the last one is younger).
        offboard_min_stream_s: how long the stream must already run before OFFBOARD is
            accepted (PX4: 0, a single setpoint suffices).
        offboard_loss_reaction_s: from COM_OF_LOSS_T to the failsafe (measured 0.06-0.09 s).
        offboard_resume_s: from the first setpoint after a loss to OFFBOARD again (measured
            0.02-0.03 s, without a mode command).
        offboard_loss_action: [NAV_RCL_ACT] failsafe action on offboard loss without RC:
            1 Hold, 2 Return (PX4 default), 3 Land.
        failsafe_hold_s: Hold this long before the action. PX4 holds for COM_FAIL_ACT_T only
            when manual control could take over; without RC it acts at once (0).
        takeoff_alt_m: [MIS_TAKEOFF_ALT] default takeoff altitude above home.
        takeoff_speed_m_s: [MPC_TKO_SPEED].
        takeoff_spoolup_s: from the takeoff command until the climb setpoint starts (PX4's
            spool-up and thrust ramp; lift-off was 3.8 s after the command).
        takeoff_ramp_s: the climb-speed limit ramps up to MPC_TKO_SPEED in this time (fitted
            to the recorded climb; PX4's own MPC_TKO_RAMP_T of 3 s also ramps the thrust up
            from below hover, which the spool-up time holds).
        takeoff_alt_radius_m: [NAV_MC_ALT_RAD] Takeoff ends (Hold) this far below the target;
            Hold then finishes the climb.
        land_speed_m_s: [MPC_LAND_SPEED] descent speed of Land above ``land_crawl_alt_m``.
        land_crawl_alt_m / land_crawl_m_s: [MPC_LAND_ALT3 / MPC_LAND_CRWL] below this height
            above the ground (SIH's distance sensor: the true height) Land descends at the
            crawl speed.
        auto_jerk_m_s3: [MPC_JERK_AUTO] the descent speed of Land ramps up and down with
            this jerk (PX4 recorded: 0.0-0.08 m lower 0.5 s after the command).
        land_detect_s: from touchdown to PX4's land detector saying ON_GROUND (and "Landing
            detected"; the COM_DISARM_LAND delay starts then): median of 9 PX4 SIH
            landings, 1.6-10.6 s (docs/sitl.md, "Landing"). Disarmed, the vehicle is on the
            ground as soon as it touches it.
        auto_cruise_m_s: [MPC_XY_CRUISE] horizontal speed in Hold and Return.
        auto_climb_m_s / auto_descend_m_s: [MPC_Z_V_AUTO_UP / _DN].
        brake_acc_m_s2: [MPC_ACC_HOR] horizontal acceleration of the automatic modes.
        rtl_return_alt_m / rtl_descend_alt_m: [RTL_RETURN_ALT / RTL_DESCEND_ALT].
        disarm_land_s: [COM_DISARM_LAND] auto-disarm delay after landing (<= 0: never).
        disarm_preflight_s: [COM_DISARM_PRFLT] auto-disarm if armed but no takeoff (<= 0: never).
        collision_min_alt_m: collisions are ignored below this true altitude above the ground
            (None: the world's robot radius; the vehicle handles ground contact itself).
        battery_cells / battery_flight_time_s: simple linear battery model.
        flight_sw_version: reported PX4 version (major, minor, patch).
        telemetry_rates_hz: (message name, Hz) pairs; changeable with SET_MESSAGE_INTERVAL.
        instant_state_reports: also send HEARTBEAT and EXTENDED_SYS_STATE the moment arming,
            mode or landed state change (PX4 does not: its 1 Hz HEARTBEAT shows a change up to
            1 s late). Off by default; an idealised option.
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
    offboard_min_stream_s: float = 0.0
    offboard_loss_reaction_s: float = 0.07
    offboard_resume_s: float = 0.02
    offboard_loss_action: int = 2
    failsafe_hold_s: float = 0.0
    takeoff_alt_m: float = 2.5
    takeoff_speed_m_s: float = 1.5
    takeoff_spoolup_s: float = 3.2
    takeoff_ramp_s: float = 2.0
    takeoff_alt_radius_m: float = 0.8
    land_speed_m_s: float = 0.7
    land_crawl_alt_m: float = 1.0
    land_crawl_m_s: float = 0.3
    auto_jerk_m_s3: float = 4.0
    land_detect_s: float = 3.6
    auto_cruise_m_s: float = 5.0
    auto_climb_m_s: float = 3.0
    auto_descend_m_s: float = 1.5
    brake_acc_m_s2: float = 3.0
    rtl_return_alt_m: float = 30.0
    rtl_descend_alt_m: float = 10.0
    disarm_land_s: float = 2.0
    disarm_preflight_s: float = 10.0
    collision_min_alt_m: float | None = None
    battery_cells: int = 4
    battery_flight_time_s: float = 1200.0
    flight_sw_version: tuple[int, int, int] = (1, 15, 0)
    telemetry_rates_hz: tuple[tuple[str, float], ...] = DEFAULT_TELEMETRY_RATES_HZ
    instant_state_reports: bool = False


#: Parameters exposed over the MAVLink parameter protocol: name -> (VehicleParams field, type).
PX4_PARAMS: dict[str, tuple[str, int]] = {
    "COM_OF_LOSS_T": ("com_of_loss_t_s", _M.MAV_PARAM_TYPE_REAL32),
    "NAV_RCL_ACT": ("offboard_loss_action", _M.MAV_PARAM_TYPE_INT32),
    "MIS_TAKEOFF_ALT": ("takeoff_alt_m", _M.MAV_PARAM_TYPE_REAL32),
    "MPC_TKO_SPEED": ("takeoff_speed_m_s", _M.MAV_PARAM_TYPE_REAL32),
    "NAV_MC_ALT_RAD": ("takeoff_alt_radius_m", _M.MAV_PARAM_TYPE_REAL32),
    "MPC_Z_V_AUTO_UP": ("auto_climb_m_s", _M.MAV_PARAM_TYPE_REAL32),
    "MPC_Z_V_AUTO_DN": ("auto_descend_m_s", _M.MAV_PARAM_TYPE_REAL32),
    "MPC_ACC_HOR": ("brake_acc_m_s2", _M.MAV_PARAM_TYPE_REAL32),
    "RTL_RETURN_ALT": ("rtl_return_alt_m", _M.MAV_PARAM_TYPE_REAL32),
    "RTL_DESCEND_ALT": ("rtl_descend_alt_m", _M.MAV_PARAM_TYPE_REAL32),
    "MPC_LAND_SPEED": ("land_speed_m_s", _M.MAV_PARAM_TYPE_REAL32),
    "MPC_LAND_ALT3": ("land_crawl_alt_m", _M.MAV_PARAM_TYPE_REAL32),
    "MPC_LAND_CRWL": ("land_crawl_m_s", _M.MAV_PARAM_TYPE_REAL32),
    "MPC_JERK_AUTO": ("auto_jerk_m_s3", _M.MAV_PARAM_TYPE_REAL32),
    "MPC_XY_CRUISE": ("auto_cruise_m_s", _M.MAV_PARAM_TYPE_REAL32),
    "COM_DISARM_LAND": ("disarm_land_s", _M.MAV_PARAM_TYPE_REAL32),
    "COM_DISARM_PRFLT": ("disarm_preflight_s", _M.MAV_PARAM_TYPE_REAL32),
}
#: Read-only parameters: name -> (value, type).
PX4_CONSTANTS: dict[str, tuple[float, int]] = {
    "SYS_HITL": (0, _M.MAV_PARAM_TYPE_INT32),
    "COM_RC_IN_MODE": (4, _M.MAV_PARAM_TYPE_INT32),  # 4: manual control disabled
    "COM_FAIL_ACT_T": (5.0, _M.MAV_PARAM_TYPE_REAL32),  # not applied without RC
    "CAL_GYRO0_ID": (1, _M.MAV_PARAM_TYPE_INT32),
    "CAL_ACC0_ID": (1, _M.MAV_PARAM_TYPE_INT32),
    "CAL_MAG0_ID": (1, _M.MAV_PARAM_TYPE_INT32),
}


def live_params(params: VehicleParams) -> dict[str, float]:
    """The writable PX4 parameters' current values, initialised from ``params``."""
    return {name: float(getattr(params, attr)) for name, (attr, _) in PX4_PARAMS.items()}
