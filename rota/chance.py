"""Chance constraint -> per-sample speed limit (paper Eqs. 10-15).

Model (paper Sec. III-C)
------------------------
Robot position ``p ~ N(p_bar, Sigma_p)`` and obstacle ``o ~ N(o_bar, Sigma_o)``
(diagonal covariances); the robot's safe region is an ellipsoid with semi-axes
``(a, b, c)``, ``Q_c = diag(1/a^2, 1/b^2, 1/c^2)``; collision means
``||p - o||_{Q_c} <= 1`` (Eq. 10). In the scaled space ``x -> Q_c^{1/2} x`` the
ellipsoid is the unit ball (Eq. 12); replacing the ball by its tangent
half-space at ``a = d / |d|``, ``d = Q_c^{1/2}(p_bar - o_bar)`` (Eq. 13) gives
(Eq. 14)::

    Pr = 1/2 + 1/2 erf((1 - |d|) / sqrt(2 a^T Sigma^r a)),
    Sigma^r = Q_c^{1/2} (Sigma_p + Sigma_o) Q_c^{1/2}.

(The paper adds ``Sigma_o`` untransformed; the obstacle covariance lives in the
same space as the robot's, so it is transformed too.) The half-space contains
the ball, so the linearised probability is an upper bound of the true one:
the constraint is conservative.

Velocity relation (Eq. 15): the standard deviation along axis ``k`` is
``s_k = max(floor, m |v| + b)`` with ``|v|`` the speed (:class:`UncertaintyModel`,
the default), or, with ``per_axis=True``, the paper's literal reading
``s_k = max(floor, m |v_k| + b)`` with ``|v_k|`` the speed along axis ``k``.
``Sigma_p = diag(s_x^2, s_y^2, s_z^2)``. The per-axis reading depends on the
coordinate frame: a path flying along x past an obstacle abeam in y gets no
lateral uncertainty at all, while the same path rotated by 45 degrees does.
Visual-inertial drift grows with speed in every direction, so the default uses
the speed on every axis, which is frame-invariant and never less cautious.

Speed limit
-----------
With the velocity ``v * u`` (``u`` the unit tangent of the path), requiring
``Pr <= Delta`` is ``a^T Sigma^r a <= ((|d| - 1) / z)^2``, ``z = Phi^{-1}(1 -
Delta)``. The left side is a piecewise quadratic, non-decreasing function of
``v`` (pieces start where an axis' linear part exceeds ``floor``), so the
largest admissible ``v`` is found in closed form, in one compiled pass over the
samples (:func:`speed_limits`, :mod:`rota.kernels.chance`). It depends only on
the position, the path direction and the obstacle - not on the speed - so it
enters the SOCP as a fixed per-sample bound ``|sigma'(tau_i)|^2 beta_i <= v_lim_i^2``.

Error memory
------------
Eq. 15 ties the uncertainty at a sample to the speed *at that sample*. The flown
deviation remembers: the position loop tracks the estimate through a low-pass,
so the deviation at a braking point is a weighted average of the estimation
errors of the last second or two, made at the speeds flown then
(``docs/safety-model.md`` derives it from a first-order tracking loop). With
``UncertaintyModel(memory_s=T)`` the speed limit ``L_i`` of a braking point also
holds over the path length ``L_i * T`` before it (:func:`memory_limits`): the
vehicle is already at ``L_i`` for the last ``T`` seconds before it reaches the
point, so every error that shaped its deviation there was made at a speed the
constraint allows. ``T = 0`` is the paper's model. The result is still one fixed
cap per node, so the problem stays the same convex program.

Point robot: ``semi_axes = (0, 0, 0)`` is accepted and means a point (a ball of
radius 0): margin ``|p - o|`` in metres, no scaling. This reproduces the
reference numbers in the notes (authors' code: no ellipsoid, the map is
inflated instead).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import ndtr, ndtri

from rota.errors import InputError, plain
from rota.jit import kernels

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: The memory time the flight service uses unless configured (s): chosen from the
#: collision experiment by a rule fixed in advance (docs/table1.md, "Memory time").
DEFAULT_MEMORY_S = 1.0

#: Largest memory time accepted (s): beyond this the braking would start so early that
#: the model (a position loop of about a second) no longer describes it.
MAX_MEMORY_S = 10.0


def _number(value: object, name: str, *, lo: float | None = None, lo_open: bool = False,
            hi: float | None = None, hi_open: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.number)):
        raise InputError(name, f"must be a number, got {type(value).__name__}")
    v = float(value)
    if not math.isfinite(v):
        raise InputError(name, f"must be finite, got {v}")
    if lo is not None and (v < lo or (lo_open and v == lo)):
        raise InputError(name, f"must be {'>' if lo_open else '>='} {lo}, got {v}")
    if hi is not None and (v > hi or (hi_open and v == hi)):
        raise InputError(name, f"must be {'<' if hi_open else '<='} {hi}, got {v}")
    return v


def _triple(value: object, name: str) -> tuple[float, float, float]:
    try:
        items = tuple(value)  # type: ignore[arg-type]
    except TypeError:
        raise InputError(name, "must be three numbers (x, y, z)") from None
    if len(items) != 3:
        raise InputError(name, f"must be three numbers (x, y, z), got {len(items)}")
    out = tuple(_number(x, f"{name}[{i}]", lo=0.0) for i, x in enumerate(items))
    return out  # type: ignore[return-value]


def _rows(value: ArrayLike, name: str, n: int | None = None, allow_nan: bool = False) -> FloatArray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(name, f"must be numeric ({exc})") from None
    if arr.ndim == 1 and arr.shape == (3,):
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != 3 or (n is not None and arr.shape[0] != n):
        want = "(n, 3)" if n is None else f"({n}, 3)"
        raise InputError(name, f"must have shape {want}, got {arr.shape}")
    bad = np.isinf(arr) if allow_nan else ~np.isfinite(arr)
    if bad.any():
        i, j = (int(k) for k in np.argwhere(bad)[0])
        raise InputError(f"{name}[{i}][{j}]", "must be finite")
    return arr


@dataclass(frozen=True)
class UncertaintyModel:
    """Velocity -> position standard deviation (paper Eq. 15).

    ``s_k = max(floor, m * |v| + b)`` on every axis ``k`` (``|v|`` the speed), or
    ``max(floor, m * |v_k| + b)`` with ``per_axis`` (the paper's literal
    reading; frame-dependent, see the module docstring). Paper values
    ``m = 0.2``, ``b = -0.1`` (no uncertainty below 0.5 m/s). ``m`` must be
    ``>= 0`` (more speed never means less uncertainty) and ``floor >= 0`` keeps
    the std non-negative. A separate object so that learned ``m``, ``b`` can
    replace it (the flight service's estimator does).

    ``memory_s`` (T, seconds): how long the vehicle's deviation remembers the
    speed flown (see the module docstring and :func:`memory_limits`). 0: the
    paper's memoryless model; the speed limit of a braking point then applies at
    that point only.
    """

    m: float = 0.2
    b: float = -0.1
    floor: float = 0.0
    per_axis: bool = False
    memory_s: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "m", _number(self.m, "m", lo=0.0))
        object.__setattr__(self, "b", _number(self.b, "b"))
        object.__setattr__(self, "floor", _number(self.floor, "floor", lo=0.0))
        object.__setattr__(self, "memory_s", _number(self.memory_s, "memory_s", lo=0.0,
                                                     hi=MAX_MEMORY_S))
        if not isinstance(self.per_axis, bool):
            raise InputError("per_axis", f"must be true or false, got {plain(self.per_axis)}")

    def std(self, velocity: ArrayLike) -> FloatArray:
        """Per-axis position std ``(n, 3)`` for velocities ``(n, 3)`` (Eq. 15)."""
        vel = _rows(velocity, "velocity")
        speed = np.abs(vel) if self.per_axis else np.broadcast_to(
            np.linalg.norm(vel, axis=1, keepdims=True), vel.shape)
        return np.maximum(self.floor, self.m * speed + self.b)


#: The smallest robot semi-axis (m) taken (a micron); below it the robot is a point (give 0).
MIN_SEMI_AXIS_M = 1e-6


@dataclass(frozen=True)
class ChanceParams:
    """Parameters of the chance constraint (Eqs. 10-14) and the speed limits.

    Attributes:
        delta: per-sample collision probability bound ``Delta`` (paper: 0.01 %).
        semi_axes: robot safety ellipsoid ``(a, b, c)`` in metres (ENU x, y, z).
            Default 0.3 m: a 250-450 mm class quadrotor has a propeller-tip radius
            of about 0.15-0.25 m; 0.3 m adds a few centimetres for the distance
            from the obstacle voxel centre to its face. Isotropic because the
            nearest obstacle may lie in any direction and the vehicle tilts.
            ``(0, 0, 0)`` is a point robot (the authors' setting, who inflate the
            map instead; do not do both).
        obstacle_std: per-axis obstacle position std (m). Default 0.03 m: the
            quantisation std of a 0.1 m voxel (uniform over a voxel of width
            ``r`` has std ``r / sqrt(12)``, 0.029 m); use ``0.29 * resolution``
            for other maps, more if the map itself is noisy.
        v_floor: lowest limit returned (m/s). Default 0.5 m/s as the authors; with
            the paper's model there is no uncertainty below 0.5 m/s.
        v_max: highest limit returned (m/s), the limit where the constraint is
            inactive. Default 3.0 m/s, the fastest setting in the paper's tests.
            The optimiser's own ``v_max`` still applies on top.
    """

    delta: float = 1e-4
    semi_axes: tuple[float, float, float] = (0.3, 0.3, 0.3)
    obstacle_std: tuple[float, float, float] = (0.03, 0.03, 0.03)
    v_floor: float = 0.5
    v_max: float = 3.0

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "delta", _number(self.delta, "delta", lo=0.0, lo_open=True, hi=1.0, hi_open=True)
        )
        axes = _triple(self.semi_axes, "semi_axes")
        if any(x == 0.0 for x in axes) and any(x > 0.0 for x in axes):
            raise InputError(
                "semi_axes", "must be all positive, or all zero for a point robot"
            )
        if any(0.0 < x < MIN_SEMI_AXIS_M for x in axes):
            # (1 / a overflows for a subnormal a, and the robot is a point at that size)
            raise InputError("semi_axes", f"must be at least {MIN_SEMI_AXIS_M:g} m, or all "
                             f"zero for a point robot, got {axes}")
        object.__setattr__(self, "semi_axes", axes)
        object.__setattr__(self, "obstacle_std", _triple(self.obstacle_std, "obstacle_std"))
        vf = _number(self.v_floor, "v_floor", lo=0.0)
        vm = _number(self.v_max, "v_max", lo=0.0, lo_open=True)
        if vm < vf:
            raise InputError("v_max", f"must be >= v_floor ({vf}), got {vm}")
        object.__setattr__(self, "v_floor", vf)
        object.__setattr__(self, "v_max", vm)

    @property
    def point_robot(self) -> bool:
        return all(x == 0.0 for x in self.semi_axes)

    @property
    def z(self) -> float:
        """``Phi^{-1}(1 - delta)``: margin in standard deviations."""
        return float(-ndtri(self.delta))


@dataclass(frozen=True, eq=False)
class SpeedLimits:
    """Result of :func:`speed_limits`.

    Attributes:
        limit: ``(n,)`` speed limit (m/s) clamped to ``[v_floor, v_max]``.
        unclamped: ``(n,)`` the largest speed satisfying the linearised
            constraint (``inf`` if unbounded, ``NaN`` where infeasible).
        infeasible: ``(n,)`` no speed ``>= 0`` satisfies ``Pr <= delta`` (the
            nominal position is inside the ellipsoid, or the obstacle / floor
            uncertainty alone is too large); ``limit`` is ``v_floor`` there.
    """

    limit: FloatArray
    unclamped: FloatArray
    infeasible: BoolArray
    v_floor: float

    @property
    def floored(self) -> BoolArray:
        """Feasible samples where ``v_floor`` exceeds the exact limit (constraint violated)."""
        with np.errstate(invalid="ignore"):
            return ~self.infeasible & (self.unclamped < self.v_floor)

    @property
    def violated(self) -> BoolArray:
        """Samples where ``limit`` does not satisfy ``Pr <= delta``."""
        return self.infeasible | self.floored


def _geometry(
    p: FloatArray, obstacle: FloatArray, params: ChanceParams
) -> tuple[FloatArray, FloatArray, FloatArray, BoolArray]:
    """Margin, per-axis variance weights, obstacle variance term, has-obstacle mask.

    The Eq. 14 constraint reads ``margin / sqrt(sum_k w_k (s_k^2 + so_k^2))``
    with ``margin = |d| - 1`` and ``w_k = (a_k / semi_k)^2`` (scaled space), or
    ``margin = |p - o|`` and ``w_k = a_k^2`` for a point robot. ``margin`` is
    ``-inf`` where the nominal position coincides with the obstacle.
    """
    has = np.isfinite(obstacle).all(axis=1)
    diff = np.where(has[:, None], p - np.where(has[:, None], obstacle, 0.0), 1.0)
    if params.point_robot:
        scaled = diff
        inv = np.ones(3)
    else:
        inv = 1.0 / np.asarray(params.semi_axes)
        scaled = diff * inv
    norm = np.linalg.norm(scaled, axis=1)
    zero = norm == 0.0
    a = scaled / np.where(zero, 1.0, norm)[:, None]
    w = (a * inv) ** 2
    margin = norm if params.point_robot else norm - 1.0
    margin = np.where(zero, -np.inf, margin)
    obs_var = w @ (np.asarray(params.obstacle_std) ** 2)
    return margin, w, obs_var, has


def _inputs(p: ArrayLike, p_name: str, vec: ArrayLike, vec_name: str, obstacle: ArrayLike,
            model: UncertaintyModel | None, params: ChanceParams | None
            ) -> tuple[UncertaintyModel, ChanceParams, FloatArray, FloatArray, FloatArray]:
    """Defaults for the model and parameters, and the three per-sample arrays checked
    to the same number of rows (obstacle rows may be NaN: no obstacle)."""
    pos = _rows(p, p_name)
    n = pos.shape[0]
    return (UncertaintyModel() if model is None else model,
            ChanceParams() if params is None else params,
            pos, _rows(vec, vec_name, n), _rows(obstacle, "obstacle", n, allow_nan=True))


def collision_probability(
    p_mean: ArrayLike,
    velocity: ArrayLike,
    obstacle: ArrayLike,
    model: UncertaintyModel | None = None,
    params: ChanceParams | None = None,
) -> FloatArray:
    """Linearised collision probability per sample (paper Eq. 14).

    Args:
        p_mean: ``(n, 3)`` nominal robot positions.
        velocity: ``(n, 3)`` velocities (set ``Sigma_p`` via Eq. 15).
        obstacle: ``(n, 3)`` nominal obstacle positions; NaN rows mean "no
            obstacle" (probability 0).

    Zero total variance gives 0 outside the ellipsoid and 1 on or inside it; a
    nominal position inside the ellipsoid gives at least 1/2 (and exactly 1 when
    it coincides with the obstacle).
    """
    model, params, p, vel, obs = _inputs(p_mean, "p_mean", velocity, "velocity", obstacle,
                                         model, params)
    margin, w, obs_var, has = _geometry(p, obs, params)
    var = np.einsum("ij,ij->i", w, model.std(vel) ** 2) + obs_var
    with np.errstate(divide="ignore", invalid="ignore"):
        pr = ndtr(-margin / np.sqrt(var))
    pr = np.where(var > 0.0, pr, np.where(margin > 0.0, 0.0, 1.0))
    pr = np.where(np.isneginf(margin), 1.0, pr)
    return np.where(has, pr, 0.0)


def speed_limits(
    p: ArrayLike,
    direction: ArrayLike,
    obstacle: ArrayLike,
    model: UncertaintyModel | None = None,
    params: ChanceParams | None = None,
) -> SpeedLimits:
    """Largest speed along ``direction`` with linearised ``Pr <= delta`` (Eqs. 14-15).

    For each sample, finds ``v* = max {v >= 0 : Pr(v * u) <= delta}`` where ``u``
    is ``direction`` normalised (zero rows mean the speed does not move the
    vehicle: the limit is then ``v_max`` or infeasible). The constraint
    ``sum_k w_k s_k(v)^2 <= R^2``, ``R = margin / z``, is piecewise quadratic in
    ``v`` with pieces split at ``(floor - b) / (m |u_k|)``; each piece is solved
    in closed form (compiled, one pass over the samples). The result is clamped to
    ``[v_floor, v_max]``; samples without an obstacle (NaN rows) get ``v_max``.

    The limit depends on position, direction and obstacle only, so it is a fixed
    bound ``|sigma'_i|^2 beta_i <= limit_i^2`` in the SOCP.
    """
    model, params, pos, u, obs = _inputs(p, "p", direction, "direction", obstacle, model,
                                         params)
    return limits_of(pos, u, obs, model, params)


def limits_of(pos: FloatArray, direction: FloatArray, obstacle: FloatArray,
              model: UncertaintyModel, params: ChanceParams) -> SpeedLimits:
    """:func:`speed_limits` on arrays already checked (``(n, 3)`` float, finite
    except NaN obstacle rows): the compiled closed form
    (:func:`rota.kernels.chance.chance_limits`), in ``x = m v`` so that a tiny or
    zero ``m`` cannot under- or overflow the quadratic."""
    n = pos.shape[0]
    limit, unclamped, infeasible = np.empty(n), np.empty(n), np.empty(n, dtype=bool)
    kernels().chance_limits(
        np.ascontiguousarray(pos, dtype=float), np.ascontiguousarray(direction, dtype=float),
        np.ascontiguousarray(obstacle, dtype=float), *kernel_args(model, params), limit,
        unclamped, infeasible)
    return SpeedLimits(limit, unclamped, infeasible, params.v_floor)


def kernel_args(model: UncertaintyModel, params: ChanceParams) -> tuple:
    """The model and parameters as :func:`rota.kernels.chance.chance_limits` takes
    them: ``1 / semi-axes`` (ones for a point robot), point robot, the obstacle's
    per-axis variance, ``z``, ``m``, ``b``, floor, per axis, ``v_floor``, ``v_max``."""
    fixed = params.__dict__.get("_kernel_args")  # (frozen: made once per params)
    if fixed is None:
        point = params.point_robot
        inv = np.ones(3) if point else 1.0 / np.asarray(params.semi_axes)
        fixed = (inv, point, np.asarray(params.obstacle_std) ** 2, params.z)
        params.__dict__["_kernel_args"] = fixed
    return (*fixed, model.m, model.b, model.floor, model.per_axis, params.v_floor,
            params.v_max)


def monte_carlo_collision_probability(
    p_mean: ArrayLike,
    velocity: ArrayLike,
    obstacle: ArrayLike,
    model: UncertaintyModel | None = None,
    params: ChanceParams | None = None,
    n_samples: int = 10_000,
    rng: np.random.Generator | int | None = None,
) -> FloatArray:
    """Monte-Carlo estimate of the TRUE collision probability (Eq. 11), per sample.

    Draws ``n_samples`` robot positions ``N(p_mean, diag(s^2))`` (``s`` from
    Eq. 15) and, independently, obstacle positions ``N(obstacle,
    diag(obstacle_std^2))``, and counts ``||Q_c^{1/2}(p - o)|| <= 1`` - the true
    ellipsoid, not the linearised half-space. Returns the hit fraction
    ``(n,)`` (0 for a point robot and for NaN obstacle rows).
    """
    model, params, p, vel, obs = _inputs(p_mean, "p_mean", velocity, "velocity", obstacle,
                                         model, params)
    n = p.shape[0]
    if isinstance(n_samples, bool) or not isinstance(n_samples, (int, np.integer)):
        raise InputError("n_samples", "must be an integer")
    if n_samples < 1:
        raise InputError("n_samples", f"must be >= 1, got {n_samples}")
    gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    has = np.isfinite(obs).all(axis=1)
    out = np.zeros(n)
    if params.point_robot:
        return out
    sp = model.std(vel)
    so = np.asarray(params.obstacle_std)
    inv = 1.0 / np.asarray(params.semi_axes)
    rows = max(1, 2_000_000 // (3 * int(n_samples)))
    for s in range(0, n, rows):
        sl = slice(s, min(n, s + rows))
        k = sl.stop - sl.start
        robot = p[sl, None, :] + sp[sl, None, :] * gen.standard_normal((k, n_samples, 3))
        ob = obs[sl, None, :] + so * gen.standard_normal((k, n_samples, 3))
        hit = (((robot - ob) * inv) ** 2).sum(axis=2) <= 1.0
        out[sl] = hit.mean(axis=1)
    return np.where(has, out, 0.0)


def risk_reach(model: UncertaintyModel, params: ChanceParams) -> float:
    """The farthest distance (m) at which an obstacle can still pull the chance limit
    below ``params.v_max``: beyond it the linearised probability (Eq. 14) at ``v_max``,
    with the std of Eq. 15 at ``v_max`` on every axis, is within Delta.

    ``|d| >= dist / a_max`` and ``a^T Sigma^r a <= (s^2 + s_o^2) / a_min^2`` (``a_max``,
    ``a_min`` the largest and smallest semi-axes, ``s`` the std at ``v_max``, ``s_o``
    the largest obstacle std), so ``Pr <= Delta`` once ``dist >= a_max (1 + z
    sqrt(s^2 + s_o^2) / a_min)``; for an isotropic robot of radius ``r`` that is
    ``r + z sqrt(s^2 + s_o^2)``, exact (docs/safety-model.md, section 2); a point
    robot: ``z sqrt(s^2 + s_o^2)``. The std never falls with speed (``m >= 0``), so the
    error memory (speeds up to ``v_max`` before the node) adds nothing to it.
    """
    s = max(model.floor, model.m * params.v_max + model.b, 0.0)
    spread = params.z * math.hypot(s, max(params.obstacle_std))
    if params.point_robot:
        return spread
    lo, hi = min(params.semi_axes), max(params.semi_axes)
    return hi * (1.0 + spread / lo)


def memory_limits(arclength: ArrayLike, limit: ArrayLike, memory_s: float) -> FloatArray:
    """Speed caps with error memory: node ``i``'s limit ``L_i`` also holds at every node
    ``j <= i`` with ``s_j >= s_i - L_i * T`` (``s`` the path length, ``T = memory_s``),
    and at the last node before that stretch, so the stretch is capped end to end.

    A vehicle that flies no faster than ``L_i`` over the ``L_i * T`` metres before node
    ``i`` needs at least ``T`` seconds for them, so it has been at ``L_i`` or slower for
    the whole of the last ``T`` seconds when it reaches the node: the estimation errors
    that shaped its deviation there were all made at speeds the chance constraint allows
    (``docs/safety-model.md``). Caps stay per node, so the re-time stays the same convex
    problem; ``inf`` entries (no limit) impose nothing. ``T = 0`` returns ``limit``.

    Args:
        arclength: ``(n,)`` non-decreasing path length of the nodes (m).
        limit: ``(n,)`` per-node speed limits (m/s, ``inf`` = none).
        memory_s: ``T`` (s), ``>= 0``.

    Returns:
        ``(n,)`` caps, never above ``limit``.
    """
    s = np.asarray(arclength, dtype=float)
    lim = np.asarray(limit, dtype=float)
    if s.ndim != 1 or lim.shape != s.shape:
        raise InputError("limit", f"must match arclength's shape {s.shape}, got {lim.shape}")
    if np.any(np.diff(s) < 0) or not np.all(np.isfinite(s)):
        raise InputError("arclength", "must be finite and non-decreasing")
    if np.any(np.isnan(lim)) or np.any(lim < 0):
        raise InputError("limit", "must be >= 0 (inf for no limit), no NaN")
    t = _number(memory_s, "memory_s", lo=0.0, hi=MAX_MEMORY_S)
    return memory_caps(s, lim, t)


def memory_caps(arclength: FloatArray, limit: FloatArray, memory_s: float) -> FloatArray:
    """:func:`memory_limits` on arrays already checked (compiled: a binary search for
    the start of every limited node's window, then its window; ``O(n w)``)."""
    out = np.empty(len(limit))
    kernels().memory_caps(np.ascontiguousarray(arclength, dtype=float),
                          np.ascontiguousarray(limit, dtype=float), float(memory_s), out)
    return out
