"""Where the limits are imposed: the grid nodes and check points inside every
interval and every input piece (paper Eqs. 23 and 26 between the nodes).

Beta is linear in tau inside an interval, alpha constant, so at fraction ``f``
of interval ``i`` the limits are linear in ``(beta_i, beta_{i+1})``. Check points:

* both ends of every interval (alpha jumps at the nodes);
* the path's own breakpoints (B-spline knots, segment ends, sample times: the
  acceleration may peak there);
* inside every input piece at least :data:`PIECE_PARTS` parts, so that a short,
  stiff piece (two samples 1 ms apart) is checked inside too;
* elsewhere (inside pieces long enough not to need their own points) a uniform
  subdivision of every interval into at least :data:`MIN_PARTS` parts, at most
  :data:`SPACING` of trajectory time apart.

After a solve, :func:`rota.rounds.audit` looks between the check points (the midpoint of
every gap); a limit broken there adds those points and the re-timer solves
again (constraint generation, :mod:`rota.rounds`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from rota.jit import kernels
from rota.path import evaluate
from rota.trajectory import Trajectory

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Below this |sigma'| (m per second of trajectory time) the path is standing still.
STILL = 1e-6
#: beta may exceed the median speed-limited beta by at most this factor (tau_dot x 100).
BETA_CAP_FACTOR = 1e4
#: Check points per interval: at least this many parts ...
MIN_PARTS = 4
#: ... and at most this far apart (s of trajectory time).
SPACING = 0.025
#: Every input piece is cut in at least this many parts by check points. Planners'
#: B-splines have knot spans of about 0.1 s: 5 parts put their check points 20 ms
#: apart, denser than :data:`SPACING`. (Measured on the bench's paths: 4 parts left a
#: limit broken between check points by more than the audit allows on 7 m at dtau
#: 0.1 s, a second round; 5 to 8 none, and 8 costs 1.6 times the points of 5.)
PIECE_PARTS = 5
#: No points added: ``(interval, fraction)`` of the check points a round adds.
NO_POINTS = (np.zeros(0, dtype=np.int64), np.zeros(0))


@dataclass(frozen=True)
class PathSamples:
    """The path and its limits on the grid and at the check points.

    Check points are grouped by interval: those of interval ``i`` are
    ``offsets[i]`` to ``offsets[i + 1] - 1``, sorted by their fraction ``frac``
    of the interval (0 and 1 are its ends).
    """

    tau: FloatArray  # (N+1,)
    d1: FloatArray  # (N+1, 3) sigma' at the nodes
    d2: FloatArray  # (N+1, 3) sigma'' at the nodes
    beta_max: FloatArray  # (N+1,) bound on beta from the node speed limits and the cap
    vlim: FloatArray  # (N+1,) speed limit per node (m/s)
    a_max: FloatArray  # (3,)
    offsets: IntArray  # (N+1,)
    frac: FloatArray  # (M,)
    cd1: FloatArray  # (M, 3) sigma' at the check points
    cd2: FloatArray  # (M, 3) sigma'' there
    moving: bool = True  # some node or check point has |sigma'| above STILL

    @property
    def n_intervals(self) -> int:
        return len(self.tau) - 1

    @property
    def h(self) -> float:
        return float(self.tau[1] - self.tau[0])

    @property
    def interval(self) -> IntArray:
        """Interval of every check point."""
        return np.repeat(np.arange(self.n_intervals), np.diff(self.offsets))

    @property
    def point_tau(self) -> FloatArray:
        """Trajectory time of every check point."""
        i = self.interval
        return self.tau[i] + self.frac * self.h


def uniform_parts(h: float) -> int:
    """Parts of the uniform subdivision of an interval of length ``h``."""
    return max(MIN_PARTS, math.ceil(h / SPACING - 1e-9))


def sample_path(trajectory: Trajectory, tau: FloatArray, vlim: FloatArray,
                a_max: FloatArray, d1: FloatArray | None = None,
                d2: FloatArray | None = None) -> PathSamples:
    """Evaluate the path on the grid and at the check points (``d1``, ``d2``: the
    path's derivatives on the grid, when the caller has them).

    ``beta_max`` is the speed bound ``v_i^2 / |sigma'_i|^2`` (Eq. 23); where the path
    stands still (``|sigma'| = 0``, e.g. a B-spline's clamped end) beta is capped at
    :data:`BETA_CAP_FACTOR` times the median speed bound, so the problem stays
    bounded and well scaled.
    """
    if d1 is None or d2 is None:
        _, d1, d2 = evaluate(trajectory, tau)
    parts = uniform_parts(float(tau[1] - tau[0]))
    vlim = np.ascontiguousarray(vlim, dtype=float)
    breaks, coefs = trajectory.pieces
    t0, t1 = trajectory.domain
    offsets, frac, c1, c2, beta_max, moving = kernels().sample(
        breaks, coefs, float(t0), float(t1), tau, parts, PIECE_PARTS, d1, vlim, STILL,
        BETA_CAP_FACTOR, *NO_POINTS)
    return PathSamples(tau=tau, d1=d1, d2=d2, beta_max=beta_max, vlim=vlim,
                       a_max=np.ascontiguousarray(a_max, dtype=float), offsets=offsets,
                       frac=frac, cd1=c1, cd2=c2, moving=bool(moving))
