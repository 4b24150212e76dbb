"""The planner's side of the ROS link (what ``rota-gs send --ros2`` uses): a ROS message
as users have it (JSON or YAML in ROS field names, as ``ros2 topic echo`` prints it, or
CDR bytes) gives the CDR rosbags' own typestore builds; bad files get errors naming the
field; and a RosPublisher puts it on real Zenoh sessions (loopback) as a ROS node of
each layout would: tokens, key, attachment, received by the service's link."""

from __future__ import annotations

import json
import queue
import time

import numpy as np
import pytest

from companion.ros2.decode import decode_bspline, decode_path
from companion.ros2.layout import parse_attachment, rmw_gid
from companion.ros2.link import Ros2Link
from companion.ros2.send import RosPublisher, read_message
from companion.ros2.settings import Ros2Settings
from rota.errors import InputError
from tests.helpers.ros2 import (
    BSPLINE,
    CFG,
    CPS,
    TS,
    Inbox,
    RosPeer,
    bspline_cdr,
    bspline_fields,
    echo_yaml,
    header,
    point,
)

T0 = 1718000000.25  # start_time of the examples: sec 1718000000, nanosec 250000000
S = Ros2Settings(enabled=True, bspline_msg="ego-planner")  # the layout of bspline_fields()


def test_json_yaml_and_cdr_give_the_bytes_rosbags_builds(tmp_path):
    reference = bspline_cdr(t=T0)  # rosbags' own typestore, not the project's
    (tmp_path / "b.json").write_text(json.dumps(bspline_fields()))
    (tmp_path / "b.yaml").write_text(echo_yaml(bspline_fields()))
    (tmp_path / "b.cdr").write_bytes(reference)
    for name in ("b.json", "b.yaml", "b.cdr"):
        msg = read_message(tmp_path / name, "bspline", S)  # the file's stamp kept
        assert msg.cdr == reference, name
        assert (msg.id, msg.topic, msg.typename) == ("bspline-17", "/planning/bspline", BSPLINE)
        assert msg.stamp == pytest.approx(T0)
    # stamped now (the default of rota-gs send): only start_time changes
    now = time.time()
    msg = read_message(tmp_path / "b.cdr", "bspline", S, stamp=now)
    inc = decode_bspline(msg.cdr, CFG)
    assert inc.stamp == pytest.approx(now, abs=1e-6) and msg.stamp == inc.stamp
    assert np.array_equal(inc.trajectory.control_points, CPS)


def test_a_path_as_ros2_topic_echo_prints_it(tmp_path):
    stamps = T0 + np.array([0.0, 0.5, 1.5])
    pts = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [1.0, 1.0, 1.5]])
    lines = ["header:", "  stamp:", "    sec: 1718000000", "    nanosec: 250000000",
             "  frame_id: world", "poses:"]
    for t, p in zip(stamps, pts.tolist(), strict=True):
        lines += ["- header:", "    stamp:", f"      sec: {int(t)}",
                  f"      nanosec: {round((t % 1) * 1e9)}", "    frame_id: world", "  pose:",
                  "    position:", *(f"      {a}: {v!r}" for a, v in zip("xyz", p, strict=True)),
                  "    orientation:", "      x: 0.0", "      y: 0.0", "      z: 0.0",
                  "      w: 1.0"]
    (tmp_path / "path.yaml").write_text("\n".join(lines) + "\n---\n")
    s = Ros2Settings(enabled=True, path_topic="/path")
    now = time.time()
    msg = read_message(tmp_path / "path.yaml", "path", s, stamp=now)
    inc = decode_path(msg.cdr, CFG)
    assert msg.id == inc.id == f"path-{int(now)}.{round((now % 1) * 1e9):09d}"
    assert np.allclose(inc.trajectory.t, stamps - stamps[0], atol=1e-9)
    assert np.allclose(inc.trajectory.p, pts)
    # what rosbags' own typestore makes of it: the same poses, the header restamped
    m = TS.deserialize_cdr(msg.cdr, "nav_msgs/msg/Path")
    assert m.header.frame_id == "world" and len(m.poses) == 3
    assert m.poses[2].pose.position == point(pts[2]) and m.poses[0].header == header(t=T0)


@pytest.mark.parametrize(("name", "text", "error"), [
    ("b.json", {"drone_id": 1}, "b.json: drone_id: not a field of traj_utils/msg/Bspline "
     "(its fields: order, traj_id, start_time, knots, pos_pts, yaw_pts, yaw_dt) (is [ros2] "
     "bspline_msg the planner's definition?)"),
    ("b.json", {"pos_pts": [{"x": 1.0}, {"x": "1"}]}, "pos_pts[1].x: must be a number, got '1'"),
    ("b.json", {"start_time": {"sec": 1.5}}, "start_time.sec: must be an integer from "
     "-2147483648 to 2147483647 (int32), got 1.5"),
    ("b.json", {"start_time": 5}, "start_time: must be a builtin_interfaces/msg/Time"),
    ("b.yaml", "knots:\n- 0.0\n- '...'\n", "knots: cut short with '...' (ros2 topic echo "
     "shortens long arrays: echo with --full-length)"),
    ("b.yaml", "order: [1\n", "b.yaml: not valid YAML"),
    ("b.json", "{'order': 3}", "b.json: not valid JSON"),
    ("b.cdr", b"\x00\x01\x00\x00\x03", "b.cdr: not the CDR of a traj_utils/msg/Bspline"),
    ("b.yaml", b"\x00\x01\x00\x00\xff", "b.yaml: not text (CDR bytes go in a .cdr file)"),
])
def test_bad_files_are_refused_naming_the_field(tmp_path, name, text, error):
    path = tmp_path / name
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text if isinstance(text, str) else json.dumps(text))
    with pytest.raises(InputError) as exc:
        read_message(path, "bspline", S)
    assert error in str(exc.value) and "\n" not in str(exc.value)
    assert str(exc.value).count(name) == 1


def test_an_input_that_is_off_needs_a_topic(tmp_path):
    (tmp_path / "p.json").write_text("{}")
    with pytest.raises(InputError, match=r"no topic for path messages: set \[ros2\] path_topic"):
        read_message(tmp_path / "p.json", "path", S)


@pytest.mark.parametrize("layout", ["rmw_zenoh", "ros2dds"])
def test_the_publisher_speaks_the_layout_to_the_service(sessions, tmp_path, layout):  # noqa: F811
    service, ros = sessions
    s = Ros2Settings(enabled=True, layout=layout, domain_id=3, namespace="/bot1",
                     bspline_topic="planning/bspline",  # relative: under the namespace
                     bspline_msg="ego-planner")
    inbox = Inbox()
    link = Ros2Link(service, s, inbox)
    (tmp_path / "b.json").write_text(json.dumps(bspline_fields()))
    msg = read_message(tmp_path / "b.json", "bspline", s, stamp=time.time())
    got: queue.Queue = queue.Queue()
    watcher = RosPeer(service, layout)  # a ROS view from the service's side
    pub = RosPublisher(ros, s, msg.topic, msg.typename)
    try:
        key = pub.key
        sub = service.declare_subscriber(key, lambda smp: got.put(smp.attachment))
        h = TS.hash_rihs01(BSPLINE)
        zid = str(ros.zid())
        if layout == "rmw_zenoh":
            assert key == f"3/bot1/planning/bspline/traj_utils::msg::dds_::Bspline_/{h}"
            mp = (f"@ros2_lv/3/{zid}/0/1/MP/%/%bot1/rota_gs/%bot1%planning%bspline/"
                  f"traj_utils::msg::dds_::Bspline_/{h}/::,10:,:,:,,")
            tokens = {f"@ros2_lv/3/{zid}/0/0/NN/%/%bot1/rota_gs", mp}
            assert watcher.wait_tokens(f"@ros2_lv/3/{zid}/**", 2) == tokens
        else:
            assert key == "bot1/planning/bspline"
            mp = (f"@/{zid}/@ros2_lv/MP/bot1§planning§bspline/traj_utils§msg§Bspline/"
                  f":1:0:0,10:typehash={h};")
            assert watcher.wait_tokens(f"@/{zid}/@ros2_lv/**", 2) == {f"@/{zid}/@ros2_lv", mp}
        pub.put(msg.cdr)
        assert inbox.get() == ("bspline", decode_bspline, msg.cdr)  # the service's link has it
        att = got.get(timeout=10)
        if layout == "rmw_zenoh":
            seq, ts, gid = parse_attachment(att.to_bytes())
            assert seq == 1 and abs(ts / 1e9 - time.time()) < 5 and gid == rmw_gid(mp)
        else:
            assert att is None
        sub.undeclare()
    finally:
        pub.close()
        watcher.close()
        link.close()


def test_ros_options_need_ros2(tmp_path, capsys):
    from companion.gs.cli import EXIT_INPUT, main

    (tmp_path / "t.json").write_text("{}")
    assert main(["send", str(tmp_path / "t.json"), "--topic", "/plan"]) == EXIT_INPUT
    assert capsys.readouterr().err == ("rota-gs send: bad input: --topic: only for a ROS "
                                       "message (--ros2)\n")
    assert main(["send", "--ros2", "bspline", str(tmp_path / "t.json"),
                 "--domain-id", "300"]) == EXIT_INPUT
    assert "bad input: ROS options: [ros2] domain_id: must be a ROS domain id from 0 to 232" \
        in capsys.readouterr().err
