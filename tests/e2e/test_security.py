"""Only authorised peers act, and no one widens the safety envelope at run time:
the config file's envelope, the exposure check, and a fleet made by
``rota-companion fleet`` (mutual TLS and Zenoh access control) tried on
loopback with real Zenoh sessions against the service flying the sitl vehicle."""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
import time
from dataclasses import replace

import numpy as np
import pytest
import zenoh

from companion.network.fleet import Fleet, make_fleet, make_member
from companion.network.security import check_exposure, exposure
from companion.settings.config import ConfigError, check_plausible, from_dict, load, to_toml
from companion.settings.reconfigure import Reconfigure
from companion.status import Reporter
from sitl.demo import free_tcp_port
from sitl.proving import CIRCLE_RADIUS_M, Flight, circle_message

FILE = from_dict({"limits": {"v_max": 2.0, "a_max": [2.0, 2.0, 1.5]},
                  "safety": {"geofence_min": [-30.0, -30.0, -1.0],
                             "geofence_max": [30.0, 30.0, 5.0]}})

#: Every widening the attack tried (and more), each refused.
WIDENINGS = [
    {"limits": {"v_max": 1000.0}}, {"limits": {"v_max": 1e308}}, {"limits": {"v_max": 15.0}},
    {"limits": {"a_max": [100.0, 2.0, 1.5]}}, {"limits": {"dtau": 1e-9}},
    {"limits": {"max_solve_s": 100.0}},
    {"safety": {"max_input_speed": 1e6}},
    {"safety": {"geofence_min": [-1e6, -1e6, -1.0], "geofence_max": [1e6, 1e6, 5.0]}},
    {"safety": {"geofence_max": [30.0, 30.0, 50.0]}},
    {"safety": {"max_tracking_error_m": 1e9}}, {"safety": {"stitch_tolerance_m": 1e6}},
    {"safety": {"max_message_age_s": 1e9}}, {"safety": {"require_stamp": False}},
    {"safety": {"input_frame": "NED"}},
    {"uncertainty": {"m": 0.0}}, {"uncertainty": {"b": -0.5}},
    {"uncertainty": {"delta": 0.5}}, {"uncertainty": {"semi_axes": [0.01, 0.01, 0.01]}},
    {"stream": {"rate_hz": 5.0}}, {"zenoh": {"insecure": True}},
]


def reconfigure():
    state = {"cfg": FILE}
    rc = Reconfigure(FILE, lambda: state["cfg"], lambda c: state.update(cfg=c), Reporter())
    return rc, state


@pytest.mark.parametrize("change", WIDENINGS, ids=lambda c: json.dumps(c)[:60])
def test_no_run_time_change_widens_the_file_envelope(change):
    rc, state = reconfigure()
    with pytest.raises(ConfigError) as err:
        rc.apply({"set": change}, "peer")
    words = str(err.value)
    assert "refused" in words or "cannot change at run time" in words or "must be" in words
    assert state["cfg"] == FILE


def test_tightening_is_allowed_audited_and_can_go_back_to_the_file():
    rc, state = reconfigure()
    rc.apply({"set": {"limits": {"v_max": 1.0}, "uncertainty": {"m": 0.3}}}, "abc123")
    assert state["cfg"].limits.v_max == 1.0 and state["cfg"].uncertainty.m == 0.3
    audit = rc.report.events[-1]
    assert audit["level"] == "audit" and audit["source"] == "abc123"
    rc.apply({"set": {"limits": {"v_max": 2.0}}}, "abc123")  # back to the file, not above
    assert state["cfg"].limits.v_max == 2.0
    with pytest.raises(ConfigError, match="at most 2.0"):
        rc.apply({"set": {"limits": {"v_max": 2.01}}}, "abc123")


def test_the_refusal_names_the_allowed_range():
    rc, _ = reconfigure()
    with pytest.raises(ConfigError) as err:
        rc.apply({"set": {"limits": {"v_max": 15.0}}}, "p")
    assert str(err.value) == ("[limits] v_max: 15.0 refused; allowed: at most 2.0 (the config "
                              "file's value), as a lower limit can only slow the flight (it "
                              "also caps every braking-point limit)")


@pytest.mark.parametrize(("section", "name", "value"), [
    ("limits", "v_max", 100.0), ("limits", "a_max", [50.0, 2.0, 2.0]),
    ("safety", "geofence_max", [1e6, 50.0, 10.0]), ("safety", "max_tracking_error_m", 100.0),
    ("uncertainty", "delta", 0.9), ("limits", "dtau", 5.0),
])
def test_an_implausible_file_envelope_is_refused(tmp_path, section, name, value):
    cfg = from_dict({section: {name: value}})
    with pytest.raises(ConfigError, match="implausible"):
        check_plausible(cfg)
    path = tmp_path / "c.toml"
    path.write_text(to_toml(cfg))
    with pytest.raises(ConfigError, match="implausible"):
        load(path)


def test_exposure_without_authentication_is_refused_unless_insecure():
    assert exposure(from_dict({})) == []  # the default: loopback only
    open_cfg = from_dict({"zenoh": {"listen": ["tcp/0.0.0.0:7447"]}})
    with pytest.raises(ConfigError, match="without authentication"):
        check_exposure(open_cfg)
    router = from_dict({"zenoh": {"mode": "client", "connect": ["tcp/10.0.0.2:7447"],
                                  "listen": []}})
    assert any("connects to" in p for p in exposure(router))
    insecure = replace(open_cfg, zenoh=replace(open_cfg.zenoh, insecure=True))
    assert check_exposure(insecure)  # starts, with the problems to announce
    mav = from_dict({"mavlink": {"url": "udpin://0.0.0.0:14540"}})
    assert any("pose as the autopilot" in p for p in exposure(mav))
    assert exposure(from_dict({"mavlink": {"url": "serial:///dev/ttyAMA0:921600"}})) == []


def test_check_config_refuses_an_exposed_service(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text(to_toml(from_dict({"zenoh": {"listen": ["tcp/0.0.0.0:7447"]}})))
    done = subprocess.run([sys.executable, "-m", "companion.cli", "check-config", str(path)],
                          capture_output=True, text=True)
    assert done.returncode == 2 and "without authentication" in done.stderr
    path.write_text(to_toml(from_dict({"zenoh": {"listen": ["tcp/0.0.0.0:7447"],
                                                  "insecure": True}})))
    done = subprocess.run([sys.executable, "-m", "companion.cli", "check-config", str(path)],
                          capture_output=True, text=True)
    assert done.returncode == 0 and "INSECURE" in done.stderr


# ------------------------------------------------------------------ the fleet
def _client(path) -> zenoh.Session:
    return zenoh.open(zenoh.Config.from_file(str(path)))


def _asks(session, key: str) -> list[dict]:
    return [json.loads(r.ok.payload.to_bytes()) for r in session.get(key, timeout=2.0)
            if r.ok is not None]


@pytest.mark.e2e
@pytest.mark.timeout(300)
def test_a_fleet_lets_each_peer_do_only_its_part(tmp_path):
    """A vehicle made by ``rota-companion fleet``: a peer without a certificate cannot
    connect; the planner may send trajectories but not arm or reconfigure; a
    certificate of the fleet not named in the access control gets nothing; the
    ground station commands; a wildcard query reaches no vehicle; and the flown
    speed and positions stay inside the file's envelope though a widening was
    tried."""
    loop_port, tls_port = free_tcp_port(), free_tcp_port()
    fleet = Fleet(vehicles=("sim",), hosts={"sim": "127.0.0.1"}, loopback_port=loop_port,
                  tls_port=tls_port)
    make_fleet(fleet, tmp_path / "fleet")
    root = tmp_path / "fleet"
    make_member(root / "ca", root / "visitor", "visitor", 30)
    (root / "visitor" / "zenoh.json5").write_text(
        (root / "planner-sim" / "zenoh.json5").read_text().replace("planner-sim", "visitor"))
    flight = Flight(workdir=str(tmp_path / "run"), gs_config=str(root / "gs" / "zenoh-sim.json5"),
                    zenoh={"config_file": str(root / "sim" / "zenoh.json5")})

    async def scenario(f: Flight):
        gs = f.gs
        await f.take_off()  # arm and takeoff through the ground station's TLS session
        refused = gs.config({"limits": {"v_max": 15.0}})
        await f.circle("c0", duration_s=30.0)
        planner, visitor = _client(root / "planner-sim" / "zenoh.json5"), \
            _client(root / "visitor" / "zenoh.json5")
        try:
            time.sleep(0.5)  # the sessions' declarations to propagate
            out = {
                "planner arm": _asks(planner, "rota/sim/cmd/arm"),
                "planner config": _asks(planner, "rota/sim/config"),
                "planner wildcard": _asks(planner, "rota/*/cmd/land"),
                "visitor status": _asks(visitor, "rota/sim/config"),
                "gs wildcard": _asks(gs.session, "rota/*/cmd/land"),
            }
            seen = []
            sub = visitor.declare_subscriber("rota/sim/status", lambda s: seen.append(1))
            sp = np.asarray(gs.telemetry["setpoint"]["position"]) - f.center
            planner.put("rota/sim/trajectory", json.dumps(circle_message(
                f.center, CIRCLE_RADIUS_M, float(np.arctan2(sp[1], sp[0])), f.speed, 30.0,
                "from-planner")).encode())
            await gs.wait_for(lambda s: s.get("trajectory_id") == "from-planner", 10,
                              "the planner's trajectory to fly")
            out["visitor reads status"] = bool(seen)
            sub.undeclare()
        finally:
            planner.close()
            visitor.close()
        try:
            zenoh.open(zenoh.Config.from_json5(json.dumps(
                {"mode": "client", "connect": {"endpoints": [f"tls/127.0.0.1:{tls_port}"]}})))
            out["no certificate"] = "connected"
        except Exception as exc:  # noqa: BLE001 - zenoh's own error type
            out["no certificate"] = str(exc)[:60]
        t0 = time.monotonic()
        await gs.wait_for(lambda s: (s.get("progress") or 0) > 0.3, 30, "the circle")
        # the ground station took every output from the session that answers as the
        # vehicle (the service names itself as their source), none from another
        out["source"] = (gs.vehicle_zid, str(f.gs.session.info.peers_zid()[0]), gs.ignored)
        return out, refused, (t0, time.monotonic())

    with flight:
        out, refused, window = asyncio.run(scenario(flight))
    report = flight.sim.report
    print(json.dumps(out, indent=1, default=str))
    assert not refused["ok"] and "at most 2.0" in refused["message"], refused
    assert out["planner arm"] == [] and out["planner config"] == []
    assert out["planner wildcard"] == [] and out["gs wildcard"] == []
    assert out["visitor status"] == [] and not out["visitor reads status"]
    assert out["no certificate"].startswith("Unable to connect")
    assert out["source"][0] == out["source"][1] and out["source"][2] == 0, out["source"]
    # what flew stayed in the file's envelope
    figures = flight.figures(window, report.setpoints)
    assert figures.max_speed <= flight.allowed_speed and not figures.outside_fence, \
        figures.summary()
    sp = report.setpoints
    speed = np.linalg.norm(sp["velocity"][sp["wall_time"] > window[0]], axis=1)
    assert speed.max() <= FILE.limits.v_max + 1e-6
