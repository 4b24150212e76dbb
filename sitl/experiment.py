"""The paper's Table I on our stack, with the controls: collision rates of the planner's timing,
ROTA as in the paper, ROTA with error memory, and a uniform slow-down matched to each ROTA arm.

Grid (paper Sec. IV-A): forest densities 0.025 / 0.043 / 0.063 trees per m^2 in a 20 m x 20 m
map, speed limits 1 / 2 / 3 m/s, acceleration limit ``a_max = accel_ratio * v_max``. For each
density and trial one random forest is drawn (its seed derived from the experiment seed) and
shared by the three speeds. For each speed the reference planner (:func:`sitl.planner.plan`)
plans a collision-free B-spline at (v_max, a_max), and every arm flies the same path in the
batched simulator (:mod:`sitl.batch`, validated against :class:`sitl.vehicle.SimVehicle`; by
default with the dynamics calibrated to PX4's SIH quadrotor), in the same world, with the same
estimation-noise seed, under each error model:

* ``planned``: the B-spline's own timing, streamed at 50 Hz as position + velocity +
  acceleration setpoints;
* ``rota:T``: the path re-timed by :func:`rota.retime` with ROTA's defaults (lambda 0.5, dtau
  0.1 s, the world's 0.1 m voxel map, ``UncertaintyModel(m=0.2, b=-0.1, memory_s=T)``,
  ``ChanceParams()`` Delta = 1e-4, 0.3 m robot sphere); ``T = 0`` is the paper's ROTA, ``T > 0``
  ROTA with error memory;
* ``uniform:T``: the planner's path uniformly slowed down so that it takes exactly as long as
  ``rota:T`` on that trial (``tau = t * D_planned / D_rota``): the control that asks whether
  ROTA does better than "just slower".

Every flight starts hovering at rest at the start and ends at its first crash or
``settle_s`` after the trajectory's end. A crash is a tree collision (the true position within
``robot_radius`` of a trunk, at any altitude) or a ground strike (the true altitude reaches the
ground); both end the flight and are counted apart and together.

Work is split into tasks of ``chunk`` trials of one density; each task (one process of the
pool) plans, re-times and flies its trials. Results do not depend on the chunking or the
number of workers: every random draw comes from a seed derived from (seed, density, speed,
trial). Statistics: :mod:`sitl.experiment_stats`; tables and plots:
:mod:`sitl.experiment_report`.
"""

from __future__ import annotations

import math
import multiprocessing
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from rota import Limits, RetimeInput, retime
from rota.braking import BrakingParams
from rota.chance import DEFAULT_MEMORY_S, UncertaintyModel
from rota.robust import Safety
from rota.trajectory import Trajectory
from rota.voxelmap import VoxelMap
from sitl.batch import BatchWorlds, SetpointTable, simulate
from sitl.dynamics import PX4_SIH_QUAD, QuadrotorParams
from sitl.estimation import DRIFT, EstimationErrorParams
from sitl.experiment_stats import CellResult, cell_stats, rota_arm, uniform_arm
from sitl.planner import DEFAULT_CLEARANCE, PlanningError, plan
from sitl.world import World, forest

FloatArray = NDArray[np.float64]

#: The vehicles the experiment can fly: the ``sitl`` vehicle calibrated to PX4's SIH
#: quadrotor (docs/sitl.md, "Calibration"), or the earlier idealised point mass.
VEHICLES: dict[str, QuadrotorParams] = {"px4-sih": PX4_SIH_QUAD, "ideal": QuadrotorParams()}


@dataclass(frozen=True)
class ExperimentConfig:
    """Everything that defines a run (stored with the results).

    Attributes:
        densities: trees per m^2 (paper: 0.025, 0.043, 0.063).
        speeds: speed limits v_max (m/s).
        accel_ratio: ``a_max = accel_ratio * v_max`` (m/s^2 per m/s); see docs/table1.md.
        trials: trials (worlds x noise seeds) per cell.
        seed: experiment seed; world, noise seeds derive from it.
        workers: processes (1: in this process).
        chunk: trials per task.
        rate_hz: setpoint streaming rate.
        settle_s: flight continues this long after the trajectory's end.
        smoothness / dtau / map_resolution: ROTA's lambda, grid step, voxel size.
        d_th: ROTA's braking zones by the paper's fixed threshold (m; Eq. 6 alone).
            None: ROTA's default, braking zones follow the risk.
        memories: the memory times T (s) of the ROTA arms; 0 is the paper's ROTA.
        uniform: also fly the uniform slow-down matched to each ROTA arm.
        errors: the estimation-error models; every arm flies under each.
        vehicle: the dynamics (:data:`VEHICLES`): ``"px4-sih"``, the vehicle calibrated to
            PX4's SIH quadrotor with PX4's default controller gains, or ``"ideal"``.
        rejected: trials whose path ROTA rejects as unsafe (the chance constraint cannot hold
            even at rest; the companion refuses to fly them): ``"exclude"`` leaves them out
            of every arm, ``"fallback"`` flies ROTA's fallback timing (uniformly slowed).
        size: map edge (m).
        clearance: the reference planner's clearance beyond the robot's radius (m).
    """

    densities: tuple[float, ...] = (0.025, 0.043, 0.063)
    speeds: tuple[float, ...] = (1.0, 2.0, 3.0)
    accel_ratio: float = 1.0
    trials: int = 500
    seed: int = 0
    workers: int = 2
    chunk: int = 50
    rate_hz: float = 50.0
    settle_s: float = 1.0
    smoothness: float = 0.5
    dtau: float = 0.1
    map_resolution: float = 0.1
    d_th: float | None = None
    memories: tuple[float, ...] = (0.0, DEFAULT_MEMORY_S)
    uniform: bool = True
    errors: tuple[EstimationErrorParams, ...] = field(
        default_factory=lambda: (EstimationErrorParams(), DRIFT))
    rejected: str = "exclude"
    size: float = 20.0
    vehicle: str = "px4-sih"
    clearance: float = DEFAULT_CLEARANCE

    def __post_init__(self) -> None:
        if self.vehicle not in VEHICLES:
            raise ValueError(f"vehicle: one of {', '.join(VEHICLES)}")
        if len(set(self.memories)) != len(self.memories) or not self.memories:
            raise ValueError("memories: distinct memory times, at least one")
        if len({e.kind for e in self.errors}) != len(self.errors) or not self.errors:
            raise ValueError("errors: at most one model of each kind, at least one")
        if self.rejected not in ("exclude", "fallback"):
            raise ValueError("rejected: 'exclude' or 'fallback'")

    def a_max(self, v_max: float) -> float:
        return self.accel_ratio * v_max

    @property
    def arms(self) -> tuple[str, ...]:
        """Arm names: ``planned``, then ``rota:T`` (and ``uniform:T``) per memory time."""
        out = ["planned"] + [rota_arm(t) for t in self.memories]
        if self.uniform:
            out += [uniform_arm(t) for t in self.memories]
        return tuple(out)


def world_seed(seed: int, density_index: int, trial: int) -> int:
    """Forest seed of a trial (shared by the three speeds)."""
    return int(np.random.SeedSequence([seed, 0, density_index, trial]).generate_state(1)[0])


def noise_seed(seed: int, density_index: int, speed_index: int, trial: int) -> int:
    """Estimation-noise seed of a trial (shared by all its flights)."""
    state = np.random.SeedSequence([seed, 1, density_index, speed_index, trial]).generate_state(
        1, dtype=np.uint64)[0]
    return int(state >> np.uint64(1))


# ---------------------------------------------------------------------- one task
def table_rows(sample: Callable[[FloatArray], tuple[FloatArray, FloatArray, FloatArray]],
                duration: float, rate_hz: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    t = np.arange(int(math.floor(duration * rate_hz + 1e-9)) + 1) / rate_hz
    if t[-1] < duration:
        t = np.append(t, duration)  # the end state (rest at the goal) as the last row
    return sample(t)


def path_clearance(world: World, traj: Trajectory) -> float:
    """The path's smallest clearance (m, robot radius subtracted), sampled every 10 ms."""
    tau = np.linspace(0.0, traj.duration, max(2, int(traj.duration / 0.01) + 1))
    return float(np.min(world.signed_distance(traj.position(tau)))) - world.robot_radius


def planned_sampler(traj: Trajectory, scale: float = 1.0):
    """The planner's timing, uniformly scaled: ``tau = scale * t`` (scale < 1: slower)."""
    def sample(t: FloatArray):
        p, v, a = traj.evaluate(np.minimum(scale * t, traj.duration))
        return p, v * scale, a * scale**2
    return sample


def rota_sampler(result):
    def sample(t: FloatArray):
        s = result.sample(t)
        return s.position, s.velocity, s.acceleration
    return sample


def _or_zero(mask: np.ndarray | None) -> np.ndarray | list[float]:
    """A per-node mask, or [0.0] where the pipeline did not make one (no map)."""
    return [0.0] if mask is None else mask


def _nan_record(rec: dict, cfg: ExperimentConfig, status: str, message: str) -> None:
    rec["planned"].append(status != "no-plan")
    for t in cfg.memories:
        rec["status"][f"{t:g}"].append(status)
        rec["message"][f"{t:g}"].append(message)
        rec["braking_fraction"][f"{t:g}"].append(math.nan)
        rec["approach_fraction"][f"{t:g}"].append(math.nan)
    for arm in cfg.arms:
        rec["duration"][arm].append(math.nan)
    rec["path_clearance"].append(math.nan)


def run_task(config: ExperimentConfig, density_index: int, trials: Sequence[int]) -> dict:
    """Plan, re-time and fly ``trials`` of one density at every speed. Returns per-trial
    data per speed (merged by :func:`run_experiment`)."""
    cfg = config
    density = cfg.densities[density_index]
    t_prep = time.perf_counter()
    worlds: list[World] = []
    maps: list[VoxelMap] = []
    for trial in trials:
        w = forest(density, world_seed(cfg.seed, density_index, trial), size=cfg.size)
        worlds.append(w)
        maps.append(VoxelMap.from_points(w.voxel_points(cfg.map_resolution), cfg.map_resolution))
    out: dict = {"density_index": density_index, "trials": list(trials), "speeds": {}}
    prep_time = time.perf_counter() - t_prep
    sim_time = 0.0
    braking = (BrakingParams() if cfg.d_th is None
               else BrakingParams(d_th=cfg.d_th, risk=False))
    arms = cfg.arms
    for vi, v_max in enumerate(cfg.speeds):
        t0 = time.perf_counter()
        a_max = cfg.a_max(v_max)
        keys = [f"{t:g}" for t in cfg.memories]
        rec: dict = {"trial": [], "world_seed": [], "noise_seed": [], "planned": [],
                     "path_clearance": [], "status": {k: [] for k in keys},
                     "message": {k: [] for k in keys}, "braking_fraction": {k: [] for k in keys},
                     "approach_fraction": {k: [] for k in keys},
                     "duration": {a: [] for a in arms}}
        rows: dict[str, list] = {a: [] for a in arms}
        flown: list[int] = []
        for j, (trial, w, vm) in enumerate(zip(trials, worlds, maps, strict=True)):
            rec["trial"].append(trial)
            rec["world_seed"].append(world_seed(cfg.seed, density_index, trial))
            rec["noise_seed"].append(noise_seed(cfg.seed, density_index, vi, trial))
            try:
                traj = plan(w, v_max, a_max, clearance=cfg.clearance)
            except PlanningError as exc:
                _nan_record(rec, cfg, "no-plan", str(exc))
                continue
            rec["planned"].append(True)
            rec["path_clearance"].append(path_clearance(w, traj))
            rec["duration"]["planned"].append(traj.duration)
            rows["planned"].append(table_rows(planned_sampler(traj), traj.duration,
                                               cfg.rate_hz))
            for t_mem, key in zip(cfg.memories, keys, strict=True):
                res = retime(RetimeInput(
                    traj, limits=Limits(v_max, a_max), smoothness=cfg.smoothness,
                    dtau=cfg.dtau, safety=Safety(map=vm, braking=braking,
                                                 uncertainty=UncertaintyModel(memory_s=t_mem))))
                rec["status"][key].append(res.status)
                rec["message"][key].append(res.message)
                rec["braking_fraction"][key].append(
                    float(np.mean(_or_zero(res.diagnostics.braking_mask))))
                rec["approach_fraction"][key].append(
                    float(np.mean(_or_zero(res.diagnostics.approach_mask))))
                rec["duration"][rota_arm(t_mem)].append(res.duration)
                rows[rota_arm(t_mem)].append(table_rows(rota_sampler(res), res.duration,
                                                         cfg.rate_hz))
                if cfg.uniform:
                    scale = traj.duration / res.duration
                    rec["duration"][uniform_arm(t_mem)].append(res.duration)
                    rows[uniform_arm(t_mem)].append(table_rows(
                        planned_sampler(traj, scale), res.duration, cfg.rate_hz))
            flown.append(j)
        prep_time += time.perf_counter() - t0
        n_trials = len(trials)
        flights: dict = {}
        idx = np.array(flown, dtype=np.intp)
        if flown:
            t1 = time.perf_counter()
            table = SetpointTable.from_lists(cfg.rate_hz, [r for a in arms for r in rows[a]])
            fly_worlds = BatchWorlds.from_worlds([worlds[j] for _ in arms for j in flown])
            t_end = np.array([rec["duration"][a][j] + cfg.settle_s for a in arms for j in flown])
            seeds = np.array([rec["noise_seed"][j] for _ in arms for j in flown], dtype=np.int64)
            radius = worlds[0].robot_radius
            for err in cfg.errors:
                res_b = simulate(table, fly_worlds, t_end, seeds, estimation=err,
                                 quad=VEHICLES[cfg.vehicle], collide_at_any_altitude=True,
                                 ground_ends_flight=True)
                per_arm = {}
                for k, arm in enumerate(arms):
                    sl = slice(k * len(flown), (k + 1) * len(flown))
                    o = {"collided": np.zeros(n_trials, bool), "ground": np.zeros(n_trials, bool),
                         "closest": np.full(n_trials, np.nan),
                         "end_time": np.full(n_trials, np.nan)}
                    o["collided"][idx] = res_b.collided[sl]
                    o["ground"][idx] = res_b.ground_contact[sl]
                    o["closest"][idx] = res_b.min_distance[sl] - radius
                    o["end_time"][idx] = res_b.end_time[sl]
                    per_arm[arm] = {k2: v.tolist() for k2, v in o.items()}
                flights[err.kind] = per_arm
            sim_time += time.perf_counter() - t1
        out["speeds"][vi] = {**rec, "flights": flights}
    out["prep_time"] = prep_time
    out["sim_time"] = sim_time
    return out


def _run_task_args(args: tuple[ExperimentConfig, int, list[int]]) -> dict:
    return run_task(*args)


# ---------------------------------------------------------------------- whole run
@dataclass(frozen=True)
class ExperimentResult:
    """A finished run: the configuration, per-cell statistics (one list per error model),
    per-trial data, timing."""

    config: ExperimentConfig
    cells: dict[str, list[CellResult]]
    trials: dict[tuple[int, int], dict]
    wall_time_s: float
    prep_time_s: float
    sim_time_s: float

    def cell(self, kind: str, density: float, v_max: float) -> CellResult:
        return next(c for c in self.cells[kind] if c.density == density and c.v_max == v_max)

    @property
    def claim_holds(self) -> bool:
        """ROTA with memory significantly safer than its equal-time uniform slow-down
        wherever the claim applies, under every error model (see CellResult.claim)."""
        return all(c.claim in ("holds", "n/a") for cs in self.cells.values() for c in cs)


def _merge(into: dict, part: dict) -> None:
    for key, val in part.items():
        if isinstance(val, dict):
            _merge(into.setdefault(key, {}), val)
        else:
            into.setdefault(key, []).extend(val)


def run_experiment(config: ExperimentConfig,
                   progress: Callable[[str], None] | None = None) -> ExperimentResult:
    """Run the grid (see module doc); ``progress`` receives one line per finished task."""
    t0 = time.perf_counter()
    tasks = [(config, di, list(range(s, min(config.trials, s + config.chunk))))
             for di in range(len(config.densities))
             for s in range(0, config.trials, config.chunk)]
    outs = []

    def done(out: dict) -> None:
        outs.append(out)
        if progress:
            progress(f"task {len(outs)}/{len(tasks)} done ({time.perf_counter() - t0:.0f} s)")

    if config.workers > 1 and len(tasks) > 1:
        ctx = multiprocessing.get_context("spawn" if os.name == "nt" else "fork")
        with ctx.Pool(config.workers) as pool:
            for out in pool.imap_unordered(_run_task_args, tasks):
                done(out)
    else:
        for task in tasks:
            done(_run_task_args(task))
    merged: dict[tuple[int, int], dict] = {}
    for out in sorted(outs, key=lambda o: (o["density_index"], o["trials"][0])):
        for vi, data in out["speeds"].items():
            _merge(merged.setdefault((out["density_index"], vi), {}), data)
    cells = {err.kind: [cell_stats(config, err.kind, di, vi, merged[(di, vi)])
                        for di in range(len(config.densities))
                        for vi in range(len(config.speeds))]
             for err in config.errors}
    return ExperimentResult(config, cells, merged, time.perf_counter() - t0,
                            sum(o["prep_time"] for o in outs), sum(o["sim_time"] for o in outs))
