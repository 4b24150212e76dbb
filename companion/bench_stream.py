"""``rota-companion bench-stream``: setpoint-stream jitter at 50 Hz while long
re-times run (issue #6's benchmark).

The `sitl` vehicle (own process) takes off; the service holds in offboard; we
measure the period jitter of the setpoint stream for a while with nothing to
solve (the baseline, measured in the same run), then publish the bundled 30 m
forest trajectory with its map again and again, re-timed at dtau = 0.01 s, and
measure the jitter while those re-times run. Prints both and their ratio.
"""

from __future__ import annotations

import asyncio
import json
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from companion.demo import demo_config, free_tcp_port, running, take_off
from rota.bench import load_data
from rota.schema import TrajectoryMessage, trajectory_to_dict
from rota.trajectory import BSplineTrajectory
from rota.voxelmap import VoxelMap
from sitl.mavsdk_util import free_udp_port
from sitl.process import SimProcess


def _p99_ms(times: np.ndarray, period: float) -> float:
    dt = np.diff(times)
    return float(np.percentile(np.abs(dt - period), 99) * 1e3)


def _window(sent: list[tuple[float, Any]], t0: float, t1: float) -> np.ndarray:
    return np.array([t for t, _ in sent if t0 <= t <= t1])


async def _run(cfg, rounds: int) -> dict[str, Any]:  # noqa: ANN001
    trajs, vmap = load_data()
    traj = trajs["30m"]
    async with running(cfg) as (service, gs):
        await take_off(gs)
        assert (await gs.command("start"))["ok"]
        await asyncio.sleep(1.0)
        here = np.asarray(gs.telemetry["position"])
        shift = here - traj.position(traj.domain[0])[0]
        local = BSplineTrajectory(control_points=traj.control_points + shift,
                                  degree=traj.degree, knot_span=traj.knot_span)
        gs.publish("map", VoxelMap(vmap.resolution, vmap.occupied + shift,
                                   origin=vmap.origin + shift).to_dict())
        await gs.wait_for(lambda s: s.get("map_voxels"), 10, "map")
        t_base = time.monotonic()
        await asyncio.sleep(5.0)
        t_busy = time.monotonic()
        solves = []
        for k in range(rounds):
            n_before = len(gs.retimed)
            msg = trajectory_to_dict(TrajectoryMessage(local, id=f"long{k}", stamp=time.time()))
            gs.publish("trajectory", msg)
            end = time.monotonic() + 20
            while len(gs.retimed) == n_before and time.monotonic() < end:
                await asyncio.sleep(0.01)
            if len(gs.retimed) > n_before:
                solves.append(gs.retimed[-1]["solver"]["wall_time"])
        t_end = time.monotonic()
        sent = list(service.sent)
        period = 1.0 / cfg.stream.rate_hz
        base = _window(sent, t_base, t_busy)
        busy = _window(sent, t_busy, t_end)
        return {"rate_hz": cfg.stream.rate_hz, "dtau": cfg.limits.dtau,
                "baseline_p99_ms": _p99_ms(base, period), "busy_p99_ms": _p99_ms(busy, period),
                "baseline_samples": len(base), "busy_samples": len(busy),
                "busy_seconds": t_end - t_busy, "retimes": len(solves),
                "median_solve_ms": float(np.median(solves) * 1e3) if solves else None,
                "grid_nodes": int(np.ceil(traj.duration / cfg.limits.dtau)) + 1}


def run_bench_stream(out: str | None = None, rounds: int = 8) -> dict[str, Any]:
    mav = free_udp_port()
    with tempfile.TemporaryDirectory() as state:
        cfg = demo_config(mav, free_tcp_port(), 2.0, state,
                          limits={"dtau": 0.01, "max_solve_s": 20.0},
                          safety={"geofence_min": [-60.0, -60.0, -1.0],
                                  "geofence_max": [60.0, 60.0, 10.0],
                                  "stitch_tolerance_m": 1.0},
                          estimator={"enabled": False})
        with SimProcess(port=mav, seed=1):
            result = asyncio.run(_run(cfg, rounds))
    ratio = result["busy_p99_ms"] / max(result["baseline_p99_ms"], 1e-9)
    print(f"setpoint stream at {result['rate_hz']:.0f} Hz, period jitter p99: "
          f"{result['baseline_p99_ms']:.2f} ms idle, {result['busy_p99_ms']:.2f} ms while "
          f"{result['retimes']} re-times of the 30 m trajectory at dtau = {result['dtau']} s "
          f"ran ({result['grid_nodes']} nodes, median {result['median_solve_ms']:.0f} ms each) "
          f"-> ratio {ratio:.2f}")
    if out:
        Path(out).mkdir(parents=True, exist_ok=True)
        (Path(out) / "stream.json").write_text(json.dumps(result | {"ratio": ratio},
                                                          indent=1) + "\n")
    return result
