"""Input trajectories: the path sigma(tau) that ROTA re-times (paper Eq. 1).

Every trajectory maps trajectory time ``tau`` (an array) to position, velocity
and acceleration with respect to ``tau`` (``sigma``, ``sigma'``, ``sigma''`` of
paper Eqs. 3-5). Three forms cover what planners publish:

* :class:`BSplineTrajectory`: uniform (or explicit-knot) B-splines, as EGO-Planner
  and Fast-Planner publish them (``traj_utils/Bspline``).
* :class:`PolynomialTrajectory`: piecewise polynomials (minimum-snap style).
* :class:`SampledTrajectory`: time-stamped samples, interpolated C2.

All are thin wrappers over scipy's spline classes; evaluation is vectorised and
clamps ``tau`` to the trajectory's domain (no extrapolation).
"""

from __future__ import annotations

import copy as _copy
import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import interpolate

from rota.errors import InputError, plain
from rota.jit import kernels
from rota.validate import KeepsReadOnly

FloatArray = NDArray[np.float64]

#: What a trajectory makes once and keeps (see :meth:`Trajectory.fresh`).
_KEPT = ("_pieces", "_edges")


def _finite_array(value: ArrayLike, name: str, ndim: int, width: int | None = None) -> FloatArray:
    """Convert to a float array and check shape and finiteness, naming the field."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(name, f"must be numeric ({exc})") from None
    if arr.ndim != ndim:
        raise InputError(name, f"must have {ndim} dimension(s), got shape {arr.shape}")
    if width is not None and arr.shape[-1] != width:
        raise InputError(name, f"must have {width} columns (x, y, z), got shape {arr.shape}")
    if arr.size == 0:
        raise InputError(name, "must not be empty")
    bad = ~np.isfinite(arr)
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise InputError(name + "".join(f"[{i}]" for i in idx), "must be finite (got NaN or inf)")
    return arr


@dataclass(frozen=True)
class Trajectory(KeepsReadOnly):
    """Base class: a C2 path over trajectory time ``[t0, t1]``.

    Subclasses provide ``_spline`` (a scipy piecewise-polynomial object evaluating
    to shape ``(n, 3)``) via ``__post_init__``.
    """

    _spline: object = field(init=False, repr=False, compare=False)
    _d1: object = field(init=False, repr=False, compare=False)
    _d2: object = field(init=False, repr=False, compare=False)

    def _set_spline(
        self, spline: interpolate.PPoly | interpolate.BSpline | interpolate.BPoly
    ) -> None:
        object.__setattr__(self, "_spline", spline)
        object.__setattr__(self, "_d1", spline.derivative(1))
        object.__setattr__(self, "_d2", spline.derivative(2))

    @property
    def domain(self) -> tuple[float, float]:
        """Trajectory-time interval ``(tau_0, tau_f)`` on which the path is defined."""
        raise NotImplementedError

    @property
    def breakpoints(self) -> FloatArray:
        """Trajectory times where the pieces join (B-spline knots, segment ends,
        sample times) inside the domain: the third derivative may jump there, so
        the acceleration may peak there."""
        return self.edges[1:-1]

    def fresh(self) -> Trajectory:
        """The same path without what re-timing it made and kept (its polynomial
        pieces, their ends): as a new trajectory from a replan arrives."""
        copy = _copy.copy(self)
        for key in _KEPT:
            copy.__dict__.pop(key, None)
        base = getattr(copy, "base", None)
        if isinstance(base, Trajectory):
            object.__setattr__(copy, "base", base.fresh())
        return copy

    @property
    def edges(self) -> FloatArray:
        """The ends of the pieces: the domain's start, the :attr:`breakpoints`, the
        domain's end (made once and kept)."""
        cached = self.__dict__.get("_edges")
        if cached is None:
            t0, t1 = self.domain
            cached = kernels().piece_edges(self.pieces[0], float(t0), float(t1))
            cached.setflags(write=False)
            object.__setattr__(self, "_edges", cached)
        return cached

    @property
    def duration(self) -> float:
        """``tau_f - tau_0``: the planner's own duration of the path."""
        t0, t1 = self.domain
        return t1 - t0

    def evaluate(self, tau: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Position, first and second derivative w.r.t. tau, each of shape ``(n, 3)``."""
        t0, t1 = self.domain
        x = np.clip(np.atleast_1d(np.asarray(tau, dtype=float)), t0, t1)
        return (
            np.asarray(self._spline(x), dtype=float),
            np.asarray(self._d1(x), dtype=float),
            np.asarray(self._d2(x), dtype=float),
        )

    def position(self, tau: ArrayLike) -> FloatArray:
        """Position only, shape ``(n, 3)``."""
        t0, t1 = self.domain
        x = np.clip(np.atleast_1d(np.asarray(tau, dtype=float)), t0, t1)
        return np.asarray(self._spline(x), dtype=float)

    @property
    def pieces(self) -> tuple[FloatArray, FloatArray]:
        """The path as plain polynomial pieces, for compiled evaluation
        (:func:`rota.path.evaluate`): ``(breaks (m + 1,), coefs (m, k + 1, 3))``,
        piece ``j`` being ``sum_r coefs[j, r] (tau - breaks[j])^r`` on
        ``[breaks[j], breaks[j + 1]]``. Made once and kept."""
        cached = self.__dict__.get("_pieces")
        if cached is None:
            cached = self._make_pieces()
            object.__setattr__(self, "_pieces", cached)
        return cached

    def _make_pieces(self) -> tuple[FloatArray, FloatArray]:
        return _pieces_of(self._spline)


def _writable(a: FloatArray) -> FloatArray:
    """``a`` itself if it is a writable C-contiguous float array, else such a copy."""
    f = a.flags
    if a.dtype == np.float64 and f.c_contiguous and f.writeable:
        return a
    return np.array(a, dtype=float, order="C")


def _pieces_of(spline: object) -> tuple[FloatArray, FloatArray]:
    """Taylor coefficients of every piece of a scipy spline (read-only arrays)."""
    if isinstance(spline, interpolate.BPoly):
        spline = interpolate.PPoly.from_bernstein_basis(spline)
    if not isinstance(spline, interpolate.PPoly):
        raise TypeError(f"no polynomial pieces for {type(spline).__name__}")
    breaks = np.asarray(spline.x, dtype=float)
    coefs = np.ascontiguousarray(np.transpose(spline.c[::-1], (1, 0, 2)), dtype=float)
    return _read_only(breaks, coefs)


def _read_only(breaks: FloatArray, coefs: FloatArray) -> tuple[FloatArray, FloatArray]:
    # A zero-length piece (repeated break) is never selected; keep shapes consistent.
    breaks = np.ascontiguousarray(breaks, dtype=float)
    breaks.setflags(write=False)
    coefs.setflags(write=False)
    return breaks, coefs


@dataclass(frozen=True)
class BSplineTrajectory(Trajectory):
    """B-spline of ``degree`` over ``control_points`` (shape ``(n, 3)``).

    With ``knot_span`` the knot vector is uniform, ``u_m = (m - degree) * knot_span``
    (EGO-Planner convention), so the domain is ``[0, (n - degree) * knot_span]``.
    Alternatively give the full, non-decreasing ``knots`` (length ``n + degree + 1``).
    """

    control_points: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    degree: int = 3
    knot_span: float | None = None
    knots: FloatArray | None = None

    def __post_init__(self) -> None:
        cps = _finite_array(self.control_points, "control_points", 2, 3)
        object.__setattr__(self, "control_points", cps)
        if not isinstance(self.degree, int | np.integer) or not 3 <= int(self.degree) <= 7:
            raise InputError("degree", f"must be an integer from 3 to 7, got {plain(self.degree)}")
        k = int(self.degree)
        n = len(cps)
        if n < k + 1:
            raise InputError("control_points", f"need at least degree + 1 = {k + 1}, got {n}")
        if (self.knots is None) == (self.knot_span is None):
            raise InputError("knot_span", "give exactly one of knot_span (uniform) or knots")
        if self.knots is None:
            try:
                span = float(self.knot_span)  # type: ignore[arg-type]
            except (TypeError, ValueError):
                span = float("nan")
            if not np.isfinite(span) or span <= 0:
                raise InputError("knot_span", "must be a positive number, got "
                                 f"{plain(self.knot_span)}")
            knots = (np.arange(n + k + 1, dtype=float) - k) * span
        else:
            knots = _finite_array(self.knots, "knots", 1)
            if len(knots) != n + k + 1:
                raise InputError(
                    "knots",
                    f"must have len(control_points) + degree + 1 = "
                    f"{n + k + 1} entries, got {len(knots)}",
                )
            if np.any(np.diff(knots) < 0):
                raise InputError("knots", "must be non-decreasing")
            if knots[n] <= knots[k]:
                raise InputError("knots", "the valid domain [knots[degree], knots[n]] is empty")
        if self.knots is not None:
            object.__setattr__(self, "knots", knots)
        object.__setattr__(self, "_knot_vector", knots)
        object.__setattr__(self, "_domain", (float(knots[k]), float(knots[n])))
        self._set_spline(interpolate.BSpline(knots, cps, k, extrapolate=False))

    def _make_pieces(self) -> tuple[FloatArray, FloatArray]:
        # derivatives at the start of every non-empty knot span (compiled), from the
        # trajectory's own arrays (scipy's accessors cost more than the kernel); the
        # kernel is compiled for writable C arrays, so read-only ones are copied
        return _read_only(*kernels().bspline_pieces(
            _writable(self._knot_vector), _writable(self.control_points),  # type: ignore[attr-defined]
            int(self.degree)))

    @property
    def knot_vector(self) -> FloatArray:
        """The full knot vector (given, or made from ``knot_span``)."""
        return self._knot_vector  # type: ignore[attr-defined]

    @property
    def domain(self) -> tuple[float, float]:
        return self._domain  # type: ignore[attr-defined]


@dataclass(frozen=True)
class PolynomialTrajectory(Trajectory):
    """Piecewise polynomial: ``durations[j]`` and ``coefficients[j]`` per segment.

    ``coefficients`` has shape ``(segments, 3, degree + 1)``: per segment and axis,
    coefficients in ascending powers of the segment's local time ``s in [0, T_j]``
    (``p(s) = c0 + c1 s + c2 s^2 + ...``). Segments must join with continuous
    position and velocity (C1); the domain is ``[0, sum(durations)]``.
    """

    durations: FloatArray = field(default_factory=lambda: np.zeros(0))
    coefficients: FloatArray = field(default_factory=lambda: np.zeros((0, 3, 1)))

    def __post_init__(self) -> None:
        durs = _finite_array(self.durations, "durations", 1)
        if np.any(durs <= 0):
            raise InputError(f"durations[{int(np.argmax(durs <= 0))}]", "must be positive")
        coefs = _finite_array(self.coefficients, "coefficients", 3)
        if coefs.shape[0] != len(durs) or coefs.shape[1] != 3:
            raise InputError(
                "coefficients",
                f"must have shape (segments={len(durs)}, 3, degree+1), got {coefs.shape}",
            )
        if coefs.shape[2] < 3:
            raise InputError("coefficients", "polynomials need degree >= 2 (acceleration)")
        object.__setattr__(self, "durations", durs)
        object.__setattr__(self, "coefficients", coefs)
        breaks = np.concatenate([[0.0], np.cumsum(durs)])
        # scipy PPoly: c[power_desc, segment, axis]
        c = np.transpose(coefs[:, :, ::-1], (2, 0, 1))
        spline = interpolate.PPoly(c, breaks, extrapolate=False)
        self._set_spline(spline)
        if len(durs) > 1:
            joints = breaks[1:-1]
            for order, what, fn in ((0, "position", self._spline), (1, "velocity", self._d1)):
                left = np.array([_segment_end(c, durs, j, order) for j in range(len(durs) - 1)])
                right = np.asarray(fn(joints))
                jump = np.linalg.norm(left - right, axis=1)
                scale = max(1.0, float(np.max(np.abs(right))))
                if np.any(jump > 1e-6 * scale):
                    j = int(np.argmax(jump))
                    raise InputError(
                        f"coefficients[{j + 1}]",
                        f"segment {j + 1} does not continue "
                        f"segment {j} in {what} (jump {jump[j]:.3g})",
                    )

    @property
    def domain(self) -> tuple[float, float]:
        return 0.0, float(np.sum(self.durations))


def _segment_end(c: FloatArray, durs: FloatArray, j: int, order: int) -> FloatArray:
    """Value (order 0) or derivative (order 1) of segment ``j`` at its end."""
    deg = c.shape[0] - 1
    s = durs[j]
    powers = np.arange(deg, -1, -1)
    coef = c[:, j, :]
    if order == 1:
        coef = coef[:-1] * powers[:-1, None]
        powers = powers[:-1] - 1
    return (coef * s ** powers[:, None]).sum(axis=0)


def quintic_hermite(h: FloatArray, p: FloatArray, v: FloatArray, a: FloatArray) -> FloatArray:
    """Bernstein coefficients ``(6, n - 1, 3)`` of the quintic Hermite spline through
    samples ``p``, ``v``, ``a`` (``n`` rows) with interval lengths ``h``: what
    ``scipy.interpolate.BPoly.from_derivatives`` builds, in closed form and vectorised
    (it loops in Python over every interval and axis: 13 ms for 300 samples, the
    bulk of decoding a planner's message). A degree-5 Bernstein polynomial on an
    interval of length h has B'(0) = 5 (c1 - c0) / h and B''(0) = 20 (c2 - 2 c1 + c0)
    / h^2, and the mirror images at its end."""
    h = h[:, None]
    p0, v0, a0, p1, v1, a1 = p[:-1], v[:-1], a[:-1], p[1:], v[1:], a[1:]
    return np.stack([p0, p0 + h * v0 / 5.0, p0 + 2.0 * h * v0 / 5.0 + h * h * a0 / 20.0,
                     p1 - 2.0 * h * v1 / 5.0 + h * h * a1 / 20.0, p1 - h * v1 / 5.0, p1])


@dataclass(frozen=True)
class SampledTrajectory(Trajectory):
    """Time-stamped samples ``t`` (strictly increasing), ``p`` and optional ``v``, ``a``.

    Interpolation is C2 in every case: a natural cubic spline through ``p`` alone;
    a quintic Hermite spline through ``(p, v, a)`` when velocities are given (a
    missing ``a`` is taken from a cubic spline through ``v``).
    """

    t: FloatArray = field(default_factory=lambda: np.zeros(0))
    p: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    v: FloatArray | None = None
    a: FloatArray | None = None

    def __post_init__(self) -> None:
        t = _finite_array(self.t, "t", 1)
        p = _finite_array(self.p, "p", 2, 3)
        if len(t) < 2:
            raise InputError("t", "need at least 2 samples")
        if len(p) != len(t):
            raise InputError("p", f"must have one row per time stamp ({len(t)}), got {len(p)}")
        dt = np.diff(t)
        if np.any(dt <= 0):
            raise InputError(
                f"t[{int(np.argmax(dt <= 0)) + 1}]", "time stamps must be strictly increasing"
            )
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "p", p)
        if self.v is None and self.a is not None:
            raise InputError("a", "accelerations need velocities too")
        if self.v is None:
            spline = interpolate.CubicSpline(t, p, bc_type="natural", extrapolate=False)
            self._set_spline(interpolate.PPoly(spline.c, spline.x, extrapolate=False))
            return
        v = _finite_array(self.v, "v", 2, 3)
        if v.shape != p.shape:
            raise InputError("v", f"must have the shape of p {p.shape}, got {v.shape}")
        if self.a is None:
            a = interpolate.CubicSpline(t, v, bc_type="natural")(t, 1)
        else:
            a = _finite_array(self.a, "a", 2, 3)
            if a.shape != p.shape:
                raise InputError("a", f"must have the shape of p {p.shape}, got {a.shape}")
        object.__setattr__(self, "v", v)
        object.__setattr__(self, "a", a)
        self._set_spline(interpolate.BPoly(quintic_hermite(dt, p, v, a), t, extrapolate=False))

    @property
    def domain(self) -> tuple[float, float]:
        return float(self.t[0]), float(self.t[-1])


#: :func:`smootherstep_fade`'s polynomial in ascending powers of ``x``.
_FADE = np.array([1.0, 0.0, 0.0, -10.0, 15.0, -6.0])


def smootherstep_fade(x: ArrayLike, length: float) -> tuple[ArrayLike, ArrayLike, ArrayLike]:
    """The quintic smootherstep falling from 1 at ``x = 0`` to 0 at ``x = 1`` (``x``
    clipped to [0, 1]), and its first two derivatives with respect to a variable
    that covers [0, 1] of ``x`` in ``length``: both are zero at the ends."""
    u = np.clip(x, 0.0, 1.0)
    w = 1.0 - u**3 * (10.0 - 15.0 * u + 6.0 * u * u)
    dw = -30.0 * u * u * (1.0 - u) ** 2 / length
    ddw = -60.0 * u * (1.0 - u) * (1.0 - 2.0 * u) / length**2
    return w, dw, ddw


def _taylor_shift(coefs: FloatArray, delta: FloatArray) -> FloatArray:
    """Coefficients (ascending powers, axis 1) of the same polynomials re-expanded
    about a point ``delta`` later: ``coefs`` (m, k + 1, ...) and ``delta`` (m,)."""
    k = coefs.shape[1] - 1
    r = np.arange(k + 1)
    binom = np.array([[math.comb(int(b), int(a)) for b in r] for a in r], dtype=float)
    power = np.clip(r[None, :] - r[:, None], 0, None)  # (s, r): r - s where r >= s
    m = binom[None] * delta[:, None, None] ** power[None]  # (m, s, r)
    return np.einsum("msr,mr...->ms...", m, coefs)


@dataclass(frozen=True)
class Window(Trajectory):
    """The part of ``base`` from trajectory time ``start`` (to ``end``, default its
    end): how a replan continues from the point the vehicle has reached.

    ``offset`` (ENU, m), if given, shifts the path at ``start`` so that it begins
    exactly at the vehicle's commanded position; the shift fades out along a
    quintic smootherstep over ``blend`` of trajectory time (its velocity and
    acceleration start and end at zero). The re-timer then re-times the path as it
    will be flown, blend included: limits, braking zones and chance constraints
    hold for it too.
    """

    base: Trajectory | None = None
    start: float = 0.0
    end: float | None = None
    offset: FloatArray | None = None
    blend: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.base, Trajectory):
            raise InputError("base", "must be a trajectory")
        b0, b1 = self.base.domain
        end = b1 if self.end is None else float(self.end)
        start = float(self.start)
        if not (np.isfinite(start) and b0 <= start < end <= b1):
            raise InputError("start", "must lie in the trajectory's domain "
                             f"[{float(b0):g}, {float(b1):g}) and "
                             f"before the end, got {plain(self.start)}")
        object.__setattr__(self, "start", start)
        object.__setattr__(self, "end", end)
        if self.offset is None:
            return
        offset = np.array(_finite_array(self.offset, "start_offset", 1, 3))
        offset.setflags(write=False)
        blend = float(self.blend)
        if not (np.isfinite(blend) and 0.0 < blend <= end - start + 1e-12):
            raise InputError("start_blend", f"must be positive and at most the window's "
                             f"length {end - start:.6g}, got {plain(self.blend)}")
        object.__setattr__(self, "offset", offset)
        object.__setattr__(self, "blend", min(blend, end - start))

    @property
    def domain(self) -> tuple[float, float]:
        return self.start, float(self.end)  # type: ignore[arg-type]

    def _fade(self, x: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The shift and its first two derivatives at trajectory times ``x``, (n, 3)."""
        w, dw, ddw = smootherstep_fade((x - self.start) / self.blend, self.blend)
        off = self.offset[None, :]  # type: ignore[index]
        return w[:, None] * off, dw[:, None] * off, ddw[:, None] * off

    def evaluate(self, tau: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        x = np.clip(np.atleast_1d(np.asarray(tau, dtype=float)), *self.domain)
        p, d1, d2 = self.base.evaluate(x)  # type: ignore[union-attr]
        if self.offset is None:
            return p, d1, d2
        f, df, ddf = self._fade(x)
        return p + f, d1 + df, d2 + ddf

    def position(self, tau: ArrayLike) -> FloatArray:
        x = np.clip(np.atleast_1d(np.asarray(tau, dtype=float)), *self.domain)
        p = self.base.position(x)  # type: ignore[union-attr]
        return p if self.offset is None else p + self._fade(x)[0]

    def _make_pieces(self) -> tuple[FloatArray, FloatArray]:
        """The base's pieces; with an offset, cut at the blend's ends, with the
        blend's quintic added to those between them and the full offset to those
        before."""
        breaks, coefs = self.base.pieces  # type: ignore[union-attr]
        if self.offset is None:
            return breaks, coefs
        t0, t1 = self.start, self.start + self.blend
        cuts = np.array([c for c in (t0, t1) if breaks[0] < c < breaks[-1]
                         and not np.any(np.abs(breaks - c) <= 1e-12)])
        new = np.sort(np.concatenate([breaks, cuts]))
        parent = np.clip(np.searchsorted(breaks, new[:-1], side="right") - 1, 0,
                         len(coefs) - 1)
        k = max(coefs.shape[1], len(_FADE))
        padded = np.zeros((len(coefs), k, 3))
        padded[:, :coefs.shape[1]] = coefs
        out = _taylor_shift(padded[parent], new[:-1] - breaks[parent])
        before = new[:-1] < t0 - 1e-12  # (outside the domain, as evaluate() has it)
        out[before, 0] += self.offset  # type: ignore[index]
        inside = ~before & (new[:-1] < t1 - 1e-12)
        if np.any(inside):
            x0 = (new[:-1][inside] - t0) / self.blend
            fade = np.zeros((len(x0), k))
            fade[:, :len(_FADE)] = _FADE
            q = _taylor_shift(fade, x0) / self.blend ** np.arange(k)  # powers of tau - c
            out[inside] += q[:, :, None] * self.offset[None, None, :]  # type: ignore[index]
        new = np.ascontiguousarray(new)
        out = np.ascontiguousarray(out)
        new.setflags(write=False)
        out.setflags(write=False)
        return new, out
