"""numba-compiled kernels of the re-timer; load them through :func:`rota.jit.kernels`
(which chooses the on-disk cache first), not by importing this package directly."""

from rota.kernels.chain import boundary_nodes, build_rows
from rota.kernels.chance import (
    assess_path,
    braking_points,
    chance_limits,
    memory_caps,
    risky_nodes,
)
from rota.kernels.ipm import ipm_solve
from rota.kernels.nearest import bricks_build, bricks_query
from rota.kernels.path import (
    audit,
    bspline_pieces,
    eval_pieces,
    grid_path,
    piece_edges,
    sample,
    time_map,
)
from rota.kernels.reach import forward_reachable, passes, tighten
from rota.kernels.rounds import one_round

__all__ = ["assess_path", "audit", "boundary_nodes", "braking_points", "bricks_build",
           "bricks_query", "bspline_pieces", "build_rows", "chance_limits", "eval_pieces",
           "forward_reachable", "grid_path", "ipm_solve", "memory_caps", "one_round", "passes",
           "piece_edges", "risky_nodes", "sample", "tighten", "time_map"]
