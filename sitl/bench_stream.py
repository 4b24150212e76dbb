"""``rota-sitl bench-stream``: setpoint-stream jitter at 50 Hz while
re-times run back to back.

The service runs as deployed, in its own process (:class:`sitl.proving.Flight`:
the `sitl` vehicle in another, a ground station on Zenoh in this one), so nothing
the benchmark does shares the service's event loop. The vehicle takes off and the
service holds in offboard; we measure the setpoint stream for a while with nothing
to solve (the baseline, in the same run), then publish the bundled 30 m forest
trajectory with its map again and again for as long, each as soon as the previous
one is re-timed at dtau = 0.01 s. Every figure comes from the setpoints the
vehicle received: their send stamps (the service's clock, whole milliseconds) and
their arrival times.
"""

from __future__ import annotations

import asyncio
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from rota.schema import TrajectoryMessage, trajectory_to_dict
from rota.trajectory import BSplineTrajectory
from rota.voxelmap import VoxelMap
from sitl.bench import load_data
from sitl.demo import start_holding, take_off
from sitl.proving import Flight


def _jitter_p99_ms(times: np.ndarray, period: float) -> float:
    """99th percentile of |period - nominal| (ms)."""
    return float(np.percentile(np.abs(np.diff(times) - period), 99) * 1e3)


async def _scenario(f: Flight, seconds: float) -> dict[str, Any]:
    trajs, vmap = load_data()
    traj = trajs["30m"]
    gs = f.gs
    await take_off(gs)
    here = await start_holding(gs)
    shift = here - traj.position(traj.domain[0])[0]
    local = BSplineTrajectory(control_points=traj.control_points + shift,
                              degree=traj.degree, knot_span=traj.knot_span)
    gs.publish("map", VoxelMap(vmap.resolution, vmap.occupied + shift,
                               origin=vmap.origin + shift).to_dict())
    await gs.wait_for(lambda s: s.get("map_voxels"), 10, "map")
    t_base = time.monotonic()
    await asyncio.sleep(seconds)
    t_busy = t_end = time.monotonic()
    solves: list[float] = []
    while time.monotonic() < t_busy + seconds:
        n_before = len(gs.retimed)
        gs.publish("trajectory", trajectory_to_dict(
            TrajectoryMessage(local, id=f"long{len(solves)}", stamp=time.time())))
        end = time.monotonic() + 5.0
        while len(gs.retimed) == n_before and time.monotonic() < end:
            await asyncio.sleep(0.005)
        if len(gs.retimed) == n_before:
            break  # refused (once the vehicle moves, a path from rest is): window ends
        solves.append(gs.retimed[-1]["solver"]["wall_time"])
        t_end = time.monotonic()
    return {"t_base": t_base, "t_busy": t_busy, "t_end": t_end, "solves": solves,
            "grid_nodes": int(np.ceil(traj.duration / f.cfg.limits.dtau)) + 1}


def run_bench_stream(out: str | None = None, seconds: float = 5.0) -> dict[str, Any]:
    flight = Flight(world="empty", limits={"dtau": 0.01, "max_solve_s": 20.0},
                    safety={"geofence_min": [-60.0, -60.0, -1.0],
                            "geofence_max": [60.0, 60.0, 10.0], "stitch_tolerance_m": 1.0},
                    estimator={"enabled": False})
    with flight:
        run = asyncio.run(_scenario(flight, seconds))
        sp = flight.sim.setpoints()
    period = 1.0 / flight.cfg.stream.rate_hz
    result: dict[str, Any] = {"rate_hz": flight.cfg.stream.rate_hz,
                              "dtau": flight.cfg.limits.dtau, "grid_nodes": run["grid_nodes"],
                              "retimes": len(run["solves"]),
                              "median_solve_ms": float(np.median(run["solves"]) * 1e3)
                              if run["solves"] else None}
    for name, (t0, t1) in (("baseline", (run["t_base"], run["t_busy"])),
                           ("busy", (run["t_busy"], run["t_end"]))):
        keep = (sp["wall_time"] >= t0) & (sp["wall_time"] <= t1)
        figures = flight.figures((t0, t1), sp)
        result[name] = {"seconds": t1 - t0, "setpoints": int(keep.sum()),
                        "jitter_p99_ms": _jitter_p99_ms(sp["sent_s"][keep], period),
                        "arrival_jitter_p99_ms": _jitter_p99_ms(sp["wall_time"][keep], period),
                        "max_gap_ms": figures.max_gap_s * 1e3,
                        "p99_gap_ms": figures.p99_gap_s * 1e3,
                        "problems": figures.problems()}
    base, busy = result["baseline"], result["busy"]
    result["ratio"] = busy["jitter_p99_ms"] / max(base["jitter_p99_ms"], 1e-9)
    print(f"setpoint stream at {result['rate_hz']:.0f} Hz, period jitter p99 (send stamps, "
          f"1 ms resolution): {base['jitter_p99_ms']:.2f} ms idle ({base['setpoints']} "
          f"setpoints), {busy['jitter_p99_ms']:.2f} ms while {result['retimes']} re-times of "
          f"the 30 m trajectory at dtau = {result['dtau']} s ran back to back "
          f"({result['grid_nodes']} nodes, solver median {result['median_solve_ms']:.1f} ms; "
          f"{busy['setpoints']} setpoints) -> ratio {result['ratio']:.2f}; largest gap "
          f"{busy['max_gap_ms']:.0f} ms, p99 gap {busy['p99_gap_ms']:.1f} ms; arrival jitter "
          f"p99 {base['arrival_jitter_p99_ms']:.2f} / {busy['arrival_jitter_p99_ms']:.2f} ms")
    if out:
        Path(out).mkdir(parents=True, exist_ok=True)
        (Path(out) / "stream.json").write_text(json.dumps(result, indent=1) + "\n")
    return result
