"""The rows of the chain problem (:mod:`rota.kernels.chain`): removing the redundant
ones keeps exactly the same feasible set of every interval."""

from __future__ import annotations

import numpy as np
import pytest

from rota.jit import kernels


def _intervals(seed: int):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 6))
    per = int(rng.integers(1, 70))
    offsets = np.arange(n + 1, dtype=np.int64) * per
    frac = np.tile(np.sort(rng.uniform(0, 1, per)), n)
    frac[::per] = 0.0
    scale = rng.uniform(0.1, 3)
    cd1 = rng.normal(size=(n * per, 3)) * scale
    cd2 = rng.normal(size=(n * per, 3)) * scale * rng.uniform(0.1, 10)
    if seed % 4 == 0:
        cd2 = np.round(cd2)  # ties and collinear rows
    if seed % 5 == 0:
        cd1[:, 2] = cd2[:, 2] = 0.0  # a flat path: zero rows
    vlim = rng.uniform(0.5, 3, n + 1)
    hi = vlim**2 / rng.uniform(0.1, 4, n + 1)
    if seed % 7 == 0:
        hi[rng.integers(0, n + 1)] = np.inf
    return (rng.uniform(0.005, 0.5), offsets, frac, cd1, cd2, vlim, rng.uniform(0.5, 3, 3), hi)


def _polygon(a: np.ndarray, c: np.ndarray, top: np.ndarray) -> np.ndarray:
    """The box ``[0, top]`` clipped by ``a x + c y <= 1`` (Sutherland-Hodgman)."""
    poly = np.array([[0, 0], [top[0], 0], top, [0, top[1]]], dtype=float)
    for ai, ci in zip(a, c, strict=True):
        val = poly @ [ai, ci] - 1.0
        out = []
        for k in range(len(poly)):
            p, q, vp, vq = poly[k - 1], poly[k], val[k - 1], val[k]
            if (vp <= 0) != (vq <= 0):
                out.append(p + (q - p) * vp / (vp - vq))
            if vq <= 0:
                out.append(q)
        poly = np.array(out).reshape(-1, 2)
    return poly


@pytest.mark.parametrize("seed", range(300))
def test_pruned_rows_bound_the_same_set(seed: int) -> None:
    """The kept rows with the node bounds cut out of each interval's plane the same
    polygon as all rows: the same support in every direction, up to rounding."""
    args = _intervals(seed)
    every = kernels().build_rows(*args, False)
    kept = kernels().build_rows(*args, True)
    hi = args[-1]
    assert len(kept[0]) <= len(every[0])
    angle = np.linspace(0, 2 * np.pi, 97)[:-1]
    dirs = np.column_stack([np.cos(angle), np.sin(angle)])
    for i in range(len(args[1]) - 1):
        top = np.minimum(hi[i:i + 2], 1e3)
        want = _polygon(every[1][every[0] == i], every[2][every[0] == i], top)
        got = _polygon(kept[1][kept[0] == i], kept[2][kept[0] == i], top)
        np.testing.assert_allclose((got @ dirs.T).max(axis=0), (want @ dirs.T).max(axis=0),
                                   rtol=1e-9, atol=1e-12 * top.max())
