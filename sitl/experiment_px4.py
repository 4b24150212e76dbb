"""ROTA on the vehicle it flies: the planner's timing, ROTA, and the equal-time uniform
slow-down, flown on real PX4 SITL (the SIH quadrotor of ``ROTA_PX4_BUILD``), at the demo's
speed and a planner's clearance, judged on SIH's ground truth.

Per trial one random forest (the demo's density, 0.043 trees per m^2, in 20 m x 20 m; its seed
from :func:`sitl.experiment.world_seed`) and one path through it, planned by the reference
planner (:func:`sitl.planner.plan`) at ``clearance`` beyond the robot's radius, ``speed`` and
``a_max``, at ``altitude``. Every arm flies that path:

* ``planned``: the planner's own timing;
* ``rota``: re-timed by :func:`rota.retime` exactly as :mod:`sitl.experiment` re-times (the
  shipped model ``UncertaintyModel(memory_s=T)``, Delta 1e-4, 0.3 m robot sphere, braking
  zones from the risk);
* ``uniform``: the planner's path uniformly slowed to take exactly as long as ``rota``.

With ``j_max`` set, a fourth arm flies too:

* ``rota_jerk``: ROTA as ``rota``, with the jerk bound ``j_max`` per axis
  (:func:`rota.jerk.retime_jerk`; PX4's own auto modes use ``MPC_JERK_AUTO`` = 4 m/s^3);

and every arm's smoothness is measured as flown: the RMS jerk of SIH's true velocity (see
:func:`rms_jerk`), beside the same measure of the commanded velocity.

Each trial also records whether ROTA with the model fitted to PX4 (``FITTED``,
docs/estimator.md) accepts the path; that model makes no flight of its own.

One PX4 instance flies a worker's trials in one flight: take off, then for each trial and arm
(in an order drawn per trial) fly to the path's start (a straight minimum-jerk transfer; SIH
has no trees, so the transfer cannot hit one), hold ``hold_s``, stream the arm's setpoints
(position, velocity and acceleration at 50 Hz through the service's own
:class:`companion.flight.autopilot.Autopilot`) and hold the end ``settle_s``. Truth: SIH's
``HIL_STATE_QUATERNION`` through :class:`sitl.observer.Observer`, from the arm's first setpoint
to the end of its settle. A **collision** is the true position within the robot's radius of a
trunk (at any altitude). Pairing is by world and path only: PX4's own noise is not seeded, so
arms of one trial meet different noise (the order is drawn so no arm always flies first).

Statistics (:mod:`sitl.experiment_px4_report`): Wilson intervals per arm, exact McNemar tests
on the paired collisions, and the paired difference of the closest approach (mean with its t
interval, Wilcoxon signed-rank test).
"""

from __future__ import annotations

import asyncio
import math
import multiprocessing
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from companion.frames import ned_to_enu
from rota import Limits, RetimeInput, retime
from rota.chance import DEFAULT_MEMORY_S, UncertaintyModel
from rota.robust import Safety
from rota.voxelmap import VoxelMap
from sitl.experiment import path_clearance, planned_sampler, rota_sampler, table_rows, world_seed
from sitl.planner import PlanningError, plan
from sitl.world import DENSITIES, World, forest

#: The model fitted to PX4 SIH's true deviation across the path (``python -m sitl.fit_px4``,
#: docs/estimator.md): m 0, b 0.53 m, floor 0.35 m.
FITTED = UncertaintyModel(m=0.0, b=0.53, memory_s=0.0)
ARMS = ("planned", "rota", "uniform")
JERK_ARM = "rota_jerk"
#: The jerk of a flight is measured on its velocity resampled at this rate (s^-1; SIH's
#: truth arrives at about 25 Hz) and differentiated twice by a cubic Savitzky-Golay filter
#: over this window (s): shorter windows measure the 1 cm/s steps of SIH's velocity, not
#: the vehicle.
JERK_RATE_HZ, JERK_WINDOW_S = 25.0, 0.6


@dataclass(frozen=True)
class Px4ExperimentConfig:
    """Everything that defines a run (stored with the results).

    Attributes:
        trials: worlds (each flown once per arm).
        seed: experiment seed (forest seeds derive from it, as in :mod:`sitl.experiment`).
        density: trees per m^2 (the demo's: ``forest-mid``).
        speed, a_max: the limits of the planner and of ROTA (m/s, m/s^2).
        clearance: the planner's clearance beyond the robot's radius (m).
        altitude: flight altitude (m above the ground).
        memory_s: ROTA's memory time T (the shipped default).
        rate_hz: setpoint rate; settle_s: held at the end before the arm's window closes;
        hold_s: held at the start before an arm begins.
        workers: PX4 instances flying at once (each its own process).
        j_max: the jerk bound of the extra arm ``rota_jerk`` (m/s^3 per axis; 0: no such
            arm).
    """

    trials: int = 30
    seed: int = 0
    density: float = DENSITIES["mid"]
    speed: float = 2.0
    a_max: float = 2.0
    clearance: float = 0.5
    altitude: float = 2.0
    memory_s: float = DEFAULT_MEMORY_S
    rate_hz: float = 50.0
    settle_s: float = 1.0
    hold_s: float = 3.0
    workers: int = 1
    j_max: float = 0.0

    def __post_init__(self) -> None:
        for name in ("trials", "workers"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}: must be at least 1, got {getattr(self, name)}")
        for name in ("speed", "a_max", "altitude", "rate_hz"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name}: must be positive, got {getattr(self, name)}")
        if self.clearance < 0:
            raise ValueError(f"clearance: must be >= 0 m, got {self.clearance}")
        if not (self.j_max >= 0 and math.isfinite(self.j_max)):
            raise ValueError(f"j_max: must be 0 (no jerk arm) or positive, got {self.j_max}")

    @property
    def arms(self) -> tuple[str, ...]:
        """The arms flown: :data:`ARMS`, and :data:`JERK_ARM` with ``j_max``."""
        return (*ARMS, JERK_ARM) if self.j_max > 0 else ARMS


@dataclass(frozen=True)
class Trial:
    """One world, its path and every arm's setpoints (world ENU), before flight."""

    index: int
    world_seed: int
    status: str  # ROTA's status with the shipped model, or "no-plan"
    fitted_status: str  # ROTA's status with the model fitted to PX4
    path_clearance: float  # the path's clearance beyond the robot's radius (m)
    braking_fraction: float  # share of ROTA's nodes in braking zones
    durations: dict[str, float]
    tables: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]


def world_of(cfg: Px4ExperimentConfig, index: int) -> World:
    return forest(cfg.density, world_seed(cfg.seed, 1, index))


def prepare(cfg: Px4ExperimentConfig, index: int) -> Trial:
    """Plan and re-time trial ``index``: the setpoints of every arm (nothing flies)."""
    seed = world_seed(cfg.seed, 1, index)
    world = forest(cfg.density, seed)
    start = np.array([world.start[0], world.start[1], cfg.altitude])
    goal = np.array([world.goal[0], world.goal[1], cfg.altitude])
    try:
        traj = plan(world, cfg.speed, cfg.a_max, start=start, goal=goal,
                    clearance=cfg.clearance)
    except PlanningError as exc:
        return Trial(index, seed, "no-plan", str(exc), math.nan, math.nan, {}, {})
    clearance = path_clearance(world, traj)
    vmap = VoxelMap.from_points(world.voxel_points(0.1), 0.1)

    def rota_with(model: UncertaintyModel, j_max: float | None = None):  # noqa: ANN202
        return retime(RetimeInput(traj, limits=Limits(cfg.speed, cfg.a_max, j_max),
                                  safety=Safety(map=vmap, uncertainty=model)))

    res = rota_with(UncertaintyModel(memory_s=cfg.memory_s))
    fitted = rota_with(FITTED)
    if res.status == "rejected":  # the companion refuses to fly it: no arm flies it either
        return Trial(index, seed, res.status, fitted.status, clearance, math.nan,
                     {"planned": traj.duration}, {})
    mask = res.diagnostics.braking_mask
    scale = traj.duration / res.duration
    tables = {
        "planned": table_rows(planned_sampler(traj), traj.duration, cfg.rate_hz),
        "rota": table_rows(rota_sampler(res), res.duration, cfg.rate_hz),
        "uniform": table_rows(planned_sampler(traj, scale), res.duration, cfg.rate_hz),
    }
    durations = {"planned": traj.duration, "rota": res.duration, "uniform": res.duration}
    if cfg.j_max > 0:
        jerk = rota_with(UncertaintyModel(memory_s=cfg.memory_s), cfg.j_max)
        if jerk.ok:  # (a fallback's uniform slow-down would not be the arm's method)
            tables[JERK_ARM] = table_rows(rota_sampler(jerk), jerk.duration, cfg.rate_hz)
            durations[JERK_ARM] = jerk.duration
    return Trial(index, seed, res.status, fitted.status, clearance,
                 float(np.mean(mask)) if mask is not None else 0.0, durations, tables)


def arm_order(cfg: Px4ExperimentConfig, index: int) -> list[str]:
    """The order the arms of trial ``index`` fly in (drawn, reproducible)."""
    rng = np.random.default_rng([cfg.seed, 7, index])
    arms = cfg.arms
    return [arms[k] for k in rng.permutation(len(arms))]


def min_jerk(p0: np.ndarray, p1: np.ndarray, rate_hz: float, peak_speed: float = 3.0,
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A straight minimum-jerk move from ``p0`` to ``p1`` at rest at both ends, peaking at
    ``peak_speed`` (its peak is 1.875 d / T)."""
    d = float(np.linalg.norm(p1 - p0))
    duration = max(2.0, 1.875 * d / peak_speed)
    s = np.arange(int(duration * rate_hz) + 1) / rate_hz / duration
    s = np.append(s, 1.0)[:, None] if s[-1] < 1.0 else s[:, None]
    u = p1 - p0
    pos = p0 + u * (10 * s**3 - 15 * s**4 + 6 * s**5)
    vel = u * (30 * s**2 - 60 * s**3 + 30 * s**4) / duration
    acc = u * (60 * s - 180 * s**2 + 120 * s**3) / duration**2
    return pos, vel, acc


class Stream:
    """Setpoints at a steady rate, row after row, across calls (no gap between programs):
    each handed to the autopilot's sender a period before it is due."""

    def __init__(self, autopilot: Any, rate_hz: float, yaw_ned_deg: float) -> None:
        self.ap, self.period, self.yaw = autopilot, 1.0 / rate_hz, yaw_ned_deg
        self.next_at: float | None = None
        self.last = np.zeros(3)
        self.late = 0  # setpoints not sent, or sent more than a period late

    async def play(self, p: np.ndarray, v: np.ndarray, a: np.ndarray) -> tuple[float, float]:
        """Stream the rows; the times (monotonic) the first and the last are due."""
        if self.next_at is None:
            self.next_at = time.monotonic() + 0.1
        first = self.next_at
        for k in range(len(p)):
            delay = self.next_at - self.period - time.monotonic()
            if delay > 0:
                await asyncio.sleep(delay)
            self.ap.send(p[k], v[k], a[k], self.yaw, self.next_at)
            self.next_at += self.period
            for sent in self.ap.sent():  # (read, or the sender's report pipe fills and blocks)
                self.late += sent.sent_at is None or sent.sent_at - sent.at > self.period
        self.last = np.asarray(p[-1], float)
        return first, self.next_at - self.period

    async def hold(self, seconds: float) -> None:
        """Hold the last setpoint's position for ``seconds``."""
        n = max(1, int(seconds / self.period))
        p = np.repeat(self.last[None], n, 0)
        await self.play(p, np.zeros_like(p), np.zeros_like(p))


async def _fly(build: str, cfg: Px4ExperimentConfig, trials: list[Trial],
               progress: Callable[[str], None]) -> list[dict[str, Any]]:
    """One PX4 instance flies ``trials``: the per-arm truth figures."""
    from companion.flight.autopilot import Autopilot
    from sitl.host_steal import read_steal
    from sitl.observer import Observer
    from sitl.px4 import Px4Sitl

    out: list[dict[str, Any]] = []
    with Px4Sitl(Path(build)) as px4, Observer.px4(px4.instance) as obs:
        ap = Autopilot(f"udpin://127.0.0.1:{px4.port}")
        await ap.connect(60.0)
        try:
            await ap.arm()
            await ap.takeoff(cfg.altitude)
            await asyncio.to_thread(obs.wait, lambda o: len(o.truth()) and
                                    -o.truth()[-1][2] > cfg.altitude - 0.3, 60.0,
                                    "the takeoff altitude")
            here = ap.telemetry.position
            stream = Stream(ap, cfg.rate_hz, ap.telemetry.yaw_ned_deg or 0.0)
            stream.last = np.array([here[0], here[1], cfg.altitude])
            holding = asyncio.create_task(stream.hold(3.0))
            await asyncio.sleep(0.5)
            await ap.start_offboard()
            await holding
            for trial in trials:
                home = np.array([*trial.tables["planned"][0][0][:2], 0.0])
                rec: dict[str, Any] = {"trial": trial.index, "arms": {}}
                world = world_of(cfg, trial.index)
                if obs.mode()[0] != "OFFBOARD":  # PX4 left offboard: nothing after counts
                    out.append({"trial": trial.index, "arms": {},
                                "error": f"PX4 in {obs.mode()[0]}, not OFFBOARD"})
                    continue
                for arm in arm_order(cfg, trial.index):
                    if arm not in trial.tables:  # (the jerk-limited re-time fell back)
                        continue
                    p, v, a = trial.tables[arm]
                    start = p[0] - home
                    await stream.play(*min_jerk(stream.last, start, cfg.rate_hz))
                    await stream.hold(cfg.hold_s)
                    late = stream.late
                    steal = read_steal()
                    t0, t1 = await stream.play(p - home, v, a)
                    await stream.hold(cfg.settle_s)
                    t_end = t1 + cfg.settle_s
                    await asyncio.to_thread(obs.wait, lambda o, t=t_end: len(o.truth(t)) > 0,
                                            5.0, "the truth after the arm")
                    truth = ned_to_enu(obs.truth(t0, t_end)) + home
                    estimate = ned_to_enu(obs.positions(t0, t_end)) + home
                    rec["arms"][arm] = figures(world, truth, estimate, p, mode=obs.mode()[0])
                    t_v, v_true = obs.truth_velocities(t0, t_end)
                    t_sp = t0 + np.arange(len(v)) / cfg.rate_hz
                    rec["arms"][arm].update(rms_jerk_truth=rms_jerk(t_v, ned_to_enu(v_true)),
                                            rms_jerk_commanded=rms_jerk(t_sp, v),
                                            late_setpoints=stream.late - late,
                                            truth_hole=obs.truth_hole(t0, t_end),
                                            host_steal_s=float(np.sum(read_steal() - steal)))
                out.append(rec)
                progress(f"trial {trial.index}: " + ", ".join(
                    f"{k} {r['closest_truth']:.2f} m" for k, r in rec["arms"].items()))
        finally:
            await ap.close()
    return out


def rms_jerk(t: np.ndarray, velocity: np.ndarray) -> float:
    """RMS of the jerk's norm (m/s^3) of a velocity sampled at times ``t`` (s): resampled at
    :data:`JERK_RATE_HZ`, its second derivative by a cubic Savitzky-Golay filter over
    :data:`JERK_WINDOW_S` (the same for the flown and the commanded velocity)."""
    from scipy.signal import savgol_filter

    t = np.asarray(t, float)
    dt = 1.0 / JERK_RATE_HZ
    window = int(round(JERK_WINDOW_S / dt)) | 1
    if len(t) < 2 or t[-1] - t[0] < window * dt:
        return math.nan
    grid = np.arange(t[0], t[-1], dt)
    v = np.column_stack([np.interp(grid, t, velocity[:, k]) for k in range(3)])
    jerk = savgol_filter(v, window, 3, deriv=2, delta=dt, axis=0)
    return float(np.sqrt(np.mean(np.sum(jerk**2, axis=1))))


def figures(world: World, truth: np.ndarray, estimate: np.ndarray, setpoints: np.ndarray,
            mode: str) -> dict[str, Any]:
    """One arm's outcome, from SIH's truth and PX4's estimate (world ENU)."""
    r = world.robot_radius
    closest = float(np.min(world.signed_distance(truth)) - r) if len(truth) else math.nan
    est = float(np.min(world.signed_distance(estimate)) - r) if len(estimate) else math.nan
    return {"closest_truth": closest, "closest_estimate": est, "collided": closest < 0,
            "min_altitude": float(truth[:, 2].min()) if len(truth) else math.nan,
            "truth_samples": len(truth), "end_miss": float(np.linalg.norm(
                truth[-1, :2] - setpoints[-1, :2])) if len(truth) else math.nan,
            "mode_after": mode}


def _worker(args: tuple[str, Px4ExperimentConfig, list[int]]) -> list[dict[str, Any]]:
    build, cfg, indices = args
    trials = [t for t in (prepare(cfg, i) for i in indices) if t.tables]
    return asyncio.run(_fly(build, cfg, trials,
                            lambda s: print(s, file=sys.stderr, flush=True)))


def run(cfg: Px4ExperimentConfig, build: str,
        progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Prepare every trial, fly them on ``cfg.workers`` PX4 instances, and return the run:
    configuration, per-trial preparation and per-arm outcomes."""
    say = progress or (lambda s: None)
    t0 = time.monotonic()
    prepared = [prepare(cfg, i) for i in range(cfg.trials)]
    flyable = [t.index for t in prepared if t.tables]
    say(f"{len(flyable)} of {cfg.trials} trials planned; flying them on "
        f"{cfg.workers} PX4 instance(s)")
    parts = [flyable[k::cfg.workers] for k in range(cfg.workers)]
    if cfg.workers == 1:
        flown = [_worker((build, cfg, parts[0]))]
    else:
        ctx = multiprocessing.get_context("spawn")
        with ctx.Pool(cfg.workers) as pool:
            flown = pool.map(_worker, [(build, cfg, part) for part in parts if part])
    by_index = {r["trial"]: r["arms"] for part in flown for r in part}
    errors = {r["trial"]: r["error"] for part in flown for r in part if "error" in r}
    trials = []
    for t in prepared:
        trials.append({"trial": t.index, "world_seed": t.world_seed, "status": t.status,
                       "fitted_status": t.fitted_status, "path_clearance": t.path_clearance,
                       "braking_fraction": t.braking_fraction, "durations": t.durations,
                       "arms": by_index.get(t.index, {}), "error": errors.get(t.index)})
    return {"config": asdict(cfg), "fitted_model": asdict(FITTED), "trials": trials,
            "wall_time_s": round(time.monotonic() - t0, 1)}
