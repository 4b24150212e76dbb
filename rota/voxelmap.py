"""Occupancy voxel map and nearest-obstacle queries (paper Alg. 1, lines 3-9).

A :class:`VoxelMap` is a set of occupied voxels on a regular grid, stored as an
``(n, 3)`` array of voxel *centres* in the ENU world frame (metres).

Grid convention
---------------
The grid has spacing ``resolution`` and ``origin`` is a voxel **corner**: voxel
index ``i = floor((x - origin) / resolution)`` (per axis) has its centre at
``origin + (i + 0.5) * resolution``. :meth:`VoxelMap.from_points` bins a point
cloud with this rule; the constructor snaps given centres to the grid (within
1e-3 of a voxel, to absorb float noise from files and JSON) and rejects centres
that are farther off.

Distances
---------
:meth:`VoxelMap.nearest` returns distances from the query point to the nearest
occupied voxel *centre*, as the authors' implementation does. The obstacle
surface can be up to ``sqrt(3)/2 * resolution`` closer; account for it in the
robot's safety ellipsoid or by :meth:`VoxelMap.inflated` (see
``docs/safety-model.md``).

JSON shape (``to_dict`` / ``from_dict``), version 1::

    {"schema": "rota/map", "version": 1, "frame": "ENU",
     "resolution": 0.1, "origin": [0.0, 0.0, 0.0],
     "occupied": [[x, y, z], ...]}        # voxel centres, metres

All keys are required and no others are accepted.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from dataclasses import field as dc_field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rota.errors import InputError
from rota.jit import kernels
from rota.validate import KeepsReadOnly, positive, vector3

FloatArray = NDArray[np.float64]

MAP_SCHEMA = "rota/map"
MAP_VERSION = 1
MAP_FRAME = "ENU"

#: Default margin (m) added around the query points' bounding box in
#: :meth:`VoxelMap.nearest`. It must be at least the braking threshold ``d_th``
#: (default 1.0 m) so that every obstacle that can make a braking point is found.
DEFAULT_BBOX_MARGIN = 2.0

_SNAP_TOL = 1e-3  # in voxels
_CHUNK = 4096  # occupied voxels per chunk in inflated()


def _index_name(field: str, idx: tuple[int, ...]) -> str:
    return field + "".join(f"[{i}]" for i in idx)


def _points_array(value: ArrayLike, field: str, allow_empty: bool = True) -> FloatArray:
    """An ``(n, 3)`` finite float array, errors naming ``field[i][j]``."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(field, f"must be numeric ({exc})") from None
    if arr.ndim == 1 and arr.size == 0:
        arr = arr.reshape(0, 3)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InputError(field, f"must have shape (n, 3), got {arr.shape}")
    if not allow_empty and arr.shape[0] == 0:
        raise InputError(field, "must not be empty")
    bad = ~np.isfinite(arr)
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise InputError(_index_name(field, idx), "must be finite")
    return arr


def _sorted_unique(keys: NDArray[np.int64]) -> NDArray[np.int64]:
    """Sorted unique values (sort + neighbour compare; much faster than np.unique here)."""
    k = np.sort(keys)
    if k.size == 0:
        return k
    return k[np.concatenate(([True], k[1:] != k[:-1]))]


def _key_layout(
    lo: NDArray[np.int64], hi: NDArray[np.int64]
) -> tuple[NDArray[np.int64], NDArray[np.int64]] | None:
    """Row-major multipliers and span for int64 keys of indices in ``[lo, hi]``."""
    span = (hi - lo + 1).astype(np.int64)
    if float(np.prod(span.astype(float))) >= 2.0**62:
        return None
    return np.array([span[1] * span[2], span[2], 1], dtype=np.int64), span


def _unique_rows(idx: NDArray[np.int64]) -> NDArray[np.int64]:
    """Unique integer (n, 3) rows, sorted lexicographically (x, then y, then z)."""
    if idx.shape[0] == 0:
        return idx.reshape(0, 3)
    lo = idx.min(axis=0)
    layout = _key_layout(lo, idx.max(axis=0))
    if layout is None:  # astronomically large extent: generic (slower) path
        return np.unique(idx, axis=0)
    mult, span = layout
    keys = _sorted_unique((idx - lo) @ mult)
    return _decode(keys, mult, span, lo)


def _decode(
    keys: NDArray[np.int64], mult: NDArray[np.int64], span: NDArray[np.int64],
    lo: NDArray[np.int64],
) -> NDArray[np.int64]:
    out = np.stack([keys // mult[0], (keys // mult[1]) % span[1], keys % span[2]], axis=1)
    return out + lo


def _readonly(arr: np.ndarray) -> np.ndarray:
    arr = np.ascontiguousarray(arr)
    arr.setflags(write=False)
    return arr


#: Maps up to this many voxels keep one brick index for all queries; larger ones
#: index only the voxels in the query's bounding box each time (paper Alg. 1,
#: lines 5-9).
INDEX_CACHE_LIMIT = 2_000_000
#: Voxels per brick side of the nearest-obstacle index (doubled until the brick
#: grid has at most :data:`MAX_BRICKS` bricks).
BRICK = 8
MAX_BRICKS = 1 << 21


@dataclass(frozen=True, eq=False)
class _Bricks:
    """The occupied centres grouped by brick (:mod:`rota.kernels.nearest`)."""

    lo: NDArray[np.int64]
    dims: NDArray[np.int64]
    size: int
    start: NDArray[np.int64]
    pts: FloatArray
    box: FloatArray

    @classmethod
    def of(cls, idx: NDArray[np.int64], centres: FloatArray) -> _Bricks:
        lo = idx.min(axis=0)
        span = idx.max(axis=0) - lo + 1
        size = BRICK
        while float(np.prod((span + size - 1) // size)) > MAX_BRICKS:
            size *= 2
        dims = ((span + size - 1) // size).astype(np.int64)
        start, pts, box = kernels().bricks_build(idx, centres, lo, dims, size)
        return cls(lo, dims, size, start, pts, box)


#: The index of no centres (an empty map, or none near the points).
_EMPTY = _Bricks(np.zeros(3, dtype=np.int64), np.ones(3, dtype=np.int64), BRICK,
                 np.zeros(2, dtype=np.int64), np.zeros((0, 3)), np.zeros((1, 6)))


@dataclass(frozen=True, eq=False)
class VoxelMap(KeepsReadOnly):
    """Occupied voxels of an occupancy map (ENU, metres).

    Attributes:
        resolution: voxel edge length (m), positive and finite.
        occupied: ``(n, 3)`` voxel centres; ``n`` may be 0 (an empty map). Snapped
            to the grid and de-duplicated on construction (sorted by index).
        origin: ``(3,)`` a voxel corner of the grid (default: zeros).
        bounds: optional ``(2, 3)`` ``[min corner, max corner]`` of the space the
            map covers (a local map around the vehicle). Outside it nothing is
            known; :mod:`rota.robust` limits the speed there. None: unbounded.
    """

    resolution: float
    occupied: FloatArray
    origin: FloatArray = dc_field(default_factory=lambda: np.zeros(3))
    bounds: FloatArray | None = None

    def __post_init__(self) -> None:
        res = positive(self.resolution, "resolution")
        origin = vector3(self.origin, "origin")
        centres = _points_array(self.occupied, "occupied")
        rel = (centres - origin) / res - 0.5
        idx = np.rint(rel)
        off = np.abs(rel - idx) > _SNAP_TOL
        if off.any():
            i, j = (int(k) for k in np.argwhere(off)[0])
            raise InputError(
                f"occupied[{i}][{j}]",
                f"{centres[i, j]!r} is not a voxel centre of the grid (resolution {res}, "
                f"origin {origin.tolist()}); build maps from raw points with "
                "VoxelMap.from_points",
            )
        idx = _unique_rows(idx.astype(np.int64).reshape(-1, 3))
        object.__setattr__(self, "resolution", res)
        object.__setattr__(self, "origin", _readonly(origin))
        object.__setattr__(self, "occupied", _readonly(origin + (idx + 0.5) * res))
        object.__setattr__(self, "_indices", _readonly(idx.reshape(-1, 3)))
        if self.bounds is not None:
            b = _json_numbers(np.asarray(self.bounds, dtype=float).tolist(), "bounds", (2, 3))
            if np.any(b[1] <= b[0]):
                raise InputError("bounds", "max corner must exceed min corner on every axis")
            object.__setattr__(self, "bounds", _readonly(b))

    # ------------------------------------------------------------------ basics
    def __len__(self) -> int:
        return int(self.occupied.shape[0])

    @property
    def indices(self) -> NDArray[np.int64]:
        """``(n, 3)`` integer voxel indices of :attr:`occupied` (same order)."""
        return self._indices  # type: ignore[attr-defined]

    def __repr__(self) -> str:
        return (
            f"VoxelMap(resolution={self.resolution}, occupied=<{len(self)} voxels>, "
            f"origin={self.origin.tolist()})"
        )

    # ------------------------------------------------------------ constructors
    @classmethod
    def from_points(
        cls, points: ArrayLike, resolution: float, origin: ArrayLike | None = None
    ) -> VoxelMap:
        """Bin a point cloud ``(n, 3)`` into unique occupied voxels (vectorised)."""
        res = positive(resolution, "resolution")
        org = np.zeros(3) if origin is None else vector3(origin, "origin")
        pts = _points_array(points, "points")
        idx = _unique_rows(np.floor((pts - org) / res).astype(np.int64).reshape(-1, 3))
        return cls._from_indices(res, idx, org)

    @classmethod
    def from_file(
        cls, path: str | Path, resolution: float, origin: ArrayLike | None = None
    ) -> VoxelMap:
        """Read a point cloud and bin it (see :meth:`from_points`).

        Supported: ``.ply`` (``vertex`` element with ``x``, ``y``, ``z``; read with
        ``plyfile``), ``.pcd`` (fields ``x``, ``y``, ``z``; read with ``pypcd4``),
        ``.npy`` (an ``(n, 3)`` array, or a structured array with ``x``, ``y``,
        ``z`` fields) and ``.csv`` (three numeric columns, optionally with a header
        row naming ``x``, ``y``, ``z`` columns among others).
        """
        p = Path(path)
        if not p.is_file():
            raise InputError("path", f"no such file: {p}")
        ext = p.suffix.lower()
        readers = {".ply": _read_ply, ".pcd": _read_pcd, ".npy": _read_npy, ".csv": _read_csv}
        if ext not in readers:
            raise InputError(
                "path", f"unknown extension {ext!r}; expected one of {sorted(readers)}"
            )
        pts = readers[ext](p)
        return cls.from_points(pts, resolution, origin)

    # -------------------------------------------------------------- operations
    def inflated(self, radius: float) -> VoxelMap:
        """Dilate by ``radius`` (m), e.g. the robot's radius.

        A voxel is occupied in the result when its centre lies within ``radius``
        of an occupied voxel centre (a ball stencil of integer offsets, applied
        with vectorised broadcasting in chunks). ``radius = 0`` returns a copy.
        """
        if isinstance(radius, bool) or not isinstance(radius, (int, float, np.number)):
            raise InputError("radius", "must be a number")
        r = float(radius)
        if not math.isfinite(r) or r < 0.0:
            raise InputError("radius", f"must be finite and >= 0, got {r}")
        idx = self.indices
        k = int(math.floor(r / self.resolution + 1e-9))
        if k == 0 or len(idx) == 0:
            return VoxelMap(self.resolution, self.occupied, self.origin)
        rng = np.arange(-k, k + 1)
        offs = np.stack(np.meshgrid(rng, rng, rng, indexing="ij"), axis=-1).reshape(-1, 3)
        offs = offs[(offs**2).sum(axis=1) * self.resolution**2 <= r * r * (1 + 1e-9)]
        lo = idx.min(axis=0) - k
        layout = _key_layout(lo, idx.max(axis=0) + k)
        if layout is None:
            raise InputError("radius", "map extent too large for inflation index keys")
        mult, span = layout
        base_keys = (idx - lo) @ mult
        off_keys = offs @ mult
        keys: list[np.ndarray] = []
        for s in range(0, len(base_keys), _CHUNK):
            keys.append(_sorted_unique((base_keys[s : s + _CHUNK, None] + off_keys).ravel()))
        out = _decode(_sorted_unique(np.concatenate(keys)), mult, span, lo)
        return VoxelMap._from_indices(self.resolution, out, self.origin)

    @classmethod
    def _from_indices(
        cls, resolution: float, idx: NDArray[np.int64], origin: FloatArray
    ) -> VoxelMap:
        """Internal: build from unique, sorted, valid indices without re-validating."""
        obj = object.__new__(cls)
        object.__setattr__(obj, "resolution", float(resolution))
        object.__setattr__(obj, "origin", _readonly(np.array(origin, dtype=float)))
        object.__setattr__(obj, "occupied", _readonly(origin + (idx + 0.5) * resolution))
        object.__setattr__(obj, "_indices", _readonly(idx.reshape(-1, 3)))
        return obj

    def nearest(
        self, points: ArrayLike, bbox_margin: float = DEFAULT_BBOX_MARGIN
    ) -> tuple[FloatArray, FloatArray]:
        """Nearest occupied voxel centre for each query point (paper Alg. 1, l. 5-9, 11).

        As in Alg. 1, only occupied voxels inside the query points' axis-aligned
        bounding box grown by ``bbox_margin`` (m) are searched: they are grouped in
        bricks of voxels and each point is searched exactly (compiled,
        :mod:`rota.kernels.nearest`). Every obstacle within ``bbox_margin`` of a
        query point lies in that box, so results are exact up to ``bbox_margin``
        (never a farther centre than the nearest); beyond it they are reported as
        "none". Maps of up to :data:`INDEX_CACHE_LIMIT` voxels instead keep one
        index over the whole map across queries (same answers, no rebuild per
        replan).

        Returns:
            ``(distances (m,), obstacles (m, 3))``. Where no occupied voxel lies
            within ``bbox_margin`` of the point (in particular for an empty map),
            the distance is ``inf`` and the obstacle row is ``NaN``.
            ``bbox_margin=math.inf`` searches the whole map.
        """
        pts = _points_array(points, "points")
        if isinstance(bbox_margin, bool) or not isinstance(bbox_margin, (int, float, np.number)):
            raise InputError("bbox_margin", "must be a number")
        margin = float(bbox_margin)
        if math.isnan(margin) or margin < 0.0:
            raise InputError("bbox_margin", f"must be >= 0, got {margin}")
        return self.nearest_of(pts, margin)

    def nearest_of(self, pts: FloatArray, margin: float) -> tuple[FloatArray, FloatArray]:
        """:meth:`nearest` without checking its arguments: ``pts`` a finite C float
        array ``(m, 3)``, ``margin`` a float >= 0 (the re-timer's own queries)."""
        m = pts.shape[0]
        dist, obst = np.empty(m), np.empty((m, 3))
        kernels().bricks_query(pts, *self.query_args(pts, margin), dist, obst)
        return dist, obst

    def query_args(self, pts: FloatArray, margin: float) -> tuple:
        """The map's arguments of :func:`rota.kernels.nearest.bricks_query` for the
        points ``pts`` within ``margin``: origin, resolution, the index's arrays and
        the squared search radius."""
        index = _EMPTY
        if len(self) <= INDEX_CACHE_LIMIT:
            # Replans query the same map again and again: one index over the whole
            # map, built on first use and kept, answers exactly like the cropped one of
            # Alg. 1 (results are cut at the same margin) without rebuilding it.
            index = self.__dict__.get("_bricks")
            if index is None:
                index = _Bricks.of(self.indices, self.occupied) if len(self) else _EMPTY
                object.__setattr__(self, "_bricks", index)
        elif pts.shape[0]:
            lo = pts.min(axis=0) - margin
            hi = pts.max(axis=0) + margin
            occ = self.occupied
            inside = np.all((occ >= lo) & (occ <= hi), axis=1)
            if inside.any():
                index = _Bricks.of(self.indices[inside], occ[inside])
        bound = margin * (1 + 1e-12)
        return (self.origin, self.resolution, index.lo, index.dims, index.size, index.start,
                index.pts, index.box, bound * bound)

    # -------------------------------------------------------------------- JSON
    def to_dict(self) -> dict[str, Any]:
        """The versioned JSON-ready dict (see module docstring)."""
        return {
            "schema": MAP_SCHEMA,
            "version": MAP_VERSION,
            "frame": MAP_FRAME,
            "resolution": self.resolution,
            "origin": self.origin.tolist(),
            "occupied": self.occupied.tolist(),
        } | ({} if self.bounds is None else {"bounds": self.bounds.tolist()})

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> VoxelMap:
        """Parse :meth:`to_dict`'s shape; errors name the field (``occupied[3][1]``)."""
        if not isinstance(d, Mapping):
            raise InputError("map", f"must be an object, got {type(d).__name__}")
        required = ("schema", "version", "frame", "resolution", "origin", "occupied")
        for key in required:
            if key not in d:
                raise InputError(key, "missing")
        optional = ("bounds", "id", "stamp")
        extra = sorted(set(d) - set(required) - set(optional))
        if extra:
            raise InputError(str(extra[0]), "unknown field (allowed: "
                             f"{', '.join(required + optional)})")
        if d["schema"] != MAP_SCHEMA:
            raise InputError("schema", f"must be {MAP_SCHEMA!r}, got {d['schema']!r}")
        if isinstance(d["version"], bool) or d["version"] != MAP_VERSION:
            raise InputError("version", f"unsupported version {d['version']!r} (expected 1)")
        if d["frame"] != MAP_FRAME:
            raise InputError("frame", f"must be {MAP_FRAME!r}, got {d['frame']!r}")
        res = positive(d["resolution"], "resolution")
        origin = _json_numbers(d["origin"], "origin", (3,))
        occ = _json_numbers(d["occupied"], "occupied", None)
        bounds = None if d.get("bounds") is None else _json_numbers(d["bounds"], "bounds", (2, 3))
        return cls(res, occ, origin, bounds)


def _json_numbers(value: Any, field: str, shape: tuple[int, ...] | None) -> FloatArray:
    """Strictly numeric JSON list(s): no bools, strings or nulls; errors name the item."""
    try:
        arr = np.array(value)
        ok = arr.dtype.kind in "iuf"
    except ValueError:
        ok = False
    if ok:
        arr = arr.astype(float)
        if shape is None and arr.size == 0:
            arr = arr.reshape(0, 3)
        want_ok = arr.shape == shape if shape is not None else (
            arr.ndim == 2 and arr.shape[1] == 3
        )
        if want_ok:
            bad = ~np.isfinite(arr)
            if bad.any():
                idx = tuple(int(i) for i in np.argwhere(bad)[0])
                raise InputError(_index_name(field, idx), "must be finite")
            return arr
    # slow path: find the offending item to name it
    if shape is not None and len(shape) == 2:
        if not isinstance(value, list | tuple) or len(value) != shape[0]:
            raise InputError(field, f"must be a list of {shape[0]} [x, y, z] rows")
        for i, row in enumerate(value):
            _check_vector(row, f"{field}[{i}]", shape[1])
    elif shape is not None:
        _check_vector(value, field, shape[0])
    else:
        if not isinstance(value, list):
            raise InputError(field, f"must be a list of [x, y, z], got {type(value).__name__}")
        for i, row in enumerate(value):
            _check_vector(row, f"{field}[{i}]", 3)
    raise InputError(field, "must be a list of [x, y, z] numbers")  # pragma: no cover


def _check_vector(value: Any, field: str, n: int) -> None:
    if not isinstance(value, list | tuple) or len(value) != n:
        raise InputError(field, f"must be a list of {n} numbers")
    for j, x in enumerate(value):
        if isinstance(x, bool) or not isinstance(x, int | float):
            raise InputError(f"{field}[{j}]", f"must be a number, got {type(x).__name__}")
        if not math.isfinite(float(x)):
            raise InputError(f"{field}[{j}]", "must be finite")


# ---------------------------------------------------------------- file readers
def _read_ply(path: Path) -> FloatArray:
    from plyfile import PlyData

    try:
        ply = PlyData.read(str(path))
    except Exception as exc:  # plyfile raises several types for malformed files
        raise InputError("path", f"cannot read PLY file {path}: {exc}") from None
    names = [el.name for el in ply.elements]
    if "vertex" not in names:
        raise InputError("path", f"PLY file {path} has no 'vertex' element (has {names})")
    vertex = ply["vertex"]
    props = [p.name for p in vertex.properties]
    for axis in ("x", "y", "z"):
        if axis not in props:
            raise InputError("path", f"PLY vertex element lacks property {axis!r} (has {props})")
    data = vertex.data
    return np.column_stack([np.asarray(data[a], dtype=float) for a in ("x", "y", "z")])


def _read_pcd(path: Path) -> FloatArray:
    from pypcd4 import PointCloud

    try:
        pc = PointCloud.from_path(path)
    except Exception as exc:  # pypcd4 raises several types for malformed files
        raise InputError("path", f"cannot read PCD file {path}: {exc}") from None
    fields = list(pc.fields)
    for axis in ("x", "y", "z"):
        if axis not in fields:
            raise InputError("path", f"PCD file lacks field {axis!r} (has {fields})")
    return np.asarray(pc.numpy(("x", "y", "z")), dtype=float).reshape(-1, 3)


def _read_npy(path: Path) -> FloatArray:
    try:
        arr = np.load(path, allow_pickle=False)
    except Exception as exc:
        raise InputError("path", f"cannot read .npy file {path}: {exc}") from None
    if arr.dtype.names is not None:
        missing = [a for a in ("x", "y", "z") if a not in arr.dtype.names]
        if missing:
            raise InputError("path", f".npy structured array lacks fields {missing}")
        return np.column_stack([np.asarray(arr[a], dtype=float).ravel() for a in "xyz"])
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InputError("path", f".npy array must have shape (n, 3), got {arr.shape}")
    return arr.astype(float)


def _read_csv(path: Path) -> FloatArray:
    with path.open() as fh:
        first = fh.readline()
    cells = [c.strip().lower() for c in first.split(",")]
    try:
        [float(c) for c in cells]
        header = None
    except ValueError:
        header = cells
    try:
        data = np.loadtxt(path, delimiter=",", skiprows=0 if header is None else 1, ndmin=2)
    except ValueError as exc:
        raise InputError("path", f"cannot parse CSV {path}: {exc}") from None
    if header is not None:
        missing = [a for a in ("x", "y", "z") if a not in header]
        if missing:
            raise InputError("path", f"CSV header lacks columns {missing} (has {header})")
        cols = [header.index(a) for a in ("x", "y", "z")]
        if data.size == 0:
            return np.zeros((0, 3))
        return data[:, cols]
    if data.shape[1] != 3:
        raise InputError("path", f"CSV without header must have 3 columns, got {data.shape[1]}")
    return data
