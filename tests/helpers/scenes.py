"""Small scenes for the re-timer: a line past a pillar, and its speeds."""

from __future__ import annotations

import numpy as np

from rota import Limits, RetimeInput, SampledTrajectory, retime
from rota.braking import BrakingParams
from rota.chance import (
    ChanceParams,
    UncertaintyModel,
)
from rota.robust import Safety
from rota.voxelmap import VoxelMap

RES = 0.05
LIMITS = Limits(3.0, 3.0)


def line(x0: float, x1: float, speed: float = 1.0) -> SampledTrajectory:
    """A straight path along x at 1 m altitude, at constant speed."""
    n = 21
    x = np.linspace(x0, x1, n)
    t = (x - x0) / speed
    return SampledTrajectory(t=t, p=np.column_stack([x, 0 * x, 0 * x + 1.0]))


def pillar(x: float = 5.0, gap: float = 0.3, radius: float = 0.1) -> VoxelMap:
    """A vertical pillar whose surface is ``gap`` from the line y = 0."""
    g = np.arange(-0.5, 0.5, RES / 2)
    xx, yy, zz = np.meshgrid(g, g, np.arange(0, 3, RES / 2), indexing="ij")
    pts = np.column_stack([xx.ravel(), yy.ravel(), zz.ravel()])
    pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= radius] + [x, gap + radius, 0]
    return VoxelMap.from_points(pts, RES)


def safety(vmap: VoxelMap, m: float = 0.2, delta: float = 1e-4, **kw) -> Safety:
    return Safety(map=vmap, uncertainty=UncertaintyModel(m=m, b=-0.1),
                  chance=ChanceParams(delta=delta, semi_axes=(0.15, 0.15, 0.15),
                                      obstacle_std=(0.015,) * 3, v_floor=0.3, v_max=3.0),
                  braking=BrakingParams(d_th=1.0, risk=False), **kw)  # paper Eq. 6


def run(traj, safe=None, **kw):
    # lambda small: the input is timed at 1 m/s against a 3 m/s limit, so tau_dot
    # must triple, and the default lambda = 0.5 would make that acceleration costly.
    kw.setdefault("smoothness", 0.02)
    return retime(RetimeInput(trajectory=traj, limits=LIMITS, dtau=0.05, safety=safe, **kw))


def node_speed(result) -> np.ndarray:
    """Speed at the grid nodes, from the positions: |sigma'| sqrt(beta)."""
    _, d1, _ = result.trajectory.evaluate(result.tau)
    return np.linalg.norm(d1, axis=1) * np.sqrt(result.beta)
