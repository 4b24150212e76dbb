"""Evaluation of a piecewise polynomial path and its first two derivatives."""

import numpy as np

from rota.kernels._njit import njit


@njit
def _piece(breaks, t, j):
    """The piece of ``t`` (the last ``j`` with ``breaks[j] <= t``), searched from
    the previous one ``j``: sorted queries cost O(1) each."""
    m = breaks.shape[0] - 1
    if t < breaks[j]:
        lo, hi = 0, j
        while lo < hi:
            mid = (lo + hi + 1) // 2
            if breaks[mid] <= t:
                lo = mid
            else:
                hi = mid - 1
        j = lo
    while j < m - 1 and breaks[j + 1] <= t:
        j += 1
    return j


@njit
def _horner(coefs, j, s, ax):
    """Position and the first two derivatives of piece ``j`` on axis ``ax`` at
    ``s`` past its start."""
    k = coefs.shape[1] - 1
    p = coefs[j, k, ax]
    v = 0.0
    a = 0.0
    for r in range(k - 1, -1, -1):
        a = a * s + 2.0 * v
        v = v * s + p
        p = p * s + coefs[j, r, ax]
    return p, v, a


@njit
def eval_pieces(breaks, coefs, tau, pos, d1, d2):
    """Fill ``pos``, ``d1``, ``d2`` (n, 3) at ``tau`` (n,), clamped to the domain.

    ``breaks`` (m + 1,) are the piece ends; ``coefs`` (m, k + 1, 3) the
    coefficients of piece j in ascending powers of ``tau - breaks[j]``. The piece
    search walks from the previous one, so sorted queries cost O(n + m).
    """
    m = coefs.shape[0]
    t0 = breaks[0]
    t1 = breaks[m]
    j = 0
    for q in range(tau.shape[0]):
        t = min(max(tau[q], t0), t1)
        j = _piece(breaks, t, j)
        s = t - breaks[j]
        for ax in range(3):
            pos[q, ax], d1[q, ax], d2[q, ax] = _horner(coefs, j, s, ax)
    return np.int64(j)


@njit
def grid_path(breaks, coefs, t0, t1, n):
    """The grid of ``n`` equal intervals over ``[t0, t1]`` (the numbers
    :func:`rota.problem.make_grid` makes: ``i * step + t0``, the last node ``t1``)
    and the path's position and first two derivatives there (:func:`eval_pieces`).
    Returns ``(tau, pos, d1, d2)``."""
    tau = np.empty(n + 1)
    step = (t1 - t0) / n
    for i in range(n + 1):
        tau[i] = i * step + t0
    tau[n] = t1
    pos = np.empty((n + 1, 3))
    d1 = np.empty((n + 1, 3))
    d2 = np.empty((n + 1, 3))
    eval_pieces(breaks, coefs, tau, pos, d1, d2)
    return tau, pos, d1, d2


@njit
def check_points(tau, edges, parts, piece_parts):
    """Check points of every interval of the grid ``tau`` (uniform step), sorted by
    interval and fraction: both ends of every interval, every inner piece end
    ``edges[1:-1]``, ``piece_parts - 1`` inner points of every piece ``[edges[j],
    edges[j + 1]]`` that the uniform subdivision of the intervals into ``parts``
    would cut in fewer than ``piece_parts`` parts ("short" pieces), and that
    subdivision's inner points where they do not fall inside a short piece (its own
    points are denser there). Points closer than 1e-12 (in fractions of an
    interval) to an earlier one of the same interval are dropped.

    Returns ``(offsets (N + 1,), frac (M,), at (M,))``: the points of interval i
    are ``offsets[i]`` to ``offsets[i + 1] - 1``; ``at`` their trajectory times.
    """
    n = tau.shape[0] - 1
    h = tau[1] - tau[0]
    n_pieces = edges.shape[0] - 1
    # the extra points, in increasing order
    cap = max(n_pieces - 1, 0)
    short = np.zeros(max(n_pieces, 1), np.bool_)
    for j in range(n_pieces):
        if (edges[j + 1] - edges[j]) * parts < piece_parts * h:
            short[j] = True
            cap += piece_parts - 1
    extra = np.empty(cap)
    m = 0
    for j in range(n_pieces):
        if j > 0:
            extra[m] = edges[j]
            m += 1
        length = edges[j + 1] - edges[j]
        if short[j]:
            for k in range(1, piece_parts):
                extra[m] = edges[j] + length * (k / piece_parts)
                m += 1
    e_idx = np.empty(m, np.int64)
    e_frac = np.empty(m)
    i = 0
    for q in range(m):  # interval: the last node at or before the point
        while i + 1 <= n - 1 and tau[i + 1] <= extra[q]:
            i += 1
        while i > 0 and tau[i] > extra[q]:
            i -= 1
        e_idx[q] = i
        e_frac[q] = min(max((extra[q] - tau[i]) / h, 0.0), 1.0)
    total = n * (parts + 1) + m
    offsets = np.empty(n + 1, np.int64)
    frac = np.empty(total)
    at = np.empty(total)
    out = 0
    q = 0
    jp = 0  # the piece of the latest uniform point
    for i in range(n):
        offsets[i] = out
        u = 0
        last = -1.0
        while u <= parts or (q < m and e_idx[q] == i):
            take_u = u <= parts
            if take_u and q < m and e_idx[q] == i:
                take_u = u / parts <= e_frac[q]
            f = u / parts if take_u else e_frac[q]
            if take_u:
                u += 1
                if 1 < u <= parts and n_pieces > 0:  # an inner uniform point
                    t = tau[i] + f * h
                    while jp < n_pieces - 1 and edges[jp + 1] <= t:
                        jp += 1
                    if short[jp] and edges[jp] < t < edges[jp + 1]:
                        continue
            else:
                q += 1
            if out > offsets[i] and f - last <= 1e-12:
                continue
            frac[out] = f
            at[out] = tau[i] + f * h
            last = f
            out += 1
    offsets[n] = out
    return offsets, frac[:out].copy(), at[:out].copy()


@njit
def beta_bounds(d1, vlim, still, cap_factor, out):
    """``out``: the speed bound ``vlim^2 / |sigma'|^2`` of every node (Eq. 23); where
    the path stands still (``|sigma'| <= still``) ``cap_factor`` times the median
    bound of the moving nodes, which also caps every bound (1 without any)."""
    n = d1.shape[0]
    moving = np.empty(n)
    k = 0
    for i in range(n):
        s2 = d1[i, 0] ** 2 + d1[i, 1] ** 2 + d1[i, 2] ** 2
        if np.sqrt(s2) > still:
            out[i] = vlim[i] ** 2 / s2
            moving[k] = out[i]
            k += 1
        else:
            out[i] = np.inf
    cap = cap_factor * np.median(moving[:k]) if k > 0 else 1.0
    for i in range(n):
        out[i] = min(out[i], cap)


@njit
def _basis_derivatives(t, k, span, u, ders, ndu, left, right, a):
    """All derivatives (orders 0..k) of the k + 1 B-spline basis functions that
    are non-zero on knot span ``span`` (``t[span] <= u < t[span + 1]``), at ``u``,
    into ``ders[order, j]`` (basis ``span - k + j``); Piegl & Tiller, Alg. A2.3.
    ``ndu``, ``left``, ``right``, ``a``: work space."""
    ndu[0, 0] = 1.0
    for j in range(1, k + 1):
        left[j] = u - t[span + 1 - j]
        right[j] = t[span + j] - u
        saved = 0.0
        for r in range(j):
            ndu[j, r] = right[r + 1] + left[j - r]
            temp = ndu[r, j - 1] / ndu[j, r]
            ndu[r, j] = saved + right[r + 1] * temp
            saved = left[j - r] * temp
        ndu[j, j] = saved
    for j in range(k + 1):
        ders[0, j] = ndu[j, k]
    for r in range(k + 1):
        s1 = 0
        s2 = 1
        a[0, 0] = 1.0
        for kk in range(1, k + 1):
            d = 0.0
            rk = r - kk
            pk = k - kk
            if r >= kk:
                a[s2, 0] = a[s1, 0] / ndu[pk + 1, rk]
                d = a[s2, 0] * ndu[rk, pk]
            j1 = 1 if rk >= -1 else -rk
            j2 = kk - 1 if r - 1 <= pk else k - r
            for j in range(j1, j2 + 1):
                a[s2, j] = (a[s1, j] - a[s1, j - 1]) / ndu[pk + 1, rk + j]
                d += a[s2, j] * ndu[rk + j, pk]
            if r <= pk:
                a[s2, kk] = -a[s1, kk - 1] / ndu[pk + 1, r]
                d += a[s2, kk] * ndu[r, pk]
            ders[kk, r] = d
            s1, s2 = s2, s1
    fac = float(k)
    for kk in range(1, k + 1):
        for j in range(k + 1):
            ders[kk, j] *= fac
        fac *= k - kk


@njit
def bspline_pieces(t, c, k):
    """The B-spline of degree ``k`` with knots ``t`` and control points ``c``
    (n, 3) as polynomial pieces, one per non-empty knot span of its domain
    ``[t[k], t[n]]``: ``(breaks (m + 1,), coefs (m, k + 1, 3))`` in ascending
    powers of ``tau - breaks[j]`` (Taylor coefficients at the span's start)."""
    n = c.shape[0]
    m = 0
    for span in range(k, n):
        if t[span + 1] > t[span]:
            m += 1
    breaks = np.empty(m + 1)
    coefs = np.zeros((m, k + 1, 3))
    ders = np.empty((k + 1, k + 1))
    ndu = np.empty((k + 1, k + 1))
    left = np.empty(k + 1)
    right = np.empty(k + 1)
    a = np.empty((2, k + 1))
    window = np.full(2 * k, np.nan)  # knots around the last span, from its start
    j = 0
    for span in range(k, n):
        if not t[span + 1] > t[span]:
            continue
        u = t[span]
        breaks[j] = u
        # The same knots around the span (uniform knots): the same derivatives.
        same = True
        tol = 1e-12 * (t[span + 1] - u)
        for q in range(2 * k):
            d = t[span - k + 1 + q] - u
            if not abs(d - window[q]) <= tol:
                same = False
            window[q] = d
        if not same:
            _basis_derivatives(t, k, span, u, ders, ndu, left, right, a)
        fact = 1.0
        for r in range(k + 1):
            if r > 0:
                fact *= r
            for q in range(k + 1):
                for ax in range(3):
                    coefs[j, r, ax] += ders[r, q] * c[span - k + q, ax] / fact
        j += 1
    breaks[m] = t[n]
    return breaks, coefs


@njit
def _ratios(b, alpha, lim2, c1, c2, a_max):
    """Speed squared over its limit squared, and the worst axis' acceleration over
    its limit, for ``beta = b``, ``tau_ddot = alpha`` where the path's derivatives
    are ``c1``, ``c2`` (Eqs. 23, 26): ``(v2, acc, axis)``."""
    v2 = (c1[0] ** 2 + c1[1] ** 2 + c1[2] ** 2) * b / lim2
    worst = 0.0
    wax = 0
    for ax in range(3):
        r = abs(c1[ax] * alpha + c2[ax] * b) / a_max[ax]
        if r > worst:
            worst = r
            wax = ax
    return v2, worst, wax


@njit
def audit(beta, tau, offsets, frac, cd1, cd2, vlim, a_max, beta_max, breaks, coefs, tol,
          bad_interval, bad_frac):
    """The limits at ``beta``: at every node and check point, and at the midpoint of
    every gap between check points (the path evaluated there).

    Returns ``(n_bad, speed, acc, axis, point)``: the midpoints where a limit is
    broken by more than ``tol`` go to ``bad_interval``, ``bad_frac`` (``n_bad`` of
    them); ``speed`` is the largest ``beta / beta_max`` at the nodes and speed
    squared over its limit squared at the check points; ``acc`` the largest
    acceleration over its limit at the check points, on ``axis`` at check point
    ``point``.
    """
    n = offsets.shape[0] - 1
    h = tau[1] - tau[0]
    inv2h = 0.5 / h
    speed = 0.0
    for i in range(n + 1):
        if beta_max[i] > 0.0:
            speed = max(speed, beta[i] / beta_max[i])
        elif beta[i] > 0.0:
            speed = np.inf
    acc = 0.0
    axis = 0
    point = 0
    n_bad = 0
    c1 = np.empty(3)
    c2 = np.empty(3)
    lim_v = (1.0 + tol) ** 2
    lim_a = 1.0 + tol
    j = 0
    t_lo = breaks[0]
    t_hi = breaks[breaks.shape[0] - 1]
    for i in range(n):
        alpha = (beta[i + 1] - beta[i]) * inv2h
        for q in range(offsets[i], offsets[i + 1]):
            f = frac[q]
            b = (1.0 - f) * beta[i] + f * beta[i + 1]
            lim2 = (1.0 - f) * vlim[i] ** 2 + f * vlim[i + 1] ** 2
            v2, r, ax = _ratios(b, alpha, lim2, cd1[q], cd2[q], a_max)
            speed = max(speed, v2)
            if r > acc:
                acc = r
                axis = ax
                point = q
            if q + 1 < offsets[i + 1]:
                fm = 0.5 * (f + frac[q + 1])
                t = min(max(tau[i] + fm * h, t_lo), t_hi)
                j = _piece(breaks, t, j)
                for a in range(3):
                    _, c1[a], c2[a] = _horner(coefs, j, t - breaks[j], a)
                bm = (1.0 - fm) * beta[i] + fm * beta[i + 1]
                lm = (1.0 - fm) * vlim[i] ** 2 + fm * vlim[i + 1] ** 2
                v2, r, _ = _ratios(bm, alpha, lm, c1, c2, a_max)
                if v2 > lim_v or r > lim_a:
                    bad_interval[n_bad] = i
                    bad_frac[n_bad] = fm
                    n_bad += 1
    return n_bad, speed, acc, axis, point


@njit
def piece_edges(breaks, t0, t1):
    """``t0``, the distinct piece ends strictly between ``t0`` and ``t1`` (``breaks``
    sorted), ``t1``."""
    out = np.empty(breaks.shape[0] + 2)
    out[0] = t0
    m = 1
    for b in breaks:
        if t0 < b < t1 and b > out[m - 1]:
            out[m] = b
            m += 1
    out[m] = t1
    return out[: m + 1].copy()


@njit
def time_map(tau, beta):
    """The time mapping of ``beta`` on ``tau`` (paper Eqs. 18-20): ``(beta_out, t,
    alpha)``, the non-negative ``beta``, the real time of every node (each interval
    lasts ``2 h / (sqrt(beta_i) + sqrt(beta_{i+1}))``) and every interval's
    ``tau_ddot``."""
    n = tau.shape[0]
    beta_out = np.empty(n)
    t = np.empty(n)
    alpha = np.empty(max(n - 1, 0))
    for i in range(n):
        beta_out[i] = max(beta[i], 0.0)
    t[0] = 0.0
    for i in range(n - 1):
        h = tau[i + 1] - tau[i]
        t[i + 1] = t[i] + 2.0 * h / (np.sqrt(beta_out[i]) + np.sqrt(beta_out[i + 1]))
        alpha[i] = (beta_out[i + 1] - beta_out[i]) / (2.0 * h)
    return beta_out, t, alpha


@njit
def with_points(tau, offsets, frac, interval, more):
    """The check points ``offsets``, ``frac`` with the points ``(interval, more)``
    added, sorted by interval and fraction; a point closer than 1e-12 (in
    fractions of an interval) to the previous one of its interval is dropped.
    Returns ``(offsets, frac, at)`` as :func:`check_points` does."""
    n = offsets.shape[0] - 1
    m0 = frac.shape[0]
    total = m0 + more.shape[0]
    key = np.empty(total)
    idx = np.empty(total, np.int64)
    fr = np.empty(total)
    for i in range(n):
        for q in range(offsets[i], offsets[i + 1]):
            idx[q] = i
            fr[q] = frac[q]
    for q in range(more.shape[0]):
        idx[m0 + q] = interval[q]
        fr[m0 + q] = more[q]
    for q in range(total):
        key[q] = idx[q] * 2.0 + fr[q]
    order = np.argsort(key, kind="mergesort")
    h = tau[1] - tau[0]
    new_off = np.zeros(n + 1, np.int64)
    new_frac = np.empty(total)
    at = np.empty(total)
    out = 0
    for r in range(total):
        q = order[r]
        if out > 0 and key[q] - key[order[r - 1]] <= 1e-12:
            continue
        new_frac[out] = fr[q]
        at[out] = tau[idx[q]] + fr[q] * h
        new_off[idx[q] + 1] += 1
        out += 1
    for i in range(n):
        new_off[i + 1] += new_off[i]
    return new_off, new_frac[:out].copy(), at[:out].copy()


@njit
def sample(breaks, coefs, t0, t1, tau, parts, piece_parts, d1, vlim, still, cap_factor,
           interval, more):
    """The check points of the grid ``tau`` (see :func:`check_points`; the pieces'
    ends from ``breaks`` within ``[t0, t1]``) and the points ``(interval, more)``
    added after earlier rounds (:func:`with_points`), the path's derivatives
    there, and the speed bound of every node (:func:`beta_bounds`).

    Returns ``(offsets, frac, cd1, cd2, beta_max, moving)``; ``moving``: some node or
    check point has a component of ``sigma'`` above ``still``.
    """
    edges = piece_edges(breaks, t0, t1)
    offsets, frac, at = check_points(tau, edges, parts, piece_parts)
    if more.shape[0]:
        offsets, frac, at = with_points(tau, offsets, frac, interval, more)
    m = at.shape[0]
    pos = np.empty((m, 3))
    cd1 = np.empty((m, 3))
    cd2 = np.empty((m, 3))
    eval_pieces(breaks, coefs, at, pos, cd1, cd2)
    beta_max = np.empty(tau.shape[0])
    beta_bounds(d1, vlim, still, cap_factor, beta_max)
    moving = False
    for arr in (d1, cd1):
        for q in range(arr.shape[0]):
            for ax in range(3):
                if abs(arr[q, ax]) > still:
                    moving = True
    return offsets, frac, cd1, cd2, beta_max, moving
