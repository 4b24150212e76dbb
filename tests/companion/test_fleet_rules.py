"""Only the vehicle speaks for the vehicle, and the fleet's names cannot collide.

A fleet made by ``rota-companion fleet`` tried with real Zenoh sessions on
loopback (mutual TLS and the vehicle's access control as generated): the
vehicle is a Zenoh session opened with its own fleet config that publishes
through the service's own :class:`~companion.status.Publisher`; the planner
(its fleet certificate), another vehicle of the fleet, a local process on the
vehicle's plain loopback listener and the ground station itself try to put on
the vehicle's outputs, declare its liveliness token or ghosts, and answer its
queries. Without the fleet (the embedded loopback default, no access control)
the ground station's own check stops the plain forgeries and the ghosts.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh

from companion.gs.client import GroundStation, list_vehicles
from companion.network.fleet import Fleet, FleetNameError, check_names, client_config, make_fleet
from companion.service import Service
from companion.status import Publisher
from sitl.demo import free_tcp_port

#: How long a put or a declaration takes to reach the other sessions on loopback
#: (measured: under 50 ms on this 2-core machine while busy; 1 s is the margin).
SETTLE_S = 1.0


def _open(config: dict | Path) -> zenoh.Session:
    if isinstance(config, Path):
        return zenoh.open(zenoh.Config.from_file(str(config)))
    return zenoh.open(zenoh.Config.from_json5(json.dumps(config)))


def _loopback_client(port: int) -> dict:
    return {"mode": "client", "connect": {"endpoints": [f"tcp/127.0.0.1:{port}"]},
            "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}}}


class FakeVehicle:
    """A Zenoh session as the service opens it: the same publishers with the same
    source info, the ``alive`` token and a ``config`` queryable."""

    def __init__(self, session: zenoh.Session, prefix: str = "rota/sim") -> None:
        self.session = s = session
        self.pubs = {n: s.declare_publisher(f"{prefix}/{n}") for n in ("status", "telemetry")}
        self.publisher = Publisher(self.pubs, dict, dict, source=Service._source_info(s))
        self.token = s.liveliness().declare_token(f"{prefix}/alive")
        self.queryable = s.declare_queryable(
            f"{prefix}/config", lambda q: q.reply(q.key_expr, b'{"ok": true}'))

    def status(self, state: str) -> None:
        self.publisher.put("status", {"state": state})

    def close(self) -> None:
        self.session.close()


def _wait(predicate, what: str, timeout_s: float = 10.0, each=None) -> None:
    """Wait until ``predicate()``; ``each()`` is called every 0.2 s meanwhile (to
    send again what a subscriber not yet known to the network would miss)."""
    end = time.monotonic() + timeout_s
    k = 0
    while not predicate():
        if time.monotonic() > end:
            raise TimeoutError(what)
        if each is not None and k % 10 == 0:
            each()
        k += 1
        time.sleep(0.02)


@pytest.fixture
def fleet(tmp_path):
    lo, tls = free_tcp_port(), free_tcp_port()
    root = tmp_path / "fleet"
    make_fleet(Fleet(vehicles=("sim", "other"), hosts={"sim": "127.0.0.1", "other": "127.0.0.1"},
                     loopback_port=lo, tls_port=tls), root)
    return root, lo, tls


@pytest.mark.timeout(120)
def test_no_member_nor_local_process_speaks_for_the_vehicle(fleet):
    """The forgeries of issue 25 (the planner's status and telemetry over mutual
    TLS, a local process's on the plain loopback listener, ghost tokens) reach
    neither the vehicle nor the ground station; the vehicle's own outputs,
    token and answers do. (With the rules made before, the planner's and the
    local process's forgeries and both ghosts reached the ground station.)"""
    root, lo, tls = fleet
    vehicle = FakeVehicle(_open(root / "sim" / "zenoh.json5"))
    heard_by_vehicle: list[str] = []
    spy = vehicle.session.declare_subscriber(
        "rota/sim/**", lambda s: heard_by_vehicle.append(s.payload.to_bytes().decode()))
    gs = GroundStation("sim", config_file=str(root / "gs" / "zenoh-sim.json5"), wait_s=10)
    forgers = {
        "planner": _open(root / "planner-sim" / "zenoh.json5"),
        "other vehicle": _open(client_config([f"tls/127.0.0.1:{tls}"], str(root / "other"))),
        "local process": _open(_loopback_client(lo)),
    }
    raw: list[str] = []  # what reaches the ground station's session, before its own check
    taps = [gs.session.declare_subscriber(k, lambda s: raw.append(s.payload.to_bytes().decode()))
            for k in ("rota/sim/status", "rota/sim/telemetry")]
    try:
        tokens = [s.liveliness().declare_token(k) for s in forgers.values()
                  for k in ("rota/ghost/alive", "rota/sim/alive")]
        fake_config = forgers["planner"].declare_queryable(
            "rota/sim/estimator", lambda q: q.reply(q.key_expr, b'{"forged": true}'))
        time.sleep(SETTLE_S)  # the declarations to propagate (nothing to wait on: denied)
        _wait(lambda: gs.status.get("state") == "real", "the vehicle's status",
              each=lambda: vehicle.status("real"))
        for who, s in forgers.items():
            s.put("rota/sim/status", json.dumps({"state": f"forged by {who}"}))
            s.put("rota/sim/telemetry", json.dumps({"setpoint": {"position": [99, 99, 99]},
                                                   "by": who}))
        for who in ("planner", "local process", "other vehicle"):
            forgers[who].put("rota/sim/trajectory", f"plan from {who}".encode())
        vehicle.status("real, after the forgeries")
        _wait(lambda: gs.status.get("state") == "real, after the forgeries", "the next status")
        time.sleep(SETTLE_S)  # any forgery would have arrived by now
        vehicles = list_vehicles(gs.session, "rota")
        answers = [r.ok.payload.to_bytes() for r in gs.session.get("rota/sim/estimator",
                                                                    timeout=2) if r.ok]
        assert {s["state"] for s in gs.statuses} == {"real", "real, after the forgeries"}
        assert any("real" in m for m in raw) and not any("forged" in m or "99" in m
                                                         for m in raw), raw
        assert any("real" in m for m in heard_by_vehicle) and not any(
            "forged" in m or "99" in m for m in heard_by_vehicle), heard_by_vehicle
        assert [(v.id, v.zid) for v in vehicles] == [("sim", str(vehicle.session.zid()))]
        assert answers == [], answers
        # the planners' path is open (so the denials above are the rules, not a dead
        # link): the planner's and the local process's trajectories arrive, not a
        # stranger's of the fleet
        _wait(lambda: {"plan from planner", "plan from local process"} <= set(heard_by_vehicle),
              "the planners' trajectories")
        assert "plan from other vehicle" not in heard_by_vehicle
        assert gs.vehicle_zid == str(vehicle.session.zid())
        del tokens, fake_config, taps
    finally:
        spy.undeclare()
        gs.close()
        for s in forgers.values():
            s.close()
        vehicle.close()


@pytest.mark.timeout(120)
def test_the_ground_station_ignores_outputs_from_another_session(tmp_path):
    """Without a fleet (the embedded loopback default, no access control), a local
    process publishes a status and telemetry on the vehicle's keys, with and
    without a source of its own, and declares a ghost's token: the ground
    station keeps the vehicle's status, counts the others as ignored, and lists
    only the vehicle that answers."""
    port = free_tcp_port()
    vehicle = FakeVehicle(_open({"mode": "peer", "listen": {"endpoints": [
        f"tcp/127.0.0.1:{port}"]}, "scouting": {"multicast": {"enabled": False},
                                               "gossip": {"enabled": False}}}))
    forger = _open(_loopback_client(port))
    gs = GroundStation("sim", connect=[f"tcp/127.0.0.1:{port}"], wait_s=10)
    try:
        _wait(lambda: gs.vehicle_zid is not None, "the vehicle's identity")
        ghost = forger.liveliness().declare_token("rota/ghost/alive")
        _wait(lambda: gs.status.get("state") == "real", "the vehicle's status",
              each=lambda: vehicle.status("real"))
        forger.put("rota/sim/status", b'{"state": "forged"}')
        forger.put("rota/sim/status", b'{"state": "forged, own source"}',
                   source_info=zenoh.SourceInfo(forger.id, 1))
        forger.put("rota/sim/telemetry", b'{"setpoint": {"position": [99, 99, 99]}}')
        _wait(lambda: gs.ignored >= 3, "the forgeries to arrive (and be ignored)")
        vehicle.status("real again")
        _wait(lambda: gs.status.get("state") == "real again", "the vehicle's next status")
        assert {s["state"] for s in gs.statuses} == {"real", "real again"}
        assert gs.telemetry == {} and gs.ignored == 3
        assert [v.id for v in list_vehicles(gs.session, "rota")] == ["sim"]
        del ghost
    finally:
        gs.close()
        forger.close()
        vehicle.close()


@pytest.mark.timeout(120)
def test_a_restarted_service_is_heard_again(tmp_path):
    """A restarted service is a new Zenoh session: the ground station asks again
    who answers as the vehicle and takes the new session's status."""
    port = free_tcp_port()
    cfg = {"mode": "peer", "listen": {"endpoints": [f"tcp/127.0.0.1:{port}"]},
           "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}}}
    first = FakeVehicle(_open(cfg))
    gs = GroundStation("sim", connect=[f"tcp/127.0.0.1:{port}"], wait_s=10)
    try:
        _wait(lambda: gs.vehicle_zid == str(first.session.zid()), "the first identity")
        first.close()
        second = FakeVehicle(_open(cfg))
        try:
            _wait(lambda: gs.session.info.peers_zid(), "the ground station to reconnect", 30)
            end = time.monotonic() + 30
            while gs.status.get("state") != "second" and time.monotonic() < end:
                second.status("second")
                time.sleep(0.2)
            assert gs.status.get("state") == "second"
            assert gs.vehicle_zid == str(second.session.zid())
        finally:
            second.close()
    finally:
        gs.close()


# ------------------------------------------------------------------ names
@pytest.mark.parametrize(("vehicles", "stations", "words"), [
    (("gs",), ("gs",), "both a vehicle and a ground station"),
    (("../escape",), ("gs",), "letters, digits"),
    (("a/b",), ("gs",), "letters, digits"),
    (("..",), ("gs",), "letters, digits"),
    (("drone1",), ("../gs",), "letters, digits"),
    (("x" * 33,), ("gs",), "letters, digits"),
    (("",), ("gs",), "letters, digits"),
    (("drone 1",), ("gs",), "letters, digits"),
    (("drone1", "drone1"), ("gs",), "given twice"),
    (("drone1",), ("gs", "gs"), "given twice"),
    (("drone1",), ("drone1",), "both a vehicle and a ground station"),
    (("ca",), ("gs",), "reserved"),
    (("drone1",), ("planner-drone1",), "reserved"),
    (("planner-x",), ("gs",), "reserved"),
    ((), ("gs",), "no vehicles"),
])
def test_colliding_or_unsafe_names_are_refused(tmp_path, vehicles, stations, words):
    with pytest.raises(FleetNameError, match=words):
        check_names(Fleet(vehicles=vehicles, ground_stations=stations), tmp_path)


@pytest.mark.parametrize("host", ["10.0.0.1#enable_mtls=false", "10.0.0.1:9999", "a/b",
                                  "h?x=1", "fd00::1"])
def test_a_host_that_would_change_the_endpoint_is_refused(host):
    with pytest.raises(FleetNameError, match="not a host name or IP"):
        check_names(Fleet(vehicles=("drone1",), hosts={"drone1": host}))


def test_good_names_and_hosts_pass():
    check_names(Fleet(vehicles=("drone1", "Drone_2", "x" * 32), ground_stations=("gs", "gs-2"),
                      hosts={"drone1": "10.0.0.11", "Drone_2": "drone2.local",
                             "x" * 32: "[fd00::2]"}))


def test_a_member_cannot_change_kind_when_the_fleet_grows(tmp_path):
    make_fleet(Fleet(vehicles=("drone1",), hosts={"drone1": "127.0.0.1"}), tmp_path / "f")
    with pytest.raises(FleetNameError, match="already a vehicle"):
        make_fleet(Fleet(vehicles=("drone2",), ground_stations=("drone1",)), tmp_path / "f")
    with pytest.raises(FleetNameError, match="already a ground station"):
        make_fleet(Fleet(vehicles=("gs",), ground_stations=("base",)), tmp_path / "f")
    make_fleet(Fleet(vehicles=("drone2",)), tmp_path / "f")  # growing the same way is fine
    assert (tmp_path / "f" / "drone2" / "zenoh.json5").is_file()


@pytest.mark.parametrize("args", [["--vehicles", "gs"], ["--vehicles", "../escape"],
                                  ["--vehicles", "a,a"], ["--vehicles", "a", "--host", "a"]])
def test_the_fleet_command_says_why_in_one_line(tmp_path, args):
    done = subprocess.run([sys.executable, "-m", "companion.cli", "fleet",
                           str(tmp_path / "f"), *args], capture_output=True, text=True)
    assert done.returncode == 2, done.stderr
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert done.stderr.startswith("rota-companion fleet: ")
    assert not (tmp_path / "f").exists() and not (tmp_path / "escape").exists()
