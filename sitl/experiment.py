"""The paper's Table I on our stack: collision rates with and without ROTA (issue #8).

Grid (paper Sec. IV-A): forest densities 0.025 / 0.043 / 0.063 trees per m^2 in a 20 m x 20 m
map, speed limits 1 / 2 / 3 m/s, acceleration limit ``a_max = accel_ratio * v_max``. For each
density and trial one random forest is drawn (its seed derived from the experiment seed) and
shared by the three speeds. For each speed the reference planner (:func:`sitl.planner.plan`)
plans a collision-free B-spline at (v_max, a_max), and the trajectory is flown twice in the
batched simulator (:mod:`sitl.batch`, validated against :class:`sitl.vehicle.SimVehicle`) with
the same world and the same estimation-noise seed:

* **planned**: the B-spline's own timing, streamed at 50 Hz as position + velocity +
  acceleration setpoints;
* **ROTA**: the same path re-timed by :func:`rota.retime` with ROTA's defaults (lambda 0.5,
  dtau 0.1 s, ``Safety`` with the world's 0.1 m voxel map, ``UncertaintyModel()`` m = 0.2,
  b = -0.1, ``ChanceParams()`` Delta = 1e-4, 0.3 m robot sphere), same limits.

Both start hovering at rest at the start; a flight ends at a collision (the true position
within ``robot_radius`` of a tree) or ``settle_s`` after the trajectory's end.

Statistics per cell: collision rate with a 95 % Wilson interval for each arm, the paired exact
McNemar test (one-sided: ROTA collides less), mean trajectory duration of each arm, and the
closest approach (smallest true distance to a tree surface minus the robot radius).

Work is split into tasks of ``chunk`` trials of one density; each task (one process of the
pool) plans, re-times and flies its trials; results do not depend on the chunking or the number
of workers (every random draw comes from a seed derived from (seed, density, speed, trial)).
"""

from __future__ import annotations

import json
import math
import multiprocessing
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy import stats

from rota import Limits, RetimeInput, retime
from rota.braking import BrakingParams
from rota.robust import Safety
from rota.trajectory import Trajectory
from rota.voxelmap import VoxelMap
from sitl.batch import BatchWorlds, SetpointTable, simulate
from sitl.estimation import EstimationErrorParams
from sitl.planner import PlanningError, plan
from sitl.world import World, forest

FloatArray = NDArray[np.float64]

#: The paper's Table I (collision rate in %, with / without time allocation, 50 trials).
PAPER_TABLE1: dict[float, dict[float, tuple[float, float]]] = {
    0.025: {1.0: (0.0, 0.0), 2.0: (0.0, 0.0), 3.0: (0.0, 2.0)},
    0.043: {1.0: (0.0, 2.0), 2.0: (2.0, 8.0), 3.0: (4.0, 10.0)},
    0.063: {1.0: (0.0, 6.0), 2.0: (2.0, 12.0), 3.0: (2.0, 14.0)},
}
DENSITY_NAMES = {0.025: "Low", 0.043: "Mid", 0.063: "High"}
ARMS = ("planned", "rota")


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
        d_th: ROTA's braking-zone distance threshold (None: ROTA's default, 1 m); for
            sensitivity runs only.
        rejected: what the statistics do with trials whose path ROTA rejects as unsafe
            (status ``rejected``: the path passes too close to the map for the chance
            constraint even at rest; the companion refuses to fly it): ``"exclude"`` leaves
            them out of both arms (the paired comparison is on the paths ROTA accepts; they
            are counted separately), ``"fallback"`` counts the ROTA arm as flying the
            library's fallback timing (uniformly slowed), which every trial flies anyway.
        estimation: the vehicle's estimation-error model (paper-like m = 0.2, b = -0.1).
        size: map edge (m).
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
    estimation: EstimationErrorParams = field(default_factory=EstimationErrorParams)
    size: float = 20.0
    d_th: float | None = None
    rejected: str = "exclude"

    def a_max(self, v_max: float) -> float:
        return self.accel_ratio * v_max


def world_seed(seed: int, density_index: int, trial: int) -> int:
    """Forest seed of a trial (shared by the three speeds)."""
    return int(np.random.SeedSequence([seed, 0, density_index, trial]).generate_state(1)[0])


def noise_seed(seed: int, density_index: int, speed_index: int, trial: int) -> int:
    """Estimation-noise seed of a trial (shared by its two flights)."""
    state = np.random.SeedSequence([seed, 1, density_index, speed_index, trial]).generate_state(
        1, dtype=np.uint64)[0]
    return int(state >> np.uint64(1))


# ---------------------------------------------------------------------- statistics
def wilson(k: int, n: int, z: float = 1.959963984540054) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion ``k / n`` (default 95 %)."""
    if n == 0:
        return (0.0, 1.0)
    p = k / n
    den = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    lo = 0.0 if k == 0 else max(0.0, centre - half)  # exact ends (no rounding residue)
    hi = 1.0 if k == n else min(1.0, centre + half)
    return (lo, hi)


def mcnemar_one_sided(planned: NDArray[np.bool_], rota: NDArray[np.bool_]) -> float:
    """Exact McNemar p-value for "ROTA collides less often" on paired outcomes.

    Only discordant pairs count: ``b`` = planned collides and ROTA not, ``c`` = the
    reverse; under H0 ``b ~ Binomial(b + c, 1/2)``; p = P(X >= b). 1.0 without discordance.
    """
    b = int(np.sum(planned & ~rota))
    c = int(np.sum(~planned & rota))
    if b + c == 0:
        return 1.0
    return float(stats.binomtest(b, b + c, 0.5, alternative="greater").pvalue)


# ---------------------------------------------------------------------- one task
def _table_rows(sample: Callable[[FloatArray], tuple[FloatArray, FloatArray, FloatArray]],
                duration: float, rate_hz: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    t = np.arange(int(math.floor(duration * rate_hz + 1e-9)) + 1) / rate_hz
    if t[-1] < duration:
        t = np.append(t, duration)  # the end state (rest at the goal) as the last row
    p, v, a = sample(t)
    return p, v, a


def _planned_sampler(traj: Trajectory):
    def sample(t: FloatArray):
        return traj.evaluate(np.minimum(t, traj.duration))
    return sample


def _rota_sampler(result):
    def sample(t: FloatArray):
        s = result.sample(t)
        return s.position, s.velocity, s.acceleration
    return sample


def run_task(config: ExperimentConfig, density_index: int, trials: Sequence[int]) -> dict:
    """Plan, re-time and fly ``trials`` of one density at every speed. Returns per-trial
    arrays per speed (see :func:`run_experiment` for the keys)."""
    density = config.densities[density_index]
    t_prep = time.perf_counter()
    worlds: list[World] = []
    maps: list[VoxelMap] = []
    for trial in trials:
        w = forest(density, world_seed(config.seed, density_index, trial), size=config.size)
        worlds.append(w)
        maps.append(VoxelMap.from_points(w.voxel_points(config.map_resolution),
                                         config.map_resolution))
    out: dict = {"density_index": density_index, "trials": list(trials), "speeds": {}}
    prep_time = time.perf_counter() - t_prep
    sim_time = 0.0
    braking = BrakingParams() if config.d_th is None else BrakingParams(d_th=config.d_th)
    for vi, v_max in enumerate(config.speeds):
        t0 = time.perf_counter()
        a_max = config.a_max(v_max)
        rows: list[tuple[FloatArray, FloatArray, FloatArray]] = []
        t_end: list[float] = []
        seeds: list[int] = []
        fly_worlds: list[World] = []
        rec: dict[str, list] = {k: [] for k in (
            "trial", "planned", "status", "message", "duration_planned", "duration_rota",
            "path_clearance", "braking_fraction", "noise_seed", "world_seed")}
        for trial, w, vm in zip(trials, worlds, maps, strict=True):
            rec["trial"].append(trial)
            rec["world_seed"].append(world_seed(config.seed, density_index, trial))
            ns = noise_seed(config.seed, density_index, vi, trial)
            rec["noise_seed"].append(ns)
            try:
                traj = plan(w, v_max, a_max)
            except PlanningError as exc:
                rec["planned"].append(False)
                rec["status"].append("no-plan")
                rec["message"].append(str(exc))
                for k in ("duration_planned", "duration_rota", "path_clearance",
                          "braking_fraction"):
                    rec[k].append(math.nan)
                continue
            res = retime(RetimeInput(traj, limits=Limits(v_max, a_max),
                                     smoothness=config.smoothness, dtau=config.dtau,
                                     safety=Safety(map=vm, braking=braking)))
            tau = np.linspace(0.0, traj.duration, max(2, int(traj.duration / 0.01) + 1))
            clearance = float(np.min(w.signed_distance(traj.position(tau)))) - w.robot_radius
            mask = res.extras.get("braking_mask")
            rec["planned"].append(True)
            rec["status"].append(res.status)
            rec["message"].append(res.message)
            rec["duration_planned"].append(traj.duration)
            rec["duration_rota"].append(res.duration)
            rec["path_clearance"].append(clearance)
            rec["braking_fraction"].append(float(np.mean(mask)) if mask is not None else 0.0)
            for sample, dur in ((_planned_sampler(traj), traj.duration),
                                (_rota_sampler(res), res.duration)):
                rows.append(_table_rows(sample, dur, config.rate_hz))
                t_end.append(dur + config.settle_s)
                seeds.append(ns)
                fly_worlds.append(w)
        prep_time += time.perf_counter() - t0
        n_trials = len(trials)
        flown = np.array(rec["planned"], dtype=bool)
        col = {arm: np.zeros(n_trials, dtype=bool) for arm in ARMS}
        min_d = {arm: np.full(n_trials, np.nan) for arm in ARMS}
        extra = {arm: {k: np.full(n_trials, np.nan) for k in (
            "collision_time", "max_tracking_error", "max_speed")} for arm in ARMS}
        ground = {arm: np.zeros(n_trials, dtype=bool) for arm in ARMS}
        if rows:
            t1 = time.perf_counter()
            table = SetpointTable.from_lists(config.rate_hz, rows)
            res_b = simulate(table, BatchWorlds.from_worlds(fly_worlds), np.array(t_end),
                             np.array(seeds, dtype=np.int64), estimation=config.estimation)
            sim_time += time.perf_counter() - t1
            idx = np.flatnonzero(flown)
            for j, arm in enumerate(ARMS):
                sl = slice(j, None, 2)
                col[arm][idx] = res_b.collided[sl]
                min_d[arm][idx] = res_b.min_distance[sl] - fly_worlds[0].robot_radius
                ground[arm][idx] = res_b.ground_contact[sl]
                extra[arm]["collision_time"][idx] = res_b.collision_time[sl]
                extra[arm]["max_tracking_error"][idx] = res_b.max_tracking_error[sl]
                extra[arm]["max_speed"][idx] = res_b.max_speed[sl]
        out["speeds"][vi] = {
            **{k: v for k, v in rec.items()},
            "collided": {a: col[a].tolist() for a in ARMS},
            "closest": {a: min_d[a].tolist() for a in ARMS},
            "ground_contact": {a: ground[a].tolist() for a in ARMS},
            **{k: {a: extra[a][k].tolist() for a in ARMS} for k in (
                "collision_time", "max_tracking_error", "max_speed")},
        }
    out["prep_time"] = prep_time
    out["sim_time"] = sim_time
    return out


def _run_task_args(args: tuple[ExperimentConfig, int, list[int]]) -> dict:
    return run_task(*args)


# ---------------------------------------------------------------------- whole run
@dataclass(frozen=True)
class CellResult:
    """Statistics of one (density, speed) cell."""

    density: float
    v_max: float
    a_max: float
    n: int
    collisions: dict[str, int]
    rate: dict[str, float]
    ci95: dict[str, tuple[float, float]]
    discordant: tuple[int, int]
    p_mcnemar: float
    mean_duration: dict[str, float]
    closest_median: dict[str, float]
    closest_p05: dict[str, float]
    ground_contacts: dict[str, int]
    retime_status: dict[str, int]
    rejected_planned_collisions: int
    plan_failures: int
    path_clearance_min: float
    braking_fraction_mean: float

    @property
    def rota_not_higher(self) -> bool:
        return self.collisions["rota"] <= self.collisions["planned"]

    @property
    def needs_significance(self) -> bool:
        return self.rate["planned"] > 0.05

    @property
    def significant(self) -> bool:
        """Non-overlapping Wilson intervals or p < 0.05 (one-sided exact McNemar)."""
        disjoint = self.ci95["rota"][1] < self.ci95["planned"][0]
        return disjoint or self.p_mcnemar < 0.05

    @property
    def done(self) -> bool:
        return self.rota_not_higher and (not self.needs_significance or self.significant)


def cell_stats(config: ExperimentConfig, density_index: int, speed_index: int,
               data: dict) -> CellResult:
    """Statistics of one cell from the merged per-trial data."""
    planned_ok = np.array(data["planned"], dtype=bool)
    rejected = planned_ok & (np.array(data["status"]) == "rejected")
    flown = planned_ok & ~rejected if config.rejected == "exclude" else planned_ok
    n = int(flown.sum())
    col = {a: np.array(data["collided"][a], dtype=bool)[flown] for a in ARMS}
    closest = {a: np.array(data["closest"][a], dtype=float)[flown] for a in ARMS}
    k = {a: int(col[a].sum()) for a in ARMS}
    status = [s for s, f in zip(data["status"], planned_ok, strict=True) if f]
    dur = {"planned": np.array(data["duration_planned"], dtype=float)[flown],
           "rota": np.array(data["duration_rota"], dtype=float)[flown]}
    v = config.speeds[speed_index]
    return CellResult(
        density=config.densities[density_index], v_max=v, a_max=config.a_max(v), n=n,
        collisions=k, rate={a: k[a] / n if n else math.nan for a in ARMS},
        ci95={a: wilson(k[a], n) for a in ARMS},
        discordant=(int(np.sum(col["planned"] & ~col["rota"])),
                    int(np.sum(~col["planned"] & col["rota"]))),
        p_mcnemar=mcnemar_one_sided(col["planned"], col["rota"]),
        mean_duration={a: float(np.mean(dur[a])) if n else math.nan for a in ARMS},
        closest_median={a: float(np.median(closest[a])) if n else math.nan for a in ARMS},
        closest_p05={a: float(np.percentile(closest[a], 5)) if n else math.nan for a in ARMS},
        ground_contacts={a: int(np.sum(np.array(data["ground_contact"][a], dtype=bool)[flown]))
                         for a in ARMS},
        retime_status={s: status.count(s) for s in sorted(set(status))},
        rejected_planned_collisions=int(np.sum(np.array(data["collided"]["planned"],
                                                        dtype=bool)[rejected])),
        plan_failures=int((~planned_ok).sum()),
        path_clearance_min=float(np.nanmin(data["path_clearance"])) if n else math.nan,
        braking_fraction_mean=float(np.nanmean(data["braking_fraction"])) if n else math.nan,
    )


@dataclass(frozen=True)
class ExperimentResult:
    """A finished run: the configuration, per-cell statistics, per-trial data, timing."""

    config: ExperimentConfig
    cells: list[CellResult]
    trials: dict[tuple[int, int], dict]
    wall_time_s: float
    prep_time_s: float
    sim_time_s: float

    @property
    def done(self) -> bool:
        return all(c.done for c in self.cells)

    def cell(self, density: float, v_max: float) -> CellResult:
        return next(c for c in self.cells if c.density == density and c.v_max == v_max)


def run_experiment(config: ExperimentConfig,
                   progress: Callable[[str], None] | None = None) -> ExperimentResult:
    """Run the grid (see module doc); ``progress`` receives one line per finished task."""
    t0 = time.perf_counter()
    tasks = []
    for di in range(len(config.densities)):
        for s in range(0, config.trials, config.chunk):
            tasks.append((config, di, list(range(s, min(config.trials, s + config.chunk)))))
    if config.workers > 1 and len(tasks) > 1:
        ctx = multiprocessing.get_context("spawn" if os.name == "nt" else "fork")
        with ctx.Pool(config.workers) as pool:
            outs = []
            for out in pool.imap_unordered(_run_task_args, tasks):
                outs.append(out)
                if progress:
                    progress(f"task {len(outs)}/{len(tasks)} done "
                             f"({time.perf_counter() - t0:.0f} s)")
    else:
        outs = []
        for task in tasks:
            outs.append(_run_task_args(task))
            if progress:
                progress(f"task {len(outs)}/{len(tasks)} done ({time.perf_counter() - t0:.0f} s)")
    merged: dict[tuple[int, int], dict] = {}
    for out in sorted(outs, key=lambda o: (o["density_index"], o["trials"][0])):
        for vi, data in out["speeds"].items():
            cell = merged.setdefault((out["density_index"], vi), {})
            for key, val in data.items():
                if isinstance(val, dict):
                    sub = cell.setdefault(key, {})
                    for a, lst in val.items():
                        sub.setdefault(a, []).extend(lst)
                else:
                    cell.setdefault(key, []).extend(val)
    cells = [cell_stats(config, di, vi, merged[(di, vi)])
             for di in range(len(config.densities)) for vi in range(len(config.speeds))]
    return ExperimentResult(config, cells, merged, time.perf_counter() - t0,
                            sum(o["prep_time"] for o in outs), sum(o["sim_time"] for o in outs))


# ---------------------------------------------------------------------- reports
def _pct(x: float) -> str:
    return f"{100 * x:.1f} %"


def markdown_table(result: ExperimentResult, command: str | None = None) -> str:
    """The paper's layout (rows: density, columns: speed, cells: "with / without" ROTA) and
    the detailed table (CIs, test, flight times, closest approach)."""
    cfg = result.config
    lines = []
    if command:
        lines += [f"Command: `{command}`", ""]
    lines += [
        f"Seed {cfg.seed}, {cfg.trials} trials per cell, a_max = {cfg.accel_ratio:g} * v_max, "
        f"estimation error sigma = max({cfg.estimation.slope_s:g} |v| + "
        f"({cfg.estimation.offset_m:g}), {cfg.estimation.min_std_m:g}) m per axis, "
        f"tau = {cfg.estimation.correlation_time_s:g} s"
        + ("" if cfg.d_th is None else f"; ROTA braking threshold d_th = {cfg.d_th:g} m")
        + f"; paths ROTA rejects: {cfg.rejected}.",
        "",
        "Collision rate with / without ROTA (paper Table I layout; paper values in brackets, "
        "50 trials there):",
        "",
        "| density | " + " | ".join(f"v = {v:g} m/s" for v in cfg.speeds) + " |",
        "|---|" + "---|" * len(cfg.speeds),
    ]
    for d in cfg.densities:
        row = [f"{DENSITY_NAMES.get(d, '')} ({d:g}/m^2)".strip()]
        for v in cfg.speeds:
            c = result.cell(d, v)
            paper = PAPER_TABLE1.get(d, {}).get(v)
            ref = f" ({paper[0]:g} / {paper[1]:g} %)" if paper else ""
            row.append(f"{_pct(c.rate['rota'])} / {_pct(c.rate['planned'])}{ref}")
        lines.append("| " + " | ".join(row) + " |")
    lines += [
        "",
        "Details (95 % Wilson intervals; p: exact one-sided McNemar test on the paired "
        "flights, b = only the planned flight collided, c = only the ROTA flight; flight time: "
        "mean trajectory duration; closest approach: smallest true distance to a tree surface "
        "minus the 0.3 m robot radius, median and 5th percentile, negative = collision; "
        "ground: flights whose true position touched the ground (z = 0; not counted as "
        "collisions); n: trials in the comparison):",
        "",
        "| density | v, a | n | without ROTA | with ROTA | b / c | p | done | "
        "flight time w/o -> w/ | closest w/o: median (p5) | closest w/: median (p5) | "
        "ground w/o / w/ | ROTA status |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c in result.cells:
        ci = {a: f"{_pct(c.rate[a])} [{100 * c.ci95[a][0]:.1f}, {100 * c.ci95[a][1]:.1f}]"
              for a in ARMS}
        status = ", ".join(f"{k} {v}" for k, v in c.retime_status.items())
        if c.retime_status.get("rejected"):
            status += (f" ({c.rejected_planned_collisions} of them collided without ROTA; "
                       f"{'excluded' if cfg.rejected == 'exclude' else 'fallback flown'})")
        if c.plan_failures:
            status += f"; no plan {c.plan_failures}"
        done = "yes" if c.done else "**no**"
        lines.append(
            f"| {c.density:g} | {c.v_max:g}, {c.a_max:g} | {c.n} | {ci['planned']} | "
            f"{ci['rota']} | {c.discordant[0]} / {c.discordant[1]} | {c.p_mcnemar:.2g} | "
            f"{done} | {c.mean_duration['planned']:.2f} s -> {c.mean_duration['rota']:.2f} s | "
            f"{c.closest_median['planned']:.3f} ({c.closest_p05['planned']:.3f}) m | "
            f"{c.closest_median['rota']:.3f} ({c.closest_p05['rota']:.3f}) m | "
            f"{c.ground_contacts['planned']} / {c.ground_contacts['rota']} | {status} |")
    lines += ["", f"Done-when (ROTA never higher; significant where the unretimed rate > 5 %): "
              f"**{'holds' if result.done else 'does not hold'}**."]
    return "\n".join(lines) + "\n"


def plot(result: ExperimentResult, path: str) -> None:
    """Collision rates with 95 % intervals per cell, and closest-approach distributions."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cfg = result.config
    nd = len(cfg.densities)
    fig, axes = plt.subplots(2, nd, figsize=(4.2 * nd, 7.5), squeeze=False)
    for j, d in enumerate(cfg.densities):
        ax = axes[0, j]
        x = np.arange(len(cfg.speeds))
        for k, (arm, label, colour) in enumerate((("planned", "without ROTA", "tab:red"),
                                                   ("rota", "with ROTA", "tab:blue"))):
            cells = [result.cell(d, v) for v in cfg.speeds]
            rate = np.array([100 * c.rate[arm] for c in cells])
            lo = np.array([100 * c.ci95[arm][0] for c in cells])
            hi = np.array([100 * c.ci95[arm][1] for c in cells])
            ax.bar(x + (k - 0.5) * 0.38, rate, 0.38, color=colour, alpha=0.8, label=label,
                   yerr=np.maximum(np.vstack([rate - lo, hi - rate]), 0.0), capsize=3)
            paper = [PAPER_TABLE1.get(d, {}).get(v) for v in cfg.speeds]
            if all(p is not None for p in paper):
                ax.plot(x + (k - 0.5) * 0.38, [p[1 - k] for p in paper], "k_", ms=14,
                        mew=2, label="paper (50 trials)" if k == 0 else None)
        ax.set_xticks(x, [f"{v:g} m/s" for v in cfg.speeds])
        ax.set_title(f"density {d:g}/m^2")
        ax.set_ylabel("collision rate (%)")
        if j == 0:
            ax.legend(fontsize=8)
        ax = axes[1, j]
        bins = np.linspace(-0.35, 1.0, 55)
        for v, ls in zip(cfg.speeds, ("-", "--", ":"), strict=False):
            di, vi = cfg.densities.index(d), cfg.speeds.index(v)
            data = result.trials[(di, vi)]
            for arm, colour in (("planned", "tab:red"), ("rota", "tab:blue")):
                vals = np.array(data["closest"][arm], dtype=float)
                vals = vals[np.isfinite(vals)]
                ax.hist(np.clip(vals, bins[0], bins[-1]), bins, histtype="step", color=colour,
                        ls=ls, label=f"{'w/o' if arm == 'planned' else 'w/'} ROTA, {v:g} m/s")
        ax.axvline(0.0, color="k", lw=0.8)
        ax.set_xlabel("closest approach: distance to tree - robot radius (m)")
        ax.set_ylabel("flights")
        if j == 0:
            ax.legend(fontsize=7)
    fig.suptitle(f"Collision rates with / without ROTA ({cfg.trials} trials per cell, "
                 f"seed {cfg.seed}, a_max = {cfg.accel_ratio:g} v_max)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def to_json(result: ExperimentResult) -> dict:
    """JSON-friendly dict of the run (configuration, cell statistics, per-trial data)."""
    cfg = asdict(result.config)
    cells = []
    for c in result.cells:
        d = asdict(c)
        d.update(done=c.done, significant=c.significant, rota_not_higher=c.rota_not_higher)
        cells.append(d)
    trials = {f"{result.config.densities[di]:g}/{result.config.speeds[vi]:g}": _rounded(data)
              for (di, vi), data in result.trials.items()}
    return {"schema": "rota/table1", "version": 1, "config": cfg, "cells": cells,
            "wall_time_s": result.wall_time_s, "prep_time_s": result.prep_time_s,
            "sim_time_s": result.sim_time_s, "trials": trials}


def _rounded(value: object) -> object:
    """Per-trial floats to 0.1 mm / 0.1 ms (keeps the JSON small); seeds stay exact."""
    if isinstance(value, float):
        return round(value, 4) if math.isfinite(value) else value
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_rounded(v) for v in value]
    return value


def write_outputs(result: ExperimentResult, out_dir: str, command: str | None = None) -> dict:
    """Write ``table1.md``, ``table1.png`` and ``table1.json`` into ``out_dir``."""
    os.makedirs(out_dir, exist_ok=True)
    paths = {k: os.path.join(out_dir, f"table1.{k}") for k in ("md", "png", "json")}
    with open(paths["md"], "w") as f:
        f.write(markdown_table(result, command))
        f.write(f"\nRun time: {result.wall_time_s:.1f} s wall with {result.config.workers} "
                f"worker(s) (planning + re-timing {result.prep_time_s:.1f} s, flights "
                f"{result.sim_time_s:.1f} s, summed over workers).\n")
    plot(result, paths["png"])
    with open(paths["json"], "w") as f:
        json.dump(to_json(result), f, allow_nan=True)
    return paths
