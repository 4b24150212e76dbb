"""Tests for rota.voxelmap: binning, file formats, inflation, nearest queries, JSON."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from plyfile import PlyData, PlyElement
from pypcd4 import PointCloud

from rota.errors import InputError
from rota.voxelmap import VoxelMap


def _brute_nearest(occ: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    d = np.linalg.norm(pts[:, None, :] - occ[None, :, :], axis=2)
    j = d.argmin(axis=1)
    return d[np.arange(len(pts)), j], occ[j]


# ----------------------------------------------------------------- from_points
def test_from_points_snaps_to_voxel_centres_and_dedups() -> None:
    pts = np.array([[0.01, 0.02, 0.03], [0.09, 0.05, 0.0], [0.15, 0.0, 0.0], [-0.01, 0, 0]])
    m = VoxelMap.from_points(pts, 0.1)
    expected = {(0.05, 0.05, 0.05), (0.15, 0.05, 0.05), (-0.05, 0.05, 0.05)}
    got = {tuple(np.round(c, 9)) for c in m.occupied}
    assert got == expected
    assert len(m) == 3
    assert m.occupied.shape == (3, 3)
    assert not m.occupied.flags.writeable


def test_from_points_with_origin_offset() -> None:
    m = VoxelMap.from_points([[1.0, 2.0, 3.0]], 0.5, origin=[0.1, 0.2, 0.3])
    # index floor((1.0-0.1)/0.5)=1 -> centre 0.1 + 1.5*0.5 = 0.85
    np.testing.assert_allclose(m.occupied, [[0.85, 1.95, 3.05]])
    np.testing.assert_allclose(m.origin, [0.1, 0.2, 0.3])


@settings(max_examples=40, deadline=None)
@given(
    st.lists(
        st.tuples(*[st.floats(-5, 5, allow_nan=False)] * 3), min_size=1, max_size=60
    ),
    st.sampled_from([0.05, 0.1, 0.25, 1.0]),
)
def test_from_points_every_point_inside_its_voxel(pts: list, res: float) -> None:
    arr = np.array(pts)
    m = VoxelMap.from_points(arr, res)
    d, c = m.nearest(arr, bbox_margin=math.inf)
    # each point's own voxel centre is within half a voxel per axis
    assert np.all(np.abs(arr - c) <= res / 2 + 1e-9)
    assert len(m) == len({tuple(np.floor(p / res).astype(int)) for p in arr})


def test_constructor_snaps_float_noise_and_dedups() -> None:
    m = VoxelMap(0.1, [[0.05 + 1e-9, 0.15, 0.25], [0.05, 0.15, 0.25 - 1e-10]])
    assert len(m) == 1
    np.testing.assert_allclose(m.occupied, [[0.05, 0.15, 0.25]], atol=1e-12)


def test_constructor_rejects_off_grid_centre() -> None:
    with pytest.raises(InputError) as e:
        VoxelMap(0.1, [[0.05, 0.05, 0.05], [0.05, 0.10, 0.05]])
    assert e.value.field == "occupied[1][1]"


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"resolution": 0.0, "occupied": np.zeros((0, 3))}, "resolution"),
        ({"resolution": -1.0, "occupied": np.zeros((0, 3))}, "resolution"),
        ({"resolution": math.nan, "occupied": np.zeros((0, 3))}, "resolution"),
        ({"resolution": 0.1, "occupied": np.zeros((2, 2))}, "occupied"),
        ({"resolution": 0.1, "occupied": [[0.05, math.inf, 0.05]]}, "occupied[0][1]"),
        ({"resolution": 0.1, "occupied": np.zeros((0, 3)), "origin": [0, 0]}, "origin"),
        ({"resolution": 0.1, "occupied": np.zeros((0, 3)), "origin": [0, math.nan, 0]},
         "origin[1]"),
    ],
)
def test_bad_input_names_field(kwargs: dict, field: str) -> None:
    with pytest.raises(InputError) as e:
        VoxelMap(**kwargs)
    assert e.value.field == field


def test_from_points_bad_points_names_field() -> None:
    with pytest.raises(InputError) as e:
        VoxelMap.from_points([[0, 0, 0], [1, math.nan, 0]], 0.1)
    assert e.value.field == "points[1][1]"


# ------------------------------------------------------------------ file I/O
@pytest.fixture
def cloud() -> np.ndarray:
    rng = np.random.default_rng(0)
    # float32-exact values so PLY/PCD (float32) round trips are exact
    return rng.uniform(-3, 3, (500, 3)).astype(np.float32).astype(float)


def test_ply_round_trip(tmp_path, cloud: np.ndarray) -> None:
    rec = np.zeros(len(cloud), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("intensity", "u1")])
    rec["x"], rec["y"], rec["z"] = cloud.T
    path = tmp_path / "cloud.ply"
    PlyData([PlyElement.describe(rec, "vertex")], text=False).write(str(path))
    m = VoxelMap.from_file(path, 0.2)
    ref = VoxelMap.from_points(cloud, 0.2)
    np.testing.assert_allclose(m.occupied, ref.occupied)
    # ASCII PLY too
    PlyData([PlyElement.describe(rec, "vertex")], text=True).write(str(path))
    np.testing.assert_allclose(VoxelMap.from_file(path, 0.2).occupied, ref.occupied)


def test_ply_missing_property(tmp_path) -> None:
    rec = np.zeros(3, dtype=[("x", "f4"), ("y", "f4")])
    path = tmp_path / "flat.ply"
    PlyData([PlyElement.describe(rec, "vertex")]).write(str(path))
    with pytest.raises(InputError, match="'z'") as e:
        VoxelMap.from_file(path, 0.1)
    assert e.value.field == "path"


def test_ply_missing_vertex_element(tmp_path) -> None:
    rec = np.zeros(3, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    path = tmp_path / "faces.ply"
    PlyData([PlyElement.describe(rec, "points")]).write(str(path))
    with pytest.raises(InputError, match="vertex"):
        VoxelMap.from_file(path, 0.1)


def test_pcd_round_trip(tmp_path, cloud: np.ndarray) -> None:
    path = tmp_path / "cloud.pcd"
    PointCloud.from_xyz_points(cloud).save(path)
    m = VoxelMap.from_file(path, 0.2)
    np.testing.assert_allclose(m.occupied, VoxelMap.from_points(cloud, 0.2).occupied)


def test_pcd_missing_field(tmp_path) -> None:
    pc = PointCloud.from_points(np.zeros((4, 2), np.float32), ("x", "y"), (np.float32,) * 2)
    path = tmp_path / "xy.pcd"
    pc.save(path)
    with pytest.raises(InputError, match="'z'"):
        VoxelMap.from_file(path, 0.1)


def test_npy_and_csv(tmp_path, cloud: np.ndarray) -> None:
    ref = VoxelMap.from_points(cloud, 0.25).occupied
    np.save(tmp_path / "c.npy", cloud)
    np.testing.assert_allclose(VoxelMap.from_file(tmp_path / "c.npy", 0.25).occupied, ref)
    np.savetxt(tmp_path / "c.csv", cloud, delimiter=",", fmt="%.9g")
    np.testing.assert_allclose(VoxelMap.from_file(tmp_path / "c.csv", 0.25).occupied, ref)
    with_header = np.column_stack([np.arange(len(cloud)), cloud[:, 2], cloud[:, 0], cloud[:, 1]])
    np.savetxt(tmp_path / "h.csv", with_header, delimiter=",", header="id,z,x,y", comments="",
               fmt="%.9g")
    np.testing.assert_allclose(VoxelMap.from_file(tmp_path / "h.csv", 0.25).occupied, ref)


def test_file_errors(tmp_path) -> None:
    (tmp_path / "m.xyz").write_text("0 0 0\n")
    with pytest.raises(InputError, match="unknown extension"):
        VoxelMap.from_file(tmp_path / "m.xyz", 0.1)
    with pytest.raises(InputError, match="no such file"):
        VoxelMap.from_file(tmp_path / "missing.ply", 0.1)
    (tmp_path / "h.csv").write_text("a,b,c\n1,2,3\n")
    with pytest.raises(InputError, match="lacks columns"):
        VoxelMap.from_file(tmp_path / "h.csv", 0.1)
    np.save(tmp_path / "bad.npy", np.zeros((4, 2)))
    with pytest.raises(InputError, match=r"\(n, 3\)"):
        VoxelMap.from_file(tmp_path / "bad.npy", 0.1)


# ----------------------------------------------------------------- inflation
def test_inflate_single_voxel_is_a_ball() -> None:
    m = VoxelMap.from_points([[0.0, 0.0, 0.0]], 0.1)
    inf = m.inflated(0.25)
    # integer offsets with |o| <= 2.5 voxels
    r = np.arange(-3, 4)
    g = np.stack(np.meshgrid(r, r, r), -1).reshape(-1, 3)
    assert len(inf) == int(((g**2).sum(1) <= 6.25).sum())  # 81
    assert np.all(np.linalg.norm(inf.occupied - m.occupied[0], axis=1) <= 0.25 + 1e-9)
    assert len(m.inflated(0.0)) == 1
    assert len(m.inflated(0.09)) == 1
    assert len(m.inflated(0.1)) == 7


@settings(max_examples=20, deadline=None)
@given(
    st.lists(st.tuples(*[st.integers(-6, 6)] * 3), min_size=1, max_size=25),
    st.floats(0.0, 0.45),
)
def test_inflate_matches_brute_force(idx: list, radius: float) -> None:
    res = 0.1
    m = VoxelMap(res, (np.array(idx) + 0.5) * res)
    got = {tuple(i) for i in m.inflated(radius).indices}
    k = 5
    r = np.arange(-6 - k, 7 + k)
    cand = np.stack(np.meshgrid(r, r, r), -1).reshape(-1, 3)
    d = np.linalg.norm((cand[:, None, :] - m.indices[None, :, :]) * res, axis=2).min(axis=1)
    want = {tuple(i) for i in cand[d <= radius + 1e-9]}
    assert got == want


def test_inflate_bad_radius() -> None:
    with pytest.raises(InputError) as e:
        VoxelMap.from_points([[0, 0, 0]], 0.1).inflated(-0.1)
    assert e.value.field == "radius"


# -------------------------------------------------------------------- nearest
def test_nearest_matches_brute_force() -> None:
    rng = np.random.default_rng(1)
    m = VoxelMap.from_points(rng.uniform(-5, 5, (400, 3)), 0.2)
    q = rng.uniform(-6, 6, (300, 3))
    d, o = m.nearest(q, bbox_margin=math.inf)
    bd, bo = _brute_nearest(m.occupied, q)
    np.testing.assert_allclose(d, bd)
    np.testing.assert_allclose(np.linalg.norm(o - q, axis=1), bd)


def test_nearest_finite_margin_exact_within_margin_inf_beyond() -> None:
    rng = np.random.default_rng(2)
    m = VoxelMap.from_points(rng.uniform(-5, 5, (60, 3)), 0.1)
    q = rng.uniform(-4, 4, (500, 3))
    bd, bo = _brute_nearest(m.occupied, q)
    d, o = m.nearest(q, bbox_margin=1.0)
    near = bd <= 1.0
    assert near.any() and (~near).any()
    np.testing.assert_allclose(d[near], bd[near])
    np.testing.assert_allclose(o[near], bo[near])
    assert np.all(np.isinf(d[~near]))
    assert np.all(np.isnan(o[~near]))


def test_nearest_empty_map_and_no_obstacle_in_box() -> None:
    empty = VoxelMap(0.1, np.zeros((0, 3)))
    d, o = empty.nearest([[0, 0, 0], [1, 1, 1]])
    assert np.all(np.isinf(d)) and np.all(np.isnan(o)) and o.shape == (2, 3)
    far = VoxelMap.from_points([[100.0, 0, 0]], 0.1)
    d, o = far.nearest([[0, 0, 0]], bbox_margin=2.0)
    assert np.isinf(d[0]) and np.isnan(o[0]).all()
    d, o = far.nearest(np.zeros((0, 3)))
    assert d.shape == (0,) and o.shape == (0, 3)
    assert len(empty.inflated(1.0)) == 0


# ----------------------------------------------------------------------- JSON
def test_json_round_trip() -> None:
    m = VoxelMap.from_points(np.random.default_rng(3).uniform(-2, 2, (50, 3)), 0.15, [0.01, 0, 0])
    d = json.loads(json.dumps(m.to_dict()))
    assert d["schema"] == "rota/map" and d["version"] == 1 and d["frame"] == "ENU"
    back = VoxelMap.from_dict(d)
    np.testing.assert_allclose(back.occupied, m.occupied)
    np.testing.assert_allclose(back.origin, m.origin)
    assert back.resolution == m.resolution
    e = VoxelMap.from_dict({**d, "occupied": []})
    assert len(e) == 0


def _good() -> dict:
    return {"schema": "rota/map", "version": 1, "frame": "ENU", "resolution": 0.1,
            "origin": [0, 0, 0], "occupied": [[0.05, 0.05, 0.05]] * 5}


@pytest.mark.parametrize(
    ("patch", "field"),
    [
        ({"occupied": [[0.05, 0.05, 0.05]] * 3 + [[0.05, math.nan, 0.05]]}, "occupied[3][1]"),
        ({"occupied": [[0.05, 0.05, 0.05], [0.05, "x", 0.05]]}, "occupied[1][1]"),
        ({"occupied": [[0.05, 0.05, 0.05], [0.05, True, 0.05]]}, "occupied[1][1]"),
        ({"occupied": [[0.05, 0.05, 0.05], [0.05, 0.05]]}, "occupied[1]"),
        ({"occupied": [[0.05, 0.05, 0.05], [0.05, None, 0.05]]}, "occupied[1][1]"),
        ({"occupied": "nope"}, "occupied"),
        ({"origin": [0, 0]}, "origin"),
        ({"origin": [0, "a", 0]}, "origin[1]"),
        ({"resolution": -0.1}, "resolution"),
        ({"resolution": "0.1"}, "resolution"),
        ({"schema": "other"}, "schema"),
        ({"version": 2}, "version"),
        ({"frame": "NED"}, "frame"),
        ({"colour": "red"}, "colour"),
    ],
)
def test_from_dict_errors_name_field(patch: dict, field: str) -> None:
    with pytest.raises(InputError) as e:
        VoxelMap.from_dict({**_good(), **patch})
    assert e.value.field == field
    assert str(e.value).startswith(field + ":")


def test_from_dict_missing_key() -> None:
    d = _good()
    del d["resolution"]
    with pytest.raises(InputError) as e:
        VoxelMap.from_dict(d)
    assert e.value.field == "resolution"


def test_cached_index_and_cropped_index_agree(monkeypatch) -> None:
    """Small maps keep one brick index; large ones crop per query (Alg. 1): same answers."""
    import rota.voxelmap as vm

    rng = np.random.default_rng(3)
    m = VoxelMap.from_points(rng.uniform(-5, 5, (4000, 3)), 0.1)
    q = rng.uniform(-7, 7, (500, 3))
    cached = m.nearest(q, bbox_margin=1.5)
    monkeypatch.setattr(vm, "INDEX_CACHE_LIMIT", 0)
    cropped = VoxelMap(m.resolution, m.occupied).nearest(q, bbox_margin=1.5)
    np.testing.assert_array_equal(cached[0], cropped[0])
    np.testing.assert_array_equal(cached[1], cropped[1])
    assert np.isinf(cached[0]).any() and np.isfinite(cached[0]).any()


@pytest.mark.parametrize("res", [0.1, 0.25])
def test_nearest_along_a_path_matches_brute_force(res: float) -> None:
    """Consecutive query points close together (a path: each search starts from the
    previous point's obstacle), through walls, pillars and empty space, on and off
    the grid's faces: the exact nearest centre within the margin, never a farther one."""
    rng = np.random.default_rng(7)
    wall = np.stack(np.meshgrid(np.arange(-3, 3, res / 2), [1.0], np.arange(0, 2, res / 2)),
                    -1).reshape(-1, 3)
    pillars = rng.uniform([-4, -4, 0], [4, 4, 2], (6, 3))
    column = np.concatenate([p + rng.normal(0, 0.15, (300, 3)) for p in pillars])
    m = VoxelMap.from_points(np.concatenate([wall, column]), res, origin=[0.03, -0.02, 0.0])
    s = np.linspace(0.0, 1.0, 1500)[:, None]
    q = np.concatenate([[-5, -5, 1] + s * [10, 9, 0.5], [5, 4, 1.5] - s * [10, 0, 1.5]])
    q[::7] = np.round(q[::7] / res) * res + 0.03  # on voxel faces
    bd, _ = _brute_nearest(m.occupied, q)
    for margin in (0.4, 1.5, math.inf):
        d, o = m.nearest(q, bbox_margin=margin)
        near = bd < margin
        np.testing.assert_allclose(d[near], bd[near], rtol=1e-12)
        np.testing.assert_allclose(np.linalg.norm(o[near] - q[near], axis=1), bd[near],
                                   rtol=1e-12)
        assert np.all(np.isinf(d[~near])) and np.all(np.isnan(o[~near]))


@pytest.mark.parametrize("crop", [False, True])
def test_nearest_inside_and_around_solid_blocks_matches_brute_force(monkeypatch,
                                                                    crop: bool) -> None:
    """Solid obstacles (voxels inside a block or a trunk, and points inside them,
    deep or in the skin): every point gets the nearest centre of all, as by brute
    force, with the cached index and the cropped one."""
    import rota.voxelmap as vm

    if crop:
        monkeypatch.setattr(vm, "INDEX_CACHE_LIMIT", 0)
    rng = np.random.default_rng(11)
    res = 0.1
    axes = [np.arange(a, b, res / 2) for a, b in ((0.0, 1.2), (0.0, 0.8), (0.0, 1.0))]
    block = np.stack(np.meshgrid(*axes), -1).reshape(-1, 3)
    trunk = np.stack(np.meshgrid(np.arange(-0.2, 0.2, res / 2), np.arange(-0.2, 0.2, res / 2),
                                 np.arange(0.0, 3.0, res / 2)), -1).reshape(-1, 3)
    m = VoxelMap.from_points(np.concatenate([block, trunk + [3.0, 1.0, 0.0]]), res,
                             origin=[0.01, -0.03, 0.0])
    q = np.concatenate([rng.uniform([-0.5, -0.5, -0.2], [4.0, 2.0, 3.2], (1500, 3)),
                        rng.uniform([0.0, 0.0, 0.0], [1.2, 0.8, 1.0], (500, 3)),  # inside
                        rng.uniform([2.8, 0.8, 0.0], [3.2, 1.2, 3.0], (300, 3))])
    bd, _ = _brute_nearest(m.occupied, q)
    assert (bd < 0.5 * res * np.sqrt(3)).sum() > 500  # many points inside occupied voxels
    for margin in (0.3, math.inf):
        d, o = m.nearest(q, bbox_margin=margin)
        near = bd < margin
        np.testing.assert_allclose(d[near], bd[near], rtol=1e-12)
        np.testing.assert_allclose(np.linalg.norm(o[near] - q[near], axis=1), bd[near],
                                   rtol=1e-12)
        assert np.all(np.isinf(d[~near]))
