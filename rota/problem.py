"""The plain input of :func:`rota.retime` and the trajectory-time grid (paper Eq. 17).

Everything a re-time needs is in one frozen :class:`RetimeInput`; everything it
produces is in one :class:`rota.result.RetimeResult` (ruckig-style).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from rota.errors import InputError, plain
from rota.robust import Safety
from rota.trajectory import Trajectory
from rota.validate import positive, vector3

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Limits:
    """Kinematic limits: speed on the velocity norm (m/s), acceleration per axis
    (m/s^2) and, optionally, jerk per axis (m/s^3).

    Paper Eq. 11c uses per-axis boxes for both; we bound the speed (the norm),
    which is what users mean by "max velocity" and what the SOCP handles exactly
    (Eq. 23). A scalar ``a_max`` (or ``j_max``) applies to all three axes.
    ``j_max`` None (the default) leaves the jerk free: the paper's problem, whose
    optimum is bang-bang in acceleration. With a jerk bound the re-time is
    :func:`rota.jerk.retime_jerk` (acceleration continuous, jerk bounded).
    """

    v_max: float
    a_max: float | tuple[float, float, float]
    j_max: float | tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "v_max", positive(self.v_max, "limits.v_max"))
        a = (
            np.broadcast_to(np.asarray(self.a_max, dtype=float), (3,))
            if np.ndim(self.a_max) == 0
            else np.asarray(self.a_max, dtype=float)
        )
        if a.shape != (3,):
            raise InputError(
                "limits.a_max", f"must be one number or 3 (x, y, z), got {plain(self.a_max)}"
            )
        vals = tuple(positive(x, f"limits.a_max[{k}]") for k, x in enumerate(a))
        object.__setattr__(self, "a_max", vals)
        if self.j_max is not None:
            object.__setattr__(self, "j_max", _per_axis(self.j_max, "limits.j_max"))

    @property
    def a_max_vec(self) -> FloatArray:
        return np.asarray(self.a_max, dtype=float)

    @property
    def j_max_vec(self) -> FloatArray | None:
        """The jerk bound per axis, or None when the jerk is free."""
        return None if self.j_max is None else np.asarray(self.j_max, dtype=float)


def _per_axis(value: object, name: str) -> tuple[float, float, float]:
    """One positive number, or three (x, y, z)."""
    if np.ndim(value) == 0:
        x = positive(value, name)
        return (x, x, x)
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(name, f"must be one number or 3 (x, y, z), got {value!r}") from None
    if a.shape != (3,):
        raise InputError(name, f"must be one number or 3 (x, y, z), got {value!r}")
    return tuple(positive(float(x), f"{name}[{k}]") for k, x in enumerate(a))  # type: ignore[return-value]


#: The solvers :class:`SolverSettings` can choose (see :mod:`rota.solver`).
METHODS = ("fast", "clarabel")


@dataclass(frozen=True)
class SolverSettings:
    """Which solver, and the settings that matter for ROTA (see :mod:`rota.solver`).

    ``method``: ``"fast"`` (default), the compiled interior-point method on beta
    that exploits the problem's chain structure, which hands over to Clarabel if
    it reports trouble; or ``"clarabel"``, the SOCP with Clarabel (the
    reference). ``fast_tol``: the fast solver's tolerance on the duality gap
    (relative to the objective) and on the residuals. ``max_iter`` applies to
    both.

    The Clarabel defaults are the measured fastest settings that still meet the
    benchmark's accuracy check (objective within 0.1 % of a 1e-10 reference
    solve, every check point within its limit; see ``docs/benchmarks.md``):

    * ``tol``: Clarabel's gap and feasibility tolerances (1e-6: objective
      error ~1e-7 relative, four orders below what the check allows);
    * ``iterative_refinement``: Clarabel refines every KKT solve to 1e-13 by
      default; ROTA's KKT systems are well conditioned after the row scaling of
      :func:`rota.socp.assemble`, and refinement doubled the time per iteration;
    * ``equilibrate``, ``presolve``: Clarabel's Ruiz scaling and presolve;
    * ``reuse_symbolic``: keep the solver of the previous call and only update
      its data (``DefaultSolver.update``) when the new problem has the same
      sparsity (a replan on the same grid, or a repeated solve), skipping the
      symbolic KKT work.

    ``keep_round``: keep the last round of constraint generation (its problem,
    bounds and greedy profile: arrays the size of the grid) in the result's
    ``diagnostics.last_round``, for benchmarks that time the solver alone on it.
    """

    method: str = "fast"
    fast_tol: float = 1e-9
    tol: float = 1e-6
    max_iter: int = 200
    time_limit: float = 5.0
    verbose: bool = False
    iterative_refinement: bool = False
    equilibrate: bool = True
    presolve: bool = True
    reuse_symbolic: bool = False
    keep_round: bool = False

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise InputError("solver.method", f"must be one of {METHODS}, got {self.method!r}")
        positive(self.fast_tol, "solver.fast_tol")
        positive(self.tol, "solver.tol")


@dataclass(frozen=True)
class RetimeInput:
    """Everything :func:`rota.retime` needs.

    Attributes:
        trajectory: the path sigma(tau) to re-time (paper Eq. 1).
        limits: speed and per-axis acceleration limits (Eq. 11c).
        smoothness: lambda, the weight of the smoothness term (Eq. 10); the
            authors use 0.5. 0 gives the time-optimal mapping.
        dtau: requested trajectory-time step (Eq. 17); the grid uses the
            nearest step that divides the duration evenly (never larger).
        speed_limits: optional per-node speed limits (m/s) on the grid of
            :func:`make_grid` (length N + 1); ``inf`` means no extra limit. This
            is the hook the chance constraints (Sec. III-C) plug into.
        start_velocity: velocity of the vehicle at the start (m/s, same frame as
            the trajectory); it must point along the path. Zero = at rest.
        start_acceleration: acceleration at the start, or None to leave it free.
            Only its component that the path can produce is imposed.
        end_velocity: velocity at the end; zero (rest) by default.
        safety: the map, uncertainty model and chance-constraint parameters
            (:class:`rota.robust.Safety`); with them the re-time is robust
            (braking zones, Sec. III-B/C). None: kinematic limits only.
        solver: Clarabel settings.
    """

    trajectory: Trajectory
    limits: Limits
    smoothness: float = 0.5
    dtau: float = 0.1
    speed_limits: FloatArray | None = None
    start_velocity: FloatArray = field(default_factory=lambda: np.zeros(3))
    start_acceleration: FloatArray | None = None
    end_velocity: FloatArray = field(default_factory=lambda: np.zeros(3))
    safety: Safety | None = None
    solver: SolverSettings = field(default_factory=SolverSettings)

    def __post_init__(self) -> None:
        if not isinstance(self.trajectory, Trajectory):
            raise InputError(
                "trajectory", f"must be a rota Trajectory, got {type(self.trajectory)}"
            )
        if not isinstance(self.limits, Limits):
            raise InputError("limits", f"must be a rota.Limits, got {type(self.limits)}")
        lam = float(self.smoothness)
        if not np.isfinite(lam) or lam < 0:
            raise InputError("smoothness", "must be a finite number >= 0, got "
                             f"{plain(self.smoothness)}")
        object.__setattr__(self, "smoothness", lam)
        dtau = positive(self.dtau, "dtau")
        if dtau > self.trajectory.duration:
            dtau = self.trajectory.duration
        object.__setattr__(self, "dtau", dtau)
        object.__setattr__(self, "start_velocity", vector3(self.start_velocity, "start_velocity"))
        object.__setattr__(self, "end_velocity", vector3(self.end_velocity, "end_velocity"))
        if self.safety is not None and not isinstance(self.safety, Safety):
            raise InputError("safety", f"must be a rota Safety, got {type(self.safety).__name__}")
        if self.start_acceleration is not None:
            object.__setattr__(
                self, "start_acceleration", vector3(self.start_acceleration, "start_acceleration")
            )
        if self.speed_limits is not None:
            lim = np.asarray(self.speed_limits, dtype=float)
            n = len(make_grid(self.trajectory, dtau))
            if lim.shape != (n,):
                raise InputError(
                    "speed_limits",
                    f"must have one value per grid node ({n}), got shape {lim.shape}",
                )
            if np.any(np.isnan(lim)) or np.any(lim <= 0):
                raise InputError("speed_limits", "must be positive (inf for no limit), no NaN")
            object.__setattr__(self, "speed_limits", lim)


#: The grid has at least this many intervals, however short the path is against dtau.
MIN_INTERVALS = 8


def make_grid(trajectory: Trajectory, dtau: float) -> FloatArray:
    """Trajectory-time nodes ``tau_0 .. tau_N`` (paper Eq. 17).

    ``N = ceil(T / dtau)``, at least :data:`MIN_INTERVALS` (a path shorter than a
    few steps is re-timed on a finer grid: one interval cannot start and stop),
    and the step is ``T / N`` so the grid ends exactly at the trajectory's end.
    """
    t0, t1 = trajectory.domain
    n = grid_intervals(trajectory, dtau)
    tau = np.arange(n + 1) * ((t1 - t0) / n) + t0  # as numpy's linspace, without its overhead
    tau[-1] = t1
    return tau


def grid_intervals(trajectory: Trajectory, dtau: float) -> int:
    """``N``, the number of intervals of :func:`make_grid`."""
    t0, t1 = trajectory.domain
    return max(MIN_INTERVALS, math.ceil((t1 - t0) / dtau - 1e-9))
