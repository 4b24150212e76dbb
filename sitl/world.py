"""Simulated worlds: static obstacles, a signed distance field and named scenes.

Coordinates are ENU metres (x east, y north, z up). A :class:`World` holds
vertical cylinders (trees, pillars) and axis-aligned boxes, the bounding volume
the vehicle may use, the robot radius and a start and goal position.

* :meth:`World.signed_distance` is the exact Euclidean signed distance to the
  union of obstacles (negative inside), vectorised over points and obstacles.
  Outside all obstacles it is exact; inside overlapping obstacles it is the
  deepest single-obstacle depth, which has the right sign but may underestimate
  the depth in the union. With no obstacles it is ``+inf``.
* :meth:`World.voxel_points` gives occupied voxel centres, the occupancy map
  ROTA's braking-zone search puts into its k-d tree (paper Alg. 1).
* :func:`forest` draws random forests like the paper's simulation (20 m x 20 m,
  0.025 / 0.043 / 0.063 obstacles per m^2); :func:`get_world` names scenes.

JSON form (``to_dict`` / ``from_dict``), schema ``rota/world`` version 1::

    {"schema": "rota/world", "version": 1, "name": "forest-mid",
     "bounds": {"min": [0, 0, 0], "max": [20, 20, 3]},
     "robot_radius": 0.3, "start": [1, 9, 1], "goal": [19, 12, 1],
     "obstacles": [
        {"type": "cylinder", "center": [4.0, 5.0], "radius": 0.3,
         "z_min": 0.0, "z_max": 3.0},
        {"type": "box", "min": [8, 8, 0], "max": [9, 10, 2]}]}
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rota.errors import InputError, plain
from rota.schema import check_envelope

FloatArray = NDArray[np.float64]
Vec3 = tuple[float, float, float]

SCHEMA = "rota/world"
SCHEMA_VERSION = 1

#: Default robot radius (m): a 250-class quadrotor including its propellers.
DEFAULT_ROBOT_RADIUS = 0.3

#: Obstacle densities of the paper's simulation (obstacles per m^2).
DENSITIES: dict[str, float] = {"low": 0.025, "mid": 0.043, "high": 0.063}

_CHUNK = 1 << 18  # point x obstacle entries evaluated per block


def _vec(value: Any, name: str, size: int) -> tuple[float, ...]:
    """A finite float tuple of length ``size``; errors name the field."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(name, f"must be a list of {size} numbers, got {plain(value)}") from None
    if arr.shape != (size,):
        raise InputError(name, f"must be a list of {size} numbers, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(name, "must be finite (got NaN or inf)")
    return tuple(float(v) for v in arr)


def _num(value: Any, name: str, positive: bool = False) -> float:
    """A finite float (optionally > 0); errors name the field."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise InputError(name, f"must be a number, got {plain(value)}")
    out = float(value)
    if not math.isfinite(out):
        raise InputError(name, "must be finite (got NaN or inf)")
    if positive and out <= 0:
        raise InputError(name, f"must be positive, got {out}")
    return out


def _points(points: ArrayLike) -> FloatArray:
    arr = np.asarray(points, dtype=float)
    if arr.ndim == 1 and arr.shape == (3,):
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InputError("points", f"must have shape (n, 3), got {arr.shape}")
    return arr


@dataclass(frozen=True)
class Cylinder:
    """Vertical cylinder: axis at ``(x, y)``, ``radius``, from ``z_min`` to ``z_max``."""

    x: float
    y: float
    radius: float
    z_min: float = 0.0
    z_max: float = 3.0

    def __post_init__(self) -> None:
        for name in ("x", "y", "z_min", "z_max"):
            object.__setattr__(self, name, _num(getattr(self, name), name))
        object.__setattr__(self, "radius", _num(self.radius, "radius", positive=True))
        if self.z_max <= self.z_min:
            raise InputError("z_max", f"must exceed z_min ({self.z_min}), got {self.z_max}")

    def aabb(self) -> tuple[Vec3, Vec3]:
        """Axis-aligned bounding box ``(min corner, max corner)``."""
        r = self.radius
        return (self.x - r, self.y - r, self.z_min), (self.x + r, self.y + r, self.z_max)

    def to_dict(self) -> dict[str, Any]:
        return {"type": "cylinder", "center": [self.x, self.y], "radius": self.radius,
                "z_min": self.z_min, "z_max": self.z_max}


@dataclass(frozen=True)
class Box:
    """Axis-aligned box between corners ``lo`` and ``hi`` (``lo < hi`` per axis)."""

    lo: Vec3
    hi: Vec3

    def __post_init__(self) -> None:
        lo, hi = _vec(self.lo, "min", 3), _vec(self.hi, "max", 3)
        if any(b <= a for a, b in zip(lo, hi, strict=True)):
            raise InputError("max", f"must exceed min on every axis, got min={lo}, max={hi}")
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)

    def aabb(self) -> tuple[Vec3, Vec3]:
        """Axis-aligned bounding box ``(min corner, max corner)``."""
        return self.lo, self.hi

    def to_dict(self) -> dict[str, Any]:
        return {"type": "box", "min": list(self.lo), "max": list(self.hi)}


Obstacle = Cylinder | Box


def _obstacle_from_dict(data: Any) -> Obstacle:
    if not isinstance(data, Mapping):
        raise InputError("", f"must be an object, got {type(data).__name__}")
    kind = data.get("type")
    if kind == "cylinder":
        for key in ("center", "radius", "z_min", "z_max"):
            if key not in data:
                raise InputError(key, "is required for a cylinder")
        cx, cy = _vec(data["center"], "center", 2)
        return Cylinder(cx, cy, data["radius"], data["z_min"], data["z_max"])
    if kind == "box":
        for key in ("min", "max"):
            if key not in data:
                raise InputError(key, "is required for a box")
        return Box(data["min"], data["max"])
    raise InputError("type", f"must be 'cylinder' or 'box', got {kind!r}")


@dataclass(frozen=True)
class World:
    """Static obstacles in a bounded volume, with a robot radius, start and goal.

    ``bounds`` is ``(min corner, max corner)``; the bounds are the volume the
    planner searches, not obstacles. ``robot_radius`` (default
    :data:`DEFAULT_ROBOT_RADIUS` = 0.3 m) is the radius of the sphere the
    vehicle must keep free: a point collides when its signed distance is below it.
    """

    obstacles: tuple[Obstacle, ...] = ()
    bounds: tuple[Vec3, Vec3] = ((0.0, 0.0, 0.0), (20.0, 20.0, 3.0))
    robot_radius: float = DEFAULT_ROBOT_RADIUS
    start: Vec3 = (1.0, 10.0, 1.0)
    goal: Vec3 = (19.0, 10.0, 1.0)
    name: str = ""
    _cyl: FloatArray = field(init=False, repr=False, compare=False)
    _box: FloatArray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        obstacles = tuple(self.obstacles)
        for i, obs in enumerate(obstacles):
            if not isinstance(obs, Cylinder | Box):
                raise InputError(f"obstacles[{i}]", f"must be a Cylinder or Box, got {obs!r}")
        object.__setattr__(self, "obstacles", obstacles)
        if not isinstance(self.bounds, Sequence) or len(self.bounds) != 2:
            raise InputError("bounds", "must be (min corner, max corner)")
        lo, hi = _vec(self.bounds[0], "bounds.min", 3), _vec(self.bounds[1], "bounds.max", 3)
        if any(b <= a for a, b in zip(lo, hi, strict=True)):
            raise InputError("bounds.max", "must exceed bounds.min on every axis, got "
                             f"{plain(lo)}, {plain(hi)}")
        object.__setattr__(self, "bounds", (lo, hi))
        object.__setattr__(self, "robot_radius",
                           _num(self.robot_radius, "robot_radius", positive=True))
        for name in ("start", "goal"):
            p = _vec(getattr(self, name), name, 3)
            if any(v < a or v > b for v, a, b in zip(p, lo, hi, strict=True)):
                raise InputError(name, f"must lie inside the bounds {plain(lo)} - {plain(hi)}, "
                                 f"got {plain(p)}")
            object.__setattr__(self, name, p)
        if not isinstance(self.name, str):
            raise InputError("name", f"must be a string, got {self.name!r}")
        cyl = [(o.x, o.y, o.radius, o.z_min, o.z_max) for o in obstacles if isinstance(o, Cylinder)]
        box = [(*o.lo, *o.hi) for o in obstacles if isinstance(o, Box)]
        object.__setattr__(self, "_cyl", np.array(cyl, dtype=float).reshape(-1, 5))
        object.__setattr__(self, "_box", np.array(box, dtype=float).reshape(-1, 6))

    # ------------------------------------------------------------------ geometry
    def signed_distance(self, points: ArrayLike) -> FloatArray:
        """Signed distance (m) from each point to the obstacles, shape ``(n,)``.

        Negative inside an obstacle; ``+inf`` when the world has no obstacles.
        """
        pts = _points(points)
        out = np.full(len(pts), np.inf)
        k = len(self._cyl) + len(self._box)
        if k == 0 or len(pts) == 0:
            return out
        step = max(1, _CHUNK // k)
        for s in range(0, len(pts), step):
            block = pts[s:s + step]
            if len(self._cyl):
                out[s:s + step] = np.minimum(out[s:s + step], _sd_cylinders(block, self._cyl))
            if len(self._box):
                out[s:s + step] = np.minimum(out[s:s + step], _sd_boxes(block, self._box))
        return out

    def collides(self, points: ArrayLike, radius: float | None = None) -> NDArray[np.bool_]:
        """True where a sphere of ``radius`` (default the robot radius) hits an obstacle."""
        r = self.robot_radius if radius is None else float(radius)
        return self.signed_distance(points) < r

    def voxel_points(self, resolution: float) -> FloatArray:
        """Centres of occupied voxels inside the bounds, shape ``(m, 3)``.

        Voxels form a grid of cubes of edge ``resolution`` anchored at the lower
        bound. A voxel counts as occupied when its centre lies within half a voxel
        diagonal of an obstacle, so every obstacle point inside the bounds lies in
        an occupied voxel (the map over-approximates by at most one diagonal).
        """
        res = _num(resolution, "resolution", positive=True)
        lo, hi = np.array(self.bounds[0]), np.array(self.bounds[1])
        shape = np.maximum(np.ceil((hi - lo) / res - 1e-9).astype(int), 1)
        if not self.obstacles:
            return np.zeros((0, 3))
        half_diag = 0.5 * math.sqrt(3.0) * res
        occupied = []
        for obs in self.obstacles:  # each obstacle tests only its own bounding block
            a, b = obs.aabb()
            i0 = np.clip(np.floor((np.array(a) - half_diag - lo) / res).astype(int), 0, shape)
            i1 = np.clip(np.ceil((np.array(b) + half_diag - lo) / res).astype(int), 0, shape)
            if np.any(i1 <= i0):
                continue
            grids = np.meshgrid(*(np.arange(s, e) for s, e in zip(i0, i1, strict=True)),
                                indexing="ij")
            idx = np.stack([g.ravel() for g in grids], axis=1)
            centres = lo + (idx + 0.5) * res
            if isinstance(obs, Cylinder):
                sd = _sd_cylinders(centres, np.array([[obs.x, obs.y, obs.radius, obs.z_min,
                                                       obs.z_max]]))
            else:
                sd = _sd_boxes(centres, np.array([[*obs.lo, *obs.hi]]))
            occupied.append(np.ravel_multi_index(tuple(idx[sd <= half_diag].T), shape))
        if not occupied:
            return np.zeros((0, 3))
        flat = np.unique(np.concatenate(occupied))
        return lo + (np.stack(np.unravel_index(flat, shape), axis=1) + 0.5) * res

    # ---------------------------------------------------------------- JSON form
    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly dict (schema ``rota/world`` version 1)."""
        return {
            "schema": SCHEMA,
            "version": SCHEMA_VERSION,
            "name": self.name,
            "bounds": {"min": list(self.bounds[0]), "max": list(self.bounds[1])},
            "robot_radius": self.robot_radius,
            "start": list(self.start),
            "goal": list(self.goal),
            "obstacles": [o.to_dict() for o in self.obstacles],
        }

    @classmethod
    def from_dict(cls, data: Any) -> World:
        """Inverse of :meth:`to_dict`; raises :class:`InputError` naming the bad field."""
        data = check_envelope(data, SCHEMA, SCHEMA_VERSION)
        for key in ("bounds", "start", "goal", "obstacles"):
            if key not in data:
                raise InputError(key, "is required")
        bounds = data["bounds"]
        if not isinstance(bounds, Mapping) or "min" not in bounds or "max" not in bounds:
            raise InputError("bounds", "must be an object with 'min' and 'max'")
        if not isinstance(data["obstacles"], list):
            raise InputError("obstacles", "must be a list")
        obstacles = []
        for i, item in enumerate(data["obstacles"]):
            try:
                obstacles.append(_obstacle_from_dict(item))
            except InputError as exc:
                raise exc.within(f"obstacles[{i}]") from None
        return cls(
            obstacles=tuple(obstacles),
            bounds=(_vec(bounds["min"], "bounds.min", 3), _vec(bounds["max"], "bounds.max", 3)),
            robot_radius=data.get("robot_radius", DEFAULT_ROBOT_RADIUS),
            start=_vec(data["start"], "start", 3),
            goal=_vec(data["goal"], "goal", 3),
            name=data.get("name", ""),
        )


def _sd_cylinders(p: FloatArray, cyl: FloatArray) -> FloatArray:
    """Min over cylinders of the exact signed distance to a finite cylinder."""
    dr = np.hypot(p[:, None, 0] - cyl[:, 0], p[:, None, 1] - cyl[:, 1]) - cyl[:, 2]
    zc, zh = 0.5 * (cyl[:, 3] + cyl[:, 4]), 0.5 * (cyl[:, 4] - cyl[:, 3])
    dz = np.abs(p[:, None, 2] - zc) - zh
    outside = np.hypot(np.maximum(dr, 0.0), np.maximum(dz, 0.0))
    inside = np.minimum(np.maximum(dr, dz), 0.0)
    return np.min(outside + inside, axis=1)


def _sd_boxes(p: FloatArray, box: FloatArray) -> FloatArray:
    """Min over boxes of the exact signed distance to an axis-aligned box."""
    centre, half = 0.5 * (box[:, :3] + box[:, 3:]), 0.5 * (box[:, 3:] - box[:, :3])
    q = np.abs(p[:, None, :] - centre) - half
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=2)
    inside = np.minimum(np.max(q, axis=2), 0.0)
    return np.min(outside + inside, axis=1)


# ------------------------------------------------------------------- generators
def forest(
    density: float,
    seed: int,
    size: float = 20.0,
    height: float = 3.0,
    radius_range: tuple[float, float] = (0.15, 0.4),
    altitude: float = 1.0,
    clear_radius: float = 1.5,
    min_gap: float = 0.3,
    robot_radius: float = DEFAULT_ROBOT_RADIUS,
    name: str = "",
) -> World:
    """A random forest of ``round(density * size**2)`` vertical tree trunks.

    Trees are cylinders from the ground to ``height`` with radii uniform in
    ``radius_range``, fully inside the ``size`` x ``size`` square, at least
    ``min_gap`` apart (surface to surface). Start and goal sit at ``altitude`` on
    opposite sides (x = 1 m and x = size - 1 m, y uniform in the middle half) with
    no trunk within ``clear_radius`` (horizontally, surface distance). The world
    is a deterministic function of the arguments (``numpy.random.default_rng(seed)``).
    """
    density = _num(density, "density")
    if density < 0:
        raise InputError("density", f"must be >= 0, got {density}")
    size = _num(size, "size", positive=True)
    r_lo, r_hi = (_num(v, "radius_range", positive=True) for v in radius_range)
    if r_hi < r_lo or 2 * r_hi >= size:
        raise InputError("radius_range", f"must be (min, max) with min <= max < size/2, "
                         f"got {radius_range}")
    count = int(round(density * size * size))
    rng = np.random.default_rng(seed)
    start = (1.0, float(rng.uniform(0.25, 0.75) * size), float(altitude))
    goal = (size - 1.0, float(rng.uniform(0.25, 0.75) * size), float(altitude))
    ends = np.array([start[:2], goal[:2]])
    trees = np.zeros((0, 3))  # x, y, r
    for _ in range(100):
        if len(trees) >= count:
            break
        n = 4 * (count - len(trees)) + 16
        r = rng.uniform(r_lo, r_hi, n)
        xy = rng.uniform(r, size - r, (2, n)).T
        to_ends = np.linalg.norm(xy[:, None, :] - ends[None], axis=2) - r[:, None]
        ok = np.all(to_ends >= clear_radius, axis=1)
        for c, rad in zip(xy[ok], r[ok], strict=True):  # sequential: spacing to accepted
            gaps = np.hypot(*(trees[:, :2] - c).T) - trees[:, 2] - rad
            if np.all(gaps >= min_gap):
                trees = np.vstack([trees, [c[0], c[1], rad]])
                if len(trees) == count:
                    break
    if len(trees) < count:
        raise InputError("density", f"could not place {count} trees with min_gap={min_gap}")
    obstacles = tuple(Cylinder(float(x), float(y), float(r), 0.0, float(height))
                      for x, y, r in trees)
    return World(obstacles, ((0.0, 0.0, 0.0), (size, size, float(height))), robot_radius,
                 start, goal, name or f"forest-{density:g}-seed{seed}")


def empty_world(size: float = 20.0, height: float = 3.0, altitude: float = 1.0) -> World:
    """No obstacles; start and goal on the mid line at x = 1 and x = size - 1."""
    mid = 0.5 * size
    return World((), ((0.0, 0.0, 0.0), (size, size, height)), DEFAULT_ROBOT_RADIUS,
                 (1.0, mid, altitude), (size - 1.0, mid, altitude), "empty")


def pillar_world(size: float = 20.0, height: float = 3.0, altitude: float = 1.0,
                 offset: float = 0.8, radius: float = 0.2) -> World:
    """One pillar beside the straight start-goal line (the line y = size/2).

    With the defaults the pillar's surface is 0.6 m from the line: the straight
    line is collision-free for the 0.3 m robot yet well inside ROTA's 1 m
    braking threshold, so it exercises braking zones without any detour.
    """
    mid = 0.5 * size
    pillar = Cylinder(mid, mid + offset, radius, 0.0, height)
    return World((pillar,), ((0.0, 0.0, 0.0), (size, size, height)), DEFAULT_ROBOT_RADIUS,
                 (1.0, mid, altitude), (size - 1.0, mid, altitude), "pillar")


WORLD_NAMES = ("forest", "forest-low", "forest-mid", "forest-high", "empty", "pillar")


def get_world(name: str, seed: int = 0) -> World:
    """A named world: ``forest`` (= ``forest-mid``), ``forest-low|mid|high``
    (paper densities 0.025 / 0.043 / 0.063 per m^2, random per ``seed``),
    ``empty`` and ``pillar`` (both independent of ``seed``)."""
    if name == "forest":
        name = "forest-mid"
    if name.startswith("forest-") and name[7:] in DENSITIES:
        return forest(DENSITIES[name[7:]], seed, name=f"{name}-seed{seed}")
    if name == "empty":
        return empty_world()
    if name == "pillar":
        return pillar_world()
    raise InputError("name", f"unknown world {name!r}; choose from {', '.join(WORLD_NAMES)}")
