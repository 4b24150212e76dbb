"""ROS 2 distributions and the planners' real Bspline messages, from golden values:
Humble's rmw_zenoh writes ``TypeHashNotSupported`` where Jazzy and later write the
RIHS01 hash (ros2/rmw_zenoh PR 388); the presets are the planners' own messages in
their upstream layouts, CDR built independently with rosbags' typestore."""

from __future__ import annotations

import queue
import re
import time

import numpy as np
import pytest
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from companion.messages import Rejected
from companion.ros2 import decode
from companion.ros2.decode import decode_bspline
from companion.ros2.layout import Endpoint, RmwZenoh
from companion.ros2.link import Ros2Link
from companion.ros2.settings import Ros2Settings
from companion.ros2.types import STRING, bspline_definition, type_hash
from companion.settings.config import ConfigError, from_dict
from tests.helpers.ros2 import CPS, DT, EGO_MSG, STRING_HASH, SWARM_MSG, ZID, Inbox, RosPeer

HUMBLE = "TypeHashNotSupported"
UPSTREAM = {"ego_planner/msg/Bspline": EGO_MSG,  # ZJU-FAST-Lab/ego-planner
            "plan_manage/msg/Bspline": EGO_MSG,  # HKUST-Aerial-Robotics/Fast-Planner
            # ZJU-FAST-Lab/ego-planner-swarm, src/planner/traj_utils/msg/Bspline.msg
            "traj_utils/msg/Bspline": SWARM_MSG}


def planner_cdr(typename: str, **extra) -> bytes:
    ts = get_typestore(Stores.ROS2_JAZZY)
    ts.register(get_types_from_msg(UPSTREAM[typename], typename))
    t = ts.types
    knots = (np.arange(len(CPS) + 4) - 3) * DT
    msg = t[typename](order=3, traj_id=17, start_time=t["builtin_interfaces/msg/Time"](
        sec=int(time.time()), nanosec=0), knots=knots,
        pos_pts=[t["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2]) for p in CPS],
        yaw_pts=np.zeros(0), yaw_dt=DT, **extra)
    return bytes(ts.serialize_cdr(msg, typename))


def cfg(**ros2):
    return from_dict({"ros2": {"enabled": True, **ros2},
                      "safety": {"geofence_min": [-30.0, -30.0, -1.0],
                                 "geofence_max": [30.0, 30.0, 5.0]}})


# ------------------------------------------------------------------ presets
def test_the_default_is_ego_planner_swarms_message_with_its_hash():
    s = Ros2Settings()
    assert (s.bspline_type, s.bspline_msg) == ("traj_utils/msg/Bspline", "")
    assert "int32 drone_id" in bspline_definition(s.bspline_msg, s.bspline_type)
    # RIHS01 of traj_utils/msg/Bspline from ego-planner-swarm's definition (a regression
    # value computed by rosbags: tests/companion/test_ros2_decode.py says why)
    assert type_hash(s.bspline_type, s.bspline_msg, s.bspline_type) == (
        "RIHS01_dc28418759dfe36d7efbbea4d1b81434f1eba1a2dc30dc9a52ddcd2c68de8569")


@pytest.mark.parametrize("typename", sorted(UPSTREAM))
def test_each_preset_reads_its_planners_message(typename):
    extra = {"drone_id": 3} if typename == "traj_utils/msg/Bspline" else {}
    payload = planner_cdr(typename, **extra)
    inc = decode_bspline(payload, cfg(bspline_type=typename))
    assert inc.id == "bspline-17" and np.array_equal(inc.trajectory.control_points, CPS)
    # the hash in keys and tokens is the one of the upstream definition
    ts = get_typestore(Stores.ROS2_JAZZY)
    ts.register(get_types_from_msg(UPSTREAM[typename], typename))
    assert type_hash(typename, "", typename) == ts.hash_rihs01(typename)


def test_presets_are_told_apart():
    hashes = {t: type_hash(t, "", t) for t in UPSTREAM}
    assert len(set(hashes.values())) == 3  # names are part of the hash
    # EGO-Planner's layout read as ego-planner-swarm's is refused, not misread
    with pytest.raises(Rejected, match="bspline /planning/bspline"):
        decode_bspline(planner_cdr("ego_planner/msg/Bspline"), cfg())


def test_an_unknown_type_is_refused_with_the_known_ones_named(tmp_path):
    with pytest.raises(ConfigError, match=r"\[ros2\] bspline_type: unknown Bspline type "
                       r"'my_planner/msg/Bspline'.*traj_utils/msg/Bspline, ego_planner/msg/"
                       r"Bspline, plan_manage/msg/Bspline.*bspline_msg"):
        cfg(bspline_type="my_planner/msg/Bspline")
    f = tmp_path / "Bspline.msg"
    f.write_text(EGO_MSG)  # with its own definition it is fine
    assert cfg(bspline_type="my_planner/msg/Bspline", bspline_msg=str(f)).ros2.bspline_msg
    with pytest.raises(ConfigError,
                       match=r"\[ros2\] distro: must be one of humble, jazzy, kilted, rolling"):
        cfg(distro="iron")


# ------------------------------------------------------------------ Humble
def test_humble_keys_and_tokens_carry_type_hash_not_supported():
    chatter = Endpoint("MS", "chatter", STRING)
    humble = RmwZenoh(Ros2Settings(enabled=True, distro="humble"), ZID)
    jazzy = RmwZenoh(Ros2Settings(enabled=True), ZID)
    # Humble's form, as rmw_zenoh on Humble writes it: the type hash replaced
    assert humble.key(chatter) == "0/chatter/std_msgs::msg::dds_::String_/TypeHashNotSupported"
    assert jazzy.key(chatter) == f"0/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
    assert humble.token(chatter, 10) == (
        f"@ros2_lv/0/{ZID}/0/10/MS/%/%/rota_companion/%chatter/std_msgs::msg::dds_::String_/"
        "TypeHashNotSupported/::,10:,:,:,,")
    # the GID is the XXH3-128 of the token, so it differs with the form
    assert humble.gid(chatter) != jazzy.gid(chatter)


@pytest.mark.parametrize(("got", "want", "words"), [
    (HUMBLE, STRING_HASH, r'runs ROS 2 Humble .* set \[ros2\] distro = "humble"'),
    (STRING_HASH, HUMBLE, r'runs ROS 2 Jazzy, Kilted or Rolling .* set \[ros2\] distro = '
                          r'"jazzy"'),
    ("RIHS01_" + "0" * 64, STRING_HASH, r"bspline_type, bspline_msg: is it the planner's"),
])
def test_a_mismatch_names_the_distro_and_the_fix(got, want, words):
    with pytest.raises(Rejected, match=words):
        decode.wrong_type(b"\x00\x01\x00\x00", cfg(), what="bspline /planning/bspline",
                          got=got, want=want)


@pytest.mark.parametrize("distro", ["humble", "jazzy"])
def test_a_humble_planner_over_zenoh(sessions, distro):  # noqa: F811
    """A Humble node's Bspline: flown when the service is set for Humble, refused in
    words naming the fix when it is not; the service's status goes out in Humble's
    form to Humble subscribers."""
    service, ros = sessions
    inbox = Inbox()
    link = Ros2Link(service, Ros2Settings(enabled=True, distro=distro), inbox)
    peer = RosPeer(ros, "rmw_zenoh")
    try:
        key = peer.advertise("/planning/bspline", "traj_utils/msg/Bspline",
                             "traj_utils::msg::dds_::Bspline_", HUMBLE)
        time.sleep(0.3)  # the subscription's declaration reaches the peer
        cdr = planner_cdr("traj_utils/msg/Bspline", drone_id=0)
        peer.publish(key, cdr)
        _, fn, payload = inbox.get()
        if distro == "humble":
            assert np.array_equal(fn(payload, cfg(distro="humble"), time.time())
                                  .trajectory.control_points, CPS)
            got: queue.Queue = queue.Queue()
            sub = ros.declare_subscriber(f"0/rota/status/std_msgs::msg::dds_::String_/{HUMBLE}",
                                         lambda s: got.put(s.payload.to_bytes()))
            end = time.monotonic() + 10
            while got.empty() and time.monotonic() < end:
                link.publish_status({"schema": "rota/status", "state": "ready"})
                time.sleep(0.1)
            assert b"ready" in got.get(timeout=1)
            sub.undeclare()
        else:
            with pytest.raises(Rejected, match='Humble .* distro = "humble"'):
                fn(payload, cfg(), time.time())
    finally:
        peer.close()
        link.close()


@pytest.mark.parametrize(("distro", "peer_hash", "words"), [
    ("jazzy", HUMBLE, r'node listener is a ROS 2 Humble subscriber of /rota/status .* set '
                      r'\[ros2\] distro = "humble"'),
    ("humble", STRING_HASH, r"node listener is a ROS 2 Jazzy, Kilted or Rolling subscriber of "
                            r'/rota/status .* set \[ros2\] distro = "jazzy"'),
])
def test_a_subscriber_of_the_other_distro_is_reported_from_its_token(sessions, distro,  # noqa: F811
                                                                      peer_hash, words):
    """No data ever flows to such a subscriber: its liveliness token is all there is."""
    service, ros = sessions
    said: queue.Queue = queue.Queue()
    link = Ros2Link(service, Ros2Settings(enabled=True, distro=distro), Inbox(),
                    warn=lambda message, source: said.put((source, message)))
    peer = RosPeer(ros, "rmw_zenoh", node="listener")
    try:
        # a subscriber of the same flavour first: nothing to say about it
        same = HUMBLE if distro == "humble" else STRING_HASH
        peer.advertise("/rota/status", STRING, "std_msgs::msg::dds_::String_", same, kind="MS")
        peer.advertise("/rota/status", STRING, "std_msgs::msg::dds_::String_", peer_hash,
                       kind="MS")
        source, message = said.get(timeout=10)
        assert source == "ros2"
        assert re.search(words, message), message
        time.sleep(0.5)
        assert said.empty()  # once, and not for the one of the same flavour
    finally:
        peer.close()
        link.close()


def test_a_bridge_route_of_another_type_is_reported_with_the_fix(sessions):  # noqa: F811
    """Behind zenoh-bridge-ros2dds the keys carry no type: a planner whose message type
    differs from [ros2] bspline_type would get a dead route and silence. The bridge's
    route token names the type; the service says what to set, once."""
    service, ros = sessions
    said: queue.Queue = queue.Queue()
    link = Ros2Link(service, Ros2Settings(enabled=True, layout="ros2dds"), Inbox(),
                    warn=lambda message, source: said.put((source, message)))
    bridge = RosPeer(ros, "ros2dds")
    try:
        # the same type first: nothing to say; then EGO-Planner's own message
        bridge.advertise("/planning/bspline", "traj_utils/msg/Bspline", "", "RIHS01_x")
        bridge.advertise("/planning/bspline", "ego_planner/msg/Bspline", "", "RIHS01_y")
        source, message = said.get(timeout=10)
        assert source == "ros2"
        assert re.search(r"behind zenoh-bridge-ros2dds publishes /planning/bspline as "
                         r"ego_planner/msg/Bspline and the service reads "
                         r'traj_utils/msg/Bspline: .*set \[ros2\] bspline_type = '
                         r'"ego_planner/msg/Bspline"', message), message
        # a subscriber of the service's status with another type: named too
        bridge.advertise("/rota/status", "std_msgs/msg/Header", "", "RIHS01_z", kind="MS")
        source, message = said.get(timeout=10)
        assert "subscribes to /rota/status as std_msgs/msg/Header" in message, message
        assert "writes std_msgs/msg/String" in message, message
    finally:
        bridge.close()
        link.close()
