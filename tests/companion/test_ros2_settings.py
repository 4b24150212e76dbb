"""The [ros2] section: defaults load, every bad value is refused naming the setting."""

from __future__ import annotations

import pytest

from companion.ros2.layout import resolve
from companion.settings.config import ConfigError, from_dict


def test_defaults_are_off_and_valid():
    cfg = from_dict({})
    assert not cfg.ros2.enabled and cfg.ros2.layout == "rmw_zenoh"
    assert from_dict({"ros2": {"enabled": True, "layout": "ros2dds"}}).ros2.layout == "ros2dds"


@pytest.mark.parametrize(("values", "words"), [
    ({"layout": "dds"}, r"\[ros2\] layout: must be one of rmw_zenoh, ros2dds"),
    ({"domain_id": 300}, r"\[ros2\] domain_id"),
    ({"domain_id": 1.5}, r"\[ros2\] domain_id: must be an integer"),
    ({"namespace": "bot1"}, r"\[ros2\] namespace"),
    ({"node_name": "rota companion"}, r"\[ros2\] node_name"),
    ({"frame_id": ""}, r"\[ros2\] frame_id"),
    ({"bspline_topic": "/planning//bspline"}, r"\[ros2\] bspline_topic"),
    ({"path_topic": "/1path"}, r"\[ros2\] path_topic"),
    ({"status_topic": "rota/status*"}, r"\[ros2\] status_topic"),
    ({"bspline_type": "traj_utils/Bspline"}, r"\[ros2\] bspline_type"),
    ({"bspline_msg": "/no/such/Bspline.msg"}, r"\[ros2\] bspline_msg: neither a built-in"),
    ({"cloud_resolution": 0.0}, r"\[ros2\] cloud_resolution: must be positive"),
    ({"max_cloud_points": 0}, r"\[ros2\] max_cloud_points"),
    ({"retimed_rate_hz": -1.0}, r"\[ros2\] retimed_rate_hz"),
    ({"topic": "/x"}, r"\[ros2\] topic: unknown setting"),
    ({"distro": "iron"}, r"\[ros2\] distro: must be one of humble, jazzy, kilted, rolling"),
])
def test_bad_settings_are_refused_naming_them(values, words):
    with pytest.raises(ConfigError, match=words):
        from_dict({"ros2": values})


@pytest.mark.parametrize("distro", ["jazzy", "kilted", "rolling"])
def test_the_distros_after_humble_speak_alike(distro):
    """Jazzy, Kilted and Rolling: the same RIHS01 keys (only Humble's differ)."""
    from companion.ros2.types import HUMBLE_HASH, type_hash

    cfg = from_dict({"ros2": {"distro": distro}}).ros2
    assert type_hash("std_msgs/msg/String", distro=cfg.distro) == \
        type_hash("std_msgs/msg/String", distro="jazzy") != HUMBLE_HASH
    assert type_hash("std_msgs/msg/String", distro="humble") == HUMBLE_HASH


def test_a_bspline_msg_file_without_the_needed_fields_is_refused(tmp_path):
    f = tmp_path / "Bspline.msg"
    f.write_text("int32 order\nfloat64[] knots\n")
    with pytest.raises(ConfigError, match="lacks the field.*pos_pts, start_time"):
        from_dict({"ros2": {"bspline_msg": str(f)}})
    f.write_text("int32[ order\n")
    with pytest.raises(ConfigError, match="not a valid .msg definition"):
        from_dict({"ros2": {"bspline_msg": str(f)}})


def test_topic_names_resolve_like_ros():
    assert resolve("planning/bspline", "") == "/planning/bspline"
    assert resolve("planning/bspline", "/bot1") == "/bot1/planning/bspline"
    assert resolve("planning/bspline", "/a/b/") == "/a/b/planning/bspline"
    assert resolve("/planning/bspline", "/bot1") == "/planning/bspline"
