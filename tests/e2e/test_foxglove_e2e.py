"""Foxglove end to end: the service (a process, as systemd runs it) flies the sitl
vehicle over real MAVLink/UDP and Zenoh on loopback while ``rota-gs foxglove``'s
server serves it to a real WebSocket client (Foxglove's protocol); then the service
is killed with SIGKILL mid-flight, as a power loss would, and its flight record is
read back: every message up to the last whole chunk decodes with its schema."""

from __future__ import annotations

import asyncio
import base64
import json
import os
import signal
import struct
import subprocess
import sys
import threading
import time

import jsonschema
import numpy as np
import pytest
import websockets
from mcap.reader import make_reader
from mcap.records import Schema as McapSchema
from mcap_protobuf.decoder import DecoderFactory

from companion.gs import GroundStation
from companion.gs.foxglove import LiveView
from companion.recording.record import CHUNK_BYTES, read_raw
from companion.settings.config import to_toml
from sitl.demo import (
    demo_config,
    free_tcp_port,
    plan_async,
    start_holding,
    take_off,
    to_local,
    trajectory_message,
)
from sitl.mavsdk_util import free_udp_port
from sitl.process import SimProcess
from sitl.stream_checks import check_stream
from sitl.world import get_world
from tests.helpers.foxglove import decode_all

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(300)]
SPEED = 2.0
SHOWN = {"/foxglove/map", "/foxglove/plan", "/foxglove/setpoint", "/foxglove/vehicle", "/tf",
         "/foxglove/body", "/plot/command", "/plot/vehicle"}


class FoxgloveClient:
    """A WebSocket client of Foxglove's protocol (as Foxglove's app is), in a thread:
    subscribes to every channel the server advertises and keeps what arrives."""

    def __init__(self, port: int) -> None:
        self.port = port
        self.channels: dict[int, dict] = {}
        self.subs: dict[int, int] = {}  # subscription id -> channel id
        self.received: list[tuple[str, int, bytes]] = []  # (topic, log time ns, payload)
        self.protocol: str | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=lambda: asyncio.run(self._run()), daemon=True)
        self._thread.start()

    async def _run(self) -> None:
        async with websockets.connect(f"ws://127.0.0.1:{self.port}",
                                      subprotocols=["foxglove.sdk.v1"]) as ws:
            self.protocol = ws.subprotocol
            while not self._stop.is_set():
                try:
                    msg = await asyncio.wait_for(ws.recv(), 0.2)
                except TimeoutError:
                    continue
                if isinstance(msg, bytes):
                    op, sub, stamp = struct.unpack_from("<BIQ", msg)
                    if op == 1:  # message data
                        topic = self.channels[self.subs[sub]]["topic"]
                        self.received.append((topic, stamp, msg[13:]))
                    continue
                m = json.loads(msg)
                if m.get("op") == "advertise":
                    new = []
                    for ch in m["channels"]:
                        self.channels[ch["id"]] = ch
                        sid = len(self.subs) + 1
                        self.subs[sid] = ch["id"]
                        new.append({"id": sid, "channelId": ch["id"]})
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))

    def topics(self) -> set[str]:
        return {t for t, _, _ in self.received}

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)


@pytest.fixture(scope="module")
def killed_flight(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("fox-e2e")
    world = get_world("forest", seed=3)
    mav, zport = free_udp_port(), free_tcp_port()
    cfg = demo_config(mav, zport, SPEED, str(tmp))
    (tmp / "companion.toml").write_text(to_toml(cfg))
    out: dict = {}
    with SimProcess(port=mav, world="forest", seed=3) as sim:
        log = open(tmp / "service.log", "w")  # noqa: SIM115 - closed below
        # its own process group: the kill takes its worker processes too, as a power
        # loss would
        proc = subprocess.Popen([sys.executable, "-m", "companion.cli", "run", "--config",
                                 str(tmp / "companion.toml")], stdout=log,
                                stderr=subprocess.STDOUT, start_new_session=True)
        endpoint = f"tcp/127.0.0.1:{zport}"
        gs = GroundStation.for_service(cfg, endpoint, wait_s=30)
        live = LiveView(GroundStation.for_service(cfg, endpoint, wait_s=30), port=0)
        client = FoxgloveClient(live.port)
        try:
            async def scenario():
                home = sim.home_enu
                await take_off(gs, world, home)  # publishes the map
                here = await start_holding(gs) + home
                traj = await plan_async(world, v_max=SPEED, a_max=2.0, start=here,
                                        goal=[world.goal[0], world.goal[1], here[2]])
                gs.publish("trajectory", trajectory_message(to_local(traj, home), "plan-0"))
                await gs.wait_for(lambda s: s.get("command") == "plan", 15, "the plan")
                t0 = time.monotonic()
                await gs.wait_for(lambda s: (s.get("progress") or 0) > 0.5, 60, "progress")
                end = time.monotonic() + 20
                while not SHOWN <= client.topics() and time.monotonic() < end:
                    await asyncio.sleep(0.1)
                return t0

            out["t0"] = asyncio.run(scenario())
            out["kill_mono"], out["kill"] = time.monotonic(), time.time()
            os.killpg(proc.pid, signal.SIGKILL)  # no chance to finish the file
            out["returncode"] = proc.wait(timeout=20)
        finally:
            client.close()
            live.close()
            live.gs.close()
            gs.close()
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
            log.close()
    print((tmp / "service.log").read_text()[-3000:])
    out.update(client=client, report=sim.report, files=sorted((tmp / "records").glob("*.mcap")))
    return out


def test_the_live_server_serves_the_flight_to_a_websocket_client(killed_flight):
    client = killed_flight["client"]
    assert client.protocol == "foxglove.sdk.v1"
    assert SHOWN <= client.topics(), client.topics()
    factory, decoders, got = DecoderFactory(), {}, {}
    by_topic = {ch["topic"]: ch for ch in client.channels.values()}
    for topic, _, payload in client.received:
        ch = by_topic[topic]
        if ch["encoding"] == "protobuf":
            assert ch["schemaEncoding"] == "protobuf"
            schema = McapSchema(id=ch["id"], name=ch["schemaName"], encoding="protobuf",
                                data=base64.b64decode(ch["schema"]))
            dec = decoders.setdefault(topic, factory.decoder_for("protobuf", schema))
            got.setdefault(topic, []).append(dec(payload))
        else:
            assert ch["encoding"] == "json" and ch["schemaEncoding"] == "jsonschema"
            obj = json.loads(payload)
            jsonschema.validate(obj, json.loads(ch["schema"]))  # as advertised
            got.setdefault(topic, []).append(obj)
    (update,) = got["/foxglove/map"][:1]
    assert len(update.entities[0].cubes) > 100  # the forest's trees
    plan = got["/foxglove/plan"][-1].entities[0]
    assert {kv.key: kv.value for kv in plan.metadata}["plan"] == "plan-0"
    assert len(plan.lines) >= 2 and len(plan.lines[1].colors) == len(plan.lines[1].points)
    tf = got["/tf"][-1]
    assert (tf.parent_frame_id, tf.child_frame_id) == ("map", "base_link")
    assert tf.translation.z > 0.5  # airborne
    cmd = got["/plot/command"]
    assert {c["v_max"] for c in cmd} == {SPEED} and max(c["speed"] for c in cmd) > 0.5
    assert any(c["plan"] == "plan-0" for c in cmd)
    assert any(v["tracking_error"] is not None for v in got["/plot/vehicle"])
    # the service's events, as the record has its log
    logs = [m.message for m in got.get("/foxglove/log", ())]
    assert any("autopilot connected" in m for m in logs), logs


def test_a_service_killed_mid_flight_leaves_a_record_readable_to_its_last_chunk(
        killed_flight):
    assert killed_flight["returncode"] == -signal.SIGKILL
    (path,) = killed_flight["files"]
    with open(path, "rb") as fh:  # cut short: no summary, no footer
        with pytest.raises(Exception):  # noqa: B017, PT011 - mcap's own error types vary
            make_reader(fh).get_summary()
    got = decode_all([path])  # every message there decodes with its schema
    assert SHOWN <= set(got) and {"/setpoint", "/telemetry", "/map", "/retimed"} <= set(got)
    sizes = [(m.log_time / 1e9, len(m.data)) for _, _, m in read_raw([path])]
    stamps = np.array([s for s, _ in sizes])
    # nothing but the unfinished chunk is lost: the record reaches to within one
    # chunk's worth of flight (at its measured data rate) of the kill, plus 1 s for
    # the writer's 50 ms wake-ups and a busy machine
    rate = sum(n for _, n in sizes) / (stamps.max() - stamps.min())
    assert stamps.max() > killed_flight["kill"] - CHUNK_BYTES / rate - 1.0
    print(f"record ends {killed_flight['kill'] - stamps.max():.2f} s before the kill; "
          f"one chunk is {CHUNK_BYTES / rate:.1f} s of flight")
    # one Foxglove pose per setpoint recorded (written just after it: the cut may
    # fall between the two)
    assert len(got["/setpoint"]) - len(got["/foxglove/setpoint"]) in (0, 1)
    assert len(got["/setpoint"]) > 100


def test_the_stream_was_not_held_up_while_recording_for_foxglove(killed_flight):
    report = killed_flight["report"]
    figures = check_stream(report.setpoints, SPEED * 1.5, None, report.home_enu,
                           (killed_flight["t0"], killed_flight["kill_mono"] - 0.3),
                           host_steal=report.host_steal)
    print("vehicle side:", figures.summary())
    assert not figures.problems(), figures.summary()
