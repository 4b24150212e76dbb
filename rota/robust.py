"""The robust part of ROTA: map -> braking zones -> chance-constrained speed limits
(paper Sec. III-B, III-C), assessed on the re-timing grid.

This is glue over :mod:`rota.voxelmap`, :mod:`rota.braking` and :mod:`rota.chance`;
with error memory (``UncertaintyModel.memory_s`` > 0) each braking point's limit
also holds over the path before it (:func:`rota.chance.memory_limits`). Its
product is one speed limit per grid node, which the SOCP takes through the
per-node speed-limit hook (Eq. 23), plus what the result reports.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from rota.braking import BrakingParams, BrakingZones, horizon_of, reach_of, zones_from
from rota.chance import ChanceParams, SpeedLimits, UncertaintyModel, kernel_args, risk_reach
from rota.errors import InputError, plain
from rota.jit import kernels
from rota.trajectory import Trajectory
from rota.voxelmap import VoxelMap

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


#: No map box (the kernel's empty bounds).
_NO_BOX = (np.zeros(0), np.zeros(0))


@dataclass(frozen=True)
class Safety:
    """What the robust re-time needs beyond the kinematic limits.

    Attributes:
        map: occupied voxels, in the trajectory's frame.
        uncertainty: velocity -> position std model (Eq. 15); the flight service
            replaces it with the in-flight estimate.
        chance: probability bound, robot ellipsoid, obstacle std (Eqs. 10-14).
        braking: braking-zone threshold and refinement (Alg. 1).
        bounds: optional ``((xmin, ymin, zmin), (xmax, ymax, zmax))`` of the space
            the map covers. Where the path leaves it nothing is known about
            obstacles, so the speed there is limited to ``unknown_speed``.
            None: the map's own ``bounds``, and if it has none the map is taken
            to cover everything.
        unknown_speed: speed limit outside ``bounds`` (m/s); default
            ``chance.v_floor``.
    """

    map: VoxelMap
    uncertainty: UncertaintyModel = field(default_factory=UncertaintyModel)
    chance: ChanceParams = field(default_factory=ChanceParams)
    braking: BrakingParams = field(default_factory=BrakingParams)
    bounds: FloatArray | None = None
    unknown_speed: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.map, VoxelMap):
            raise InputError("map", f"must be a rota VoxelMap, got {type(self.map).__name__}")
        if self.bounds is not None:
            b = np.asarray(self.bounds, dtype=float)
            if b.shape != (2, 3) or not np.all(np.isfinite(b)) or np.any(b[1] <= b[0]):
                raise InputError("bounds", "must be ((xmin, ymin, zmin), (xmax, ymax, zmax)) "
                                 "with min < max, finite")
            object.__setattr__(self, "bounds", b)
        if self.unknown_speed is not None and not (np.isfinite(self.unknown_speed)
                                                   and self.unknown_speed > 0):
            raise InputError("unknown_speed", f"must be positive, got {plain(self.unknown_speed)}")


@dataclass(frozen=True, eq=False)
class Assessment:
    """The map seen from the path, on the grid.

    Attributes:
        speed_limits: ``(N+1,)`` per-node limit (m/s); ``inf`` where none applies.
        zones: braking zones (raw mask drives the limits, refined intervals report).
        chance: the chance-constraint limits at every node (applied on the mask).
        collision: ``(N+1,)`` nodes whose nominal position is inside the robot's
            safety ellipsoid of an obstacle, or so close that even at rest the
            probability bound cannot hold: the path itself is unsafe there.
        outside: ``(N+1,)`` nodes outside the map's ``bounds``.
        position: ``(N+1, 3)`` path positions at the nodes.
        approach: ``(N+1,)`` nodes limited only because a braking point follows
            within its memory window (error memory; all False without it).
    """

    speed_limits: FloatArray
    zones: BrakingZones
    chance: SpeedLimits
    collision: BoolArray
    outside: BoolArray
    position: FloatArray
    approach: BoolArray
    model: UncertaintyModel = field(default_factory=UncertaintyModel)
    params: ChanceParams = field(default_factory=ChanceParams)

    def describe_collision(self, tau: FloatArray) -> str:
        """The closest unsafe node, its clearance, the clearance the model needs there at
        rest, and the model in use (the flight service adds where it came from)."""
        hit = np.flatnonzero(self.collision)
        i = int(hit[np.argmin(self.zones.distance[hit])])
        p = np.round(self.position[i], 2).tolist()
        o = np.round(self.zones.nearest[i], 2).tolist()
        u, c = self.model, self.params
        need = risk_reach(u, replace(c, v_max=max(c.v_floor, 1e-9)))
        at_rest = risk_reach(u, replace(c, v_floor=0.0, v_max=1e-9))
        return (f"the path is unsafe: closest at tau={tau[i]:.2f} s, position {p} is "
                f"{self.zones.distance[i]:.2f} m from the obstacle at {o} (voxel centre); "
                f"with the uncertainty model m={u.m:.3g} s, b={u.b:.3g} m, floor={u.floor:.3g} "
                f"m, memory {u.memory_s:g} s, Delta={c.delta:g} and a {max(c.semi_axes):g} m "
                f"robot the path needs {at_rest:.2f} m of clearance even at rest "
                f"({need:.2f} m at v_floor {c.v_floor:g} m/s); "
                f"{int(self.collision.sum())} grid nodes are closer")


def assess(trajectory: Trajectory, tau: FloatArray, safety: Safety,
           position: FloatArray | None = None,
           velocity: FloatArray | None = None) -> Assessment:
    """Braking zones (Alg. 1) and chance-constraint speed limits (Sec. III-C) on ``tau``.

    ``position`` and ``velocity`` (``sigma'``) on ``tau``, when the caller has them.
    """
    if position is None or velocity is None:
        position, velocity, _ = trajectory.evaluate(tau)
    p, d1 = position, velocity
    reach = reach_of(safety.braking, safety.uncertainty, safety.chance)
    margin = max(2.0, reach * (1.0 + 1e-9) + 1e-9)
    p = np.ascontiguousarray(p, dtype=float)
    bounds = safety.bounds if safety.bounds is not None else safety.map.bounds
    # (a writable copy: the kernel is compiled for writable arrays)
    box = _NO_BOX if bounds is None else np.array(bounds, dtype=float)
    unknown = safety.chance.v_floor if safety.unknown_speed is None else safety.unknown_speed
    distance, obstacle, flags, values, starts, ends = kernels().assess_path(
        p, d1, *safety.map.query_args(p, margin), safety.braking.d_th, safety.braking.risk,
        horizon_of(safety.braking), *kernel_args(safety.uncertainty, safety.chance),
        float(safety.uncertainty.memory_s),
        max(reach, max(safety.chance.semi_axes)), box[0], box[1],
        float(unknown))
    mask, infeasible, approach, collision, outside = flags
    limit, unclamped, limits = values
    zones = zones_from(tau, mask, starts, ends, distance, obstacle, safety.braking)
    chance = SpeedLimits(limit, unclamped, infeasible, safety.chance.v_floor)
    return Assessment(limits, zones, chance, collision, outside, p, approach,
                      safety.uncertainty, safety.chance)
