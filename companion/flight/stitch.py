"""Joining a new trajectory onto what the vehicle is commanded to do (pure
functions; they run in the re-time worker, off the event loop)."""

from __future__ import annotations

import numpy as np

from companion.flight.plan import blend_time
from rota.trajectory import Trajectory, Window


class StitchError(ValueError):
    """The new trajectory cannot take over from the commanded state."""


#: The join's refinement: passes of this many points around the best one (the bracket,
#: two of the 2001-point grid's steps at first, ends 8000 times narrower: under 1e-6 of
#: the trajectory's duration)
REFINE_PASSES, REFINE_POINTS = 3, 41


def nearest_tau(traj: Trajectory, position: np.ndarray, tolerance: float) -> float:
    """Trajectory time where the vehicle joins the path: the nearest point of the
    first stretch of the path that comes within ``tolerance`` of ``position`` (so
    a path that loops back past the vehicle later is not joined there), refined
    around it; the global nearest point if none comes that close."""
    t0, t1 = traj.domain
    tau = np.linspace(t0, t1, 2001)
    d = np.linalg.norm(traj.position(tau) - position, axis=1)
    near = np.flatnonzero(d <= tolerance)
    if len(near):
        breaks = np.flatnonzero(np.diff(near) > 1)
        run_end = near[breaks[0]] + 1 if len(breaks) else near[-1] + 1
        i = near[0] + int(np.argmin(d[near[0]:run_end]))
    else:
        i = int(np.argmin(d))
    lo, hi = tau[max(i - 1, 0)], tau[min(i + 1, len(tau) - 1)]
    # refined by three dense passes around the best point (one vectorised evaluation each,
    # not 80 scalar ones: this runs for every replan), each shrinking the bracket 20-fold
    for _ in range(REFINE_PASSES):
        x = np.linspace(lo, hi, REFINE_POINTS)
        k = int(np.argmin(np.linalg.norm(traj.position(x) - position, axis=1)))
        lo, hi = x[max(k - 1, 0)], x[min(k + 1, REFINE_POINTS - 1)]
    return float(np.clip(0.5 * (lo + hi), t0, t1))


def along_path(traj: Trajectory, velocity: np.ndarray, v_max: float) -> np.ndarray:
    """The commanded velocity's component along the path's tangent at its start,
    at most ``v_max`` (a takeover blend still fading out may add a little speed).

    A replan never starts exactly on the commanded velocity; the cross-track rest
    (up to 0.5 m/s or 30 % of the speed) is left to PX4's position loop. More
    than that means the new path turns away sharply: :class:`StitchError`."""
    _, d1, _ = traj.evaluate(traj.domain[0])
    norm = float(np.linalg.norm(d1[0]))
    speed = float(np.linalg.norm(velocity))
    if norm <= 1e-9:
        if speed > 0.3:
            raise StitchError(f"starts at rest while the vehicle moves at {speed:.2f} m/s")
        return np.zeros(3)
    tangent = d1[0] / norm
    along = max(float(velocity @ tangent), 0.0) * tangent
    cross = float(np.linalg.norm(velocity - along))
    if cross > max(0.5, 0.3 * speed):
        raise StitchError(f"its start direction differs from the vehicle's velocity by "
                          f"{cross:.2f} m/s")
    speed_along = float(np.linalg.norm(along))
    return along * min(1.0, v_max / speed_along) if speed_along > 0 else along


def join(traj: Trajectory, position: np.ndarray, velocity: np.ndarray, tolerance: float,
         v_max: float) -> tuple[Trajectory, np.ndarray]:
    """The part of ``traj`` to fly from the commanded state, and its start velocity.

    The part begins exactly at ``position``: the gap to the path (at most
    ``tolerance``) is carried as an offset that fades out along the path
    (:class:`rota.trajectory.Window`), so the re-time bounds speed, acceleration
    and the chance constraints of the path as it will be flown, blend included."""
    tau0 = nearest_tau(traj, position, tolerance)
    offset = np.asarray(position, dtype=float) - traj.position(tau0)[0]
    gap = float(np.linalg.norm(offset))
    if gap > tolerance:
        raise StitchError(f"starts {gap:.2f} m from the commanded position "
                          f"(tolerance {tolerance} m)")
    if tau0 >= traj.domain[1] - 1e-6:
        raise StitchError("the vehicle is already past its end")
    if gap > 1e-9:  # begin exactly at the command; the re-time bounds the blend too
        blend = min(blend_time(gap), traj.domain[1] - tau0)
        traj = Window(base=traj, start=tau0, offset=offset, blend=blend)
    elif tau0 > traj.domain[0]:
        traj = Window(base=traj, start=tau0)
    return traj, along_path(traj, velocity, v_max)
