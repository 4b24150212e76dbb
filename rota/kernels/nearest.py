"""Exact nearest occupied voxel centre, by a search over bricks of voxels.

The occupied voxel centres are grouped into cubic bricks of ``B`` voxels a side
(counting sort by brick, :func:`bricks_build`); each brick keeps the bounding box
of its centres. A query (:func:`bricks_query`) visits the bricks in rings of
growing Chebyshev distance around the point's brick and stops when no further
ring can hold a closer centre; a brick whose box is no closer than the best centre
found so far is skipped whole. Every centre that could be closer is measured, so
the answer is the exact nearest centre (ties aside), never a farther one. Along a
path the previous point's obstacle is a good first bound (it is an occupied
centre, so starting from it changes nothing but the work).
"""

import numpy as np

from rota.kernels._njit import njit


@njit
def bricks_build(idx, centres, lo, dims, size):
    """Sort the centres by brick. ``idx`` (n, 3) voxel indices, ``lo`` (3,) the
    lowest index, ``dims`` (3,) bricks per axis, ``size`` voxels per brick side.

    Returns ``(start, pts, box)``: the centres of brick ``k`` (linear id
    ``(bx * dims[1] + by) * dims[2] + bz``) are ``pts[start[k]:start[k + 1]]``;
    ``box[k]`` is their bounding box ``(xmin, ymin, zmin, xmax, ymax, zmax)``.
    """
    n = idx.shape[0]
    nb = dims[0] * dims[1] * dims[2]
    key = np.empty(n, np.int64)
    count = np.zeros(nb + 1, np.int64)
    for q in range(n):
        bx = (idx[q, 0] - lo[0]) // size
        by = (idx[q, 1] - lo[1]) // size
        bz = (idx[q, 2] - lo[2]) // size
        k = (bx * dims[1] + by) * dims[2] + bz
        key[q] = k
        count[k + 1] += 1
    start = np.empty(nb + 1, np.int64)
    start[0] = 0
    for k in range(nb):
        start[k + 1] = start[k] + count[k + 1]
    fill = start[:-1].copy()
    pts = np.empty((n, 3))
    box = np.empty((nb, 6))
    for k in range(nb):
        for a in range(3):
            box[k, a] = np.inf
            box[k, 3 + a] = -np.inf
    for q in range(n):
        k = key[q]
        j = fill[k]
        fill[k] += 1
        for a in range(3):
            c = centres[q, a]
            pts[j, a] = c
            box[k, a] = min(box[k, a], c)
            box[k, 3 + a] = max(box[k, 3 + a], c)
    return start, pts, box


@njit
def _axis_gap(u, b, off, size):
    """Lower bound (voxels) on the distance along one axis from ``u`` (in brick
    ``b``) to any point of brick ``b + off``."""
    if off > 0:
        return (off - 1) * size + ((b + 1) * size - u)
    if off < 0:
        return (-off - 1) * size + (u - b * size)
    return 0.0


@njit
def bricks_query(points, origin, res, lo, dims, size, start, pts, box, bound2, dist, obst):
    """Nearest centre to each of ``points`` (m, 3) closer than ``sqrt(bound2)``:
    its distance into ``dist`` and coordinates into ``obst`` (``inf`` / NaN where
    none). Returns how many points found one."""
    found = 0
    if pts.shape[0] == 0:  # no centres: nothing is near
        for q in range(points.shape[0]):
            dist[q] = np.inf
            obst[q, 0] = obst[q, 1] = obst[q, 2] = np.nan
        return found
    have_prev = False
    px = 0.0
    py = 0.0
    pz = 0.0
    for q in range(points.shape[0]):
        x = points[q, 0]
        y = points[q, 1]
        z = points[q, 2]
        best2 = bound2
        bx_ = np.nan
        by_ = np.nan
        bz_ = np.nan
        if have_prev:
            d2 = (x - px) ** 2 + (y - py) ** 2 + (z - pz) ** 2
            if d2 < best2:
                best2 = d2
                bx_ = px
                by_ = py
                bz_ = pz
        # the point in voxel units from the lowest index, and its brick
        ux = (x - origin[0]) / res - lo[0]
        uy = (y - origin[1]) / res - lo[1]
        uz = (z - origin[2]) / res - lo[2]
        cx = int(np.floor(ux / size))
        cy = int(np.floor(uy / size))
        cz = int(np.floor(uz / size))
        # rings beyond this one hold no brick of the grid
        last = max(max(abs(cx), abs(dims[0] - 1 - cx)),
                   max(max(abs(cy), abs(dims[1] - 1 - cy)), max(abs(cz), abs(dims[2] - 1 - cz))))
        edge = min(min(min(ux - cx * size, (cx + 1) * size - ux),
                       min(uy - cy * size, (cy + 1) * size - uy)),
                   min(uz - cz * size, (cz + 1) * size - uz))
        inv_res2 = 1.0 / (res * res)
        for ring in range(last + 1):
            if ring > 0:
                lb = ((ring - 1) * size + edge)
                if lb * lb >= best2 * inv_res2:
                    break
            reach2 = best2 * inv_res2  # squared search radius in voxels
            for dz in range(-ring, ring + 1):
                kz = cz + dz
                if kz < 0 or kz >= dims[2]:
                    continue
                gz = _axis_gap(uz, cz, dz, size)
                if gz * gz >= reach2:
                    continue
                for dy in range(-ring, ring + 1):
                    ky = cy + dy
                    if ky < 0 or ky >= dims[1]:
                        continue
                    gy = _axis_gap(uy, cy, dy, size)
                    if gz * gz + gy * gy >= reach2:
                        continue
                    full = dz == ring or dz == -ring or dy == ring or dy == -ring
                    step = 1 if (full or ring == 0) else 2 * ring
                    for dx in range(-ring, ring + 1, step):
                        kx = cx + dx
                        if kx < 0 or kx >= dims[0]:
                            continue
                        k = (kx * dims[1] + ky) * dims[2] + kz
                        s0 = start[k]
                        s1 = start[k + 1]
                        if s0 == s1:
                            continue
                        ex = max(box[k, 0] - x, 0.0, x - box[k, 3])
                        ey = max(box[k, 1] - y, 0.0, y - box[k, 4])
                        ez = max(box[k, 2] - z, 0.0, z - box[k, 5])
                        if ex * ex + ey * ey + ez * ez >= best2:
                            continue
                        for j in range(s0, s1):
                            d2 = ((pts[j, 0] - x) ** 2 + (pts[j, 1] - y) ** 2
                                  + (pts[j, 2] - z) ** 2)
                            if d2 < best2:
                                best2 = d2
                                bx_ = pts[j, 0]
                                by_ = pts[j, 1]
                                bz_ = pts[j, 2]
                        reach2 = best2 * inv_res2
        if bx_ == bx_:  # found (not NaN)
            dist[q] = np.sqrt(best2)
            obst[q, 0] = bx_
            obst[q, 1] = by_
            obst[q, 2] = bz_
            px = bx_
            py = by_
            pz = bz_
            have_prev = True
            found += 1
        else:
            dist[q] = np.inf
            obst[q, 0] = np.nan
            obst[q, 1] = np.nan
            obst[q, 2] = np.nan
    return found
