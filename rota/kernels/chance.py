"""Chance-constraint speed limits (paper Eqs. 10-15) and their error-memory caps,
compiled: one pass over the samples, no temporaries (see :mod:`rota.chance` for
the model and the closed form)."""

import numpy as np

from rota.kernels._njit import njit
from rota.kernels.nearest import bricks_query


@njit
def _load(w, g, fl, b, x):
    """``sum_k w_k max(fl, g_k x + b)^2``: the variance budget used at speed ``m x``."""
    total = 0.0
    for k in range(3):
        s = max(fl, g[k] * x + b)
        total += w[k] * s * s
    return total


@njit
def _largest_x(w, g, fl, b, rem):
    """Largest ``x >= 0`` with ``_load(x) <= rem`` (-inf: none; inf: every x). The
    load is a piecewise quadratic, non-decreasing in ``x``; each piece (split where
    an axis leaves the floor) is solved in closed form."""
    bp = np.empty(3)
    for k in range(3):
        bp[k] = max(0.0, (fl - b) / g[k]) if g[k] > 0.0 else np.inf
    edges = np.empty(5)
    edges[0] = 0.0
    edges[4] = np.inf
    for k in range(3):  # sorted breakpoints
        j = k + 1
        while j > 1 and edges[j - 1] > bp[k]:
            edges[j] = edges[j - 1]
            j -= 1
        edges[j] = bp[k]
    s_inactive = max(fl, b)
    best = -np.inf
    for j in range(4):
        lo = edges[j]
        hi = edges[j + 1]
        live = j == 0 or (np.isfinite(lo) and hi > lo)
        qa = 0.0
        qg = 0.0
        qw = 0.0
        qi = 0.0
        for k in range(3):
            if bp[k] <= lo and g[k] > 0.0:
                qa += w[k] * g[k] * g[k]
                qg += w[k] * g[k]
                qw += w[k]
            else:
                qi += w[k]
        qb = 2.0 * b * qg
        qc = b * b * qw + s_inactive * s_inactive * qi
        f_lo = _load(w, g, fl, b, lo if live else 0.0)
        hi_fin = np.isfinite(hi)
        f_hi = _load(w, g, fl, b, hi) if hi_fin else np.inf
        ok_lo = live and f_lo <= rem
        whole = ok_lo and hi_fin and f_hi <= rem
        # largest root of qa x^2 + qb x + (qc - rem) = 0 (qa > 0), cancellation-free
        c0 = qc - rem
        disc = qb * qb - 4.0 * qa * c0
        sq = np.sqrt(disc) if disc > 0.0 else (0.0 if disc == disc else np.nan)
        if not qa > 0.0:
            root = np.inf
        elif qb >= 0.0:
            root = -2.0 * c0 / (qb + sq)
        else:
            root = (-qb + sq) / (2.0 * qa)
        if root != root:
            root = -np.inf
        root = min(max(root, lo), hi)
        if whole:
            cand = hi
        elif ok_lo:
            cand = root
        else:
            cand = -np.inf
        best = max(best, cand)
    return best


@njit
def chance_limits(pos, direction, obstacle, inv_axes, point_robot, obs_var, z, m, b, fl,
                  per_axis, v_floor, v_max, limit, unclamped, infeasible):
    """Per sample, the largest speed along ``direction`` with the linearised
    collision probability (Eq. 14, std from Eq. 15) within its bound, into
    ``unclamped`` (inf: any speed; NaN: none, then ``infeasible``) and, clamped to
    ``[v_floor, v_max]``, into ``limit`` (``v_max`` without an obstacle).

    ``inv_axes``: 1 / the robot's semi-axes (ones for a point robot); ``obs_var``:
    the obstacle's per-axis variance; ``z``: ``Phi^-1(1 - delta)``.
    """
    w = np.empty(3)
    g = np.empty(3)
    for q in range(pos.shape[0]):
        has = (np.isfinite(obstacle[q, 0]) and np.isfinite(obstacle[q, 1])
               and np.isfinite(obstacle[q, 2]))
        if not has:
            limit[q] = v_max
            unclamped[q] = np.inf
            infeasible[q] = False
            continue
        norm2 = 0.0
        for k in range(3):
            sk = (pos[q, k] - obstacle[q, k]) * inv_axes[k]
            w[k] = sk
            norm2 += sk * sk
        norm = np.sqrt(norm2)
        div = 1.0 if norm == 0.0 else norm
        var_o = 0.0
        for k in range(3):
            w[k] = (w[k] / div * inv_axes[k]) ** 2  # (a_k / semi_k)^2
            var_o += w[k] * obs_var[k]
        if norm == 0.0:
            margin = -np.inf
        else:
            margin = norm if point_robot else norm - 1.0
        if margin > 0.0:
            r2 = (margin / z) ** 2 if z > 0.0 else np.inf
        else:
            r2 = -np.inf
        rem = r2 - var_o
        un = np.sqrt(direction[q, 0] ** 2 + direction[q, 1] ** 2 + direction[q, 2] ** 2)
        for k in range(3):
            if per_axis:
                g[k] = abs(direction[q, k] / (un if un > 0.0 else 1.0))
            else:
                g[k] = 1.0 if un > 0.0 else 0.0
        best = _largest_x(w, g, fl, b, rem)
        if not best >= 0.0:
            infeasible[q] = True
            unclamped[q] = np.nan
            limit[q] = v_floor
            continue
        infeasible[q] = False
        v = best / m if m > 0.0 else np.inf
        unclamped[q] = v
        limit[q] = min(max(v, v_floor), v_max)


@njit
def memory_caps(arclength, limit, memory_s, out):
    """Node ``i``'s limit ``L_i`` also at every node ``j < i`` with
    ``s_j >= s_i - L_i T`` and at the last node before that stretch (see
    :func:`rota.chance.memory_limits`); ``out`` starts as ``limit``."""
    n = arclength.shape[0]
    for i in range(n):
        out[i] = limit[i]
    if memory_s == 0.0:
        return
    for i in range(n):
        cap = limit[i]
        if not np.isfinite(cap):
            continue
        j = max(np.searchsorted(arclength, arclength[i] - cap * memory_s, side="right") - 1, 0)
        for k in range(j, i):
            if cap < out[k]:
                out[k] = cap


@njit
def braking_points(pos, vel, dist, obstacle, d_th, risky, horizon, mask):
    """Braking points (paper Eq. 6, threshold replaced by the risk) into ``mask``: an
    obstacle not behind (``(o - p) . v >= 0``) that is within ``d_th`` or whose chance
    limit at the node is below ``v_max`` (``risky[q]``; an empty ``risky``: the
    distance alone, the paper's Eq. 6), within ``horizon`` metres of path from the
    first sample. Returns ``(starts, ends)`` of the runs of braking points
    (inclusive)."""
    n = pos.shape[0]
    use_risk = risky.shape[0] == n
    length = 0.0
    runs = 0
    for q in range(n):
        if q > 0:
            length += np.sqrt((pos[q, 0] - pos[q - 1, 0]) ** 2 + (pos[q, 1] - pos[q - 1, 1]) ** 2
                              + (pos[q, 2] - pos[q - 1, 2]) ** 2)
        has = (np.isfinite(dist[q]) and np.isfinite(obstacle[q, 0])
               and np.isfinite(obstacle[q, 1]) and np.isfinite(obstacle[q, 2]))
        ahead = 0.0
        if has:
            for k in range(3):
                ahead += (obstacle[q, k] - pos[q, k]) * vel[q, k]
        close = dist[q] <= d_th or (use_risk and risky[q])
        mask[q] = has and close and ahead >= 0.0 and length <= horizon
        if mask[q] and (q == 0 or not mask[q - 1]):
            runs += 1
    starts = np.empty(runs, np.int64)
    ends = np.empty(runs, np.int64)
    r = -1
    for q in range(n):
        if mask[q] and (q == 0 or not mask[q - 1]):
            r += 1
            starts[r] = q
        if mask[q]:
            ends[r] = q
    return starts, ends


@njit
def risky_nodes(limit, infeasible, v_max, out):
    """Nodes whose chance limit falls below ``v_max`` (or that have none) into ``out``."""
    for q in range(limit.shape[0]):
        out[q] = infeasible[q] or limit[q] < v_max


@njit
def assess_nodes(pos, vel, dist, obstacle, d_th, risk, horizon, inv_axes, point_robot, obs_var, z,
                 m, b, fl, per_axis, v_floor, v_max, memory_s, near, lo, hi, unknown, flags,
                 values):
    """The map seen from the path on the grid, in one call (:func:`rota.robust.assess`).

    :func:`chance_limits` and :func:`braking_points` (with ``risk``: also where the
    chance limit falls below ``v_max``); every node's speed limit: the
    chance limit at braking points, ``inf`` elsewhere, then held over the path
    before each braking point for ``memory_s`` (:func:`memory_caps`), then at most
    ``unknown`` outside the box ``lo``-``hi`` (``lo`` empty: no box).

    Into ``flags`` (5, n): braking points, chance infeasible, limited only by the
    memory ("approach"), collision (infeasible within ``near`` of the obstacle),
    outside the box; into ``values`` (3, n): chance limit, unclamped limit, node
    limit. Returns the braking points' runs ``(starts, ends)``.
    """
    n = pos.shape[0]
    mask, infeasible, approach, collision, outside = (flags[0], flags[1], flags[2],
                                                      flags[3], flags[4])
    limit, unclamped, node_limit = values[0], values[1], values[2]
    chance_limits(pos, vel, obstacle, inv_axes, point_robot, obs_var, z, m, b, fl, per_axis,
                  v_floor, v_max, limit, unclamped, infeasible)
    risky = np.empty(n if risk else 0, np.bool_)
    if risk:
        risky_nodes(limit, infeasible, v_max, risky)
    starts, ends = braking_points(pos, vel, dist, obstacle, d_th, risky, horizon, mask)
    raw = np.empty(n)
    for q in range(n):
        raw[q] = limit[q] if mask[q] else np.inf
    arclength = np.empty(n)
    arclength[0] = 0.0
    for q in range(1, n):
        arclength[q] = arclength[q - 1] + np.sqrt(
            (pos[q, 0] - pos[q - 1, 0]) ** 2 + (pos[q, 1] - pos[q - 1, 1]) ** 2
            + (pos[q, 2] - pos[q - 1, 2]) ** 2)
    memory_caps(arclength, raw, memory_s, node_limit)
    box = lo.shape[0] == 3
    for q in range(n):
        approach[q] = node_limit[q] < raw[q]
        collision[q] = infeasible[q] and dist[q] <= near
        out = False
        if box:
            for ax in range(3):
                if pos[q, ax] < lo[ax] or pos[q, ax] > hi[ax]:
                    out = True
        outside[q] = out
        if out and unknown < node_limit[q]:
            node_limit[q] = unknown
    return starts, ends


@njit
def assess_path(pos, vel, origin, res, lo, dims, size, start, pts, box, bound2, d_th, risk,
                horizon,
                inv_axes, point_robot, obs_var, z, m, b, fl, per_axis, v_floor, v_max,
                memory_s, near, box_lo, box_hi, unknown):
    """The nearest occupied centre to every node (:func:`rota.kernels.nearest.bricks_query`
    on the index ``lo`` .. ``box``, within ``sqrt(bound2)``), then
    :func:`assess_nodes`, in one call. Returns ``(dist, obstacle, flags, values,
    starts, ends)``."""
    n = pos.shape[0]
    dist = np.empty(n)
    obstacle = np.empty((n, 3))
    bricks_query(pos, origin, res, lo, dims, size, start, pts, box, bound2, dist, obstacle)
    flags = np.empty((5, n), np.bool_)
    values = np.empty((3, n))
    starts, ends = assess_nodes(pos, vel, dist, obstacle, d_th, risk, horizon, inv_axes,
                                point_robot, obs_var, z, m, b, fl, per_axis, v_floor, v_max,
                                memory_s, near, box_lo, box_hi, unknown, flags, values)
    return dist, obstacle, flags, values, starts, ends
