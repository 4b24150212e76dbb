"""Speed limits under which the heading keeps up with the path (beyond the paper).

A multirotor that faces where it flies (a camera looking ahead, the flight service's
``[stream] yaw = "path"``) turns its heading as the path turns. Its yaw rate is
``psi'(tau) * dtau/dt`` and its speed ``|sigma'(tau)| * dtau/dt`` (the time mapping of
paper Eqs. 3-4), so a yaw-rate limit ``omega`` is, node by node, a speed limit

    v <= omega * |sigma'(tau)| / |psi'(tau)|,

which enters the re-time exactly as the chance constraints' limits do (the
``speed_limits`` hook of :class:`rota.problem.RetimeInput`, imposed with the
speed limit of Eq. 23). Two headings:

* **the path's direction**, ``psi = atan2(y', x')``, whose rate along the path is
  ``psi' = (x' y'' - y' x'') / (x'^2 + y'^2)``: the limit keeps the horizontal speed at
  most ``omega / kappa_h`` (``kappa_h`` the horizontal curvature);
* **a planner's heading** (:class:`rota.schema.Heading`, EGO-Planner's ``yaw_pts``):
  straight lines between samples, so ``psi'`` at a node is the fastest rate of the
  sample intervals that meet the grid intervals on either side of it.

Never below ``floor`` (m/s, of the horizontal speed for the path's direction): a
corner tighter than ``floor / omega`` (0.38 m at 45 deg/s and 0.3 m/s) or a turn on
the spot would otherwise stop the vehicle; there it slows to ``floor`` and the
flight service's yaw limiter lets the heading lag through the corner. Where the
path is (nearly) vertical, its direction is not followed (the flight service holds
the yaw below ``floor`` of horizontal speed) and nothing is limited. The yaw
acceleration is left to the flight service's limiter.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from rota.errors import InputError
from rota.path import evaluate
from rota.schema import Heading
from rota.trajectory import Trajectory

FloatArray = NDArray[np.float64]

#: The horizontal speed (m/s) below which the flight service stops turning the heading
#: along the path (:mod:`companion.flight.stream`), and the least speed this module
#: ever asks for.
FLOOR_M_S = 0.3


def heading_speed_limits(trajectory: Trajectory, tau: FloatArray, yaw_rate_max: float,
                         heading: Heading | None = None,
                         floor: float = FLOOR_M_S) -> FloatArray:
    """Per-node speed limits (m/s; ``inf`` where none applies) at the trajectory times
    ``tau`` (the grid of :func:`rota.problem.make_grid`) under which the heading turns
    no faster than ``yaw_rate_max`` (rad/s): the path's direction, or the planner's
    ``heading`` (degrees; its frame does not matter, only its rate). See the module
    docstring."""
    if not (np.isfinite(yaw_rate_max) and yaw_rate_max > 0):
        raise InputError("yaw_rate_max", f"must be a positive number (rad/s), got "
                         f"{yaw_rate_max!r}")
    tau = np.asarray(tau, dtype=float)
    if heading is not None:
        _, d1, _ = evaluate(trajectory, tau)
        with np.errstate(divide="ignore", invalid="ignore"):
            limit = np.maximum(yaw_rate_max * np.linalg.norm(d1, axis=1)
                               / _planned_rate(heading, tau), floor)
        return np.where(np.isfinite(limit) & (limit > 0), limit, np.inf)
    # The path's direction: the limit is imposed at the nodes, and between two nodes
    # the re-time's b (the squared speed along the path) lies between theirs; so each
    # node takes the lowest limit over both grid intervals it bounds (where the
    # curvature rises fastest, entering a turn, a node's own value let the direction
    # turn 6 % over the limit between nodes).
    step = float(np.max(np.diff(tau))) if len(tau) > 1 else 0.0
    t0, t1 = trajectory.domain
    where = np.clip(tau[:, None] + np.linspace(-step, step, 9)[None, :], t0, t1)
    _, d1, d2 = evaluate(trajectory, where.ravel())
    with np.errstate(divide="ignore", invalid="ignore"):
        flat2 = d1[:, 0] ** 2 + d1[:, 1] ** 2
        rate = np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / flat2
        flat = np.sqrt(flat2)
        horizontal = np.maximum(yaw_rate_max * flat / rate, floor)
        limit = horizontal * np.linalg.norm(d1, axis=1) / flat
    limit = np.where(np.isfinite(limit) & (limit > 0), limit, np.inf)
    return limit.reshape(len(tau), -1).min(axis=1)


def _planned_rate(heading: Heading, tau: FloatArray) -> FloatArray:
    """``|psi'|`` (rad per s of trajectory time) of the planner's heading at ``tau``: the
    fastest of the sample intervals that meet the grid intervals either side of a node
    (the speed between two nodes follows from both: each must hold the faster turn);
    0 outside the samples (the heading holds there)."""
    yaw = np.unwrap(np.radians(np.asarray(heading.yaw_deg, dtype=float)))
    if len(yaw) < 2:
        return np.zeros(len(tau))
    slope = np.abs(np.diff(yaw)) / heading.dt
    step = float(np.max(np.diff(tau))) if len(tau) > 1 else 0.0
    # points at most a sample interval apart across [tau - step, tau + step]
    m = int(np.ceil(step / heading.dt)) + 1
    t = tau[:, None] + np.linspace(-step, step, 2 * m + 1)[None, :]
    k = np.floor((t - heading.t0) / heading.dt).astype(int)
    inside = (k >= 0) & (k < len(slope))
    return np.where(inside, slope[np.clip(k, 0, len(slope) - 1)], 0.0).max(axis=1)
