"""ROTA: Robust Optimal Time Allocation for quadrotor trajectories.

One entry point::

    from rota import retime, RetimeInput, Limits, BSplineTrajectory
    result = retime(RetimeInput(trajectory=traj, limits=Limits(v_max=2.0, a_max=3.0)))
    setpoints = result.sample_rate(50.0)

The re-timer's inner loops are compiled (numba) on first use and cached on disk;
call :func:`warm_up` once before the first re-time that must be fast.
"""

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
