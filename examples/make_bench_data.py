"""Regenerate the benchmark data in sitl/data/ (paper Table II).

* ``bench_forest_map.json``: the occupancy map (rota/map v1, 0.1 m voxels) of a
  32 m x 32 m forest at the paper's middle density 0.043 trees/m^2
  (``sitl.world.forest(0.043, seed=2, size=32)``, 44 trunks, 3 m tall).
* ``bench_traj_30m.json``: the long global path, start to goal across the forest
  (30.2 m), planned by ``sitl.planner.plan`` at v_max = 2 m/s, a_max = 1.5 m/s^2
  (the authors' navigation stack: 2.0 m/s, 1.5 m/s^2).
* ``bench_traj_7m.json``: a local replan through the densest part of the forest:
  from the point 8.5 m along the long path to the point 15.5 m along it (7 m),
  same planner and limits, at rest at both ends. Both paths pass obstacles within
  the braking threshold, so the full pipeline has braking zones to work on.

Deterministic: run it again and the files do not change.
"""

import json
from pathlib import Path

import numpy as np

from rota.schema import TrajectoryMessage, trajectory_to_dict
from rota.voxelmap import VoxelMap
from sitl.planner import plan
from sitl.world import forest

DENSITY, SEED, SIZE, RESOLUTION = 0.043, 2, 32.0, 0.1
V_MAX, A_MAX = 2.0, 1.5
OUT = Path(__file__).resolve().parents[1] / "sitl" / "data"


def arc_length(traj, n=4000):
    t = np.linspace(*traj.domain, n)
    p = traj.position(t)
    return p, np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])


def main() -> None:
    world = forest(DENSITY, SEED, size=SIZE)
    long = plan(world, V_MAX, A_MAX)
    p, s = arc_length(long)
    local = plan(world, V_MAX, A_MAX, start=p[np.searchsorted(s, 8.5)],
                 goal=p[np.searchsorted(s, 15.5)])
    vmap = VoxelMap.from_points(world.voxel_points(RESOLUTION), RESOLUTION)
    doc = vmap.to_dict()
    doc["occupied"] = np.round(vmap.occupied, 3).tolist()
    (OUT / "bench_forest_map.json").write_text(json.dumps(doc, separators=(",", ":")) + "\n")
    for name, traj in (("30m", long), ("7m", local)):
        length = arc_length(traj)[1][-1]
        msg = TrajectoryMessage(traj, id=f"bench-{name}", frame="ENU")
        out = OUT / f"bench_traj_{name}.json"
        out.write_text(json.dumps(trajectory_to_dict(msg), indent=1) + "\n")
        print(f"wrote {out.name}: length {length:.2f} m, duration {traj.duration:.2f} s")
    print(f"wrote bench_forest_map.json: {len(vmap)} voxels, {len(world.obstacles)} trunks")


if __name__ == "__main__":
    main()
