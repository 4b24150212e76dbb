"""The entry point: :func:`retime` takes a :class:`RetimeInput`, returns a
:class:`RetimeResult`. It never raises for solver trouble and never returns NaN:
when the optimum cannot be had, the result says why and carries the fallback."""

from __future__ import annotations

from rota.jerk import retime_jerk
from rota.optimal import retime_free
from rota.problem import RetimeInput
from rota.result import RetimeResult


def retime(inp: RetimeInput) -> RetimeResult:
    """Re-time ``inp.trajectory`` optimally (paper Eq. 11 on the grid of Eq. 17).

    With ``inp.safety`` the speed limit of every grid node also includes the
    chance-constraint limit in braking zones (Sec. III-B/C). The problem is
    solved on beta (:mod:`rota.chain`) by the solver ``inp.solver.method``
    (:mod:`rota.solver`), after a reachability pass that decides feasibility
    exactly and, at lambda = 0, often the optimum itself (:mod:`rota.optimal`).
    With a jerk bound (``inp.limits.j_max``) the re-time is
    :func:`rota.jerk.retime_jerk`.
    """
    if inp.limits.j_max is not None:
        return retime_jerk(inp)
    return retime_free(inp)
