"""Flight records in Foxglove's well-known schemas: every channel decodes with its
schema's own decoder (protobuf from the schema's FileDescriptorSet, JSON against
its JSON Schema), and what it shows is the flight: the map voxel for voxel, the
paths and braking zones of a real re-time, the setpoints and the vehicle."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from companion.recording.foxglove import Scene, speed_colours, voxel_boxes, yaw_quaternion
from companion.recording.record import Recorder, read, read_raw
from rota import Limits, RetimeInput, SampledTrajectory, retime
from rota.braking import BrakingParams
from rota.chance import ChanceParams, UncertaintyModel
from rota.robust import Safety
from rota.schema import TrajectoryMessage, result_to_dict
from rota.voxelmap import VoxelMap
from tests.helpers.foxglove import decode_all

RES = 0.05
V_MAX = 3.0
PROTOBUF = {"/foxglove/map": "foxglove.SceneUpdate", "/foxglove/plan": "foxglove.SceneUpdate",
            "/foxglove/body": "foxglove.SceneUpdate",
            "/foxglove/setpoint": "foxglove.PoseInFrame",
            "/foxglove/vehicle": "foxglove.PoseInFrame", "/tf": "foxglove.FrameTransform",
            "/foxglove/log": "foxglove.Log"}
PLOTS = {"/plot/command": "rota.plot.Command", "/plot/vehicle": "rota.plot.Vehicle"}


def pillar() -> VoxelMap:
    g = np.arange(-0.5, 0.5, RES / 2)
    xx, yy, zz = np.meshgrid(g, g, np.arange(0, 3, RES / 2), indexing="ij")
    pts = np.column_stack([xx.ravel(), yy.ravel(), zz.ravel()])
    pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= 0.1] + [5.0, 0.4, 0.0]
    return VoxelMap.from_points(pts, RES)


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    """A record as the service writes one: its configuration, the map, a real re-time
    with a braking zone (a pillar beside the path), the setpoints flying it at 50 Hz
    and telemetry at 10 Hz lagging 0.1 s behind them, a warning."""
    n = 21
    x = np.linspace(0.0, 10.0, n)
    traj = SampledTrajectory(t=x, p=np.column_stack([x, 0 * x, 0 * x + 1.0]))
    vmap = pillar()
    safety = Safety(map=vmap, uncertainty=UncertaintyModel(m=0.2, b=-0.1),
                    chance=ChanceParams(delta=1e-4, semi_axes=(0.15,) * 3,
                                        obstacle_std=(0.015,) * 3, v_floor=0.3, v_max=V_MAX),
                    braking=BrakingParams(d_th=1.0))
    res = retime(RetimeInput(trajectory=traj, limits=Limits(V_MAX, 3.0), dtau=0.05,
                             smoothness=0.02, safety=safety))
    assert res.ok and res.diagnostics.intervals, res.message
    result = result_to_dict(res, TrajectoryMessage(traj, id="plan-0", frame="ENU"))
    rec = Recorder(tmp_path_factory.mktemp("fox"), "t").start()
    t0 = 1_800_000_000.0
    rec.put("config", {"limits": {"v_max": V_MAX}, "safety": {"max_tracking_error_m": 1.0}}, t0)
    rec.put("map", json.dumps(vmap.to_dict()).encode(), t0 + 0.1)  # as received
    rec.show("map", vmap, t0 + 0.2)  # as decoded and in use
    rec.put("retimed", json.dumps(result).encode(), t0 + 0.5)
    sp = res.sample_rate(50.0)
    start = t0 + 1.0
    yaw = 30.0
    for k in range(len(sp.t)):
        rec.put("setpoint", {"t": 100.0 + sp.t[k], "p": sp.position[k], "v": sp.velocity[k],
                             "a": sp.acceleration[k], "yaw": yaw, "source": "plan-0"},
                start + sp.t[k])
    for k in range(0, len(sp.t), 5):
        lag = max(k - 5, 0)
        rec.put("telemetry", {"schema": "rota/telemetry", "position": sp.position[lag],
                              "velocity": sp.velocity[lag],
                              "setpoint": {"yaw_ned_deg": yaw},
                              "tracking_error": float(np.linalg.norm(
                                  sp.position[k] - sp.position[lag]))}, start + sp.t[k] + 0.01)
    rec.put("log", {"level": "WARNING", "logger": "rota.companion", "message": "braking"},
            start + 1.0)
    rec.close()
    assert rec.dropped == 0 and rec.stats()["foxglove_errors"] == 0
    return {"files": rec.files, "res": res, "sp": sp, "start": start, "vmap": vmap,
            "yaw": yaw, "decoded": decode_all(rec.files)}


def test_every_channel_decodes_with_its_published_schema(flight):
    got = flight["decoded"]
    assert set(got) == set(PROTOBUF) | set(PLOTS) | {
        "/config", "/map", "/retimed", "/setpoint", "/telemetry", "/log"}
    factory = DecoderFactory()
    for path in flight["files"]:
        for schema, channel, _ in read_raw([path]):
            if channel.topic in PROTOBUF:
                assert schema.name == PROTOBUF[channel.topic]
                assert factory.decoder_for("protobuf", schema) is not None
            elif channel.topic in PLOTS:
                assert schema.name == PLOTS[channel.topic]
    # the service's own channels read back as before
    assert [c for c, _, _ in read(flight["files"])].count("setpoint") == len(flight["sp"].t)


def test_the_map_is_its_voxels_exactly(flight):
    (_, update), = flight["decoded"]["/foxglove/map"]
    entity, = update.entities
    assert entity.frame_id == "map" and entity.id == "obstacles"
    base = flight["vmap"].occupied.min(axis=0)
    voxels = set()
    for cube in entity.cubes:
        assert cube.size.x == pytest.approx(RES) and cube.size.y == pytest.approx(RES)
        n = round(cube.size.z / RES)
        assert n >= 1 and cube.size.z == pytest.approx(n * RES)
        z0 = cube.pose.position.z - cube.size.z / 2 + RES / 2
        for k in range(n):
            voxels.add(tuple(np.round((np.array([cube.pose.position.x, cube.pose.position.y,
                                                 z0 + k * RES]) - base) / RES).astype(int)))
    want = {tuple(v) for v in np.round((flight["vmap"].occupied - base) / RES).astype(int)}
    assert voxels == want
    assert len(entity.cubes) < len(want) / 10  # vertical runs: a pillar is few boxes


def test_the_plan_shows_both_paths_speed_colours_and_braking_zones(flight):
    (_, update), = flight["decoded"]["/foxglove/plan"]
    entity, = update.entities
    res = flight["res"]
    zones = res.diagnostics.intervals
    planned, retimed, *zone_lines = entity.lines
    assert len(zone_lines) == len(zones)
    pts = np.array([[p.x, p.y, p.z] for p in retimed.points])
    assert len(retimed.colors) == len(pts)
    # the re-timed path lies on the planned one, and its colours are its speeds
    assert np.allclose(pts[:, 1:], [0.0, 1.0]) and pts[0, 0] == pytest.approx(0.0)
    speed = np.linalg.norm(res.sample(np.linspace(0, res.duration, len(pts))).velocity, axis=1)
    rgb = np.array([[c.r, c.g, c.b] for c in retimed.colors])
    assert np.allclose(rgb, speed_colours(speed, V_MAX), atol=1e-6)
    assert rgb[np.argmax(speed), 0] > rgb[np.argmin(speed), 0]  # fast is red, slow blue
    assert len(planned.points) > 2 and planned.color.a > 0
    for line, (a, b) in zip(zone_lines, zones, strict=True):
        xs = [p.x for p in line.points]
        ends = res.trajectory.position(np.array([a, b]))[:, 0]
        assert min(xs) == pytest.approx(ends[0]) and max(xs) == pytest.approx(ends[1])
        # before the pillar at x = 5 (its start follows the risk: 3.0 with this model;
        # the exact ends are checked against the result just above)
        assert 2.5 < min(xs) <= max(xs) < 5.5
    meta = {kv.key: kv.value for kv in entity.metadata}
    assert meta["plan"] == "plan-0" and meta["braking_zones"] == str(len(zones))


def test_setpoints_vehicle_pose_and_plots_follow_the_flight(flight):
    got, sp, res, start = flight["decoded"], flight["sp"], flight["res"], flight["start"]
    poses = got["/foxglove/setpoint"]
    assert len(poses) == len(sp.t)
    assert np.allclose([[m.pose.position.x, m.pose.position.y, m.pose.position.z]
                        for _, m in poses], sp.position)
    _, _, qz, qw = yaw_quaternion(flight["yaw"])  # 30 deg east of north: 60 deg from east
    assert 2 * math.degrees(math.atan2(qz, qw)) == pytest.approx(60.0)
    assert poses[0][1].pose.orientation.z == pytest.approx(qz)
    assert poses[5][1].timestamp.ToNanoseconds() == pytest.approx((start + sp.t[5]) * 1e9, abs=1e3)
    tfs = got["/tf"]
    assert {(m.parent_frame_id, m.child_frame_id) for _, m in tfs} == {("map", "base_link")}
    tel = [m for _, _, m in read(flight["files"], ["telemetry"])]
    assert np.allclose([[m.translation.x, m.translation.y, m.translation.z] for _, m in tfs],
                       [t["position"] for t in tel])
    assert len(got["/foxglove/vehicle"]) == len(tfs) and len(got["/foxglove/body"]) == 1
    # plots: commanded speed, the chance-constrained limit, braking zones, tracking error
    cmd = [m for _, m in got["/plot/command"]]
    assert np.allclose([c["speed"] for c in cmd], np.linalg.norm(sp.velocity, axis=1),
                       atol=1e-4)
    assert {c["v_max"] for c in cmd} == {V_MAX} and {c["plan"] for c in cmd} == {"plan-0"}
    limits = np.interp(sp.t, res.t, res.speed_limits)
    assert np.allclose([c["chance_limit"] for c in cmd], limits, atol=1e-3)
    in_zone = np.array([c["braking_zone"] for c in cmd])
    a, b = res.diagnostics.intervals[0]
    assert np.array_equal(in_zone, (sp.tau >= a - 1e-9) & (sp.tau <= b + 1e-9))
    assert in_zone.any()
    veh = [m for _, m in got["/plot/vehicle"]]
    assert [v["tracking_error"] for v in veh] == pytest.approx([t["tracking_error"] for t in tel])
    assert {v["brake_threshold"] for v in veh} == {1.0}
    (_, warning), = got["/foxglove/log"]
    assert warning.level == 3 and warning.message == "braking"  # foxglove.LogLevel WARNING


def test_a_record_cut_anywhere_decodes_up_to_its_last_chunk(flight, tmp_path):
    """Power loss: the file ends mid-chunk, without index or footer. A minute of
    flight (the re-time flown again and again) fills many chunks."""
    rec = Recorder(tmp_path, "long").start()
    for path in flight["files"]:
        for channel, stamp, m in read([path]):
            rec.put(channel, json.dumps(m).encode() if channel in ("map", "retimed") else m,
                    stamp)
    sp, t = flight["sp"], flight["start"] + 10.0
    for _ in range(6):
        for k in range(len(sp.t)):
            rec.put("setpoint", {"p": sp.position[k], "v": sp.velocity[k], "yaw": 0.0,
                                 "source": "plan-0"}, t)
            if k % 5 == 0:
                rec.put("telemetry", {"position": sp.position[k], "velocity": sp.velocity[k],
                                      "tracking_error": 0.1}, t)
            t += 0.02
    rec.close()
    whole = decode_all(rec.files)
    with open(rec.files[0], "rb") as fh:
        stats = make_reader(fh).get_summary().statistics
    assert stats.chunk_count >= 4
    per_chunk = stats.message_count / stats.chunk_count
    total = sum(len(v) for v in whole.values())
    data = rec.files[0].read_bytes()
    for frac in (0.3, 0.55, 0.8):
        cut = tmp_path / f"cut-{frac}.mcap"
        cut.write_bytes(data[: int(len(data) * frac)])
        got = decode_all([cut])  # every message there decodes with its schema
        n = sum(len(v) for v in got.values())
        assert frac * total - 2 * per_chunk < n < total  # at most the last chunk lost
        for topic, msgs in got.items():  # a prefix of the flight on every channel
            assert [s for s, _ in msgs] == [s for s, _ in whole[topic][: len(msgs)]]
        assert {"/foxglove/setpoint", "/tf", "/plot/command"} <= set(got)


def test_voxel_boxes_cover_duplicates_and_gaps():
    occ = np.array([[0.05, 0.05, 0.05], [0.05, 0.05, 0.15], [0.05, 0.05, 0.35],
                    [0.05, 0.05, 0.15], [0.15, 0.05, 0.05]])
    centres, heights = voxel_boxes(occ, 0.1)
    boxes = sorted(zip(map(tuple, np.round(centres, 3)), np.round(heights, 3), strict=True))
    assert boxes == [((0.05, 0.05, 0.1), 0.2), ((0.05, 0.05, 0.35), 0.1),
                     ((0.15, 0.05, 0.05), 0.1)]


def test_unknown_channels_are_not_shown_and_bad_messages_are_counted(tmp_path):
    assert Scene().translate("status", {"state": "ready"}, 1.0) == []
    rec = Recorder(tmp_path, "t").start()
    rec.put("retimed", b'{"schema": "rota/result", "tau": "nonsense"}', 1.0)
    rec.put("setpoint", {"p": [0, 0, 1], "v": [0, 0, 0], "source": "hold"}, 2.0)
    rec.close()
    assert rec.stats()["foxglove_errors"] == 1 and rec.written == 2
    assert [c for c, _, _ in read(rec.files)] == ["retimed", "setpoint"]
    assert set(decode_all(rec.files)) == {"/retimed", "/setpoint", "/foxglove/setpoint",
                                          "/plot/command"}


def test_the_shipped_layout_is_the_generated_one_and_shows_recorded_topics(flight):
    from pathlib import Path

    from companion.gs.foxglove import layout_json
    from companion.recording.foxglove import TOPICS

    shipped = Path(__file__).resolve().parents[2] / "docs" / "foxglove" / "layout.json"
    assert shipped.read_text() == layout_json()  # `rota-gs foxglove --layout` wrote it
    text = shipped.read_text()
    named = {t for t in TOPICS if f'"{t}' in text}
    assert named == set(TOPICS) - {"/tf"}  # /tf is used through follow_tf
    assert named <= set(flight["decoded"]) and '"followTf": "base_link"' in text


def test_rota_gs_foxglove_renders_a_record_and_refuses_bad_input(flight, tmp_path, capsys):
    from companion.gs.cli import main

    out = tmp_path / "scene.png"
    assert main(["foxglove", "--render", str(out), *map(str, flight["files"])]) == 0
    assert out.stat().st_size > 20_000
    assert main(["foxglove", str(flight["files"][0])]) == 2  # serving takes no files
    assert "only with --render" in capsys.readouterr().err
    plain = tmp_path / "plain"
    rec = Recorder(plain, "t", foxglove=False).start()
    rec.put("setpoint", {"p": [0, 0, 1], "v": [0, 0, 0]}, 1.0)
    rec.close()
    assert main(["foxglove", "--render", str(out), str(rec.files[0])]) == 2
    assert "no Foxglove channels" in capsys.readouterr().err


def test_rota_gs_foxglove_without_a_service_says_so(capsys):
    from companion.gs.cli import main
    from sitl.demo import free_tcp_port

    port = free_tcp_port()  # nobody listens there
    assert main(["foxglove", "--connect", f"tcp/127.0.0.1:{port}", "--timeout", "0.5",
                 "--port", "0"]) == 3
    assert f"cannot reach tcp/127.0.0.1:{port}" in capsys.readouterr().err


def test_every_part_of_a_rotated_record_shows_the_map_and_plan(flight, tmp_path):
    """Foxglove opens one file at a time: each part starts with the map, the plan and
    the body in force."""
    rec = Recorder(tmp_path, "parts", max_file_mb=0.1, max_total_mb=100.0).start()
    for channel, stamp, m in read(flight["files"]):
        if channel == "map":
            rec.show("map", flight["vmap"], stamp)
        rec.put(channel, json.dumps(m).encode() if channel in ("map", "retimed") else m, stamp)
    sp, t = flight["sp"], flight["start"] + 10.0
    for _ in range(6):
        for k in range(len(sp.t)):
            rec.put("setpoint", {"p": sp.position[k], "v": sp.velocity[k], "source": "plan-0"},
                    t)
            t += 0.02
    rec.close()
    assert len(rec.files) >= 3
    for path in rec.files:
        got = decode_all([path])
        assert {"/foxglove/map", "/foxglove/plan", "/foxglove/body"} <= set(got), path
