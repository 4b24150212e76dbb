"""ROS 2 messages in: CDR built independently with rosbags' own typestore, decoded by
companion.ros2.decode with the same checks as JSON input; RIHS01 type hashes equal
the ones rosidl generates."""

from __future__ import annotations

import multiprocessing
import pickle
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pytest

from companion.messages import Rejected
from companion.ros2.decode import (
    decode_bspline,
    decode_multidof,
    decode_path,
    decode_pointcloud,
    max_payload_bytes,
)
from companion.ros2.types import dds_type_name, type_hash
from companion.settings.config import from_dict
from rota.voxelmap import VoxelMap
from tests.helpers.ros2 import (
    BSPLINE,
    CFG,
    CPS,
    DT,
    SWARM_MSG,
    TS,
    T,
    bspline_cdr,
    cfg,
    header,
    multidof_cdr,
    path_cdr,
    store,
)


# ------------------------------------------------------------------ types
@pytest.mark.parametrize(("typename", "expected"), [
    # from rmw_zenoh's design document (demo_nodes_cpp chatter)
    ("std_msgs/msg/String", "df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"),
    # from rosidl-generated *__description.c files of ROS 2 builds
    ("nav_msgs/msg/Path", "1957a5bb3cee5da65c4e52e52b65a93df227efce4c20f8458b36e73066ca334b"),
    ("trajectory_msgs/msg/MultiDOFJointTrajectory",
     "3a18fd095292a65cfde8833c72985a30af981f3ec44494655c6267262b443a4a"),
    ("sensor_msgs/msg/PointCloud2",
     "9198cabf7da3796ae6fe19c4cb3bdd3525492988c70522628af5daa124bae2b5"),
    ("builtin_interfaces/msg/Time",
     "b106235e25a4c5ed35098aa0a61a3ee9c9b18d197f398b0e4206cea9acf9c197"),
    ("geometry_msgs/msg/Point", "6963084842a9b04494d6b2941d11444708d892da2f4b09843b9c43f42a7f6881"),
])
def test_type_hashes_are_the_ones_rosidl_generates(typename, expected):
    assert type_hash(typename) == "RIHS01_" + expected


def test_bspline_hash_stays_what_ego_planner_swarms_definition_gives():
    # traj_utils/msg/Bspline with drone_id: a regression value, computed by rosbags from
    # the upstream Bspline.msg (no published rosidl build of it was found to check it
    # against; the standard types' hashes above are ROS 2's own published values)
    assert type_hash(BSPLINE, "ego-planner-swarm") == (
        "RIHS01_dc28418759dfe36d7efbbea4d1b81434f1eba1a2dc30dc9a52ddcd2c68de8569")
    assert type_hash(BSPLINE) != type_hash(BSPLINE, "ego-planner-swarm")


def test_dds_type_name():
    assert dds_type_name("std_msgs/msg/String") == "std_msgs::msg::dds_::String_"
    assert dds_type_name(BSPLINE) == "traj_utils::msg::dds_::Bspline_"


# ---------------------------------------------------------------- bspline
def test_bspline_decodes_to_the_same_spline():
    inc = decode_bspline(bspline_cdr(), CFG)
    assert inc.id == "bspline-17" and inc.frame == "ENU"
    assert inc.stamp == pytest.approx(time.time(), abs=1.0)
    assert np.array_equal(inc.trajectory.control_points, CPS)
    assert inc.trajectory.domain == pytest.approx((0.0, (len(CPS) - 3) * DT))
    # the same curve the planner meant: EGO-Planner's knots are (m - order) * dt
    from rota.trajectory import BSplineTrajectory
    ref = BSplineTrajectory(control_points=CPS, degree=3, knot_span=DT)
    tau = np.linspace(*ref.domain, 50)
    assert np.allclose(inc.trajectory.position(tau), ref.position(tau))


def test_bspline_swarm_variant_and_msg_file(tmp_path):
    swarm = store(SWARM_MSG)
    payload = bspline_cdr(ts=swarm, drone_id=2)
    assert decode_bspline(payload, cfg(bspline_msg="ego-planner-swarm")).id == "bspline-17"
    f = tmp_path / "Bspline.msg"
    f.write_text(SWARM_MSG)
    assert decode_bspline(payload, cfg(bspline_msg=str(f))).trajectory.domain[1] > 0
    # read with the wrong definition: refused, not misread
    with pytest.raises(Rejected, match="bspline /planning/bspline"):
        decode_bspline(payload, CFG)


@pytest.mark.parametrize(("change", "words"), [
    (lambda c: c.__setitem__((4, 1), np.nan), r"pos_pts\[4\]\.y: must be finite"),
    (lambda c: c.__setitem__((2, 2), np.inf), r"pos_pts\[2\]\.z: must be finite"),
    (lambda c: c.__iadd__([0, 0, 40]), "leaves the geofence"),
    (lambda c: c.__imul__(100), r"planned speed .* \(wrong units\?\)"),
])
def test_bspline_bad_values_are_rejected_naming_the_field(change, words):
    cps = CPS.copy()
    change(cps)
    with pytest.raises(Rejected, match=words):
        decode_bspline(bspline_cdr(cps), CFG)


def test_bspline_stale_order_size_and_garbage():
    with pytest.raises(Rejected, match="stale, stamped"):
        decode_bspline(bspline_cdr(t=time.time() - 60), CFG)
    with pytest.raises(Rejected, match="order: must be an integer from 3 to 7"):
        decode_bspline(bspline_cdr(order=2), CFG)
    with pytest.raises(Rejected, match="not a valid CDR traj_utils/msg/Bspline"):
        decode_bspline(bspline_cdr()[:-30], CFG)
    small = from_dict({"ros2": {"enabled": True}, "safety": {"max_trajectory_points": 20}})
    big = np.column_stack([np.linspace(0, 5, 60), np.zeros(60), np.ones(60)])
    with pytest.raises(Rejected, match="sequence over 36 elements"):
        decode_bspline(bspline_cdr(big), small)
    too_big = b"\x00\x01\x00\x00" + bytes(max_payload_bytes("bspline", small))
    with pytest.raises(Rejected, match="more than the size caps allow"):
        decode_bspline(too_big, small)


def test_decoders_are_picklable_and_run_in_a_spawned_worker():
    assert pickle.loads(pickle.dumps(decode_bspline)) is decode_bspline
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        # ages count to the arrival time, as the service's decoder passes it (the worker
        # may take seconds to start)
        inc = pool.submit(decode_bspline, bspline_cdr(), CFG, time.time()).result(timeout=60)
        with pytest.raises(Rejected, match="finite"):
            bad = CPS.copy()
            bad[1, 0] = np.nan
            pool.submit(decode_bspline, bspline_cdr(bad), CFG, time.time()).result(timeout=60)
    assert np.array_equal(inc.trajectory.control_points, CPS)


P = np.array([[0, 0, 1], [1, 0, 1], [2, 0.5, 1.2], [3, 1, 1.2], [4, 1, 1]], dtype=float)


def test_path_stamped_and_unstamped():
    times = np.array([0, 0.8, 1.6, 2.5, 3.3])
    inc = decode_path(path_cdr(P, times, pose_frame="world"), CFG)
    assert np.allclose(inc.trajectory.t, times, atol=1e-6)
    assert np.array_equal(inc.trajectory.p, P)
    assert inc.id.startswith("path-")
    # unstamped poses: timed by arc length at v_max
    un = decode_path(path_cdr(np.vstack([P[:2], P[1:]])), CFG)  # a duplicate pose too
    length = np.linalg.norm(np.diff(P, axis=0), axis=1).sum()
    assert un.trajectory.t[-1] == pytest.approx(length / CFG.limits.v_max)


def test_path_frame_stamps_and_size_errors():
    with pytest.raises(Rejected, match=r"frame_id: 'map' is not the configured frame 'world'"):
        decode_path(path_cdr(P, frame="map"), CFG)
    with pytest.raises(Rejected, match=r"poses\[0\].header.frame_id: 'odom'"):
        decode_path(path_cdr(P, pose_frame="odom"), CFG)
    assert decode_path(path_cdr(P, frame="/world"), CFG)  # ROS 1 style leading slash
    with pytest.raises(Rejected, match=r"poses\[3\].header.stamp: time stamps must be strictly"):
        decode_path(path_cdr(P, [0, 1, 2, 2, 3]), CFG)
    with pytest.raises(Rejected, match=r"poses: need at least 2"):
        decode_path(path_cdr(P[:1]), CFG)
    bad = P.copy()
    bad[2, 0] = np.nan
    with pytest.raises(Rejected, match=r"poses\[2\].pose.position.x: must be finite"):
        decode_path(path_cdr(bad), CFG)


def test_multidof_with_velocities_and_accelerations():
    v = np.gradient(P, 0.5, axis=0)
    a = np.zeros_like(P)
    inc = decode_multidof(multidof_cdr(P, v, a), CFG)
    tr = inc.trajectory
    assert np.allclose(tr.t, np.arange(5) * 0.5)
    assert np.array_equal(tr.p, P) and np.array_equal(tr.v, v) and np.array_equal(tr.a, a)
    assert decode_multidof(multidof_cdr(P), CFG).trajectory.v is None
    with pytest.raises(Rejected, match="planned speed"):
        decode_multidof(multidof_cdr(P * 30, dt=0.1), cfg())
    with pytest.raises(Rejected, match=r"header.frame_id: 'odom'"):
        decode_multidof(multidof_cdr(P, frame="odom"), CFG)
    bad = v.copy()
    bad[3, 1] = np.nan
    with pytest.raises(Rejected, match=r"points\[3\].velocities\[0\].linear.y: must be finite"):
        decode_multidof(multidof_cdr(P, bad), CFG)


# ------------------------------------------------------------- pointcloud
def cloud_cdr(xyz, *, f64=False, big=False, organised=None, pad=0, frame="world",
              extra_field=True) -> bytes:
    """x, y, z (+ intensity) records; ``organised=(h, w)``; ``pad`` bytes per row."""
    ft = ">" if big else "<"
    fmt = ft + ("f8" if f64 else "f4")
    size = 8 if f64 else 4
    names, formats, offsets = ["x", "y", "z"], [fmt] * 3, [0, size, 2 * size]
    if extra_field:
        names.append("intensity")
        formats.append(ft + "f4")
        offsets.append(3 * size + 4)  # a 4-byte hole before it
    step = offsets[-1] + 4 if extra_field else 3 * size
    rec = np.zeros(len(xyz), dtype={"names": names, "formats": formats, "offsets": offsets,
                                    "itemsize": step})
    for k, axis in enumerate("xyz"):
        rec[axis] = xyz[:, k]
    h, w = organised or (1, len(xyz))
    rows = rec.tobytes()
    data = b"".join(rows[r * w * step:(r + 1) * w * step] + bytes(pad) for r in range(h))
    pf = T["sensor_msgs/msg/PointField"]
    fields = [pf(name=n, offset=o, datatype=8 if (f64 and n != "intensity") else 7, count=1)
              for n, o in zip(names, offsets, strict=True)]
    msg = T["sensor_msgs/msg/PointCloud2"](
        header=header(frame), height=h, width=w, fields=fields, is_bigendian=big,
        point_step=step, row_step=w * step + pad,
        data=np.frombuffer(data, dtype=np.uint8), is_dense=False)
    return bytes(TS.serialize_cdr(msg, "sensor_msgs/msg/PointCloud2"))


RNG = np.random.default_rng(4)
XYZ = RNG.uniform(-5, 5, (240, 3))


@pytest.mark.parametrize("kw", [{}, {"f64": True}, {"big": True}, {"organised": (12, 20),
                                                                     "pad": 8},
                                {"extra_field": False}])
def test_pointcloud_becomes_the_voxel_map_of_its_points(kw):
    xyz = XYZ.copy()
    xyz[[3, 77]] = np.nan  # invalid points, as ROS marks them
    vmap = decode_pointcloud(cloud_cdr(xyz, **kw), CFG)
    finite = xyz[np.isfinite(xyz).all(axis=1)]
    if not kw.get("f64"):
        finite = finite.astype(np.float32).astype(float)
    ref = VoxelMap.from_points(finite, CFG.ros2.cloud_resolution)
    assert len(vmap) == len(ref) > 200
    assert np.array_equal(vmap.occupied, ref.occupied)


def test_pointcloud_errors():
    with pytest.raises(Rejected, match="over \\[ros2\\] max_cloud_points"):
        decode_pointcloud(cloud_cdr(XYZ), cfg(max_cloud_points=100))
    with pytest.raises(Rejected, match=r"occupied voxels at 0.1 m is over \[inputs\] max_map_v"):
        decode_pointcloud(cloud_cdr(XYZ), from_dict({"ros2": {"pointcloud_topic": "/c"},
                                                     "inputs": {"max_map_voxels": 100}}))
    with pytest.raises(Rejected, match="frame_id: 'camera'"):
        decode_pointcloud(cloud_cdr(XYZ, frame="camera"), CFG)
    raw = cloud_cdr(XYZ)
    with pytest.raises(Rejected, match="not a valid CDR sensor_msgs/msg/PointCloud2"):
        decode_pointcloud(raw[: len(raw) // 2], CFG)
