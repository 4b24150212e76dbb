"""ROTA: Robust Optimal Time Allocation for quadrotor trajectories.

One entry point::

    from rota import retime, RetimeInput, Limits, BSplineTrajectory
    result = retime(RetimeInput(trajectory=traj, limits=Limits(v_max=2.0, a_max=3.0)))
    setpoints = result.sample_rate(50.0)

The re-timer's inner loops are compiled (numba) on first use and cached on disk;
call :func:`warm_up` once before the first re-time that must be fast.
"""

import importlib
from typing import TYPE_CHECKING, Any

#: Where each public name lives: loaded on first use (PEP 562), so a process that needs
#: one small module (a decode worker: the trajectory and map types) does not load the
#: solver (Clarabel, the compiled kernels) with the package
_HOMES = {
    "InputError": "rota.errors", "Limits": "rota.problem", "RetimeInput": "rota.problem",
    "SolverSettings": "rota.problem", "make_grid": "rota.problem",
    "RetimeResult": "rota.result", "Setpoints": "rota.result", "retime": "rota.retime",
    "BSplineTrajectory": "rota.trajectory", "PolynomialTrajectory": "rota.trajectory",
    "SampledTrajectory": "rota.trajectory", "Trajectory": "rota.trajectory",
    "warm_up": "rota.warmup",
}

if TYPE_CHECKING:
    from rota.errors import InputError
    from rota.problem import Limits, RetimeInput, SolverSettings, make_grid
    from rota.result import RetimeResult, Setpoints
    from rota.retime import retime
    from rota.trajectory import (
        BSplineTrajectory,
        PolynomialTrajectory,
        SampledTrajectory,
        Trajectory,
    )
    from rota.warmup import warm_up


def __getattr__(name: str) -> Any:
    if name not in _HOMES:
        raise AttributeError(f"module 'rota' has no attribute {name!r}")
    value = getattr(importlib.import_module(_HOMES[name]), name)
    globals()[name] = value
    return value


__all__ = [
    "BSplineTrajectory",
    "InputError",
    "Limits",
    "PolynomialTrajectory",
    "RetimeInput",
    "RetimeResult",
    "SampledTrajectory",
    "Setpoints",
    "SolverSettings",
    "Trajectory",
    "make_grid",
    "retime",
    "warm_up",
]
