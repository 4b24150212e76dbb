"""The reference planner's grid search (:mod:`sitl.planner`): free cells of a
:class:`World` at a resolution, their graph, and line-of-sight shortcuts."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import sparse

from sitl.world import World

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Grid:
    axes: tuple[FloatArray, FloatArray, FloatArray]  # cell-centre coordinates per axis
    free: NDArray[np.bool_]  # shape (nx, ny, nz)

    @property
    def shape(self) -> tuple[int, int, int]:
        return self.free.shape  # type: ignore[return-value]

    def index(self, pts: FloatArray) -> NDArray[np.intp]:
        """Nearest cell index per point, shape ``(n, 3)`` (clipped to the grid)."""
        out = np.empty((len(pts), 3), dtype=np.intp)
        for k, ax in enumerate(self.axes):
            step = ax[1] - ax[0] if len(ax) > 1 else 1.0
            out[:, k] = np.clip(np.rint((pts[:, k] - ax[0]) / step), 0, len(ax) - 1)
        return out

    def centres(self, idx: NDArray[np.intp]) -> FloatArray:
        return np.stack([ax[idx[:, k]] for k, ax in enumerate(self.axes)], axis=1)

    def is_free(self, pts: FloatArray) -> NDArray[np.bool_]:
        i = self.index(pts)
        return self.free[i[:, 0], i[:, 1], i[:, 2]]


def build_grid(world: World, res: float, z_a: float, z_b: float, inflation: float,
               relax: list[FloatArray], relax_radius: float, hard_margin: float) -> Grid:
    """Free cells at ``res`` between heights ``z_a`` and ``z_b``: at least ``inflation``
    from every obstacle, or ``robot_radius + hard_margin`` within ``relax_radius`` of a
    point of ``relax`` (the start and the goal may be near an obstacle)."""
    lo, hi = np.array(world.bounds[0]), np.array(world.bounds[1])
    axes = []
    for k in range(2):
        n = max(1, int(math.floor((hi[k] - lo[k]) / res)))
        pad = 0.5 * (hi[k] - lo[k] - n * res)
        axes.append(lo[k] + pad + (np.arange(n) + 0.5) * res)
    if abs(z_b - z_a) < 0.5 * res:
        axes.append(np.array([z_a]))
    else:
        axes.append(np.linspace(min(z_a, z_b), max(z_a, z_b), int(round(abs(z_b - z_a) / res)) + 1))
    mesh = np.meshgrid(*axes, indexing="ij")
    centres = np.stack([m.ravel() for m in mesh], axis=1)
    # exact distances only where an obstacle's bounding box (grown by the inflation) reaches
    near = np.zeros(mesh[0].shape, dtype=bool)
    for obs in world.obstacles:
        a, b = obs.aabb()
        box = tuple(slice(np.searchsorted(ax, a[k] - inflation),
                          np.searchsorted(ax, b[k] + inflation, side="right"))
                    for k, ax in enumerate(axes))
        near[box] = True
    near = near.ravel()
    sd = np.full(len(centres), np.inf)
    sd[near] = world.signed_distance(centres[near])
    free = sd >= inflation
    hard = sd >= world.robot_radius + hard_margin
    for p in relax:
        free |= hard & (np.linalg.norm(centres - p, axis=1) <= relax_radius)
    return Grid((axes[0], axes[1], axes[2]), free.reshape(mesh[0].shape))


def grid_graph(grid: Grid) -> sparse.csr_matrix:
    """Undirected graph of free cells, 8-connected per layer, 26-connected across."""
    shape = grid.shape
    ids = np.arange(grid.free.size).reshape(shape)
    steps = [ax[1] - ax[0] if len(ax) > 1 else 0.0 for ax in grid.axes]
    rows, cols, weights = [], [], []
    for off in itertools.product((-1, 0, 1), repeat=3):
        nz = [o for o in off if o]
        if not nz or nz[0] < 0 or any(o and shape[k] == 1 for k, o in enumerate(off)):
            continue  # keep one direction of each edge
        src = tuple(slice(max(0, -o), s - max(0, o)) for o, s in zip(off, shape, strict=True))
        dst = tuple(slice(max(0, o), s - max(0, -o)) for o, s in zip(off, shape, strict=True))
        ok = grid.free[src] & grid.free[dst]
        rows.append(ids[src][ok])
        cols.append(ids[dst][ok])
        length = math.sqrt(sum((o * st) ** 2 for o, st in zip(off, steps, strict=True)))
        weights.append(np.full(int(ok.sum()), length))
    n = grid.free.size
    return sparse.csr_matrix(
        (np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))


def visible(grid: Grid, p: FloatArray, qs: FloatArray, step: float) -> NDArray[np.bool_]:
    """For each ``q`` in ``qs``: is the segment ``p -> q`` free on the grid?"""
    counts = np.maximum(np.ceil(np.linalg.norm(qs - p, axis=1) / step).astype(int), 1) + 1
    seg = np.repeat(np.arange(len(qs)), counts)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    frac = (np.arange(counts.sum()) - starts[seg]) / (counts[seg] - 1)
    samples = p + frac[:, None] * (qs[seg] - p)
    return np.minimum.reduceat(grid.is_free(samples).astype(np.int8), starts).astype(bool)


def shortcut(grid: Grid, pts: FloatArray, step: float) -> FloatArray:
    """Greedy line-of-sight simplification: from each kept point jump to the farthest visible."""
    keep, i, m = [0], 0, len(pts)
    while i < m - 1:
        js = np.arange(i + 1, m)
        vis = visible(grid, pts[i], pts[js], step)
        vis[0] = True  # consecutive grid points are always connected
        i = int(js[vis][-1])
        keep.append(i)
    return pts[keep]


def nearest_free(grid: Grid, p: FloatArray, reach: int = 2) -> NDArray[np.intp] | None:
    """Index of the free cell nearest to ``p`` within ``reach`` cells (None if none)."""
    centre = grid.index(p[None])[0]
    if grid.free[tuple(centre)]:
        return centre
    span = [np.arange(max(0, c - reach), min(n, c + reach + 1))
            for c, n in zip(centre, grid.shape, strict=True)]
    idx = np.stack([g.ravel() for g in np.meshgrid(*span, indexing="ij")], axis=1)
    idx = idx[grid.free[idx[:, 0], idx[:, 1], idx[:, 2]]]
    if len(idx) == 0:
        return None
    return idx[np.argmin(np.linalg.norm(grid.centres(idx) - p, axis=1))]
