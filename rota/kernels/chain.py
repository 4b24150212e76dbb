"""Rows of the chain problem: every limit at every check point as a half-plane in
``(beta_i, beta_{i+1})``, the redundant ones removed exactly.

At fraction ``f`` of interval ``i`` (step ``h``), ``beta = (1 - f) beta_i + f
beta_{i+1}`` and ``alpha = (beta_{i+1} - beta_i) / 2h`` (paper Eqs. 18-20 with the
factor 2), so the speed limit (Eq. 23) and each per-axis acceleration limit
(Eq. 26) read ``a beta_i + c beta_{i+1} <= 1`` after scaling by the limit.
"""

import numpy as np

from rota.kernels._njit import njit

#: Row kinds: speed, then acceleration x+, x-, y+, y-, z+, z-.
SPEED = 0


@njit
def _upper_right_hull(px, py, ids, n, keep):
    """Mark in ``keep`` the ids of the points on the part of the convex hull of
    ``(px, py)[:n]`` whose outward normals lie in the closed first quadrant: the
    rows that bound ``{x >= 0: p . x <= 1}`` (polar duality); every other row is
    implied by them.

    Gift wrapping from the rightmost point (ties: the highest) up and to the left
    until no point is higher: each step scans the points once, and an interval
    has few points and fewer such vertices. Collinear points between two
    vertices are left out (their rows are implied)."""
    p = 0
    for j in range(1, n):
        if px[j] > px[p] or (px[j] == px[p] and py[j] > py[p]):
            p = j
    while True:
        if ids[p] >= 0 and (px[p] > 0.0 or py[p] > 0.0):
            keep[ids[p]] = True
        q = -1
        for r in range(n):
            if py[r] <= py[p]:
                continue
            if q < 0:
                q = r
                continue
            # r right of p -> q: q is no vertex (r is further clockwise); on the
            # line: the farther one
            cross = (px[q] - px[p]) * (py[r] - py[p]) - (py[q] - py[p]) * (px[r] - px[p])
            if cross < 0.0 or (cross == 0.0 and py[r] > py[q]):
                q = r
        if q < 0:
            return
        p = q


@njit
def build_rows(h, offsets, frac, cd1, cd2, vlim, a_max, hi, prune):
    """Rows of every interval from its check points.

    ``offsets`` (N + 1,): check points of interval i are ``offsets[i]`` to
    ``offsets[i + 1] - 1`` (``frac`` in [0, 1], ``cd1``, ``cd2`` the path's
    derivatives there). ``hi`` (N + 1,) the upper bound on beta per node (``inf``
    when none). With ``prune`` only the rows on the hull are kept.

    Returns ``(interval, a, c, kind, point)`` per kept row, and ``rptr`` (N + 1,):
    the rows of interval i are ``rptr[i]`` to ``rptr[i + 1] - 1``.
    """
    n = offsets.shape[0] - 1
    total = offsets[n]
    cap = 7 * total
    r_int = np.empty(cap, np.int64)
    r_a = np.empty(cap)
    r_c = np.empty(cap)
    r_kind = np.empty(cap, np.int8)
    r_pt = np.empty(cap, np.int64)
    maxpts = 0
    for i in range(n):
        maxpts = max(maxpts, offsets[i + 1] - offsets[i])
    px = np.empty(7 * maxpts + 3)
    py = np.empty(7 * maxpts + 3)
    ids = np.empty(7 * maxpts + 3, np.int64)
    keep = np.zeros(7 * maxpts, np.bool_)
    la = np.empty(7 * maxpts)
    lc = np.empty(7 * maxpts)
    lkind = np.empty(7 * maxpts, np.int8)
    lpt = np.empty(7 * maxpts, np.int64)
    out = 0
    inv2h = 0.5 / h
    for i in range(n):
        m = 0
        for q in range(offsets[i], offsets[i + 1]):
            f = frac[q]
            if 0.0 < f < 1.0:
                lim2 = (1.0 - f) * vlim[i] ** 2 + f * vlim[i + 1] ** 2
                s2 = cd1[q, 0] ** 2 + cd1[q, 1] ** 2 + cd1[q, 2] ** 2
                w = s2 / lim2
                if w > 0.0:
                    la[m] = (1.0 - f) * w
                    lc[m] = f * w
                    lkind[m] = SPEED
                    lpt[m] = q
                    m += 1
            for ax in range(3):
                c_lo = (-cd1[q, ax] * inv2h + (1.0 - f) * cd2[q, ax]) / a_max[ax]
                c_hi = (cd1[q, ax] * inv2h + f * cd2[q, ax]) / a_max[ax]
                for sgn in range(2):
                    sign = 1.0 - 2.0 * sgn
                    la[m] = sign * c_lo
                    lc[m] = sign * c_hi
                    lkind[m] = 1 + 2 * ax + sgn
                    lpt[m] = q
                    m += 1
        if prune:
            # Rows no beta within the node bounds can make binding are left out
            # (exact), the rest go to the hull with the bounds themselves.
            c = 0
            for j in range(m):
                keep[j] = False
                reach_a = la[j] * hi[i] if la[j] > 0.0 else 0.0
                reach_c = lc[j] * hi[i + 1] if lc[j] > 0.0 else 0.0
                if reach_a + reach_c > 1.0:
                    px[c] = la[j]
                    py[c] = lc[j]
                    ids[c] = j
                    c += 1
            px[c] = 1.0 / hi[i]
            py[c] = 0.0
            px[c + 1] = 0.0
            py[c + 1] = 1.0 / hi[i + 1]
            px[c + 2] = 0.0
            py[c + 2] = 0.0
            ids[c] = -1
            ids[c + 1] = -1
            ids[c + 2] = -1
            _upper_right_hull(px, py, ids, c + 3, keep)
        for j in range(m):
            if prune and not keep[j]:
                continue
            if not prune and la[j] <= 0.0 and lc[j] <= 0.0:
                continue
            r_int[out] = i
            r_a[out] = la[j]
            r_c[out] = lc[j]
            r_kind[out] = lkind[j]
            r_pt[out] = lpt[j]
            out += 1
    rptr = np.zeros(n + 1, np.int64)
    for r in range(out):
        rptr[r_int[r] + 1] += 1
    for i in range(n):
        rptr[i + 1] += rptr[i]
    return (r_int[:out].copy(), r_a[:out].copy(), r_c[:out].copy(), r_kind[:out].copy(),
            r_pt[:out].copy(), rptr)


@njit
def boundary_nodes(n, h, beta_start, alpha_start, beta_end):
    """``(fixed, value)`` of the ``n`` nodes from the boundary equalities (NaN: free);
    a start acceleration also fixes ``beta_1 = beta_0 + 2 h alpha_0`` (at least 0)."""
    fixed = np.zeros(n, np.bool_)
    value = np.zeros(n)
    if not np.isnan(beta_start):
        fixed[0] = True
        value[0] = beta_start
        if not np.isnan(alpha_start):
            fixed[1] = True
            value[1] = max(beta_start + 2.0 * h * alpha_start, 0.0)
    if not np.isnan(beta_end):
        fixed[n - 1] = True
        value[n - 1] = beta_end
    return fixed, value
