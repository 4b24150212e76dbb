"""Reference planner: collision-free uniform cubic B-splines through a :class:`World`.

It produces the kind of trajectory ROTA receives from a real planner (EGO-Planner
/ Fast-Planner style): a uniform B-spline planned at ``v_max`` / ``a_max``, with
velocity near ``v_max`` on open stretches, slowing for turns, starting and
ending at rest (or starting from a moving vehicle's state when replanning).

Pipeline (:func:`plan_detailed`):

1. **Occupancy grid** over the world's x-y bounds at ``resolution``, on the
   altitude layers between start and goal (one layer when they share an
   altitude). A cell is free when its centre's signed distance is at least
   ``robot_radius + clearance``; near the start and goal only
   ``robot_radius + 0.05`` is required, so a vehicle already close to an
   obstacle can still leave.
2. **Shortest grid path** with Dijkstra (:func:`scipy.sparse.csgraph.dijkstra`)
   on the 8- (or 26-) connected graph of free cells.
3. **Shortcut**: greedy line of sight on the free grid, leaving a polyline.
4. **Fillets**: every corner is replaced by a circular arc whose radius is the
   largest (up to ``v_max**2 / (0.8 a_max)``) whose arc keeps
   ``robot_radius + clearance / 2`` from obstacles; sharp corners without room
   become stop-and-turn corners.
5. **Speed profile** along arc length: ``v <= v_max``, on arcs
   ``v**2 / R <= 0.8 a_max`` and tangential acceleration limited so that the
   total acceleration stays within ``a_max`` pointwise (forward-backward pass,
   constant acceleration per 1 cm piece).
6. **B-spline**: control points are samples of the timed path every
   ``knot_span``. Spline velocity control points are averages of the path
   velocity and acceleration control points weighted averages of the path
   acceleration, so ``|v| <= v_max`` and ``|a| <= a_max`` carry over (the
   exact maximum is checked and, for rest starts, any rounding excess removed by
   uniform time scaling).
7. **Check**: the spline is sampled every 5 mm of arc length and must keep
   ``robot_radius + 2.5 mm`` from every obstacle, which, the signed distance
   being 1-Lipschitz, rules out collisions between samples too. On failure the
   plan is repeated with more clearance and a shorter knot span; if nothing
   works :class:`PlanningError` is raised. A colliding trajectory is never returned.

Search is on the altitude layers between start and goal only; a world that
can only be crossed by climbing over obstacles raises :class:`PlanningError`.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.sparse import csgraph

from rota.errors import InputError, plain
from rota.trajectory import BSplineTrajectory
from rota.validate import positive, vector3
from sitl.planner_grid import build_grid, grid_graph, nearest_free, shortcut
from sitl.world import World

FloatArray = NDArray[np.float64]

#: Default clearance (m) added to the robot radius when inflating the grid.
DEFAULT_CLEARANCE = 0.2
#: Default uniform knot span (s) of the output B-spline.
DEFAULT_KNOT_SPAN = 0.1

_LATERAL_SHARE = 0.8  # fraction of a_max usable for centripetal acceleration on arcs
_PROFILE_STEP = 0.01  # m, arc-length step of the speed profile
_CHECK_STEP = 0.005  # m, arc-length step of the final collision check
_HARD_MARGIN = 0.05  # m, extra distance required near start / goal
_MIN_FILLET = 0.03  # m, smaller fillet radii become stop-and-turn corners


class PlanningError(RuntimeError):
    """No collision-free trajectory could be planned (the message says why)."""


@dataclass(frozen=True)
class PlanResult:
    """A planned trajectory with what it took to get it.

    ``attempts`` is 1 when the first try passed the collision check; larger
    values mean the plan was repaired (more clearance, shorter knot span).
    ``min_clearance`` is the smallest sampled signed distance minus the robot
    radius (m). ``time_scale`` is the uniform time scaling applied after fitting
    (1.0 when the fitted spline already met the limits). ``max_speed`` bounds the
    spline's speed (largest velocity control point); ``max_acceleration`` is the
    exact maximum of its acceleration norm (reached at a knot).
    """

    trajectory: BSplineTrajectory
    grid_path: FloatArray
    waypoints: FloatArray
    attempts: int
    clearance: float
    knot_span: float
    min_clearance: float
    time_scale: float
    max_speed: float
    max_acceleration: float


# ----------------------------------------------------------------------- public
def plan(
    world: World,
    v_max: float,
    a_max: float,
    start: ArrayLike | None = None,
    goal: ArrayLike | None = None,
    start_velocity: ArrayLike | None = None,
    resolution: float = 0.1,
    clearance: float = DEFAULT_CLEARANCE,
    knot_span: float = DEFAULT_KNOT_SPAN,
    strict: bool = True,
) -> BSplineTrajectory:
    """Plan a collision-free cubic B-spline from ``start`` to ``goal`` (see module doc).

    ``start`` / ``goal`` default to the world's. ``start_velocity`` (m/s, ENU)
    makes the trajectory begin with that velocity (zero acceleration), for
    replanning from a moving vehicle; it always ends at rest at ``goal``.

    The speed stays within ``max(v_max, |start_velocity|)`` and the acceleration
    norm within ``a_max``. A moving start that cannot brake in time (heading at an
    obstacle) would need more: with ``strict`` (default) that raises
    :class:`PlanningError`, otherwise the over-limit trajectory is returned (see
    :attr:`PlanResult.max_acceleration`). Raises :class:`PlanningError` when no
    collision-free trajectory is found and :class:`~rota.errors.InputError` for
    bad arguments.
    """
    return plan_detailed(world, v_max, a_max, start, goal, start_velocity, resolution,
                         clearance, knot_span, strict).trajectory


def plan_detailed(
    world: World,
    v_max: float,
    a_max: float,
    start: ArrayLike | None = None,
    goal: ArrayLike | None = None,
    start_velocity: ArrayLike | None = None,
    resolution: float = 0.1,
    clearance: float = DEFAULT_CLEARANCE,
    knot_span: float = DEFAULT_KNOT_SPAN,
    strict: bool = True,
) -> PlanResult:
    """As :func:`plan`, returning a :class:`PlanResult` with diagnostics."""
    v_max, a_max = positive(v_max, "v_max"), positive(a_max, "a_max")
    resolution, knot_span = positive(resolution, "resolution"), positive(knot_span, "knot_span")
    clearance = float(clearance)
    if not math.isfinite(clearance) or clearance < 0:
        raise InputError("clearance", f"must be a non-negative number, got {plain(clearance)}")
    p0 = vector3(world.start if start is None else start, "start")
    p1 = vector3(world.goal if goal is None else goal, "goal")
    v0 = np.zeros(3) if start_velocity is None else vector3(start_velocity, "start_velocity")
    r = world.robot_radius
    for name, p in (("start", p0), ("goal", p1)):
        d = float(world.signed_distance(p[None])[0])
        if d < r:
            raise PlanningError(f"{name} {p.tolist()} is in collision (distance {d:.3f} m to "
                                f"the nearest obstacle, robot radius {r} m)")
    if np.linalg.norm(p1 - p0) < 1e-6 and np.linalg.norm(v0) < 1e-9:
        raise InputError("goal", "coincides with the start")

    schedule = [(clearance, knot_span), (clearance + 0.1, knot_span),
                (clearance + 0.2, 0.5 * knot_span), (0.5 * clearance, 0.5 * knot_span),
                (min(clearance, 0.05), 0.5 * knot_span)]
    reasons = []
    for attempt, (clr, ks) in enumerate(schedule, start=1):
        try:
            grid_path, waypoints = _geometric_path(world, p0, p1, v0, resolution, clr, ks, a_max)
        except _NoPath as exc:
            reasons.append(f"attempt {attempt} (clearance {clr:.2f} m): {exc}")
            continue
        speed = float(np.linalg.norm(v0))
        path = _fillet_path(world, waypoints, v_max, a_max, r + 0.5 * clr, speed, speed * ks)
        traj, scale = _fit_bspline(path, v0, v_max, a_max, ks)
        min_clear = _min_clearance(world, traj)
        label = f"attempt {attempt} (clearance {clr:.2f} m, knot span {ks:g} s)"
        if min_clear < 0.5 * _CHECK_STEP:
            reasons.append(f"{label}: trajectory clips an obstacle (clearance {min_clear:.3f} m)")
            continue
        cps = traj.control_points
        top_v = float(np.max(np.linalg.norm(np.diff(cps, axis=0), axis=1))) / traj.knot_span
        top_a = float(np.max(np.linalg.norm(np.diff(cps, 2, axis=0), axis=1))) / traj.knot_span**2
        tol = 1.0 + 1e-6
        if strict and (top_v > max(v_max, speed) * tol or top_a > a_max * tol):
            reasons.append(f"{label}: the start velocity cannot be absorbed within the limits "
                           f"(speed {top_v:.2f} m/s, acceleration {top_a:.2f} m/s^2)")
            continue
        return PlanResult(traj, grid_path, waypoints, attempt, clr, traj.knot_span,
                          min_clear, scale, top_v, top_a)
    raise PlanningError("no collision-free trajectory: " + "; ".join(reasons))


def straight_line(
    p0: ArrayLike, p1: ArrayLike, v_max: float, a_max: float,
    knot_span: float = DEFAULT_KNOT_SPAN,
) -> BSplineTrajectory:
    """Rest-to-rest straight line from ``p0`` to ``p1`` at ``v_max`` / ``a_max``.

    Trapezoidal (or triangular) speed profile along the line; no obstacle check.
    """
    a, b = vector3(p0, "p0"), vector3(p1, "p1")
    if np.linalg.norm(b - a) < 1e-9:
        raise InputError("p1", "coincides with p0")
    v_max, a_max = positive(v_max, "v_max"), positive(a_max, "a_max")
    path = _Path.from_primitives([_line(a, b)], v_max, a_max)
    return _fit_bspline(path, np.zeros(3), v_max, a_max, positive(knot_span, "knot_span"))[0]


# ------------------------------------------------------------ search (sitl/planner_grid.py)
class _NoPath(Exception):
    pass


def _segment_clear(world: World, a: FloatArray, b: FloatArray, dist: float) -> bool:
    n = max(2, int(math.ceil(np.linalg.norm(b - a) / 0.01)) + 1)
    pts = a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)
    return bool(np.all(world.signed_distance(pts) >= dist))


def _geometric_path(world: World, p0: FloatArray, p1: FloatArray, v0: FloatArray, res: float,
                    clearance: float, knot_span: float,
                    a_max: float) -> tuple[FloatArray, FloatArray]:
    """Grid path and shortcut polyline from ``p0`` (moving at ``v0``) to ``p1``."""
    r = world.robot_radius
    head = [p0]
    speed = float(np.linalg.norm(v0))
    if speed > 1e-9:  # keep going along v0 while braking: the path's first leg is straight
        reserve = speed * knot_span
        want = reserve + speed**2 / (2.0 * a_max) + 0.05
        lo, hi = np.array(world.bounds[0]), np.array(world.bounds[1])
        for frac in (1.0, 0.75, 0.5, 0.25, 0.0):
            d = reserve + 1e-3 + frac * (want - reserve)
            ahead = p0 + v0 / speed * d
            if np.all(ahead >= lo) and np.all(ahead <= hi) and _segment_clear(
                    world, p0, ahead, r + _HARD_MARGIN):
                head.append(ahead)
                break
        else:
            raise _NoPath("no room to continue along the start velocity")
    src = head[-1]
    grid = build_grid(world, res, float(src[2]), float(p1[2]), r + clearance, [src, p1],
                      clearance + 2.0 * res, _HARD_MARGIN)
    si, gi = nearest_free(grid, src), nearest_free(grid, p1)
    if si is None or gi is None:
        raise _NoPath(f"no free grid cell next to the {'start' if si is None else 'goal'}")
    s_id = int(np.ravel_multi_index(tuple(si), grid.shape))
    g_id = int(np.ravel_multi_index(tuple(gi), grid.shape))
    _, pred = csgraph.dijkstra(grid_graph(grid), directed=False, indices=s_id,
                               return_predecessors=True)
    if pred[g_id] < 0 and g_id != s_id:
        raise _NoPath("no grid path between start and goal")
    chain = [g_id]
    while chain[-1] != s_id:
        chain.append(int(pred[chain[-1]]))
    cells = grid.centres(np.stack(np.unravel_index(np.array(chain[::-1]), grid.shape), axis=1))
    grid_path = np.vstack([*head, cells, p1])
    tail = shortcut(grid, np.vstack([src, cells, p1]), 0.5 * res)
    waypoints = np.vstack([*head[:-1], tail])
    return grid_path, _drop_collinear(waypoints)


def _drop_collinear(pts: FloatArray) -> FloatArray:
    """Remove repeated points and points where the polyline does not turn."""
    keep = [pts[0]]
    for p in pts[1:]:
        if np.linalg.norm(p - keep[-1]) > 1e-9:
            keep.append(p)
    out = [keep[0]]
    for i in range(1, len(keep) - 1):
        u = keep[i] - out[-1]
        w = keep[i + 1] - keep[i]
        cos = float(u @ w) / (np.linalg.norm(u) * np.linalg.norm(w))
        if cos < 1.0 - 1e-9:
            out.append(keep[i])
    out.append(keep[-1])
    return np.array(out)


# ------------------------------------------------------------- path geometry
@dataclass(frozen=True)
class _Prim:
    """A line (``radius == 0``) or circular arc of the smoothed path."""

    origin: FloatArray  # line start, or arc centre
    e1: FloatArray  # line direction, or unit vector centre -> arc start
    e2: FloatArray  # unused for lines; arc tangent at its start
    radius: float
    length: float


def _line(a: FloatArray, b: FloatArray) -> _Prim:
    d = b - a
    n = float(np.linalg.norm(d))
    return _Prim(a, d / n, np.zeros(3), 0.0, n)


@dataclass(frozen=True)
class _Path:
    """Arc-length parametrised chain of lines and arcs with per-primitive limits."""

    origin: FloatArray  # (P, 3)
    e1: FloatArray
    e2: FloatArray
    radius: FloatArray  # (P,), 0 for lines
    s0: FloatArray  # (P + 1,) cumulative arc length at primitive starts, last = total
    v_lim: FloatArray  # (P,) speed limit per primitive (up to the start speed if faster)
    a_tan: FloatArray  # (P,) tangential acceleration limit per primitive
    stops: FloatArray  # arc lengths where the speed must be zero (sharp corners)
    v_max: float
    a_max: float

    @classmethod
    def from_primitives(cls, prims: list[_Prim], v_max: float, a_max: float,
                        stops: list[float] | None = None, v_start: float = 0.0) -> _Path:
        radius = np.array([p.radius for p in prims])
        arc = radius > 0
        v_cap = max(v_max, v_start)  # a faster start may keep its speed while braking
        v_lim = np.full(len(prims), v_cap)
        v_lim[arc] = np.minimum(v_cap, np.sqrt(_LATERAL_SHARE * a_max * radius[arc]))
        a_tan = np.full(len(prims), a_max)
        lat = np.where(arc, v_lim**2 / np.where(arc, radius, 1.0), 0.0)
        a_tan[arc] = np.sqrt(np.maximum(a_max**2 - lat[arc] ** 2, 0.0))
        return cls(np.array([p.origin for p in prims]), np.array([p.e1 for p in prims]),
                   np.array([p.e2 for p in prims]), radius,
                   np.concatenate([[0.0], np.cumsum([p.length for p in prims])]),
                   v_lim, a_tan, np.array(stops or [], dtype=float), v_max, a_max)

    @property
    def length(self) -> float:
        return float(self.s0[-1])

    def position(self, s: FloatArray) -> FloatArray:
        s = np.clip(s, 0.0, self.length)
        j = np.clip(np.searchsorted(self.s0, s, side="right") - 1, 0, len(self.radius) - 1)
        u = (s - self.s0[j])[:, None]
        r = self.radius[j][:, None]
        phi = u / np.where(r > 0, r, 1.0)
        on_arc = self.origin[j] + r * (np.cos(phi) * self.e1[j] + np.sin(phi) * self.e2[j])
        on_line = self.origin[j] + u * self.e1[j]
        return np.where(r > 0, on_arc, on_line)


def _fillet_path(world: World, pts: FloatArray, v_max: float, a_max: float, keep: float,
                 entry_speed: float, reserve: float) -> _Path:
    """Round the polyline's corners with the largest safe arcs (see module doc).

    With a moving start (``entry_speed > 0``) the first ``reserve`` metres stay
    straight and the first corner leaves room to brake to its arc's speed.
    """
    n = len(pts)
    seg = np.diff(pts, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    dirs = seg / seg_len[:, None]
    # length of each segment available to the corner at its start / end: middle segments
    # split half/half; the first and last give everything to their one corner (the first
    # keeps ``reserve`` straight for the start velocity)
    avail_start, avail_end = 0.5 * seg_len, 0.5 * seg_len
    avail_end[0] = max(seg_len[0] - reserve - 1e-4, 0.0)
    avail_start[-1] = seg_len[-1]
    r_want = v_max**2 / (_LATERAL_SHARE * a_max)
    prims: list[_Prim] = []
    stops: list[float] = []
    cursor = pts[0]
    s_acc = 0.0
    for i in range(1, n - 1):
        u1, u2 = dirs[i - 1], dirs[i]
        theta = math.acos(float(np.clip(u1 @ u2, -1.0, 1.0)))
        half_tan = math.tan(0.5 * theta) if theta < math.pi - 1e-6 else math.inf
        r_geo = min(avail_end[i - 1], avail_start[i]) / half_tan
        entry = (entry_speed, seg_len[0] - reserve, a_max) if i == 1 and entry_speed > 0 else None
        arc = _best_fillet(world, pts[i], u1, u2, theta, min(r_want, r_geo), keep, entry)
        if arc is None:  # stop-and-turn corner
            prims.append(_line(cursor, pts[i]))
            s_acc += prims[-1].length
            stops.append(s_acc)
            cursor = pts[i]
            continue
        t1 = pts[i] - arc.radius * half_tan * u1
        if np.linalg.norm(t1 - cursor) > 1e-9:
            prims.append(_line(cursor, t1))
            s_acc += prims[-1].length
        prims.append(arc)
        s_acc += arc.length
        cursor = pts[i] + arc.radius * half_tan * u2
    if np.linalg.norm(pts[-1] - cursor) > 1e-9:
        prims.append(_line(cursor, pts[-1]))
    return _Path.from_primitives(prims, v_max, a_max, stops, entry_speed)


def _arc(vertex: FloatArray, u1: FloatArray, u2: FloatArray, theta: float, r: float) -> _Prim:
    half = 0.5 * theta
    t1 = vertex - r * math.tan(half) * u1
    bis = u2 - u1
    centre = vertex + bis / np.linalg.norm(bis) * (r / math.cos(half))
    return _Prim(centre, (t1 - centre) / r, u1, r, r * theta)


def _best_fillet(world: World, vertex: FloatArray, u1: FloatArray, u2: FloatArray, theta: float,
                 r_max: float, keep: float,
                 entry: tuple[float, float, float] | None = None) -> _Prim | None:
    """Largest arc (radius r_max * 0.7**k >= _MIN_FILLET) keeping ``keep`` from obstacles.

    ``entry = (speed, room, a_max)``: the corner is approached at ``speed`` with
    ``room`` metres of straight line; the arc must leave enough of it to brake to
    the arc's speed limit.
    """
    if not r_max >= _MIN_FILLET or theta >= math.pi - 1e-3:
        return None
    radii = r_max * 0.7 ** np.arange(int(math.log(_MIN_FILLET / r_max) / math.log(0.7)) + 1)
    if entry is not None:
        speed, room, a_max = entry
        v_arc = np.minimum(speed, np.sqrt(_LATERAL_SHARE * a_max * radii))
        brake = (speed**2 - v_arc**2) / (2.0 * a_max)
        radii = radii[brake + radii * math.tan(0.5 * theta) <= room]
        if len(radii) == 0:
            return None
    arcs = [_arc(vertex, u1, u2, theta, float(r)) for r in radii]
    counts = [max(4, int(math.ceil(a.length / 0.02)) + 1) for a in arcs]
    pts = np.vstack([a.origin + a.radius * (np.cos(ph)[:, None] * a.e1 + np.sin(ph)[:, None] * a.e2)
                     for a, c in zip(arcs, counts, strict=True)
                     for ph in [np.linspace(0.0, theta, c)]])
    sd = world.signed_distance(pts)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    ok = np.minimum.reduceat(sd, starts) >= keep
    return arcs[int(np.argmax(ok))] if ok.any() else None


# ------------------------------------------------------- timing and B-spline
def _speed_profile(path: _Path, v_start: float,
                   s_begin: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Nodes ``s``, speeds ``v`` and times ``t`` of the fastest admissible profile."""
    edges = np.concatenate([path.s0, path.stops, [s_begin]])
    edges = np.unique(edges[(edges >= s_begin) & (edges <= path.length)])
    pieces = [np.linspace(a, b, max(1, int(math.ceil((b - a) / _PROFILE_STEP))) + 1)[:-1]
              for a, b in itertools.pairwise(edges)]
    s = np.concatenate([*pieces, [path.length]])
    mid = 0.5 * (s[:-1] + s[1:])
    prim = np.clip(np.searchsorted(path.s0, mid, side="right") - 1, 0, len(path.radius) - 1)
    a_piece = path.a_tan[prim]
    v_piece = path.v_lim[prim]
    lim = np.minimum(np.concatenate([v_piece, [0.0]]), np.concatenate([[np.inf], v_piece]))
    # above v_max only while braking from a faster start at a_max
    lim = np.minimum(lim, np.maximum(path.v_max, np.sqrt(np.maximum(
        v_start**2 - 2.0 * path.a_max * (s - s_begin), 0.0))))
    lim[0] = v_start
    if len(path.stops):
        lim[np.isin(s, path.stops)] = 0.0
    ds = np.diff(s)
    v = lim.copy()
    two_a_ds = 2.0 * a_piece * ds
    for k in range(len(ds)):  # forward: accelerate
        v[k + 1] = min(v[k + 1], math.sqrt(v[k] ** 2 + two_a_ds[k]))
    for k in range(len(ds) - 1, -1, -1):  # backward: brake
        v[k] = min(v[k], math.sqrt(v[k + 1] ** 2 + two_a_ds[k]))
    v[0] = v_start  # an unstoppable start velocity is kept; the limits are then exceeded
    # A piece between two stops (both speeds 0) is crossed by accelerating to its
    # middle and braking again: 2 sqrt(ds / a); elsewhere constant acceleration.
    vsum = v[:-1] + v[1:]
    with np.errstate(divide="ignore", invalid="ignore"):
        dt = np.where(vsum > 0, 2.0 * ds / np.where(vsum > 0, vsum, 1.0),
                      2.0 * np.sqrt(ds / np.maximum(a_piece, 1e-9)))
    t = np.concatenate([[0.0], np.cumsum(dt)])
    return s, v, t


def _sample_profile(s: FloatArray, v: FloatArray, t: FloatArray, times: FloatArray) -> FloatArray:
    """Arc length at ``times`` with constant acceleration between profile nodes."""
    k = np.clip(np.searchsorted(t, times, side="right") - 1, 0, len(s) - 2)
    ds = s[k + 1] - s[k]
    span = t[k + 1] - t[k]
    acc = (v[k + 1] ** 2 - v[k] ** 2) / (2.0 * ds)
    dt = np.clip(times - t[k], 0.0, span)
    out = np.minimum(s[k] + v[k] * dt + 0.5 * acc * dt**2, s[k + 1])
    # between two stops: accelerate to the middle, brake to the next stop
    still = (v[k] + v[k + 1]) <= 0
    if still.any():
        a2 = 4.0 * ds / np.where(span > 0, span, 1.0) ** 2
        rise = s[k] + 0.5 * a2 * dt**2
        fall = s[k + 1] - 0.5 * a2 * (span - dt) ** 2
        out = np.where(still, np.where(dt <= 0.5 * span, rise, fall), out)
    return out


def _fit_bspline(path: _Path, v0: FloatArray, v_max: float, a_max: float,
                 knot_span: float) -> tuple[BSplineTrajectory, float]:
    """Uniform cubic B-spline whose control points sample the timed path.

    Timeline of the sampled path q(t): [0, dt] keeps the start velocity
    (a dwell when at rest), then the speed profile, then rest at the goal. The
    control point C_j is q((j - 1) dt), with q extended backwards at v0, so the
    spline starts exactly at the start with velocity v0 and ends at rest at the goal.
    """
    dt = knot_span
    speed = float(np.linalg.norm(v0))
    s, v, t = _speed_profile(path, speed, min(speed * dt, path.length))
    start, goal = path.position(np.array([0.0]))[0], path.position(np.array([path.length]))[0]
    t_end = dt + t[-1]
    last = int(math.ceil(t_end / dt - 1e-9)) + 1  # first j with (j - 1) dt >= t_end
    times = (np.arange(last + 3) - 1) * dt
    cps = np.empty((len(times), 3))
    head = times <= dt
    cps[head] = start + times[head, None] * v0
    body = ~head
    cps[body] = path.position(_sample_profile(s, v, t, times[body] - dt))
    cps[times >= t_end] = goal
    vel = np.diff(cps, axis=0) / dt
    acc = np.diff(cps, 2, axis=0) / dt**2
    v_cap = max(v_max, speed)
    scale = max(1.0, float(np.max(np.linalg.norm(vel, axis=1))) / v_cap,
                math.sqrt(float(np.max(np.linalg.norm(acc, axis=1))) / a_max))
    if speed > 1e-9:
        scale = 1.0  # time scaling would change the start velocity
    return BSplineTrajectory(cps, 3, knot_span * scale), scale


def _min_clearance(world: World, traj: BSplineTrajectory) -> float:
    """Smallest signed distance minus robot radius, sampled every _CHECK_STEP of arc length."""
    t0, t1 = traj.domain
    vmax = float(np.max(np.linalg.norm(np.diff(traj.control_points, axis=0), axis=1)))
    vmax /= traj.knot_span  # bound on the spline speed (convex hull of velocity control points)
    n = max(2, int(math.ceil((t1 - t0) * vmax / _CHECK_STEP)) + 1)
    pts = traj.position(np.linspace(t0, t1, n))
    return float(np.min(world.signed_distance(pts))) - world.robot_radius
