"""Replay PX4's recorded flights through the ``sitl`` vehicle and measure both the same way.

The reference (:mod:`sitl.px4_reference`) holds every offboard setpoint PX4 received and PX4's
response. :func:`replay` sends the same setpoints, at the same times, to a
:class:`~sitl.vehicle.SimVehicle` on the simulated clock (after the vehicle's own takeoff to
2 m, like the recordings); the metrics below are then computed for PX4 and for the vehicle
alike, on the *position estimate* (what PX4 controls and reports):

* tracking (:func:`tracking_metrics`): error ``|p(t) - p_ref(t)|`` with ``p_ref`` linearly
  interpolated between setpoints; lag = the time shift minimising the RMS error; overshoot
  after the end (lines: travel past the end point along the motion; circles: distance from the
  end point; within the 4 s hold); the mean distance from the end point in the 2 s after it,
  and in the last second of the hold (the residual); settling = when the distance stays below
  ``SETTLE_M`` for the rest of the hold (NaN: not within the hold);
* position steps (:func:`step_metrics`): delay to 10 %, rise 10-90 %, overshoot, peak speed;
* hover (:func:`hover_stats`), takeoff (:func:`takeoff_profile`), offboard loss and re-entry
  (:func:`loss_timing`), arming as seen in the 1 Hz HEARTBEAT (:func:`arm_latency`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from sitl.dynamics import Setpoint
from sitl.px4_reference import phase_span
from sitl.vehicle import Px4Mode, SimVehicle, VehicleParams

#: the tracking runs: (phase, kind)
RUNS = tuple((f"line_v{v}_{d}", "line") for v in (1, 2, 3) for d in ("out", "back")) + tuple(
    (f"circle_v{v}", "circle") for v in (1, 2, 3))
SETTLE_M = 0.5
_MASK_NO_VEL_ACC = 8 | 16 | 32 | 64 | 128 | 256


@dataclass(frozen=True)
class TrackingMetrics:
    """Tracking of one run (see module docstring); metres and seconds."""

    lag_s: float
    rms_m: float
    max_m: float
    rms_no_lag_m: float
    overshoot_m: float
    mean_after_m: float
    residual_m: float
    settle_s: float

    @staticmethod
    def mean(items: list[TrackingMetrics]) -> TrackingMetrics:
        """Field-wise mean (NaN-aware for the settling time)."""
        cols = np.array([[getattr(m, f) for f in TrackingMetrics.__dataclass_fields__]
                         for m in items])
        with np.errstate(invalid="ignore"):
            means = [float(np.nanmean(c)) if np.isfinite(c).any() else math.nan
                     for c in cols.T]
        return TrackingMetrics(*means)


@dataclass(frozen=True)
class Flight:
    """A response at ~50 Hz (times on the recording's clock, s; NED m)."""

    t: np.ndarray
    pos: np.ndarray
    mode: np.ndarray
    truth: np.ndarray | None = None
    vel: np.ndarray | None = None
    events: tuple[tuple[float, str], ...] = ()


def reference(ref: dict[str, Any], run: str) -> Flight:
    """PX4's recorded response of ``run``."""
    return Flight(ref[f"{run}/t"], ref[f"{run}/pos"], ref[f"{run}/mode"],
                  ref.get(f"{run}/truth"), ref.get(f"{run}/vel"))


def setpoint_position(ref: dict[str, Any], run: str, t: np.ndarray) -> np.ndarray:
    """The setpoint position at times ``t``, linearly interpolated between messages."""
    sp_t, sp_p = ref[f"{run}/sp_t"], ref[f"{run}/sp_pva"][:, :3]
    return np.column_stack([np.interp(t, sp_t, sp_p[:, i]) for i in range(3)])


# ------------------------------------------------------------------ replay


def _setpoint(row: np.ndarray, mask: int) -> Setpoint:
    nan3 = np.full(3, np.nan)
    if mask & _MASK_NO_VEL_ACC:
        return Setpoint(row[:3].copy(), nan3, nan3.copy(), yaw=0.0)
    return Setpoint(row[:3].copy(), row[3:6].copy(), row[6:9].copy(), yaw=0.0)


def replay(ref: dict[str, Any], run: str, seed: int = 0, until: float | None = None,
           **vehicle: Any) -> Flight:
    """Fly the recorded setpoints of ``run`` with a simulated-clock vehicle.

    The vehicle takes off to 2 m (MIS_TAKEOFF_ALT, as recorded) and hovers; then the
    setpoints are sent at their recorded times and OFFBOARD is requested 0.5 s after the first
    one (as MAVSDK's ``offboard.start()`` was), nothing else: gaps in the stream are gaps.
    ``vehicle`` overrides :class:`SimVehicle` arguments (``params`` must set takeoff_alt_m).
    """
    kw: dict[str, Any] = {"params": VehicleParams(takeoff_alt_m=2.0), "seed": seed}
    kw.update(vehicle)
    sim = SimVehicle(record_history=True, history_decimation=5, **kw)
    assert sim.arm() == mavlink2.MAV_RESULT_ACCEPTED
    assert sim.takeoff() == mavlink2.MAV_RESULT_ACCEPTED
    sim.run_for(12.0)
    sp_t, pva, masks = ref[f"{run}/sp_t"], ref[f"{run}/sp_pva"], ref[f"{run}/sp_mask"]
    end = float(sp_t[-1] if until is None else until)
    n0 = len(sim.history.time_s)
    offset = sim.time_s - float(sp_t[0])  # sim time = recorded time + offset
    start_t = float(sp_t[0]) + 0.5
    started = False
    dt = sim.params.physics_dt_s
    for k in range(int(np.searchsorted(sp_t, end, side="right"))):
        target = float(sp_t[k]) + offset
        if target > sim.time_s + 0.5 * dt:
            sim.step(target - sim.time_s)
        sim.set_position_target(_setpoint(pva[k], int(masks[k])))
        if not started and sp_t[k] >= start_t:
            sim.set_mode(Px4Mode.OFFBOARD)
            started = True
    sim.step(end + 4.0 + offset - sim.time_s)
    h = sim.history.arrays()
    return Flight(h["time_s"][n0:] - offset, h["estimated_position_ned"][n0:],
                  h["mode"][n0:], h["true_position_ned"][n0:], h["velocity_ned"][n0:],
                  tuple((t - offset, text) for t, text in sim.events))


# ------------------------------------------------------------------ metrics


def best_lag(tt: np.ndarray, pp: np.ndarray, at: Any, lags: np.ndarray
             ) -> tuple[float, float]:
    """(lag, RMS error at it): the time shift of the setpoints ``at(t)`` that minimises
    the RMS distance of the positions ``pp`` (at times ``tt``) from them."""
    rms = [math.sqrt(float(np.mean(np.sum((pp - at(tt - lag)) ** 2, axis=1)))) for lag in lags]
    best = int(np.argmin(rms))
    return float(lags[best]), rms[best]


def settle_time(t: np.ndarray, dist: np.ndarray, t_end: float) -> float:
    """When, after ``t_end``, the distances ``dist`` (at times ``t``) stay below SETTLE_M
    for good: 0 if they always were, NaN if the last one is not."""
    outside = np.flatnonzero(dist >= SETTLE_M)
    if outside.size == 0:
        return 0.0
    if outside[-1] == dist.size - 1:
        return math.nan
    return float(t[outside[-1] + 1] - t_end)


def tracking_metrics(ref: dict[str, Any], flight: Flight, phase: str, kind: str,
                     run: str = "tracking") -> TrackingMetrics:
    """Tracking metrics of one run of ``flight`` (PX4's or a replay) against its setpoints."""
    t0, t1 = phase_span(ref, run, phase)
    _, t_hold = phase_span(ref, run, f"{phase}_hold")
    t, pos = flight.t, flight.pos
    inside = (t >= t0) & (t <= t1)
    tt, pp = t[inside], pos[inside]
    err = np.linalg.norm(pp - setpoint_position(ref, run, tt), axis=1)
    lag, rms_lag = best_lag(tt, pp, lambda x: setpoint_position(ref, run, x),
                            np.arange(-0.3, 1.0, 0.01))
    p_start, p_end = setpoint_position(ref, run, np.array([t0, t1]))
    hold = (t > t1) & (t <= t_hold)
    if kind == "line":
        u = (p_end - p_start) / np.linalg.norm(p_end - p_start)
        overshoot = max(0.0, float(((pos[hold] - p_end) @ u).max()))
    else:
        overshoot = float(np.linalg.norm(pos[hold] - p_end, axis=1).max())
    after = (t > t1) & (t <= t1 + 2.0)
    settle = settle_time(t[hold], np.linalg.norm(pos[hold] - p_end, axis=1), t1)
    last = (t > t_hold - 1.0) & (t <= t_hold)
    return TrackingMetrics(lag, math.sqrt(float(np.mean(err**2))),
                           float(err.max()), rms_lag, overshoot,
                           float(np.linalg.norm(pos[after] - p_end, axis=1).mean()),
                           float(np.linalg.norm(pos[last] - p_end, axis=1).mean()), settle)


def step_metrics(ref: dict[str, Any], flight: Flight, phase: str) -> dict[str, float]:
    """A position step (``step_<axis>_<d>m_out/back``): size measured from the position at
    the step; delay to 10 % and rise 10-90 % (s), overshoot (% of the size), peak speed."""
    t0, t1 = phase_span(ref, "steps", phase)
    axis = "xyz".index(phase.split("_")[1])
    m = (flight.t >= t0) & (flight.t <= t1)
    t, p = flight.t[m] - t0, flight.pos[m, axis]
    size = float(setpoint_position(ref, "steps", np.array([t0 + 0.1]))[0, axis]) - p[0]
    frac = (p - p[0]) / size

    def first(level: float) -> float:
        k = np.flatnonzero(frac >= level)
        return float(t[k[0]]) if k.size else math.nan

    speed = np.abs(np.gradient(p, t))
    return {"size_m": size, "delay_s": first(0.1), "rise_s": first(0.9) - first(0.1),
            "overshoot_pct": max(0.0, float(frac.max()) - 1.0) * 100.0,
            "peak_speed_m_s": float(np.convolve(speed, np.ones(5) / 5, "same").max())}


def hover_stats(ref: dict[str, Any], flight: Flight) -> dict[str, Any]:
    """Wander in the 30 s hover at a fixed setpoint: std of the estimate (per axis), of the
    estimated velocity, largest 3-D distance from the setpoint, estimate - truth."""
    t0, t1 = phase_span(ref, "hover", "hover_noise_30s")
    m = (flight.t >= t0) & (flight.t <= t1)
    dev = flight.pos[m] - setpoint_position(ref, "hover", flight.t[m])
    out = {"std_m": dev.std(axis=0), "max_m": float(np.linalg.norm(dev, axis=1).max())}
    if flight.vel is not None:
        out["vel_std_m_s"] = flight.vel[m].std(axis=0)
    if flight.truth is not None:
        out["est_minus_truth_std_m"] = (flight.pos[m] - flight.truth[m]).std(axis=0)
    return out


def takeoff_profile(t: np.ndarray, alt: np.ndarray, mode: np.ndarray,
                    target: float = 2.0) -> dict[str, float]:
    """Times (s after the takeoff command) and altitudes (m above home) of a takeoff."""
    def first(mask: np.ndarray) -> float:
        k = np.flatnonzero(mask)
        return float(t[k[0]]) if k.size else math.nan

    loiter = np.flatnonzero((mode == "AUTO_LOITER") & (t > 1.0))
    k = loiter[0] if loiter.size else -1
    settle = (t >= t[k] + 4.0) & (t <= t[k] + 5.0)
    return {"t_0.5m_s": first((alt >= 0.5) & (t > 0)),
            "t_hold_s": float(t[k]), "alt_at_hold_m": float(alt[k]),
            f"t_{target - 0.2:.1f}m_s": first((alt >= target - 0.2) & (t > 0)),
            "alt_4s_after_hold_m": float(alt[settle].mean()),
            "max_alt_m": float(alt[(t > 0) & (t < t[k] + 5.0)].max())}


def sim_takeoff_trace(seed: int = 0, **vehicle: Any
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The vehicle's takeoff (MIS_TAKEOFF_ALT 2 m, like the recordings): time after the
    command (s), altitude above home (m), mode, at 50 Hz."""
    kw: dict[str, Any] = {"params": VehicleParams(takeoff_alt_m=2.0), "seed": seed}
    kw.update(vehicle)
    sim = SimVehicle(record_history=True, history_decimation=5, **kw)
    sim.run_for(1.0)
    sim.arm()
    t0 = sim.time_s
    sim.takeoff()
    sim.run_for(14.0)
    h = sim.history.arrays()
    return (h["time_s"] - t0, sim.commander.home[2] - h["estimated_position_ned"][:, 2],
            h["mode"])


def sim_takeoff(seed: int = 0, **vehicle: Any) -> dict[str, float]:
    """:func:`takeoff_profile` of the vehicle."""
    return takeoff_profile(*sim_takeoff_trace(seed, **vehicle))


def px4_takeoff(ref: dict[str, Any]) -> dict[str, float]:
    """:func:`takeoff_profile` of the recording (home = the ground estimate before arming)."""
    t, z = ref["takeoff/t"], ref["takeoff/z"]
    home_z = float(np.mean(z[(t > -1.0) & (t < 0.0)]))
    return takeoff_profile(t, home_z - z, ref["takeoff/mode"])


def loss_timing(ref: dict[str, Any], flight: Flight) -> list[dict[str, Any]]:
    """Per offboard loss: last setpoint -> mode change (s), the failsafe mode, first setpoint
    after the gap -> OFFBOARD (s). Times from the 50 Hz mode samples (PX4 sent CURRENT_MODE at
    50 Hz: +-0.02 s)."""
    sp_t = ref["loss/sp_t"]
    gaps = np.flatnonzero(np.diff(sp_t) > 0.5)
    out = []
    for g in gaps:
        t_last, t_back = float(sp_t[g]), float(sp_t[g + 1])
        after = (flight.t > t_last) & (flight.mode != "OFFBOARD")
        k = np.flatnonzero(after)[0]
        back = np.flatnonzero((flight.t > t_back) & (flight.mode == "OFFBOARD"))
        out.append({"loss_to_mode_s": float(flight.t[k]) - t_last,
                    "failsafe_mode": str(flight.mode[k]),
                    "resume_to_offboard_s": (float(flight.t[back[0]]) - t_back
                                             if back.size else math.nan)})
    return out


def sim_loss_events(flight: Flight, ref: dict[str, Any]) -> list[dict[str, float]]:
    """The same from the vehicle's own event times (exact)."""
    sp_t = ref["loss/sp_t"]
    out = []
    for g in np.flatnonzero(np.diff(sp_t) > 0.5):
        t_last, t_back = float(sp_t[g]), float(sp_t[g + 1])
        fs = min(t for t, e in flight.events if e.startswith("Failsafe action") and t > t_last)
        back = [t for t, e in flight.events if e.startswith("Offboard setpoints back")
                and t >= t_back]
        out.append({"loss_to_mode_s": fs - t_last,
                    "resume_to_offboard_s": back[0] - t_back if back else math.nan})
    return out


def arm_latency(trials: int = 100, seed: int = 0) -> np.ndarray:
    """Arm command -> first HEARTBEAT with the armed flag, on the simulated clock (arming at
    a random phase of the 1 Hz heartbeat, like the recorded trials; disarmed in between)."""
    rng = np.random.default_rng(seed)
    sim = SimVehicle(seed=seed)
    captured = sim.link.capture()
    out = []
    for _ in range(trials):
        sim.run_for(float(rng.uniform(0.1, 1.1)))
        t_arm = sim.time_s
        sim.arm()
        sim.run_for(1.05)
        hb = [t for t, m in captured if t >= t_arm and m.get_type() == "HEARTBEAT"
              and m.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED]
        out.append(hb[0] - t_arm)
        sim.disarm()
        captured.clear()
    return np.array(out)
