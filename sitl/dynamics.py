"""Quadrotor point-mass model with a PX4-like cascaded position/velocity controller.

Frames and units: everything here is **local NED** (x north, y east, z down; metres, m/s,
m/s^2), like PX4's local position. The ground is the plane ``z = ground_z_ned`` (default 0).

Plant (``QuadrotorModel``): a point mass driven by a collective-thrust *specific force* vector
``f`` (m/s^2, NED) plus gravity and linear drag::

    p' = v,    v' = f_act + [0, 0, g] - c_d * v + d,
    f_act,xy' = (f_cmd,xy - f_act,xy) / tau_att,    f_act,z' = (f_cmd,z - f_act,z) / tau_thr

The first-order lag ``tau_att`` of the horizontal thrust lumps attitude tracking (the thrust
vector can only turn as fast as the vehicle tilts), ``tau_thr`` is the motors' lag on the
vertical thrust; ``d`` is an optional disturbance acceleration (the hover wander of
:mod:`sitl.estimation`). The commanded force is already limited by the
controller to the tilt limit and the maximum thrust (thrust-to-weight ratio). Ground contact is
a unilateral constraint: on the ground with less than hover thrust the vehicle rests (landed).

Controller (``PositionController``), modelled on PX4's multicopter position controller
(PX4 docs, "Controller Diagrams" > "Multicopter Position Controller"; parameters MPC_*):

1. position P loop -> velocity setpoint, plus velocity feed-forward, limited to
   MPC_XY_VEL_MAX horizontally and MPC_Z_VEL_MAX_UP / MPC_Z_VEL_MAX_DN vertically;
2. velocity PID loop -> acceleration setpoint (D acts on the measured acceleration), plus
   acceleration feed-forward, integrator with anti-windup;
3. acceleration -> thrust vector: vertical thrust first, limited to [MPC_THR_MIN, MPC_THR_MAX],
   then the horizontal part limited by the tilt limit MPC_TILTMAX_AIR and by the thrust left.

Setpoint components that are NaN are "not set", as in PX4's trajectory setpoint: an axis
without position setpoint is velocity-controlled, an axis without position and velocity
setpoint is acceleration-controlled.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

_NAN3 = (math.nan, math.nan, math.nan)


@dataclass(frozen=True)
class QuadrotorParams:
    """Physical parameters of the point-mass quadrotor.

    Attributes:
        mass_kg: vehicle mass (only used to report forces; the model works per unit mass).
        gravity_m_s2: gravitational acceleration.
        thrust_to_weight: maximum collective thrust divided by weight (2.0 -> hover at 50 %).
        attitude_time_constant_s: first-order lag of the horizontal thrust (attitude loop).
        thrust_time_constant_s: first-order lag of the vertical thrust (motors).
        drag_per_s: linear drag coefficient per unit mass (1/s).
        yaw_rate_max_rad_s: yaw-rate limit.
        ground_z_ned: NED z of the ground plane (m); home is at z = 0.
    """

    mass_kg: float = 1.5
    gravity_m_s2: float = 9.80665
    thrust_to_weight: float = 2.0
    attitude_time_constant_s: float = 0.08
    thrust_time_constant_s: float = 0.08
    drag_per_s: float = 0.05
    yaw_rate_max_rad_s: float = math.radians(120.0)
    ground_z_ned: float = 0.0


#: PX4's SIH quadrotor x (airframe 10040): 1 kg, four 5 N motors (thrust/weight 2.04), motor lag
#: SIH_T_TAU 0.05 s, first-order drag SIH_KDV 1 N per m/s; the attitude lag of 0.25 s was fitted to
#: the recorded tilt response to PX4's acceleration setpoint (docs/sitl.md, "Calibration").
PX4_SIH_QUAD = QuadrotorParams(mass_kg=1.0, thrust_to_weight=20.0 / 9.80665,
                               attitude_time_constant_s=0.25, thrust_time_constant_s=0.05,
                               drag_per_s=1.0)


@dataclass(frozen=True)
class ControllerParams:
    """Gains and limits of the cascaded controller, defaults = PX4 multicopter defaults.

    Names follow the PX4 parameters (PX4 docs, "Parameter Reference" > "Multicopter Position
    Control"): ``pos_p_xy`` = MPC_XY_P, ``vel_p_xy`` = MPC_XY_VEL_P_ACC, ... Thrusts are
    normalised to [0, 1] of the maximum thrust, like MPC_THR_*.
    """

    pos_p_xy: float = 0.95
    pos_p_z: float = 1.0
    vel_p_xy: float = 1.8
    vel_i_xy: float = 0.4
    vel_d_xy: float = 0.2
    vel_p_z: float = 4.0
    vel_i_z: float = 2.0
    vel_d_z: float = 0.0
    vel_max_xy_m_s: float = 12.0
    vel_max_up_m_s: float = 3.0
    vel_max_down_m_s: float = 1.5
    tilt_max_deg: float = 45.0
    thr_min: float = 0.12
    thr_max: float = 1.0
    thr_hover: float = 0.5
    yaw_p: float = 2.8
    integrator_limit_m_s2: float = 9.80665  # PX4 clamps the vertical integrator at 1 g


@dataclass(frozen=True)
class Setpoint:
    """Trajectory setpoint in local NED; NaN components are "not set".

    Attributes:
        position: (3,) metres.
        velocity: (3,) m/s (feed-forward if the position is set).
        acceleration: (3,) m/s^2 feed-forward.
        yaw: heading in radians (NaN: keep heading unless ``yaw_rate`` is set).
        yaw_rate: rad/s, used when ``yaw`` is NaN.
    """

    position: np.ndarray = field(default_factory=lambda: np.array(_NAN3))
    velocity: np.ndarray = field(default_factory=lambda: np.array(_NAN3))
    acceleration: np.ndarray = field(default_factory=lambda: np.array(_NAN3))
    yaw: float = math.nan
    yaw_rate: float = math.nan

    @staticmethod
    def hold(position: np.ndarray, yaw: float = math.nan) -> Setpoint:
        """Hold a position (zero velocity and acceleration feed-forward)."""
        return Setpoint(
            position=np.asarray(position, dtype=float).copy(),
            velocity=np.zeros(3),
            acceleration=np.zeros(3),
            yaw=yaw,
        )


@dataclass
class QuadState:
    """True state of the point-mass quadrotor (NED)."""

    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    acceleration: np.ndarray = field(default_factory=lambda: np.zeros(3))
    #: Actual specific thrust force (m/s^2, NED); points up (negative z) in flight.
    thrust: np.ndarray = field(default_factory=lambda: np.zeros(3))
    yaw: float = 0.0
    yaw_rate: float = 0.0
    on_ground: bool = True

    def copy(self) -> QuadState:
        """Deep copy."""
        return QuadState(
            self.position.copy(),
            self.velocity.copy(),
            self.acceleration.copy(),
            self.thrust.copy(),
            self.yaw,
            self.yaw_rate,
            self.on_ground,
        )


def wrap_pi(angle: float) -> float:
    """Wrap an angle to [-pi, pi)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


class PositionController:
    """PX4-like cascaded position -> velocity -> thrust-vector controller (see module doc)."""

    def __init__(self, params: ControllerParams, quad: QuadrotorParams) -> None:
        self.params = params
        self.quad = quad
        self._g = quad.gravity_m_s2
        # Normalised thrust -> specific force (m/s^2) using the controller's hover estimate.
        self._thr_to_acc = self._g / params.thr_hover
        self._kp_pos = (params.pos_p_xy, params.pos_p_xy, params.pos_p_z)
        self._kp_vel = (params.vel_p_xy, params.vel_p_xy, params.vel_p_z)
        self._ki_vel = (params.vel_i_xy, params.vel_i_xy, params.vel_i_z)
        self._kd_vel = (params.vel_d_xy, params.vel_d_xy, params.vel_d_z)
        self._tan_tilt = math.tan(math.radians(params.tilt_max_deg))
        self.integral = np.zeros(3)
        self.last_velocity_setpoint = np.zeros(3)
        self.last_acceleration_setpoint = np.zeros(3)

    def reset(self) -> None:
        """Clear the integrator (e.g. when landed or disarmed)."""
        self.integral[:] = 0.0

    def update(
        self,
        dt: float,
        position: np.ndarray,
        velocity: np.ndarray,
        acceleration: np.ndarray,
        setpoint: Setpoint,
        vel_max_up_m_s: float | None = None,
        vel_max_down_m_s: float | None = None,
        vel_max_xy_m_s: float | None = None,
    ) -> np.ndarray:
        """One control step; returns the commanded specific thrust force (NED, m/s^2).

        Args:
            dt: step length (s), used by the integrator.
            position: position the controller believes in (the *estimate*), NED.
            velocity: velocity estimate, NED.
            acceleration: measured acceleration (for the D term), NED.
            setpoint: trajectory setpoint (NaN = not set).
            vel_max_up_m_s / vel_max_down_m_s / vel_max_xy_m_s: optional tighter speed limits
                (takeoff / land speeds, cruise speed of the auto modes).
        """
        # Scalar per-axis code: for 3-vectors this is several times faster than numpy calls.
        p = self.params
        pos_sp, vel_ff = setpoint.position.tolist(), setpoint.velocity.tolist()
        acc_ff = setpoint.acceleration.tolist()
        pos, vel, acc = position.tolist(), velocity.tolist(), acceleration.tolist()
        integral = self.integral.tolist()
        nan = math.nan

        # --- position loop (P) + velocity feed-forward; NaN = axis not position-controlled ---
        vel_sp = [nan, nan, nan]
        for i in range(3):
            e, ff = pos_sp[i] - pos[i], vel_ff[i]
            if e == e:  # not NaN
                vel_sp[i] = self._kp_pos[i] * e + (ff if ff == ff else 0.0)
            elif ff == ff:
                vel_sp[i] = ff
        # Limits: horizontal norm, vertical up/down (NED: up is negative z).
        xy_max = (
            p.vel_max_xy_m_s if vel_max_xy_m_s is None else min(vel_max_xy_m_s, p.vel_max_xy_m_s)
        )
        if vel_sp[0] == vel_sp[0] and vel_sp[1] == vel_sp[1]:
            h = math.hypot(vel_sp[0], vel_sp[1])
            if h > xy_max:
                vel_sp[0] *= xy_max / h
                vel_sp[1] *= xy_max / h
        up = p.vel_max_up_m_s if vel_max_up_m_s is None else min(vel_max_up_m_s, p.vel_max_up_m_s)
        dn = p.vel_max_down_m_s
        if vel_max_down_m_s is not None:
            dn = min(vel_max_down_m_s, dn)
        if vel_sp[2] == vel_sp[2]:
            vel_sp[2] = min(max(vel_sp[2], -up), dn)

        # --- velocity loop (PID, D on measured acceleration) + acceleration feed-forward ---
        vel_err = [0.0, 0.0, 0.0]
        acc_sp = [0.0, 0.0, 0.0]
        for i in range(3):
            if vel_sp[i] == vel_sp[i]:
                vel_err[i] = vel_sp[i] - vel[i]
                acc_sp[i] = self._kp_vel[i] * vel_err[i] + integral[i] - self._kd_vel[i] * acc[i]
            if acc_ff[i] == acc_ff[i]:
                acc_sp[i] += acc_ff[i]

        # --- acceleration -> thrust vector with vertical priority and tilt limit ---
        fx, fy = acc_sp[0], acc_sp[1]
        f_up_raw = self._g - acc_sp[2]  # upward specific force wanted
        f_up_min = p.thr_min * self._thr_to_acc
        f_up_max = p.thr_max * self._thr_to_acc
        f_up = min(max(f_up_raw, f_up_min), f_up_max)
        h_max = min(self._tan_tilt * f_up, math.sqrt(max(f_up_max**2 - f_up**2, 0.0)))
        h = math.hypot(fx, fy)
        sat_xy = h > h_max
        if sat_xy:
            fx, fy = fx * h_max / h, fy * h_max / h
        f = np.array([fx, fy, -f_up])

        # --- integrator with anti-windup: stop integrating into a saturated direction ---
        lim = p.integrator_limit_m_s2
        for i in range(3):
            inc = self._ki_vel[i] * vel_err[i] * dt
            if i < 2 and sat_xy:
                inc = 0.0
            # NED: a negative z increment asks for more upward thrust.
            if i == 2 and (
                (f_up_raw > f_up_max and inc < 0.0) or (f_up_raw < f_up_min and inc > 0.0)
            ):
                inc = 0.0
            integral[i] = min(max(integral[i] + inc, -lim), lim)
        self.integral = np.array(integral)
        self.last_velocity_setpoint = np.array(vel_sp)
        self.last_acceleration_setpoint = np.array(acc_sp)
        return f

    def yaw_rate_command(self, yaw: float, setpoint: Setpoint) -> float:
        """Yaw-rate command (rad/s) from the yaw / yaw-rate setpoint (0 if neither is set)."""
        if math.isfinite(setpoint.yaw):
            return self.params.yaw_p * wrap_pi(setpoint.yaw - yaw)
        if math.isfinite(setpoint.yaw_rate):
            return setpoint.yaw_rate
        return 0.0


class QuadrotorModel:
    """Point-mass quadrotor with a first-order thrust-vector lag and ground contact."""

    def __init__(self, params: QuadrotorParams, state: QuadState | None = None) -> None:
        self.params = params
        self.state = state if state is not None else QuadState()
        self._g_vec = np.array([0.0, 0.0, params.gravity_m_s2])
        self._f_max = params.thrust_to_weight * params.gravity_m_s2
        self._lag_dt = -1.0
        self._lag = np.zeros(3)

    def lag_gains(self, dt: float) -> np.ndarray:
        """Per-axis discrete gains of the thrust lags for a step ``dt``."""
        q = self.params
        a = 1.0 - math.exp(-dt / q.attitude_time_constant_s)
        return np.array([a, a, 1.0 - math.exp(-dt / q.thrust_time_constant_s)])

    def step(self, dt: float, thrust_cmd: np.ndarray, yaw_rate_cmd: float,
             disturbance: np.ndarray | None = None) -> QuadState:
        """Integrate ``dt`` seconds with the commanded specific thrust force and yaw rate
        (and an optional disturbance acceleration, NED m/s^2)."""
        s = self.state
        q = self.params
        # Physical saturation of the collective thrust.
        cmd = np.asarray(thrust_cmd, dtype=float)
        n = float(np.linalg.norm(cmd))
        if n > self._f_max:
            cmd = cmd * (self._f_max / n)
        if self._lag_dt != dt:
            self._lag, self._lag_dt = self.lag_gains(dt), dt
        s.thrust = s.thrust + self._lag * (cmd - s.thrust)
        acc = s.thrust + self._g_vec - q.drag_per_s * s.velocity
        if disturbance is not None:
            acc = acc + disturbance
        # Ground contact: resting on the ground unless the net force lifts the vehicle.
        on_ground = s.position[2] >= q.ground_z_ned - 1e-6
        if on_ground and acc[2] >= 0.0:
            s.velocity = np.zeros(3)
            s.acceleration = np.zeros(3)
            s.position[2] = q.ground_z_ned
            s.on_ground = True
        else:
            s.velocity = s.velocity + acc * dt  # semi-implicit Euler
            s.position = s.position + s.velocity * dt
            s.acceleration = acc
            s.on_ground = False
            if s.position[2] > q.ground_z_ned:  # touched down during this step
                s.position[2] = q.ground_z_ned
                s.velocity = np.zeros(3)
                s.on_ground = True
        rate = min(max(yaw_rate_cmd, -q.yaw_rate_max_rad_s), q.yaw_rate_max_rad_s)
        if s.on_ground and float(np.linalg.norm(s.thrust)) < 0.5 * q.gravity_m_s2:
            rate = 0.0  # no yawing on the ground at idle
        s.yaw_rate = rate
        s.yaw = wrap_pi(s.yaw + rate * dt)
        return s


def rotation_from_thrust_yaw(thrust: np.ndarray, yaw: float, g: float = 9.80665) -> np.ndarray:
    """Body-to-NED rotation (FRD body) whose -z axis is along ``thrust`` with heading ``yaw``.

    With no meaningful thrust (idle on the ground) the vehicle is level.
    """
    n = float(np.linalg.norm(thrust))
    z_b = -thrust / n if n > 0.05 * g else np.array([0.0, 0.0, 1.0])
    x_c = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    y_b = np.cross(z_b, x_c)
    y_b /= np.linalg.norm(y_b)
    x_b = np.cross(y_b, z_b)
    return np.column_stack((x_b, y_b, z_b))


def euler_from_rotation(r: np.ndarray) -> tuple[float, float, float]:
    """ZYX Euler angles (roll, pitch, yaw) in radians from a body-to-NED rotation matrix."""
    roll = math.atan2(r[2, 1], r[2, 2])
    pitch = -math.asin(max(-1.0, min(1.0, r[2, 0])))
    yaw = math.atan2(r[1, 0], r[0, 0])
    return roll, pitch, yaw


def quaternion_from_rotation(r: np.ndarray) -> np.ndarray:
    """Hamilton quaternion (w, x, y, z) of a rotation matrix (body-to-NED)."""
    tr = r[0, 0] + r[1, 1] + r[2, 2]
    if tr > 0.0:
        s = math.sqrt(tr + 1.0) * 2.0
        q = (0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s)
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2]) * 2.0
        q = ((r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s)
    elif r[1, 1] > r[2, 2]:
        s = math.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2]) * 2.0
        q = ((r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s)
    else:
        s = math.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1]) * 2.0
        q = ((r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s)
    out = np.array(q)
    return out if out[0] >= 0.0 else -out
