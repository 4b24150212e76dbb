"""``rota-gs send --ros2`` as a user runs it, against the service in its own process
with ``[ros2]`` on and the ``sitl`` vehicle on the ground (a trajectory is re-timed
without flying), over real Zenoh on loopback: a planner's Bspline and a point cloud as
files in ROS field names reach the service over rmw_zenoh's layout, are decoded and
used; invalid ones get one-line errors."""

from __future__ import annotations

import asyncio
import json
import signal
import subprocess
import sys

import numpy as np
import pytest

from companion.gs import GroundStation
from companion.settings.config import to_toml
from sitl.demo import demo_config, free_tcp_port
from sitl.mavsdk_util import free_udp_port
from sitl.process import SimProcess
from tests.helpers.ros2 import bspline_fields, echo_yaml

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(180)]


@pytest.fixture(scope="module")
def service(tmp_path_factory):
    """(run rota-gs with ARGS, the ground station, the work directory)."""
    tmp = tmp_path_factory.mktemp("gs-ros2")
    mav, zport = free_udp_port(), free_tcp_port()
    cfg = demo_config(mav, zport, 2.0, str(tmp / "state"), record={"enabled": False},
                      ros2={"enabled": True, "pointcloud_topic": "/map_generator/global_cloud",
                            "bspline_msg": "ego-planner"})
    config = tmp / "companion.toml"
    config.write_text(to_toml(cfg))
    endpoint = f"tcp/127.0.0.1:{zport}"

    def rota_gs(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "companion.gs.cli", *args, "--config",
                               str(config), "--connect", endpoint, "-V", "sim"],
                              capture_output=True, text=True, timeout=60)

    with SimProcess(port=mav, world="pillar", seed=0):
        proc = subprocess.Popen(  # noqa: S603
            [sys.executable, "-m", "companion.cli", "run", "--config", str(config)],
            stdout=open(tmp / "service.log", "w"), stderr=subprocess.STDOUT)  # noqa: SIM115
        gs = GroundStation("sim", connect=[endpoint], wait_s=30)
        try:
            asyncio.run(gs.wait_for(lambda s: s["state"] == "ready", 60, "a ready vehicle"))
            yield rota_gs, gs, tmp
        finally:
            gs.close()
            proc.send_signal(signal.SIGTERM)
            proc.wait(30)


def one_line(r: subprocess.CompletedProcess, code: int, text: str) -> None:
    assert r.returncode == code, (r.stdout, r.stderr)
    assert r.stderr.count("\n") == 1 and text in r.stderr, r.stderr


def test_a_planners_bspline_is_decoded_and_retimed(service):
    rota_gs, gs, tmp = service
    fields = bspline_fields() | {"traj_id": 7}  # stamped 2024: rota-gs stamps it now
    (tmp / "msg.json").write_text(json.dumps(fields))
    r = rota_gs("send", "--ros2", "bspline", str(tmp / "msg.json"))
    assert r.returncode == 0, (r.stdout, r.stderr)
    assert r.stdout.startswith("bspline-7: optimal, ") and " s re-timed" in r.stdout, r.stdout
    status = asyncio.run(gs.wait_for(lambda s: (s.get("last_retime") or {}).get("id")
                                     == "bspline-7", 5, "the re-time on status"))
    assert status["state"] == "ready"  # on the ground: re-timed, not flown
    assert gs.retimed[-1]["id"] == "bspline-7"
    print(r.stdout, end="")

    # the same as ros2 topic echo prints it (YAML), another traj_id
    (tmp / "msg.yaml").write_text(echo_yaml(fields | {"traj_id": 8}))
    r = rota_gs("send", "--ros2", "bspline", str(tmp / "msg.yaml"))
    assert r.returncode == 0 and r.stdout.startswith("bspline-8: optimal, "), r

    # invalid for the service (a NaN control point): its error, on one line
    bad = fields | {"traj_id": 9}
    bad["pos_pts"][5]["y"] = float("nan")
    (tmp / "nan.json").write_text(json.dumps(bad))
    one_line(rota_gs("send", "--ros2", "bspline", str(tmp / "nan.json")), 1,
             "rota-gs: 'bspline-9' rejected: bspline /planning/bspline: pos_pts[5].y: must be "
             "finite, got nan")
    # not a Bspline at all: refused before sending
    (tmp / "swarm.json").write_text(json.dumps(fields | {"drone_id": 1}))
    one_line(rota_gs("send", "--ros2", "bspline", str(tmp / "swarm.json")), 2,
             "rota-gs send: bad input: ")
    assert "drone_id: not a field of traj_utils/msg/Bspline" in rota_gs(
        "send", "--ros2", "bspline", str(tmp / "swarm.json")).stderr


def test_a_point_cloud_becomes_the_map(service):
    rota_gs, gs, tmp = service
    # four FLOAT32 x y z points, two of them in one 0.1 m voxel, as ros2 topic echo prints
    pts = np.array([[2.0, 0.0, 1.0], [2.02, 0.03, 1.01], [2.5, 0.0, 1.0], [3.0, 1.0, 1.5]],
                   dtype="<f4")
    fields = "".join(f"- name: {a}\n  offset: {4 * k}\n  datatype: 7\n  count: 1\n"
                     for k, a in enumerate("xyz"))
    data = "".join(f"- {b}\n" for b in pts.tobytes())
    (tmp / "cloud.yaml").write_text(
        "header:\n  stamp:\n    sec: 1718000000\n    nanosec: 0\n  frame_id: world\n"
        f"height: 1\nwidth: 4\nfields:\n{fields}is_bigendian: false\npoint_step: 12\n"
        f"row_step: 48\ndata:\n{data}is_dense: true\n---\n")
    r = rota_gs("send-map", "--ros2", str(tmp / "cloud.yaml"))
    assert r.returncode == 0, (r.stdout, r.stderr)
    assert "3 occupied voxels at 0.1 m in use" in r.stdout, r.stdout
    assert gs.status["map_voxels"] == 3
    print(r.stdout, end="")
    # a cloud in another frame: refused with the service's own words, before sending
    (tmp / "map.yaml").write_text((tmp / "cloud.yaml").read_text().replace("world", "map"))
    one_line(rota_gs("send-map", "--ros2", str(tmp / "map.yaml")), 2,
             "header.frame_id: 'map' is not the configured frame 'world'")
