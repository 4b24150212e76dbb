"""Fixtures of the service's unit tests."""

from __future__ import annotations

import pytest

from sitl.demo import free_tcp_port
from tests.helpers.ros2 import open_session


@pytest.fixture
def sessions():
    """Two Zenoh sessions on loopback: the service's (listening) and a ROS peer's."""
    port = free_tcp_port()
    service = open_session(listen=f"tcp/127.0.0.1:{port}")
    ros = open_session(connect=f"tcp/127.0.0.1:{port}")
    yield service, ros
    ros.close()
    service.close()
