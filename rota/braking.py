"""Trajectory braking zones (paper Eq. 6 and Alg. 1, lines 10-17).

A sample ``i`` of the path is a *braking point* (paper Eq. 6) when its nearest
obstacle ``o_i`` is close and ahead:

    ||o_i - p_i|| <= d_th   and   (o_i - p_i) . v_i >= 0

"Close" is the paper's fixed ``d_th``. Here, by default, it follows the risk: an
obstacle is close when, with the uncertainty model's std at ``v_max``, Delta and
the obstacle's distance, the chance-constrained speed limit at the sample (Eqs.
14-15) falls below ``v_max`` (or no speed meets the bound). That is exactly the set
of samples where a limit can bind, so no other threshold is needed
(``docs/safety-model.md``, section 2). ``d_th`` stays as an explicit override: an
obstacle within ``d_th`` makes a braking point as well, and ``risk=False`` gives
the paper's Eq. 6 alone.

An obstacle behind the vehicle never makes a braking point. Runs of braking
points become time intervals in trajectory time ``tau`` (Alg. 1 line 16), which
are then refined (line 17): short gaps are merged and short intervals dropped.

Which mask drives the speed limits
----------------------------------
:attr:`BrakingZones.mask` (the raw per-sample Eq. 6 result) is the one to use
for the chance-constraint speed limits; :attr:`BrakingZones.speed_limit_mask`
returns it. The refined intervals / :attr:`BrakingZones.refined_mask` are for
reports, plots and problem splitting only. Reasons:

* Dropping a short raw interval would drop a real close approach (a thin pole
  passed at speed is within ``d_th`` only briefly): that is exactly where the
  constraint matters, so refinement must never remove a limit.
* Samples inside a merged gap are, by Eq. 6, not braking points (the obstacle
  is farther than ``d_th`` or behind). Limiting them adds no safety under the
  paper's model and only slows the flight; the acceleration limits and the
  smoothness term of the optimiser already shape the deceleration into and the
  acceleration out of each zone.
* It matches the authors' implementation, so results stay comparable.

All per-sample work is vectorised; only the (few) intervals are looped over.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rota.chance import ChanceParams, UncertaintyModel, kernel_args, risk_reach
from rota.errors import InputError
from rota.jit import kernels

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: Authors' refinement constants (notes sec. 2): an interval no longer than
#: ``min(0.1 T, 0.5 s)`` is dropped, a gap no longer than ``min(0.05 T, 0.25 s)``
#: is merged, ``T`` being the trajectory duration in ``tau``.
MIN_INTERVAL_RATIO, MIN_INTERVAL_CAP = 0.1, 0.5
MERGE_GAP_RATIO, MERGE_GAP_CAP = 0.05, 0.25


def _opt_nonneg(value: float | None, name: str) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float, np.number)):
        raise InputError(name, f"must be a number or None, got {type(value).__name__}")
    v = float(value)
    if math.isnan(v) or v < 0.0:
        raise InputError(name, f"must be >= 0, got {v}")
    return v


@dataclass(frozen=True)
class BrakingParams:
    """Parameters of Alg. 1.

    Attributes:
        d_th: fixed distance threshold of Eq. 6 (m): an obstacle within it always
            makes a braking point. Default 0: none (paper / authors: 1.0 m).
        risk: braking points also where the chance limit falls below ``v_max``
            (default; see the module docstring). ``False`` with ``d_th = 1.0`` is
            the paper's Eq. 6.
        min_interval: refined intervals no longer than this (tau seconds) are
            dropped. ``None``: ``min(0.1 T, 0.5)`` as in the authors' code.
        merge_gap: gaps between intervals no longer than this (tau seconds) are
            merged. ``None``: ``min(0.05 T, 0.25)`` as in the authors' code.
        horizon_length: only samples within this path length (m) from the first
            sample are checked (authors: 20 m, for receding-horizon replanning).
            ``None`` (default): the whole trajectory.
    """

    d_th: float = 0.0
    risk: bool = True
    min_interval: float | None = None
    merge_gap: float | None = None
    horizon_length: float | None = None

    def __post_init__(self) -> None:
        d = _opt_nonneg(self.d_th, "d_th")
        if d is None or not math.isfinite(d):
            raise InputError("d_th", "must be a finite number >= 0")
        object.__setattr__(self, "d_th", d)
        if not isinstance(self.risk, bool):
            raise InputError("risk", f"must be true or false, got {self.risk!r}")
        for name in ("min_interval", "merge_gap", "horizon_length"):
            object.__setattr__(self, name, _opt_nonneg(getattr(self, name), name))


@dataclass(frozen=True, eq=False)
class BrakingZones:
    """Result of :func:`find_braking_zones`.

    Attributes:
        mask: ``(n,)`` raw braking points (Eq. 6). Drives the speed limits.
        intervals: refined braking zones ``((tau_start, tau_end), ...)``, sorted.
        refined_mask: ``(n,)`` samples with ``tau`` inside a refined interval
            (reporting / plots).
        nearest: ``(n, 3)`` nearest obstacle per sample (NaN where none).
        distance: ``(n,)`` distance to it (inf where none).
        raw_intervals: the unrefined runs of ``mask`` as ``(tau_start, tau_end)``.
    """

    mask: BoolArray
    intervals: tuple[tuple[float, float], ...]
    refined_mask: BoolArray
    nearest: FloatArray
    distance: FloatArray
    raw_intervals: tuple[tuple[float, float], ...] = ()

    @property
    def speed_limit_mask(self) -> BoolArray:
        """Samples that get a chance-constraint speed limit: the raw :attr:`mask`."""
        return self.mask


def _array(value: ArrayLike, name: str, shape: tuple[int, ...], allow_nan: bool = False,
           allow_inf: bool = False) -> FloatArray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(name, f"must be numeric ({exc})") from None
    if arr.shape != shape:
        raise InputError(name, f"must have shape {shape}, got {arr.shape}")
    bad = np.isnan(arr) if not allow_nan else np.zeros(arr.shape, bool)
    if not allow_inf:
        bad |= np.isinf(arr)
    if bad.any():
        idx = "".join(f"[{int(i)}]" for i in np.argwhere(bad)[0])
        raise InputError(f"{name}{idx}", "must be finite")
    return arr


def refine_intervals(
    intervals: list[tuple[float, float]] | tuple[tuple[float, float], ...],
    min_interval: float,
    merge_gap: float,
) -> tuple[tuple[float, float], ...]:
    """Alg. 1 line 17: merge gaps ``<= merge_gap``, then drop intervals ``<= min_interval``.

    Merging first (the authors drop first) keeps a zone that flickers on and off
    between samples as one zone instead of dropping all its short pieces.
    """
    merged: list[list[float]] = []
    for a, b in sorted(intervals):
        if merged and a - merged[-1][1] <= merge_gap:
            merged[-1][1] = max(merged[-1][1], b)
        else:
            merged.append([a, b])
    return tuple((a, b) for a, b in merged if b - a > min_interval)


def find_braking_zones(
    tau: ArrayLike,
    p: ArrayLike,
    v: ArrayLike,
    distance: ArrayLike,
    obstacle: ArrayLike,
    params: BrakingParams | None = None,
    model: UncertaintyModel | None = None,
    chance: ChanceParams | None = None,
) -> BrakingZones:
    """Braking points (paper Eq. 6) and refined braking zones (Alg. 1).

    Args:
        tau: ``(n,)`` strictly increasing trajectory times of the samples.
        p: ``(n, 3)`` sample positions.
        v: ``(n, 3)`` velocities ``sigma'(tau)`` (only the direction matters).
        distance: ``(n,)`` distance to the nearest obstacle (``inf`` = none),
            e.g. from :meth:`rota.voxelmap.VoxelMap.nearest`.
        obstacle: ``(n, 3)`` nearest obstacle points (``NaN`` rows = none).
        params: :class:`BrakingParams` (defaults if omitted).
        model, chance: the uncertainty model and chance parameters the risk is
            judged with (defaults if omitted; unused with ``params.risk`` off).

    A sample with zero velocity counts as a braking point when close (the
    paper's ``>= 0``). Samples beyond ``params.horizon_length`` of path length
    are never braking points.
    """
    params = BrakingParams() if params is None else params
    if np.ndim(tau) != 1 or np.size(tau) == 0:
        raise InputError("tau", f"must be a non-empty 1-D array, got shape {np.shape(tau)}")
    t = _array(tau, "tau", (np.size(tau),))
    n = t.shape[0]
    if n > 1 and not np.all(np.diff(t) > 0):
        raise InputError("tau", "must be strictly increasing")
    pos = _array(p, "p", (n, 3))
    vel = _array(v, "v", (n, 3))
    dist = _array(distance, "distance", (n,), allow_inf=True)
    if (dist < 0).any():
        raise InputError(f"distance[{int(np.argmax(dist < 0))}]", "must be >= 0")
    obst = _array(obstacle, "obstacle", (n, 3), allow_nan=True)

    return zones_of(t, pos, vel, dist.copy(), obst.copy(), params,
                    UncertaintyModel() if model is None else model,
                    ChanceParams() if chance is None else chance)


def zones_of(t: FloatArray, pos: FloatArray, vel: FloatArray, dist: FloatArray,
             obst: FloatArray, params: BrakingParams, model: UncertaintyModel,
             chance: ChanceParams) -> BrakingZones:
    """:func:`find_braking_zones` on checked arrays; ``dist`` and ``obst`` become the
    result's (read-only) arrays, not copied."""
    n = t.shape[0]
    mask = np.empty(n, dtype=bool)
    k = kernels()
    risky = np.empty(n if params.risk else 0, dtype=bool)
    if params.risk:
        limit, unclamped, infeasible = np.empty(n), np.empty(n), np.empty(n, dtype=bool)
        k.chance_limits(np.ascontiguousarray(pos), np.ascontiguousarray(vel),
                        np.ascontiguousarray(obst), *kernel_args(model, chance), limit,
                        unclamped, infeasible)
        k.risky_nodes(limit, infeasible, chance.v_max, risky)
    starts, ends = k.braking_points(pos, vel, dist, obst, params.d_th, risky,
                                    horizon_of(params), mask)
    return zones_from(t, mask, starts, ends, dist, obst, params)


def horizon_of(params: BrakingParams) -> float:
    return np.inf if params.horizon_length is None else params.horizon_length


def reach_of(params: BrakingParams, model: UncertaintyModel, chance: ChanceParams) -> float:
    """How far (m) an obstacle can make a braking point: ``d_th``, and with the risk
    on the distance :func:`rota.chance.risk_reach` beyond which no chance limit falls
    below ``v_max``. The nearest-obstacle query must reach at least this far."""
    return max(params.d_th, risk_reach(model, chance) if params.risk else 0.0)


def zones_from(t: FloatArray, mask: BoolArray, starts: NDArray[np.int64],
               ends: NDArray[np.int64], dist: FloatArray, obst: FloatArray,
               params: BrakingParams) -> BrakingZones:
    """The zones of the braking points ``mask`` (runs ``starts`` to ``ends``, both
    inclusive): raw intervals, refined ones (Alg. 1 line 17) and their mask."""
    n = t.shape[0]
    tl = t.tolist()
    raw = tuple((tl[a], tl[b]) for a, b in zip(starts.tolist(), ends.tolist(), strict=True))
    duration = tl[-1] - tl[0]
    min_iv = (
        min(MIN_INTERVAL_RATIO * duration, MIN_INTERVAL_CAP)
        if params.min_interval is None
        else params.min_interval
    )
    gap = (
        min(MERGE_GAP_RATIO * duration, MERGE_GAP_CAP)
        if params.merge_gap is None
        else params.merge_gap
    )
    refined = refine_intervals(raw, min_iv, gap)
    refined_mask = np.zeros(n, dtype=bool)
    if refined:
        # samples from the first at or after a zone's start to the last at or before its end
        cuts = np.searchsorted(t, refined).tolist()
        for (_, end), (i, j) in zip(refined, cuts, strict=True):
            refined_mask[i:j + (j < n and tl[j] == end)] = True
    for arr in (mask, refined_mask, dist, obst):
        arr.setflags(write=False)
    return BrakingZones(mask, refined, refined_mask, obst, dist, raw)
