"""One round of the re-time in one compiled call: check points, rows, reachability,
tightening, the interior-point solve and the audit of its answer.

The same kernels :mod:`rota.checkpoints`, :mod:`rota.chain`, :mod:`rota.solver`
and :func:`rota.rounds.audit` call one by one, composed here so that a re-time
crosses from Python into compiled code once per round instead of half a dozen
times (on small grids those crossings, and the numpy glue between them, cost
more than the work itself).
"""

import numpy as np

from rota.kernels._njit import njit
from rota.kernels.chain import boundary_nodes, build_rows
from rota.kernels.ipm import ipm_solve
from rota.kernels.path import audit, sample
from rota.kernels.reach import passes, tighten

#: ``code`` of a round whose interior-point method did not run.
NOT_RUN = -1


@njit
def one_round(breaks, coefs, t0, t1, tau, d1, vlim, a_max, parts, piece_parts, still,
              cap_factor, interval, more, lam, beta_start, alpha_start, beta_end, prune,
              certify, certify_tol, solve, share, cap, tol, max_iter, refine_tol):
    """Check points (with the points ``(interval, more)`` of earlier rounds) and the
    chain problem of the grid ``tau``; when the path moves, the reachability
    passes and the tightened bounds; when feasible, not certified optimal by
    reachability and ``solve``, the interior-point method; the audit of the
    answer (the greedy profile when certified, else the solver's) when there is one.

    The boundary ``beta_start``, ``alpha_start``, ``beta_end``: NaN when free.
    Returns four tuples (see :func:`rota.rounds.one_round` for what becomes of them):
    ``path (offsets, frac, cd1, cd2, beta_max, moving)``, ``reach (greedy, node,
    row, exact, ok)`` (``ok``: feasible, and the tightened bounds leave no two
    neighbours standing still), ``solved (x, code, iterations, objective)``
    (``code`` :data:`NOT_RUN` when it did not run) and ``audited (n, bad_interval,
    bad_frac, speed, acc, axis, point)`` (``n`` -1 when there was nothing to
    audit). The chain problem itself stays inside (returning its arrays costs
    more than making them again on the rare paths that need them).
    """
    n = tau.shape[0]
    h = tau[1] - tau[0]
    offsets, frac, cd1, cd2, beta_max, moving = sample(
        breaks, coefs, t0, t1, tau, parts, piece_parts, d1, vlim, still, cap_factor,
        interval, more)
    fixed, value = boundary_nodes(n, h, beta_start, alpha_start, beta_end)
    rk, ra, rc, kind, point, rptr = build_rows(h, offsets, frac, cd1, cd2, vlim, a_max,
                                               beta_max, prune)
    lo = np.zeros(n)
    kl = np.empty(n)
    ku = np.empty(n)
    greedy = np.zeros(n)
    node, row, exact = -1, -1, False
    if moving:
        node, row, exact = passes(lo, beta_max, fixed, value, rptr, ra, rc, certify,
                                  certify_tol, kl, ku, greedy)
    hi_t, fixed_t, value_t, ok = beta_max, fixed, value, False
    if moving and node < 0:
        hi_t, fixed_t, value_t, ok = tighten(beta_max, fixed, value, ku)
    x = np.empty(n)
    code, iterations, objective = NOT_RUN, 0, np.nan
    go = ok
    if go and not exact and solve:
        code, iterations, objective = ipm_solve(h, lam, lo, hi_t, fixed_t, value_t, greedy,
                                                share, cap, rk, ra, rc, tol, max_iter, x)
    m = frac.shape[0]
    bad_i = np.empty(m, np.int64)
    bad_f = np.empty(m)
    n_bad, speed, acc, axis, worst = -1, 0.0, 0.0, 0, 0
    if go and (exact or code == 0):
        beta = greedy if exact else x
        n_bad, speed, acc, axis, worst = audit(beta, tau, offsets, frac, cd1, cd2, vlim,
                                               a_max, beta_max, breaks, coefs, refine_tol,
                                               bad_i, bad_f)
    return ((offsets, frac, cd1, cd2, beta_max, moving),
            (greedy, node, row, exact, ok),
            (x, code, iterations, objective),
            (n_bad, bad_i[:max(n_bad, 0)], bad_f[:max(n_bad, 0)], speed, acc, axis, worst))
