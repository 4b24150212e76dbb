"""Regenerate rota/data/example_trajectory.json: a slalom B-spline of about 12 m,
timed the way a planner with v_max = 1 m/s and a_max = 3 m/s^2 would (the paper's
sample trajectory 1), starting and ending at rest."""

import json
from pathlib import Path

import numpy as np

from rota import BSplineTrajectory
from rota.schema import TrajectoryMessage, trajectory_to_dict

x = np.linspace(0.0, 12.0, 13)
y = 1.2 * np.sin(x / 12.0 * 2 * np.pi)
z = 1.5 + 0.2 * np.sin(x / 6.0 * np.pi)
cps = np.column_stack([x, y, z])
cps = np.vstack([cps[:1], cps[:1], cps, cps[-1:], cps[-1:]])
span = 1.0
for _ in range(50):  # scale the knot span until the planner's own limits are met
    traj = BSplineTrajectory(control_points=cps, knot_span=span)
    _, v, a = traj.evaluate(np.linspace(*traj.domain, 2000))
    k = max(np.linalg.norm(v, axis=1).max() / 1.0, np.sqrt(np.abs(a).max() / 3.0))
    if abs(k - 1) < 1e-4:
        break
    span *= k
msg = TrajectoryMessage(traj, id="example-slalom", frame="ENU")
out = Path(__file__).resolve().parents[1] / "rota" / "data" / "example_trajectory.json"
out.write_text(json.dumps(trajectory_to_dict(msg), indent=1) + "\n")
print(f"wrote {out}: duration {traj.duration:.2f} s, knot span {span:.4f} s")
