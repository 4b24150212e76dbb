"""The ROS 2 link on real Zenoh sessions (loopback): a ROS-side peer built from the
layouts' documents (rmw_zenoh's design.md; zenoh-plugin-ros2dds' key and token
formats) publishes CDR with the exact keys, attachments and liveliness tokens; the
link delivers the raw payload with the right decoder, announces itself, and its
status and re-timed trajectory come back as ROS messages."""

from __future__ import annotations

import json
import queue
import struct
import time

import numpy as np
import pytest

from companion.messages import Rejected
from companion.ros2 import decode
from companion.ros2.layout import (
    Endpoint,
    RmwZenoh,
    Ros2Dds,
    parse_attachment,
    rmw_gid,
    rmw_qos,
)
from companion.ros2.link import Ros2Link
from companion.ros2.settings import Ros2Settings
from companion.ros2.types import STRING
from companion.settings.config import from_dict
from rota import BSplineTrajectory, Limits, RetimeInput, retime
from rota.schema import TrajectoryMessage, result_to_dict
from tests.helpers.ros2 import (
    BSPLINE,
    CPS,
    STRING_HASH,
    TS,
    ZID,
    Inbox,
    RosPeer,
    bspline_cdr,
    store,
)


def settings(**kw) -> Ros2Settings:
    kw.setdefault("bspline_msg", "ego-planner")  # the layout these tests' planner sends
    return Ros2Settings(enabled=True, **kw)


EGO = {"ros2": {"bspline_msg": "ego-planner"}}


# --------------------------------------------- the documents' own examples
def test_keys_and_tokens_equal_the_design_documents_examples():
    chatter = Endpoint("MS", "chatter", STRING)
    r = RmwZenoh(settings(domain_id=0), ZID)
    assert r.key(chatter) == f"0/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
    ns = RmwZenoh(settings(namespace="/robot1"), ZID)
    assert ns.key(chatter) == f"0/robot1/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
    listener = RmwZenoh(settings(domain_id=2, node_name="listener"), ZID)
    assert listener.node_token() == f"@ros2_lv/2/{ZID}/0/0/NN/%/%/listener"
    assert listener.token(chatter, entity_id=10) == (
        f"@ros2_lv/2/{ZID}/0/10/MS/%/%/listener/%chatter/std_msgs::msg::dds_::String_/"
        f"{STRING_HASH}/::,10:,:,:,,")
    assert rmw_qos(7) == "::,7:,:,:,,"  # the talker's depth-7 publisher in the examples
    # zenoh-plugin-ros2dds: topic /chatter is key "chatter" ("bot1/chatter" with namespace)
    dds = Ros2Dds(settings(namespace="/bot1"), ZID)
    assert dds.key(chatter) == "bot1/chatter"
    assert dds.token(Endpoint("MP", "/rota/status", STRING)) == (
        f"@/{ZID}/@ros2_lv/MP/bot1§rota§status/std_msgs§msg§String/:1:0:0,10:"
        f"typehash={STRING_HASH};")


def test_gid_is_xxh3_128_of_the_token_low_half_first():
    # XXH3-128 (seed 0) of no bytes is 99aa06d3014798d8_6001c324468d497f (xxHash's
    # reference); rmw_zenoh copies the low 64 bits, then the high, each little-endian
    assert rmw_gid("") == bytes.fromhex("7f498d4624c30160" "d8984701d306aa99")
    assert len({rmw_gid(f"@ros2_lv/0/{ZID}/0/{i}/MP") for i in range(100)}) == 100


# ------------------------------------------------------------- rmw_zenoh
def test_rmw_zenoh_bspline_in_status_out(sessions):
    service, ros = sessions
    inbox = Inbox()
    link = Ros2Link(service, settings(), inbox)
    peer = RosPeer(ros, "rmw_zenoh")
    try:
        zid = str(service.zid())
        h = TS.hash_rihs01(BSPLINE)
        tokens = peer.wait_tokens(f"@ros2_lv/0/{zid}/**", 4)
        assert tokens == {
            f"@ros2_lv/0/{zid}/0/0/NN/%/%/rota_companion",
            f"@ros2_lv/0/{zid}/0/1/MS/%/%/rota_companion/%planning%bspline/"
            f"traj_utils::msg::dds_::Bspline_/{h}/::,10:,:,:,,",
            f"@ros2_lv/0/{zid}/0/2/MP/%/%/rota_companion/%rota%status/"
            f"std_msgs::msg::dds_::String_/{STRING_HASH}/::,10:,:,:,,",
            f"@ros2_lv/0/{zid}/0/3/MP/%/%/rota_companion/%rota%retimed/"
            "trajectory_msgs::msg::dds_::MultiDOFJointTrajectory_/"
            "RIHS01_3a18fd095292a65cfde8833c72985a30af981f3ec44494655c6267262b443a4a/::,10:,:,:,,",
        }
        key = peer.advertise("/planning/bspline", BSPLINE, "traj_utils::msg::dds_::Bspline_", h)
        cdr = bspline_cdr()
        peer.publish(key, cdr)
        kind, fn, payload = inbox.get()
        assert (kind, fn, payload) == ("bspline", decode.decode_bspline, cdr)
        decoded = fn(payload, from_dict(EGO), time.time())  # as the decoder calls it
        assert np.array_equal(decoded.trajectory.control_points, CPS)

        # another definition of the type (a different hash): a clear error, not silence
        swarm = store("int32 drone_id\n" + open_definition())
        other = peer.key("/planning/bspline", "traj_utils::msg::dds_::Bspline_",
                         swarm.hash_rihs01(BSPLINE))
        peer.publish(other, bspline_cdr(ts=swarm, drone_id=1))
        kind, fn, payload = inbox.get()
        with pytest.raises(Rejected, match="type hash RIHS01_.* is not RIHS01_"):
            fn(payload, from_dict(EGO), time.time())  # as the decoder calls it

        # status out: the exact key of std_msgs/String with the design document's hash
        got: queue.Queue = queue.Queue()
        sub = ros.declare_subscriber(f"0/rota/status/std_msgs::msg::dds_::String_/{STRING_HASH}",
                                     lambda s: got.put((s.payload.to_bytes(),
                                                        s.attachment.to_bytes())))
        status = {"schema": "rota/status", "state": "ready", "progress": 0.5}
        sample = publish_until_received(lambda: link.publish_status(status), got)
        msg = TS.deserialize_cdr(sample[0], "std_msgs/msg/String")
        assert json.loads(msg.data) == status
        seq, ts, gid = parse_attachment(sample[1])
        assert struct.unpack("<qqB16s", sample[1]) == (seq, ts, 16, gid)  # the documented bytes
        # the GID rmw_zenoh's graph derives from the publisher's token
        assert gid == rmw_gid(next(t for t in tokens if "/MP/" in t and "%rota%status/" in t))
        assert abs(ts / 1e9 - time.time()) < 5
        link.publish_status(status)
        assert parse_attachment(got.get(timeout=5)[1])[0] == seq + 1
        sub.undeclare()
    finally:
        peer.close()
        link.close()
    peer.wait_gone(f"@ros2_lv/0/{zid}/**")  # close() undeclared every token


def open_definition() -> str:
    from companion.ros2.types import BSPLINE_MSGS
    return BSPLINE_MSGS["ego-planner"]


def publish_until_received(publish, got: queue.Queue, timeout: float = 10.0):
    """Publish until the remote subscriber (whose declaration propagates
    asynchronously) has one."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        publish()
        try:
            return got.get(timeout=0.2)
        except queue.Empty:
            continue
    raise TimeoutError("nothing received")


@pytest.mark.parametrize(("ns", "topic", "key_topic"), [
    ("/bot1", "planning/bspline", "bot1/planning/bspline"),  # relative: under the namespace
    ("/bot1", "/planning/bspline", "planning/bspline"),  # absolute: as it is
])
def test_rmw_zenoh_domain_and_namespace(sessions, ns, topic, key_topic):
    service, ros = sessions
    inbox = Inbox()
    link = Ros2Link(service, settings(domain_id=7, namespace=ns, bspline_topic=topic), inbox)
    peer = RosPeer(ros, "rmw_zenoh", domain=7)
    try:
        zid = str(service.zid())
        tokens = peer.wait_tokens(f"@ros2_lv/7/{zid}/**", 4)
        assert f"@ros2_lv/7/{zid}/0/0/NN/%/%bot1/rota_companion" in tokens
        h = TS.hash_rihs01(BSPLINE)
        peer.publish(f"7/{key_topic}/traj_utils::msg::dds_::Bspline_/{h}", bspline_cdr())
        assert inbox.get()[0] == "bspline"
    finally:
        peer.close()
        link.close()


# --------------------------------------------------------------- ros2dds
@pytest.mark.parametrize("ns", ["", "/bot1"])
def test_ros2dds_bspline_in_status_and_retimed_out(sessions, ns):
    service, ros = sessions
    inbox = Inbox()
    s = settings(layout="ros2dds", namespace=ns)
    link = Ros2Link(service, s, inbox)
    bridge = RosPeer(ros, "ros2dds", namespace=ns)
    pre = f"{ns.strip('/')}§" if ns else ""
    try:
        zid = str(service.zid())
        tokens = bridge.wait_tokens(f"@/{zid}/@ros2_lv/**", 4)
        h = TS.hash_rihs01(BSPLINE)
        mt = "RIHS01_3a18fd095292a65cfde8833c72985a30af981f3ec44494655c6267262b443a4a"
        assert tokens == {
            f"@/{zid}/@ros2_lv",  # "a bridge is here"
            f"@/{zid}/@ros2_lv/MS/{pre}planning§bspline/traj_utils§msg§Bspline/:1:0:0,10:"
            f"typehash={h};",
            f"@/{zid}/@ros2_lv/MP/{pre}rota§status/std_msgs§msg§String/:1:0:0,10:"
            f"typehash={STRING_HASH};",
            f"@/{zid}/@ros2_lv/MP/{pre}rota§retimed/trajectory_msgs§msg§MultiDOFJointTrajectory"
            f"/:1:0:0,10:typehash={mt};"}
        key = bridge.advertise("/planning/bspline", BSPLINE, "", h)
        assert key == f"{ns.strip('/')}/planning/bspline".lstrip("/")
        cdr = bspline_cdr()
        bridge.publish(key, cdr)
        assert inbox.get() == ("bspline", decode.decode_bspline, cdr)

        # the re-timed trajectory: what a DDS subscriber behind the bridge receives
        got: queue.Queue = queue.Queue()
        sub = ros.declare_subscriber(f"{ns.strip('/')}/rota/retimed".lstrip("/"),
                                     lambda smp: got.put((smp.payload.to_bytes(),
                                                          smp.attachment)))
        traj = BSplineTrajectory(control_points=CPS, degree=3, knot_span=0.4)
        result = retime(RetimeInput(trajectory=traj, limits=Limits(1.0, 2.0)))
        payload = json.dumps(result_to_dict(result, TrajectoryMessage(traj, id="r"))).encode()
        cdr_out, att = publish_until_received(lambda: link.publish_retimed(payload), got)
        assert att is None  # the bridge layout has no attachment
        msg = TS.deserialize_cdr(cdr_out, "trajectory_msgs/msg/MultiDOFJointTrajectory")
        assert msg.header.frame_id == "world" and msg.joint_names == ["base_link"]
        t = np.array([p.time_from_start.sec + p.time_from_start.nanosec * 1e-9
                      for p in msg.points])
        pos = np.array([[p.transforms[0].translation.x, p.transforms[0].translation.y,
                         p.transforms[0].translation.z] for p in msg.points])
        vel = np.array([[p.velocities[0].linear.x, p.velocities[0].linear.y,
                         p.velocities[0].linear.z] for p in msg.points])
        ref = result.sample(t)
        assert t[-1] == pytest.approx(result.duration, abs=1e-6) and np.all(np.diff(t) > 0)
        assert np.allclose(pos, ref.position, atol=1e-9)
        assert np.allclose(vel, ref.velocity, atol=1e-9)
        assert np.linalg.norm(vel, axis=1).max() <= 1.0 + 1e-3
        # and the service's own output is valid input
        back = decode.decode_multidof(cdr_out, from_dict({"ros2": {"multidof_topic": "/x"}}))
        assert np.allclose(back.trajectory.p, pos)
        sub.undeclare()
    finally:
        bridge.close()
        link.close()
