"""Batched flight simulator: many vehicles at once, vectorised over vehicles in numpy.

The single-vehicle stack (:class:`sitl.vehicle.SimVehicle`) steps one vehicle per Python loop
iteration; a collision-rate experiment flies thousands of trajectories, so this module runs the
**same model** for a batch of ``n`` vehicles with one numpy operation per formula:

* plant: :class:`sitl.dynamics.QuadrotorModel` (point mass, first-order thrust-vector lag,
  thrust saturation, linear drag, unilateral ground contact, semi-implicit Euler);
* controller: :class:`sitl.dynamics.PositionController` (position P + velocity feed-forward,
  velocity limits, velocity PID with D on the measured acceleration, acceleration feed-forward,
  vertical-priority thrust conversion with tilt limit, anti-windup integrator);
* estimation error and wander: :class:`sitl.estimation.PositionErrorModel` (unit-variance
  Gauss-Markov ``z`` per axis, exact discretisation, ``e = sigma(|v|) * z``, or the drift
  model whose increments scale with ``sigma(|v|)``; plus the smooth speed-independent part
  and the disturbance acceleration when they are on), the controller flying on ``p_true + e``;
* the order of one physics step is that of ``SimVehicle._physics_step`` for an armed vehicle
  in OFFBOARD: controller on the estimate of the previous step, plant step, error step; the
  true position is then checked against the world like ``SimVehicle._check_collisions``
  (``signed_distance < robot_radius``, ignored below ``robot_radius`` altitude unless
  ``collide_at_any_altitude``), and a collision ends that vehicle's flight (so does touching
  the ground with ``ground_ends_flight``: a crash for a real vehicle);
* setpoints are streamed like ``SimVehicle.run_for(..., setpoint_fn, rate)``: sampled at
  ``k / rate`` and held until the next one.

Random numbers: vehicle ``i`` draws its noise from ``numpy.random.default_rng(seeds[i])`` in
exactly the order :class:`~sitl.estimation.PositionErrorModel` does (its initial draws, then
``draws_per_step`` per physics step), in blocks (block and one-at-a-time draws give the same
stream). Two vehicles with the same seed therefore see identical noise draws, and a vehicle
reproduces ``SimVehicle(seed=s)`` started in the same state (tests/sitl/test_batch.py).

Scope: OFFBOARD flight with full setpoints (position, velocity and acceleration feed-forward
all set); no commander (modes, failsafes, landing), no yaw (it has no effect on translation),
no MAVLink. Frames: NED internally, like the vehicle, with home (the NED origin) at the world's
ENU origin; inputs and outputs are ENU world coordinates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from companion.frames import SWAP, enu_to_ned, ned_to_enu
from sitl.dynamics import ControllerParams, QuadrotorParams
from sitl.estimation import EstimationErrorParams, smooth_coefficients
from sitl.world import Box, Cylinder, World

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: Physics step of the single-vehicle simulator (``VehicleParams.physics_dt_s``).
DEFAULT_DT = 0.004
_FAR = 1.0e6  # padding obstacles are placed this far away


@dataclass(frozen=True, eq=False)
class BatchWorlds:
    """The obstacles of one world per vehicle, padded to common shapes.

    Attributes:
        cylinders: ``(n, kc, 5)`` rows ``(x, y, r, z_min, z_max)`` (ENU); padding is far away.
        boxes: ``(n, kb, 6)`` rows ``(xmin, ymin, zmin, xmax, ymax, zmax)``.
        robot_radius: ``(n,)`` collision radius per vehicle (m).
    """

    cylinders: FloatArray
    boxes: FloatArray
    robot_radius: FloatArray

    @staticmethod
    def from_worlds(worlds: list[World]) -> BatchWorlds:
        """Pack ``worlds`` (one per vehicle; the same object may repeat)."""
        n = len(worlds)
        cyl = [[(o.x, o.y, o.radius, o.z_min, o.z_max) for o in w.obstacles
                if isinstance(o, Cylinder)] for w in worlds]
        box = [[(*o.lo, *o.hi) for o in w.obstacles if isinstance(o, Box)] for w in worlds]
        kc = max([len(c) for c in cyl] + [1])
        kb = max([len(b) for b in box] + [0])
        cyl_arr = np.tile(np.array([_FAR, _FAR, 1.0, 0.0, 1.0]), (n, kc, 1))
        box_arr = np.tile(np.array([_FAR, _FAR, _FAR, _FAR + 1, _FAR + 1, _FAR + 1]), (n, kb, 1))
        for i in range(n):
            if cyl[i]:
                cyl_arr[i, : len(cyl[i])] = cyl[i]
            if box[i]:
                box_arr[i, : len(box[i])] = box[i]
        radius = np.array([w.robot_radius for w in worlds], dtype=float)
        return BatchWorlds(cyl_arr, box_arr, radius)

    def take(self, idx: NDArray[np.intp]) -> BatchWorlds:
        """The worlds of the vehicles ``idx``."""
        return BatchWorlds(self.cylinders[idx], self.boxes[idx], self.robot_radius[idx])

    def signed_distance(self, p_enu: FloatArray) -> FloatArray:
        """Signed distance of vehicle ``i``'s point ``p_enu[i]`` to world ``i``, shape ``(n,)``.

        Same closed forms as :meth:`sitl.world.World.signed_distance`.
        """
        c = self.cylinders
        dr = np.hypot(p_enu[:, None, 0] - c[..., 0], p_enu[:, None, 1] - c[..., 1]) - c[..., 2]
        zc, zh = 0.5 * (c[..., 3] + c[..., 4]), 0.5 * (c[..., 4] - c[..., 3])
        dz = np.abs(p_enu[:, None, 2] - zc) - zh
        sd = np.hypot(np.maximum(dr, 0.0), np.maximum(dz, 0.0)) + np.minimum(
            np.maximum(dr, dz), 0.0)
        out = sd.min(axis=1)
        if self.boxes.shape[1]:
            b = self.boxes
            centre, half = 0.5 * (b[..., :3] + b[..., 3:]), 0.5 * (b[..., 3:] - b[..., :3])
            q = np.abs(p_enu[:, None, :] - centre) - half
            sdb = np.linalg.norm(np.maximum(q, 0.0), axis=2) + np.minimum(q.max(axis=2), 0.0)
            out = np.minimum(out, sdb.min(axis=1))
        return out


@dataclass(frozen=True, eq=False)
class SetpointTable:
    """Setpoints of ``n`` vehicles sampled at ``rate_hz`` (ENU), held after each one's end.

    Row ``k`` of vehicle ``i`` is its setpoint at ``t = k / rate_hz``. Rows past a vehicle's
    ``length[i]`` repeat its last row (callers fill them; :meth:`from_lists` does).

    Attributes:
        rate_hz: setpoint rate (Hz).
        position / velocity / acceleration: ``(n, m, 3)`` ENU.
        length: ``(n,)`` number of valid rows per vehicle.
    """

    rate_hz: float
    position: FloatArray
    velocity: FloatArray
    acceleration: FloatArray
    length: NDArray[np.intp]

    @staticmethod
    def from_lists(rate_hz: float, rows: list[tuple[FloatArray, FloatArray, FloatArray]]
                   ) -> SetpointTable:
        """Stack per-vehicle ``(position, velocity, acceleration)`` arrays ``(m_i, 3)``;
        shorter ones are padded with their last position and zero velocity/acceleration."""
        n = len(rows)
        m = max(len(r[0]) for r in rows)
        pos = np.empty((n, m, 3))
        vel = np.zeros((n, m, 3))
        acc = np.zeros((n, m, 3))
        length = np.empty(n, dtype=np.intp)
        for i, (p, v, a) in enumerate(rows):
            k = len(p)
            pos[i, :k], vel[i, :k], acc[i, :k] = p, v, a
            pos[i, k:] = p[-1]
            length[i] = k
        return SetpointTable(float(rate_hz), pos, vel, acc, length)

    def take(self, idx: NDArray[np.intp]) -> SetpointTable:
        """The setpoints of the vehicles ``idx``."""
        return SetpointTable(self.rate_hz, self.position[idx], self.velocity[idx],
                             self.acceleration[idx], self.length[idx])


@dataclass(frozen=True, eq=False)
class BatchResult:
    """Outcome of :func:`simulate` per vehicle (ENU, SI units).

    Attributes:
        collided: ``(n,)`` the true position came within the robot radius of an obstacle.
        collision_time: ``(n,)`` time of the first collision (s), NaN if none.
        collision_position: ``(n, 3)`` true position at the collision, NaN if none.
        min_distance: ``(n,)`` smallest true signed distance to the obstacles during the flight
            (m; below ``robot_radius`` means collision). Only steps where collisions count
            (airborne, above ``robot_radius``) enter.
        ground_contact: ``(n,)`` the vehicle touched the ground (z = 0) in flight.
        ground_time: ``(n,)`` time of the first ground contact (s), NaN if none.
        end_time: ``(n,)`` time the flight ended (collision or ``t_end``).
        final_position: ``(n, 3)`` true position at the end.
        max_tracking_error: ``(n,)`` largest ``|p_true - p_setpoint|`` (m).
        max_estimation_error: ``(n,)`` largest ``|p_est - p_true|`` (m).
        max_speed: ``(n,)`` largest true speed (m/s).
        history: with ``record=True``: ``time (s,)``, ``true_position``, ``estimated_position``,
            ``velocity``, ``error_std`` ``(s, n, 3)`` ENU, one row per physics step (after it,
            like ``SimVehicle.history``); rows after a vehicle's end repeat its final state.
    """

    collided: BoolArray
    collision_time: FloatArray
    collision_position: FloatArray
    min_distance: FloatArray
    ground_contact: BoolArray
    ground_time: FloatArray
    end_time: FloatArray
    final_position: FloatArray
    max_tracking_error: FloatArray
    max_estimation_error: FloatArray
    max_speed: FloatArray
    history: dict[str, FloatArray] = field(default_factory=dict)


@dataclass
class _State:
    """Mutable state of the vehicles still flying (NED)."""

    ids: NDArray[np.intp]
    pos: FloatArray
    vel: FloatArray
    acc: FloatArray
    thrust: FloatArray
    integral: FloatArray
    z: FloatArray
    err: FloatArray
    on_ground: BoolArray
    u: FloatArray
    y: FloatArray
    q: FloatArray
    var: FloatArray  # the drift model's running error variance

    def take(self, keep: NDArray[np.intp]) -> _State:
        return _State(self.ids[keep], self.pos[keep], self.vel[keep], self.acc[keep],
                      self.thrust[keep], self.integral[keep], self.z[keep], self.err[keep],
                      self.on_ground[keep], self.u[keep], self.y[keep], self.q[keep],
                      self.var[keep])


class NoiseStreams:
    """Per-vehicle normal draws, in :class:`~sitl.estimation.PositionErrorModel` order.

    ``seeds[i]`` seeds ``numpy.random.default_rng`` for vehicle ``i``; vehicles sharing a seed
    share one generator's draws (drawn once, copied). ``first(m)`` gives the ``m`` initial
    draws ``(n, m)``, ``block(k, width=w)`` the next ``k`` steps ``(n, k, w)``.
    """

    def __init__(self, seeds: NDArray[np.int64] | list[int]) -> None:
        seeds_arr = np.asarray(seeds, dtype=np.int64)
        uniq, self._inverse = np.unique(seeds_arr, return_inverse=True)
        self._rngs = [np.random.default_rng(int(s)) for s in uniq]

    @staticmethod
    def from_generators(rngs: list[np.random.Generator]) -> NoiseStreams:
        """Streams continuing existing generators (one per vehicle, used as they are)."""
        out = NoiseStreams.__new__(NoiseStreams)
        out._rngs = list(rngs)
        out._inverse = np.arange(len(rngs))
        return out

    def first(self, count: int = 3) -> FloatArray:
        return np.stack([g.standard_normal(count) for g in self._rngs])[self._inverse]

    def block(self, k: int, which: NDArray[np.intp] | None = None,
              width: int = 3) -> FloatArray:
        """Next ``k`` steps for every stream; returns rows of vehicles ``which`` (default all).

        Every stream advances, also those of vehicles that have finished, so a stream's draws
        do not depend on which other vehicles are still flying.
        """
        draws = np.stack([g.standard_normal((k, width)) for g in self._rngs])
        inv = self._inverse if which is None else self._inverse[which]
        return draws[inv]


def simulate(
    setpoints: SetpointTable,
    worlds: BatchWorlds | None,
    t_end: FloatArray,
    seeds: NDArray[np.int64] | list[int] | NoiseStreams,
    *,
    start_enu: FloatArray | None = None,
    initial: dict[str, FloatArray] | None = None,
    quad: QuadrotorParams | None = None,
    controller: ControllerParams | None = None,
    estimation: EstimationErrorParams | None = None,
    dt: float = DEFAULT_DT,
    record: bool = False,
    chunk_steps: int = 250,
    collide_at_any_altitude: bool = False,
    ground_ends_flight: bool = False,
) -> BatchResult:
    """Fly ``n`` vehicles along their setpoint tables until ``t_end[i]`` or a collision.

    Args:
        setpoints: setpoint table (ENU), streamed at its rate with zero-order hold.
        worlds: obstacles per vehicle (None: no collisions).
        t_end: ``(n,)`` flight duration per vehicle (s).
        seeds: per-vehicle noise seeds (vehicles with equal seeds get identical draws), or
            prepared :class:`NoiseStreams`.
        start_enu: ``(n, 3)`` initial true position (default: the first setpoint). Vehicles
            start hovering at rest there (thrust = weight, integrator zero).
        initial: optional full initial state overriding ``start_enu``: NED arrays ``(n, 3)``
            ``pos, vel, acc, thrust, integral, z`` (and ``u, y, q`` of the smooth error and
            the wander, ``var`` of the drift model, see
            :meth:`sitl.estimation.PositionErrorModel.state`; zero, or for ``var`` the
            model's value at the start velocity, if absent)
            and bool ``on_ground (n,)`` (used to continue a :class:`~sitl.vehicle.SimVehicle`
            in the validation tests). With ``initial`` no initial draws are made.
        quad / controller / estimation: model parameters (defaults as the vehicle's).
        dt: physics step (s), 4 ms like the vehicle.
        record: keep the per-step history (memory ``O(steps * n)``: for small batches).
        chunk_steps: noise is drawn and finished vehicles are dropped every this many steps.
        collide_at_any_altitude: count collisions also below ``robot_radius`` altitude and
            on the ground (``SimVehicle`` ignores them there).
        ground_ends_flight: the first ground contact ends the flight.
    """
    q = quad if quad is not None else QuadrotorParams()
    c = controller if controller is not None else ControllerParams()
    e = estimation if estimation is not None else EstimationErrorParams()
    n = setpoints.position.shape[0]
    t_end = np.broadcast_to(np.asarray(t_end, dtype=float), (n,)).copy()
    noise = seeds if isinstance(seeds, NoiseStreams) else NoiseStreams(seeds)

    # Setpoint tables in NED.
    sp_pos = enu_to_ned(setpoints.position)
    sp_vel = enu_to_ned(setpoints.velocity)
    sp_acc = enu_to_ned(setpoints.acceleration)
    m_rows = sp_pos.shape[1]
    steps_per_sp = 1.0 / (setpoints.rate_hz * dt)

    # Initial state (PositionErrorModel.__init__).
    has_base, has_wander = e.has_base, e.has_wander
    phi0, scale0, phid, gaind = smooth_coefficients(e, dt)
    zeros = np.zeros((n, 3))
    drift = e.kind == "drift"
    if initial is not None:
        st = _State(np.arange(n), *(np.array(initial[k], dtype=float) for k in
                                    ("pos", "vel", "acc", "thrust", "integral", "z")),
                    zeros.copy(), np.array(initial["on_ground"], dtype=bool),
                    *(np.array(initial.get(k, zeros), dtype=float) for k in ("u", "y", "q")),
                    zeros.copy())
        st.var = np.array(initial["var"], dtype=float) if "var" in initial \
            else _std(e, st.vel) ** 2
    else:
        p0 = enu_to_ned(setpoints.position[:, 0] if start_enu is None else
                        np.asarray(start_enu, dtype=float))
        thrust0 = np.tile([0.0, 0.0, -q.gravity_m_s2], (n, 1))
        first = noise.first(3 + 6 * has_base + 3 * has_wander)
        u0, y0, q0 = zeros.copy(), zeros.copy(), zeros.copy()
        k0 = 3
        if has_base:
            u0 = first[:, 3:6]
            y0 = (phi0 * u0 + first[:, 6:9]) / (1.0 + phi0)
            k0 = 9
        if has_wander:
            q0 = first[:, k0:k0 + 3]
        st = _State(np.arange(n), p0.copy(), zeros.copy(), zeros.copy(), thrust0,
                    zeros.copy(), first[:, :3].copy(), zeros.copy(), np.zeros(n, dtype=bool),
                    u0, y0, q0, _std(e, zeros) ** 2)
        if drift:  # the drift model carries its error itself, stationary at hover
            st.z = np.sqrt(st.var) * st.z
    st.err = _error(e, st, scale0)
    width = 3 + 3 * has_base + 3 * has_wander
    wander = np.asarray(e.wander_acc_std_m_s2, dtype=float)
    gain0 = np.sqrt(1.0 - phi0**2)

    # Constants.
    g = q.gravity_m_s2
    g_vec = np.array([0.0, 0.0, g])
    f_max = q.thrust_to_weight * g
    lag = np.array([1.0 - math.exp(-dt / q.attitude_time_constant_s)] * 2
                   + [1.0 - math.exp(-dt / q.thrust_time_constant_s)])
    kp_pos = np.array([c.pos_p_xy, c.pos_p_xy, c.pos_p_z])
    kp_vel = np.array([c.vel_p_xy, c.vel_p_xy, c.vel_p_z])
    ki_vel = np.array([c.vel_i_xy, c.vel_i_xy, c.vel_i_z])
    kd_vel = np.array([c.vel_d_xy, c.vel_d_xy, c.vel_d_z])
    tan_tilt = math.tan(math.radians(c.tilt_max_deg))
    thr_to_acc = g / c.thr_hover
    f_up_min, f_up_max = c.thr_min * thr_to_acc, c.thr_max * thr_to_acc
    phi = math.exp(-dt / e.correlation_time_s)
    gain = math.sqrt(1.0 - phi * phi)
    ground = q.ground_z_ned

    # Outputs.
    collided = np.zeros(n, dtype=bool)
    col_t = np.full(n, np.nan)
    col_p = np.full((n, 3), np.nan)
    min_d = np.full(n, np.inf)
    ground_contact = np.zeros(n, dtype=bool)
    ground_t = np.full(n, np.nan)
    end_time = t_end.copy()
    final = np.zeros((n, 3))
    max_track = np.zeros(n)
    max_est = np.zeros(n)
    max_speed = np.zeros(n)
    hist: dict[str, list[FloatArray]] = {k: [] for k in (
        "time", "true_position", "estimated_position", "velocity", "error_std")}
    frozen = {"pos": np.zeros((n, 3)), "est": np.zeros((n, 3)), "vel": np.zeros((n, 3)),
              "std": np.zeros((n, 3))}

    w = worlds
    table = np.arange(n)  # row of each live vehicle in the setpoint tables / worlds
    total_steps = int(math.floor(float(t_end.max()) / dt + 0.5)) if n else 0
    step = 0
    while step < total_steps and len(st.ids):
        k_chunk = min(chunk_steps, total_steps - step)
        draws = noise.block(k_chunk, st.ids, width)
        for j in range(k_chunk):
            t_now = step * dt
            # --- setpoint (zero-order hold of the sample at k / rate) ---
            row = np.minimum(int(math.floor(step / steps_per_sp + 1e-9)), m_rows - 1)
            psp, vff, aff = sp_pos[table, row], sp_vel[table, row], sp_acc[table, row]
            # --- controller on the estimate (PositionController.update) ---
            est = st.pos + st.err
            vel_sp = kp_pos * (psp - est) + vff
            h = np.hypot(vel_sp[:, 0], vel_sp[:, 1])
            over = h > c.vel_max_xy_m_s
            if over.any():
                vel_sp[over, :2] *= (c.vel_max_xy_m_s / h[over])[:, None]
            vel_sp[:, 2] = np.clip(vel_sp[:, 2], -c.vel_max_up_m_s, c.vel_max_down_m_s)
            vel_err = vel_sp - st.vel
            acc_sp = kp_vel * vel_err + st.integral - kd_vel * st.acc + aff
            f_up_raw = g - acc_sp[:, 2]
            f_up = np.clip(f_up_raw, f_up_min, f_up_max)
            h_max = np.minimum(tan_tilt * f_up, np.sqrt(np.maximum(f_up_max**2 - f_up**2, 0.0)))
            h = np.hypot(acc_sp[:, 0], acc_sp[:, 1])
            sat = h > h_max
            scale = np.where(sat, h_max / np.where(sat, h, 1.0), 1.0)
            cmd = np.column_stack([acc_sp[:, 0] * scale, acc_sp[:, 1] * scale, -f_up])
            inc = ki_vel * vel_err * dt
            inc[sat, :2] = 0.0
            inc[((f_up_raw > f_up_max) & (inc[:, 2] < 0.0))
                | ((f_up_raw < f_up_min) & (inc[:, 2] > 0.0)), 2] = 0.0
            st.integral = np.clip(st.integral + inc, -c.integrator_limit_m_s2,
                                  c.integrator_limit_m_s2)
            if st.on_ground.any():  # SimVehicle resets the integrator on the ground
                st.integral[st.on_ground] = 0.0
            # --- plant (QuadrotorModel.step) ---
            nrm = np.linalg.norm(cmd, axis=1)
            big = nrm > f_max
            if big.any():
                cmd[big] *= (f_max / nrm[big])[:, None]
            st.thrust = st.thrust + lag * (cmd - st.thrust)
            acc = st.thrust + g_vec - q.drag_per_s * st.vel
            if has_wander:
                acc = acc + wander * st.q
            rest = (st.pos[:, 2] >= ground - 1e-6) & (acc[:, 2] >= 0.0)
            vel = st.vel + acc * dt
            pos = st.pos + vel * dt
            touch = ~rest & (pos[:, 2] > ground)
            pos[touch, 2] = ground
            vel[touch] = 0.0
            vel[rest] = 0.0
            acc[rest] = 0.0
            pos[rest] = st.pos[rest]
            pos[rest, 2] = ground
            st.pos, st.vel, st.acc = pos, vel, acc
            st.on_ground = rest | touch
            # --- estimation error and wander (PositionErrorModel.step) ---
            std = _std(e, st.vel)
            if drift:
                st.z = phi * st.z + gain * std * draws[:, j, :3]
                st.var = phi * phi * st.var + (gain * std) ** 2
                std = np.sqrt(st.var)
            else:
                st.z = phi * st.z + gain * draws[:, j, :3]
            if has_base:
                st.y = phi0 * st.y + (1.0 - phi0) * st.u
                st.u = phi0 * st.u + gain0 * draws[:, j, 3:6]
            if has_wander:
                st.q = phid * st.q + gaind * draws[:, j, width - 3:]
            st.err = _error(e, st, scale0)
            if has_base:
                std = np.sqrt(std**2 + np.asarray(e.base_std_m) ** 2)
            step += 1
            t_now = step * dt
            # --- bookkeeping, collisions (SimVehicle._check_collisions) ---
            ids = st.ids
            landed = st.on_ground & ~ground_contact[ids]
            if landed.any():
                ground_t[ids[landed]] = t_now
            ground_contact[ids] |= st.on_ground
            max_track[ids] = np.maximum(max_track[ids], np.linalg.norm(st.pos - psp, axis=1))
            max_est[ids] = np.maximum(max_est[ids], np.linalg.norm(st.err, axis=1))
            max_speed[ids] = np.maximum(max_speed[ids], np.linalg.norm(st.vel, axis=1))
            hit = np.zeros(len(ids), dtype=bool)
            if w is not None:
                p_enu = ned_to_enu(st.pos)
                sd = w.signed_distance(p_enu)
                if not collide_at_any_altitude:
                    relevant = ~st.on_ground & (ground - st.pos[:, 2] >= w.robot_radius)
                    sd = np.where(relevant, sd, np.inf)
                min_d[ids] = np.minimum(min_d[ids], sd)
                hit = sd < w.robot_radius
                if hit.any():
                    hid = ids[hit]
                    collided[hid] = True
                    col_t[hid] = t_now
                    col_p[hid] = p_enu[hit]
                    end_time[hid] = t_now
            done = hit | (t_now >= t_end[ids] - 0.5 * dt)
            if ground_ends_flight and st.on_ground.any():
                end_time[ids[st.on_ground & ~hit]] = t_now
                done |= st.on_ground
            if record:
                frozen["pos"][ids] = ned_to_enu(st.pos)
                frozen["est"][ids] = ned_to_enu(st.pos + st.err)
                frozen["vel"][ids] = ned_to_enu(st.vel)
                frozen["std"][ids] = std[:, SWAP]  # a std has no sign
                if w is not None and hit.any():
                    frozen["vel"][ids[hit]] = 0.0
                hist["time"].append(np.array(t_now))
                hist["true_position"].append(frozen["pos"].copy())
                hist["estimated_position"].append(frozen["est"].copy())
                hist["velocity"].append(frozen["vel"].copy())
                hist["error_std"].append(frozen["std"].copy())
            if done.any():
                final[ids[done]] = ned_to_enu(st.pos[done])
                keep = np.flatnonzero(~done)
                st = st.take(keep)
                table = table[keep]
                draws = draws[keep]
                if w is not None:
                    w = w.take(keep)
                if not len(st.ids):
                    break
    if len(st.ids):
        final[st.ids] = ned_to_enu(st.pos)
    history = {k: np.stack(v) for k, v in hist.items()} if record and hist["time"] else {}
    return BatchResult(collided, col_t, col_p, min_d, ground_contact, ground_t, end_time, final,
                       max_track, max_est, max_speed, history)


def _error(e: EstimationErrorParams, st: _State, scale0: FloatArray) -> FloatArray:
    """Estimation error of the vehicles ``(n, 3)`` (PositionErrorModel._update)."""
    if not e.enabled:
        return np.zeros_like(st.z)
    err = st.z.copy() if e.kind == "drift" else _std(e, st.vel) * st.z
    return err + scale0 * st.y if e.has_base else err


def _std(e: EstimationErrorParams, vel: FloatArray) -> FloatArray:
    """Per-axis error std for velocities ``(n, 3)`` (:func:`sitl.estimation.error_std`)."""
    if not e.enabled:
        return np.zeros_like(vel)
    if e.speed_mode == "norm":
        speed = np.broadcast_to(np.linalg.norm(vel, axis=1, keepdims=True), vel.shape)
    else:
        speed = np.abs(vel)
    return np.maximum(e.slope_s * speed + e.offset_m, e.min_std_m) * e.axis_scale
