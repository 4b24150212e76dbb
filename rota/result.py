"""The plain output of :func:`rota.retime`: status in words, the time mapping, and
a sampler that turns it into position/velocity/acceleration setpoints (Eqs. 3-5)."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rota.solver import SolverStats
from rota.timemap import TimeMap
from rota.trajectory import Trajectory

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


class Outcome(StrEnum):
    """How a re-time ended (a ``str``: JSON and comparisons see its word)."""

    OPTIMAL = "optimal"
    FALLBACK = "fallback"
    REJECTED = "rejected"


OPTIMAL, FALLBACK, REJECTED = Outcome.OPTIMAL, Outcome.FALLBACK, Outcome.REJECTED


@dataclass(frozen=True, eq=False)
class Diagnostics:
    """What the pipeline found besides the time mapping (per-node arrays on the
    result's grid; None where it did not run).

    Attributes:
        intervals: the braking zones in trajectory time (Sec. III-B, refined).
        braking_mask: the braking points, per node (Eq. 6).
        obstacle_distance: each node's distance to the nearest obstacle (m).
        nearest_obstacle: that obstacle's point, per node.
        chance_limits: the chance-constraint speed limit of every node (Eq. 10),
            applied where ``braking_mask``.
        approach_mask: nodes slowed by the error memory ahead of a zone.
        memory_s: the uncertainty model's memory time in use (s).
        solve_rounds: rounds of constraint generation (:mod:`rota.rounds`).
        unlimited_duration: with a jerk bound, the duration without it (s).
        jerk_steps, jerk_ratio, jerk_finer: with a jerk bound, the steps of the
            successive convexification, the worst jerk over its bound, and how much
            finer the grid was made (:mod:`rota.jerk`).
        last_round: the last round of constraint generation as it came from the
            solver (:class:`rota.rounds.Round`), kept only when
            ``SolverSettings.keep_round`` asks for it.
    """

    intervals: tuple[tuple[float, float], ...] | list = ()
    braking_mask: BoolArray | None = None
    obstacle_distance: FloatArray | None = None
    nearest_obstacle: FloatArray | None = None
    chance_limits: FloatArray | None = None
    approach_mask: BoolArray | None = None
    memory_s: float | None = None
    solve_rounds: int = 0
    unlimited_duration: float | None = None
    jerk_steps: int | None = None
    jerk_ratio: float | None = None
    jerk_finer: int | None = None
    last_round: Any = None


@dataclass(frozen=True)
class Setpoints:
    """Re-timed states at real times ``t``: arrays ``(n,)`` and ``(n, 3)``."""

    t: FloatArray
    tau: FloatArray
    position: FloatArray
    velocity: FloatArray
    acceleration: FloatArray


@dataclass(frozen=True)
class RetimeResult:
    """Outcome of a re-time.

    Attributes:
        status: ``"optimal"`` (the SOCP was solved and its solution checked),
            ``"fallback"`` (it could not be: ``message`` says why in words, and the
            time mapping is the authors' fallback, the input uniformly slowed down
            until it meets the limits), or ``"rejected"`` (the path itself is unsafe:
            it passes through an obstacle of the map; do not fly it - the time
            mapping is the fallback, for inspection only).
        message: human-readable explanation; empty when optimal.
        warnings: things the user should know about an otherwise usable result
            (for example: the path leaves the map; the start is too fast for the
            first braking zone and the vehicle brakes as hard as allowed).
        timemap: the time mapping tau = h(t) on the grid.
        trajectory: the input path.
        solver: what Clarabel reported (None when it was not called).
        speed_limits: the per-node speed limit that was imposed (m/s).
        diagnostics: what the pipeline found besides (:class:`Diagnostics`: the
            braking zones and points, the chance limits, the solve's rounds).
    """

    status: Outcome
    message: str
    timemap: TimeMap
    trajectory: Trajectory
    solver: SolverStats | None
    speed_limits: FloatArray
    diagnostics: Diagnostics
    warnings: tuple[str, ...] = ()

    @property
    def ok(self) -> bool:
        """True when the optimal mapping is available (not the fallback)."""
        return self.status == OPTIMAL

    @property
    def duration(self) -> float:
        """Real-time duration of the re-timed trajectory (s)."""
        return self.timemap.duration

    @property
    def tau(self) -> FloatArray:
        return self.timemap.tau

    @property
    def t(self) -> FloatArray:
        return self.timemap.t

    @property
    def beta(self) -> FloatArray:
        return self.timemap.beta

    @property
    def alpha(self) -> FloatArray:
        return self.timemap.alpha

    @property
    def ends_at_rest(self) -> bool:
        """True when the re-timed trajectory ends at rest exactly (beta_N = 0, or
        the path itself stands still at its end)."""
        if self.timemap.beta[-1] == 0.0:
            return True
        _, d1, _ = self.trajectory.evaluate(self.timemap.tau[-1:])
        return bool(np.all(d1 == 0.0))

    def sample(self, t: ArrayLike) -> Setpoints:
        """Position, velocity and acceleration at real times ``t`` (vectorised).

        Position is ``sigma(h(t))``, so it lies on the input path; velocity and
        acceleration follow paper Eqs. 4-5. Times beyond the end hold the end;
        when it ends at rest (:attr:`ends_at_rest`) from its end on velocity and
        acceleration are exactly zero.
        """
        tq = np.atleast_1d(np.asarray(t, dtype=float))
        tau, tau_dot, tau_ddot = self.timemap.evaluate(tq)
        p, d1, d2 = self.trajectory.evaluate(tau)
        vel = d1 * tau_dot[:, None]
        acc = d1 * tau_ddot[:, None] + d2 * (tau_dot**2)[:, None]
        after = tq >= self.duration
        if after.any() and self.ends_at_rest:
            vel[after] = 0.0
            acc[after] = 0.0
        return Setpoints(tq, tau, p, vel, acc)

    def sample_rate(self, rate_hz: float) -> Setpoints:
        """Setpoints at a fixed rate from t = 0 to the end (inclusive)."""
        if not np.isfinite(rate_hz) or rate_hz <= 0:
            raise ValueError(f"rate_hz must be positive, got {float(rate_hz):g}")
        n = int(np.floor(self.duration * rate_hz + 1e-9)) + 1
        t = np.arange(n) / rate_hz
        if t[-1] < self.duration:
            t = np.append(t, self.duration)
        return self.sample(t)
