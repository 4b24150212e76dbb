"""A primal-dual interior-point method (Mehrotra predictor-corrector) for the
ROTA problem on beta alone, with one O(N) tridiagonal Newton solve per step.

Problem (paper Eqs. 21-26 with zeta and gamma eliminated)::

    min  sum_i 2h / (sqrt(b_i) + sqrt(b_{i+1})) + w sum_i (b_{i+1} - b_i)^2,
         w = lambda / 4h  (lambda sum alpha_i^2 h, alpha_i = (b_{i+1} - b_i) / 2h)
    s.t. a_r b_{k_r} + c_r b_{k_r + 1} <= 1   (every row r)
         lo_i < b_i <= hi_i,  b_i = value_i where fixed.

The objective is convex (1 / (concave, positive)) and couples neighbours only,
every row touches two neighbours, so the Newton matrix
``H + G' (Z/S) G + bounds`` is tridiagonal and symmetric positive definite.
Rows have slacks (an infeasible start is fine); the lower bounds are kept
strictly feasible so the objective stays defined.
"""

import numpy as np

from rota.kernels._njit import njit

SOLVED, MAX_ITER, NUMERICAL = 0, 1, 2


@njit
def _objective(h, w, x):
    n = x.shape[0]
    total = 0.0
    for i in range(n - 1):
        total += 2.0 * h / (np.sqrt(x[i]) + np.sqrt(x[i + 1]))
        total += w * (x[i + 1] - x[i]) ** 2
    return total


@njit
def _derivatives(h, w, x, fixed, g, hd, he):
    """Gradient ``g`` and tridiagonal Hessian (``hd`` diagonal, ``he`` upper) of f;
    returns f."""
    n = x.shape[0]
    total = 0.0
    for i in range(n):
        g[i] = 0.0
        hd[i] = 0.0
    for i in range(n - 1):
        rx = np.sqrt(x[i])
        ry = np.sqrt(x[i + 1])
        s = rx + ry
        s2 = s * s
        s3 = s2 * s
        total += 2.0 * h / s
        e = 0.0
        if rx > 0.0:
            g[i] += -h / (s2 * rx)
            hd[i] += h * (1.0 / (s3 * x[i]) + 0.5 / (s2 * x[i] * rx))
        if ry > 0.0:
            g[i + 1] += -h / (s2 * ry)
            hd[i + 1] += h * (1.0 / (s3 * x[i + 1]) + 0.5 / (s2 * x[i + 1] * ry))
        if rx > 0.0 and ry > 0.0:
            e = h / (s3 * rx * ry)
        d = x[i + 1] - x[i]
        total += w * d * d
        g[i] += -2.0 * w * d
        g[i + 1] += 2.0 * w * d
        hd[i] += 2.0 * w
        hd[i + 1] += 2.0 * w
        he[i] = e - 2.0 * w
    for i in range(n):
        if fixed[i]:
            g[i] = 0.0
    return total


@njit
def _factor(md, me, fixed, ld, ll):
    """LDL' of the tridiagonal matrix (fixed nodes: identity rows and columns)."""
    n = md.shape[0]
    for i in range(n):
        d = 1.0 if fixed[i] else md[i]
        if i > 0:
            e = 0.0 if (fixed[i] or fixed[i - 1]) else me[i - 1]
            ll[i - 1] = e / ld[i - 1]
            d -= ll[i - 1] * e
        if not d > 0.0:
            return False
        ld[i] = d
    return True


@njit
def _solve(ld, ll, fixed, rhs, out):
    n = ld.shape[0]
    for i in range(n):
        v = 0.0 if fixed[i] else rhs[i]
        if i > 0:
            v -= ll[i - 1] * out[i - 1]
        out[i] = v
    for i in range(n):
        out[i] /= ld[i]
    for i in range(n - 2, -1, -1):
        out[i] -= ll[i] * out[i + 1]


@njit
def _rows(lo, hi, fixed, rk, ra, rc):
    """The rows, then the upper bound of every free node as a row of its own
    interval (the last node's in the last interval)."""
    n = lo.shape[0]
    m0 = rk.shape[0]
    m = m0
    for i in range(n):
        if not fixed[i] and np.isfinite(hi[i]):
            m += 1
    k = np.empty(m, np.int64)
    a = np.empty(m)
    c = np.empty(m)
    k[:m0] = rk
    a[:m0] = ra
    c[:m0] = rc
    r = m0
    for i in range(n):
        if not fixed[i] and np.isfinite(hi[i]):
            if i < n - 1:
                k[r] = i
                a[r] = 1.0 / hi[i]
                c[r] = 0.0
            else:
                k[r] = i - 1
                a[r] = 0.0
                c[r] = 1.0 / hi[i]
            r += 1
    return k, a, c


@njit
def start_point(lo, hi, fixed, value, start, smooth, share, cap, x):
    """The starting point into ``x``: ``share`` times ``start`` (within the bounds)
    on free nodes, at most ``cap`` times its median there when ``smooth``, and at
    least a thousandth of its largest value; ``value`` on fixed nodes."""
    n = x.shape[0]
    top = np.empty(n)
    k = 0
    for i in range(n):
        x[i] = min(start[i], hi[i])
        if not fixed[i]:
            top[k] = x[i]
            k += 1
    limit = cap * np.median(top[:k]) if k > 0 else 0.0
    largest = 0.0
    for i in range(n):
        if smooth and limit > 0.0:
            x[i] = min(x[i], limit)
        if not fixed[i]:
            largest = max(largest, x[i])
    floor = max(1e-3 * share * largest, 1e-12)
    for i in range(n):
        x[i] = value[i] if fixed[i] else max(share * x[i], floor, lo[i] + 1e-12)


@njit
def ipm_solve(h, lam, lo, hi, fixed, value, start, share, cap, rk, ra, rc, tol, max_iter, x):
    """Solve into ``x``, from the point :func:`start_point` makes of ``start``,
    ``share`` and ``cap`` (with the cap when ``lam > 0``); on success fixed nodes
    hold their value exactly and no node is negative.

    Every step makes three passes over the rows: residuals with the Newton matrix
    and the predictor's right-hand side; the predictor's directions with what the
    corrector needs (Mehrotra's centring from closed-form sums); the corrected
    directions. The step of the rows is applied at the start of the next pass.
    The centring target has a floor below the stopping test's gap.

    Returns ``(status, iterations, objective)``; ``x`` holds the solution.
    """
    n = x.shape[0]
    w = lam / (4.0 * h)
    start_point(lo, hi, fixed, value, start, lam > 0.0, share, cap, x)
    k, a, c = _rows(lo, hi, fixed, rk, ra, rc)
    m = k.shape[0]
    free = 0
    for i in range(n):
        if not fixed[i]:
            free += 1
    g = np.empty(n)
    hd = np.empty(n)
    he = np.empty(max(n - 1, 1))
    md = np.empty(n)
    me = np.empty(max(n - 1, 1))
    ld = np.empty(n)
    ll = np.empty(max(n - 1, 1))
    rhs = np.empty(n)
    rd = np.empty(n)
    q1 = np.empty(n)
    q2 = np.empty(n)
    dx = np.empty(n)
    dxc = np.empty(n)
    xl = np.ones(n)  # x - lo on free nodes (1 on fixed ones)
    zl = np.zeros(n)
    dzl = np.zeros(n)
    s = np.empty(m)
    z = np.empty(m)
    rp = np.empty(m)
    ds = np.zeros(m)
    dz = np.zeros(m)

    obj = _derivatives(h, w, x, fixed, g, hd, he)
    scale = 0.0
    for i in range(n):
        if not fixed[i]:
            scale += abs(g[i]) * max(x[i] - lo[i], 1e-12)
    mu0 = max(scale / max(free, 1), 1e-12)
    for r in range(m):
        i = k[r]
        s[r] = max(1.0 - a[r] * x[i] - c[r] * x[i + 1], 0.1)
        z[r] = mu0 / s[r]
    for i in range(n):
        if not fixed[i]:
            xl[i] = x[i] - lo[i]
            zl[i] = mu0 / xl[i]
    n_comp = m + free
    status = MAX_ITER
    it = 0
    step = 0.0  # the rows' pending step
    while it < max_iter:
        it += 1
        if it > 1:
            obj = _derivatives(h, w, x, fixed, g, hd, he)
        # Pass 1 over the rows: residuals, Newton matrix, predictor right-hand side.
        for i in range(n):
            md[i] = hd[i]
            rd[i] = g[i]
            rhs[i] = -g[i]
        for i in range(n - 1):
            me[i] = he[i]
        pres = 0.0
        gap = 0.0
        for r in range(m):
            i = k[r]
            ar = a[r]
            cr = c[r]
            sr = s[r] + step * ds[r]
            zr = z[r] + step * dz[r]
            s[r] = sr
            z[r] = zr
            res = ar * x[i] + cr * x[i + 1] + sr - 1.0
            rp[r] = res
            pres = max(pres, abs(res))
            gap += sr * zr
            d = zr / sr
            md[i] += d * ar * ar
            md[i + 1] += d * cr * cr
            me[i] += d * ar * cr
            rd[i] += ar * zr
            rd[i + 1] += cr * zr
            t = d * res
            rhs[i] -= ar * t
            rhs[i + 1] -= cr * t
        gmax = 0.0
        dres = 0.0
        for i in range(n):
            if fixed[i]:
                md[i] = 1.0
                rhs[i] = 0.0
            else:
                gmax = max(gmax, abs(g[i]))
                dres = max(dres, abs(rd[i] - zl[i]))
                gap += xl[i] * zl[i]
                md[i] += zl[i] / xl[i]
        if (pres <= tol and dres <= tol * max(1.0, gmax)
                and gap <= tol * max(1.0, abs(obj))):
            status = SOLVED
            break
        if not _factor(md, me, fixed, ld, ll):
            status = NUMERICAL
            break
        _solve(ld, ll, fixed, rhs, dx)
        mu = gap / max(n_comp, 1)
        # Pass 2: predictor directions; the sums that give its complementarity at
        # any step (Mehrotra's centring) and the corrector's right-hand side.
        for i in range(n):
            q1[i] = 0.0
            q2[i] = 0.0
        ap = 1.0
        ad = 1.0
        s_zds = 0.0
        s_sdz = 0.0
        s_dd = 0.0
        for r in range(m):
            i = k[r]
            ar = a[r]
            cr = c[r]
            sr = s[r]
            zr = z[r]
            dsr = -rp[r] - ar * dx[i] - cr * dx[i + 1]
            dzr = -zr - zr * dsr / sr
            ds[r] = dsr
            dz[r] = dzr
            if dsr < 0.0:
                ap = min(ap, -sr / dsr)
            if dzr < 0.0:
                ad = min(ad, -zr / dzr)
            s_zds += zr * dsr
            s_sdz += sr * dzr
            s_dd += dsr * dzr
            u = dsr * dzr / sr
            v = 1.0 / sr
            q1[i] += ar * u
            q1[i + 1] += cr * u
            q2[i] += ar * v
            q2[i + 1] += cr * v
        for i in range(n):
            if not fixed[i]:
                dzl[i] = -zl[i] - zl[i] * dx[i] / xl[i]
                if dx[i] < 0.0:
                    ap = min(ap, -xl[i] / dx[i])
                if dzl[i] < 0.0:
                    ad = min(ad, -zl[i] / dzl[i])
                s_zds += zl[i] * dx[i]
                s_sdz += xl[i] * dzl[i]
                s_dd += dx[i] * dzl[i]
        mu_aff = (gap + ap * s_zds + ad * s_sdz + ap * ad * s_dd) / max(n_comp, 1)
        sigma = min(1.0, (max(mu_aff, 0.0) / mu) ** 3)
        # The centring target stays above a tenth of the gap the stopping test asks
        # for: a gap driven to rounding level makes z/s of the active rows so large
        # that the Newton solve can no longer reduce the dual residual (at lambda = 0
        # one stayed near 1e-7 for 160 steps).
        smu = max(sigma * mu, 0.1 * tol * max(1.0, abs(obj)) / max(n_comp, 1))
        # Corrector: the same matrix, the second-order and centring terms only.
        for i in range(n):
            if fixed[i]:
                rhs[i] = 0.0
            else:
                rhs[i] = q1[i] - smu * q2[i] - (dx[i] * dzl[i] - smu) / xl[i]
        _solve(ld, ll, fixed, rhs, dxc)
        # Lower bounds: corrected directions and the largest steps.
        step_p = 1.0
        step_d = 1.0
        for i in range(n):
            if not fixed[i]:
                corr = (dx[i] * dzl[i] - smu) / xl[i]
                dx[i] += dxc[i]
                dzl[i] = -zl[i] - corr - zl[i] * dx[i] / xl[i]
                if dx[i] < 0.0:
                    step_p = min(step_p, -0.99 * xl[i] / dx[i])
                if dzl[i] < 0.0:
                    step_d = min(step_d, -0.99 * zl[i] / dzl[i])
            else:
                dx[i] = 0.0
        # Pass 3: corrected directions of the rows and the largest steps.
        for r in range(m):
            i = k[r]
            sr = s[r]
            zr = z[r]
            dsr = -rp[r] - a[r] * dx[i] - c[r] * dx[i + 1]
            dzr = -zr - (ds[r] * dz[r] - smu) / sr - zr * dsr / sr
            ds[r] = dsr
            dz[r] = dzr
            if dsr < 0.0:
                step_p = min(step_p, -0.99 * sr / dsr)
            if dzr < 0.0:
                step_d = min(step_d, -0.99 * zr / dzr)
        step = min(step_p, step_d)  # one step: the objective is not linear
        if not (step > 1e-12) or not np.isfinite(step):
            status = NUMERICAL
            break
        for i in range(n):
            if not fixed[i]:
                x[i] += step * dx[i]
                xl[i] = x[i] - lo[i]
                zl[i] += step * dzl[i]
    for i in range(n):
        if not np.isfinite(x[i]) and status == SOLVED:
            status = NUMERICAL
        x[i] = max(x[i], 0.0)
    return status, it, _objective(h, w, x)

