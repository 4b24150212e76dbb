"""Reachability on the chain (TOPP-RA style, Pham & Pham 2018): the interval of
beta from which the end can still be reached within every limit (backward), the
interval reachable from the start (forward), and the greedy fastest profile.

Each interval's rows bound a convex polygon in ``(beta_i, beta_{i+1})``; a pass
clips a rectangle (the bounds of the two nodes) by them and projects the
polygon on one axis, so every answer is exact up to rounding (``EPS``).
"""

import numpy as np

from rota.kernels._njit import njit

#: Relative slack of the half-planes, for rounding only.
EPS = 1e-12


@njit
def _polygon(x_lo, x_hi, y_lo, y_hi, r0, r1, ra, rc, bx, by):
    """Clip the rectangle ``[x_lo, x_hi] x [y_lo, y_hi]`` by the half-planes
    ``ra[r] x + rc[r] y <= 1`` of rows ``r0 .. r1 - 1`` (Sutherland-Hodgman),
    alternating between the two rows of the buffers ``bx, by`` (2, width).

    Returns ``(count, failing row, s)``: the polygon is ``bx[s, :count], by[s,
    :count]``; count 0 (empty) names the row that emptied it, else row -1.
    """
    bx[0, 0] = x_lo
    by[0, 0] = y_lo
    bx[0, 1] = x_hi
    by[0, 1] = y_lo
    bx[0, 2] = x_hi
    by[0, 2] = y_hi
    bx[0, 3] = x_lo
    by[0, 3] = y_hi
    cnt = 4
    s = 0
    lim = 1.0 + EPS
    for r in range(r0, r1):
        a = ra[r]
        c = rc[r]
        cuts = False  # most rows do not cut: no copy then
        for q in range(cnt):
            if a * bx[s, q] + c * by[s, q] > lim:
                cuts = True
                break
        if not cuts:
            continue
        d = 1 - s
        out = 0
        vp = a * bx[s, cnt - 1] + c * by[s, cnt - 1]
        for q in range(cnt):
            p = q - 1 if q > 0 else cnt - 1
            vq = a * bx[s, q] + c * by[s, q]
            in_q = vq <= lim
            if in_q != (vp <= lim):
                # From the vertex inside: the one outside may be far away (a bound
                # of 1e15 where the path nearly stops), and interpolating from it
                # would round the crossing to its ulp.
                i, o, vi, vo = (q, p, vq, vp) if in_q else (p, q, vp, vq)
                t = min(max((1.0 - vi) / (vo - vi), 0.0), 1.0)
                bx[d, out] = bx[s, i] + t * (bx[s, o] - bx[s, i])
                by[d, out] = by[s, i] + t * (by[s, o] - by[s, i])
                out += 1
            if in_q:
                bx[d, out] = bx[s, q]
                by[d, out] = by[s, q]
                out += 1
            vp = vq
        cnt = out
        s = d
        if cnt == 0:
            return 0, r, s
    return cnt, -1, s


@njit
def backward(lo, hi, fixed, value, rptr, ra, rc, kl, ku):
    """Controllable sets ``[kl_i, ku_i]`` into ``kl``, ``ku``.

    Returns ``(node, row)``: ``(-1, -1)`` when every set is non-empty, else the
    node whose set is empty and the row that emptied it (-1: its bounds).
    """
    n = lo.shape[0]
    width = 2 * (rptr[n - 1] - rptr[0]) + 8
    bx = np.empty((2, width))
    by = np.empty((2, width))
    last = n - 1
    kl[last] = value[last] if fixed[last] else lo[last]
    ku[last] = value[last] if fixed[last] else hi[last]
    if kl[last] > hi[last] * (1 + EPS) or ku[last] < lo[last]:
        return last, -1
    for i in range(n - 2, -1, -1):
        x_lo = value[i] if fixed[i] else lo[i]
        x_hi = value[i] if fixed[i] else hi[i]
        if x_lo > hi[i] * (1 + EPS):
            return i, -1
        cnt, bad, s = _polygon(x_lo, x_hi, kl[i + 1], ku[i + 1], rptr[i], rptr[i + 1], ra,
                               rc, bx, by)
        if cnt == 0:
            return i, bad
        mn = bx[s, 0]
        mx = bx[s, 0]
        for q in range(1, cnt):
            mn = min(mn, bx[s, q])
            mx = max(mx, bx[s, q])
        kl[i] = max(mn, x_lo)
        ku[i] = min(mx, x_hi)
        if kl[i] > ku[i]:
            kl[i] = ku[i]
    return -1, -1


@njit
def forward_greedy(kl, ku, fixed, value, rptr, ra, rc, x):
    """The greedy profile: at every node the largest beta reachable from the
    previous one inside the controllable sets (time-optimal where the feasible
    set has a largest element). Returns the first node where rounding left no
    room (-1: none)."""
    n = kl.shape[0]
    x[0] = value[0] if fixed[0] else ku[0]
    worst = -1
    for i in range(n - 1):
        y_lo = kl[i + 1]
        y_hi = ku[i + 1]
        for r in range(rptr[i], rptr[i + 1]):
            rhs = 1.0 - ra[r] * x[i]
            c = rc[r]
            if c > 0.0:
                y_hi = min(y_hi, rhs / c)
            elif c < 0.0:
                y_lo = max(y_lo, rhs / c)
        if fixed[i + 1]:
            x[i + 1] = value[i + 1]
        elif y_hi >= y_lo:
            x[i + 1] = y_hi
        else:
            # Rounding left no room: stay inside the controllable set. Above it an
            # error of 1e-10 grows node by node along a deceleration (each row
            # multiplies it by a / |c|) and without bound on a row with c near 0.
            x[i + 1] = min(y_lo, ku[i + 1])
            if worst < 0 and y_lo - y_hi > 1e-9 * max(1.0, y_lo):
                worst = i + 1
    return worst


@njit
def forward_reachable(kl, ku, fixed, value, rptr, ra, rc, rl, ru):
    """Sets ``[rl_i, ru_i]`` of beta reachable from the start inside ``[kl, ku]``
    (the controllable sets, or just the bounds). Returns ``(node, row)``: the first
    node that cannot be reached and the row that cut it off (-1: its own bounds,
    ``rl`` at that node then holds the lowest beta the rows allow), or
    ``(-1, -1)``."""
    n = kl.shape[0]
    width = 2 * (rptr[n - 1] - rptr[0]) + 8
    bx = np.empty((2, width))
    by = np.empty((2, width))
    rl[0] = value[0] if fixed[0] else kl[0]
    ru[0] = value[0] if fixed[0] else ku[0]
    if rl[0] > ku[0] * (1 + EPS):
        return 0, -1
    for i in range(n - 1):
        y_lo = value[i + 1] if fixed[i + 1] else kl[i + 1]
        y_hi = value[i + 1] if fixed[i + 1] else ku[i + 1]
        if y_lo > ku[i + 1] * (1 + EPS) + 1e-300:
            return i + 1, -1
        cnt, bad, s = _polygon(rl[i], ru[i], y_lo, y_hi, rptr[i], rptr[i + 1], ra, rc, bx, by)
        if cnt == 0:
            # What the rows alone allow at the node that cannot be reached: its
            # lowest reachable beta goes to rl (inf when none), for the diagnosis.
            rl[i + 1] = np.inf
            big = 1e3 * max(1.0, ru[i], ku[i + 1])
            cnt2, _, s = _polygon(rl[i], ru[i], 0.0, big, rptr[i], rptr[i + 1], ra, rc, bx, by)
            for q in range(cnt2):
                rl[i + 1] = min(rl[i + 1], by[s, q])
            # The rows alone leave room: the node's own bounds (its speed limit, or
            # its fixed value) cut it off.
            return i + 1, (-1 if cnt2 > 0 else bad)
        mn = by[s, 0]
        mx = by[s, 0]
        for q in range(1, cnt):
            mn = min(mn, by[s, q])
            mx = max(mx, by[s, q])
        rl[i + 1] = max(mn, kl[i + 1])
        ru[i + 1] = min(mx, ku[i + 1])
        if rl[i + 1] > ru[i + 1]:
            rl[i + 1] = ru[i + 1]
    return -1, -1


@njit
def passes(lo, hi, fixed, value, rptr, ra, rc, certify, tol, kl, ku, greedy):
    """The backward pass, then (when feasible) the greedy profile into ``greedy``
    (zeros otherwise); with ``certify`` also the forward reachable sets, to tell
    whether the greedy profile attains the top of every one of them (within the
    relative ``tol``): then it is the largest feasible beta, time-optimal.

    Returns ``(node, row, exact)``: where the backward pass failed (see
    :func:`backward`) and whether the greedy profile is certified.
    """
    n = lo.shape[0]
    node, row = backward(lo, hi, fixed, value, rptr, ra, rc, kl, ku)
    for i in range(n):
        greedy[i] = 0.0
    if node >= 0:
        return node, row, False
    forward_greedy(kl, ku, fixed, value, rptr, ra, rc, greedy)
    if not certify:
        return node, row, False
    rl = np.empty(n)
    ru = np.empty(n)
    node_r, _ = forward_reachable(kl, ku, fixed, value, rptr, ra, rc, rl, ru)
    if node_r >= 0:
        return node, row, False
    for i in range(n):
        if not greedy[i] >= ru[i] * (1.0 - tol):
            return node, row, False
    return node, row, True


@njit
def tighten(hi, fixed, value, ku):
    """The bounds of the free nodes tightened to the controllable sets ``ku`` (exact);
    a node whose set is {0} is fixed at rest. Returns ``(hi, fixed, value, ok)``,
    new arrays; ``ok`` is False when two neighbours must both stand still."""
    n = hi.shape[0]
    hi_t = hi.copy()
    fixed_t = fixed.copy()
    value_t = value.copy()
    still = False
    for i in range(n):
        if not fixed[i]:
            hi_t[i] = min(hi[i], ku[i])
            if hi_t[i] <= 0.0:
                fixed_t[i] = True
                value_t[i] = 0.0
                still = True
    if still:
        for i in range(n - 1):
            if (fixed_t[i] and value_t[i] <= 0.0) and (fixed_t[i + 1] and value_t[i + 1] <= 0.0):
                return hi_t, fixed_t, value_t, False
    return hi_t, fixed_t, value_t, True
