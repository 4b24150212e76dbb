"""The exposure check reads a Zenoh configuration as Zenoh will use it: scouting
(multicast and gossip, with Zenoh's own defaults where a file says nothing),
every listener and connection with its own ``#`` settings, TLS, user/password
and the access control. Each configuration of issue 25 is tried, and where a
real Zenoh can show it, the check is held against what Zenoh does: a TLS client
without a certificate gets in exactly where the check says so, and a stranger
with no credentials on a network link (two network namespaces made here)
reaches a service whose file leaves scouting unset, not the embedded default.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh

from companion.network.fleet import Fleet, make_fleet
from companion.network.security import exposure, zenoh_config, zenoh_exposure
from companion.settings.config import from_dict
from sitl.demo import free_tcp_port

ROOT = Path(__file__).resolve().parents[2]
OFF = {"multicast": {"enabled": False}, "gossip": {"enabled": False}}
ACL = {"enabled": True, "default_permission": "deny"}
TLS = {"root_ca_certificate": "/fleet/v/ca.pem", "enable_mtls": True,
       "listen_private_key": "/fleet/v/key.pem", "listen_certificate": "/fleet/v/cert.pem",
       "connect_private_key": "/fleet/v/key.pem", "connect_certificate": "/fleet/v/cert.pem"}


def _config(d: dict) -> zenoh.Config:
    return zenoh.Config.from_json5(json.dumps(d))


def _vehicle(*listen: str, tls: dict | None = None, **more) -> dict:
    return {"mode": "peer", "listen": {"endpoints": list(listen)}, "scouting": OFF,
            "transport": {"link": {"tls": TLS if tls is None else tls}},
            "access_control": ACL} | more


#: (what, Zenoh config, words each expected problem has; empty: it passes)
CASES = [
    ("loopback listener, scouting left to Zenoh (the issue's)",
     {"mode": "peer", "listen": {"endpoints": ["tcp/127.0.0.1:7447"]}},
     ["multicast scouting is on (Zenoh's default", "gossip scouting is on (Zenoh's default"]),
    ("multicast scouting on", {"mode": "peer", "listen": {"endpoints": ["tcp/127.0.0.1:7447"]},
                               "scouting": {"multicast": {"enabled": True},
                                            "gossip": {"enabled": False}}},
     ["multicast scouting is on:"]),
    ("gossip scouting on", {"mode": "peer", "listen": {"endpoints": ["tcp/127.0.0.1:7447"]},
                            "scouting": {"multicast": {"enabled": False},
                                         "gossip": {"enabled": True}}},
     ["gossip scouting is on:"]),
    ("gossip on, connecting to no one it hears of",
     {"mode": "peer", "listen": {"endpoints": ["tcp/127.0.0.1:7447"]},
      "scouting": {"multicast": {"enabled": False},
                   "gossip": {"enabled": True, "autoconnect": {"peer": []}}}}, []),
    ("the fleet's listeners", _vehicle("tcp/127.0.0.1:7447", "tls/0.0.0.0:7448"), []),
    ("a listener's own #enable_mtls=false (the issue's)",
     _vehicle("tcp/127.0.0.1:7447", "tls/0.0.0.0:7448#enable_mtls=false"),
     ["tls/0.0.0.0:7448#enable_mtls=false without authentication: TLS without client "
      "certificates (its own #enable_mtls=false)"]),
    ("?enable_mtls=false is metadata: Zenoh ignores it there",
     _vehicle("tls/0.0.0.0:7448?enable_mtls=false"), []),
    ("mutual TLS off in the file, on for the listener",
     _vehicle("tls/0.0.0.0:7448#enable_mtls=true", tls=TLS | {"enable_mtls": False}), []),
    ("mutual TLS off", _vehicle("tls/0.0.0.0:7448", tls=TLS | {"enable_mtls": False}),
     ["without authentication: TLS without client certificates (enable_mtls off)"]),
    ("mutual TLS without an authority", _vehicle(
        "tls/0.0.0.0:7448", tls={k: v for k, v in TLS.items() if k != "root_ca_certificate"}),
     ["no root certificate authority"]),
    ("a listener trusting another authority",
     _vehicle("tls/0.0.0.0:7448#root_ca_certificate_file=/tmp/mine.pem"),
     ["another certificate authority"]),
    ("quic without mutual TLS", _vehicle("quic/0.0.0.0:7448#enable_mtls=false"),
     ["quic/0.0.0.0:7448#enable_mtls=false without authentication"]),
    ("plain TCP on the network", _vehicle("tcp/0.0.0.0:7447"),
     ["tcp/0.0.0.0:7447 without authentication"]),
    ("a listener asking user/password",
     _vehicle("tcp/0.0.0.0:7447", transport={"auth": {"usrpwd": {
         "dictionary_file": "/fleet/users.txt"}}}), []),
    ("connecting out with user/password only",
     {"mode": "client", "connect": {"endpoints": ["tcp/10.0.0.2:7447"]}, "scouting": OFF,
      "transport": {"auth": {"usrpwd": {"user": "v", "password": "p",
                                        "dictionary_file": "/fleet/users.txt"}}},
      "access_control": ACL},
     ["connects to tcp/10.0.0.2:7447 without authentication (user/password proves"]),
    ("connecting out over mutual TLS", {"mode": "client", "scouting": OFF,
                                        "connect": {"endpoints": ["tls/router.fleet:7447"]},
                                        "transport": {"link": {"tls": TLS}},
                                        "access_control": ACL}, []),
    ("connecting out without checking the router's name",
     {"mode": "client", "scouting": OFF,
      "connect": {"endpoints": ["tls/router.fleet:7447#verify_name_on_connect=false"]},
      "transport": {"link": {"tls": TLS}}, "access_control": ACL},
     ["without checking the peer's name"]),
    ("authenticated, but no access control", _vehicle("tls/0.0.0.0:7448", access_control={}),
     ["without access control denying by default"]),
    ("access control allowing by default",
     _vehicle("tls/0.0.0.0:7448", access_control=ACL | {"default_permission": "allow"}),
     ["without access control denying by default"]),
    ("a peer whose file names no listener (Zenoh's tcp/[::]:0)",
     {"mode": "peer", "scouting": OFF, "access_control": ACL},
     ["listens on tcp/[::]:0 without authentication"]),
    ("a router whose file names no listener (Zenoh's tcp/[::]:7447)",
     {"mode": "router", "scouting": OFF, "access_control": ACL},
     ["listens on tcp/[::]:7447 without authentication"]),
    ("listeners given per mode", {"mode": "peer", "scouting": OFF, "listen": {"endpoints": {
        "peer": ["tcp/127.0.0.1:7447"], "router": ["tcp/0.0.0.0:7447"]}}}, []),
    ("a unix socket", {"mode": "peer", "scouting": OFF,
                       "listen": {"endpoints": ["unixsock-stream//run/rota/zenoh.sock"]}}, []),
]


@pytest.mark.parametrize(("what", "config", "words"), CASES, ids=[c[0] for c in CASES])
def test_each_configuration_is_read_as_zenoh_uses_it(what, config, words):
    problems = zenoh_exposure(_config(config))
    assert len(problems) == len(words), problems
    for problem, expected in zip(problems, words, strict=True):
        assert expected in problem, problems


def test_the_shipped_and_generated_configs_pass(tmp_path):
    assert exposure(from_dict({})) == []  # the embedded default
    for name in ("loopback", "vehicle"):
        assert zenoh_exposure(zenoh.Config.from_file(str(ROOT / "configs" /
                                                         f"zenoh-{name}.json5"))) == []
    written = make_fleet(Fleet(vehicles=("drone1", "drone2"), hosts={"drone1": "10.0.0.11"}),
                         tmp_path / "fleet")
    vehicles = [p for p in written if p.parent.name in ("drone1", "drone2")]
    assert len(vehicles) == 2
    for path in vehicles:
        assert zenoh_exposure(zenoh.Config.from_file(str(path))) == [], path


def _check_config(tmp_path: Path, zenoh_file: dict, insecure: bool = False):
    (tmp_path / "zenoh.json5").write_text(json.dumps(zenoh_file))
    (tmp_path / "c.toml").write_text(
        f'[zenoh]\nconfig_file = "{tmp_path / "zenoh.json5"}"\n'
        + ("insecure = true\n" if insecure else ""))
    return subprocess.run([sys.executable, "-m", "companion.cli", "check-config",
                           str(tmp_path / "c.toml")], capture_output=True, text=True)


def test_check_config_refuses_scouting_left_to_zenoh(tmp_path):
    """The issue's configuration: loopback only, scouting unset. Refused in one
    line (exit 2); with ``insecure`` it passes and says INSECURE for each way in."""
    issue = {"mode": "peer", "listen": {"endpoints": ["tcp/127.0.0.1:7447"]}}
    done = _check_config(tmp_path, issue)
    assert done.returncode == 2 and "multicast scouting is on" in done.stderr, done.stderr
    assert len(done.stderr.strip().splitlines()) == 1
    done = _check_config(tmp_path, issue, insecure=True)
    assert done.returncode == 0, done.stderr
    insecure = [line for line in done.stderr.splitlines() if "INSECURE:" in line]
    assert len(insecure) == 2 and "multicast" in insecure[0] and "gossip" in insecure[1]
    assert _check_config(tmp_path, issue | {"scouting": OFF}).returncode == 0


# ---------------------------------------------------------------- real Zenoh
@pytest.fixture(scope="module")
def certificates(tmp_path_factory):
    root = tmp_path_factory.mktemp("fleet")
    make_fleet(Fleet(vehicles=("sim",), hosts={"sim": "127.0.0.1"}), root)
    return root


@pytest.mark.timeout(120)
@pytest.mark.parametrize("suffix", ["", "#enable_mtls=false", "?enable_mtls=false",
                                    "?priorities=1-7#enable_mtls=false"])
def test_a_tls_listener_is_flagged_exactly_when_a_client_without_certificate_gets_in(
        certificates, suffix):
    """The vehicle's fleet config with its TLS listener changed; a TLS client that
    trusts the fleet's authority but has no certificate of its own tries it."""
    port = free_tcp_port()
    config = json.loads("\n".join(line for line in (certificates / "sim" / "zenoh.json5")
                                  .read_text().splitlines() if not line.startswith("//")))
    config["listen"]["endpoints"] = [f"tls/0.0.0.0:{port}{suffix}"]
    del config["access_control"]  # what the link lets in, not what the rules then allow
    flagged = [p for p in zenoh_exposure(_config(config)) if "without authentication" in p]
    vehicle = zenoh.open(_config(config))
    answer = vehicle.declare_queryable("rota/sim/config", lambda q: q.reply(q.key_expr, b"{}"))
    try:
        stranger = zenoh.open(_config({
            "mode": "client", "connect": {"endpoints": [f"tls/127.0.0.1:{port}"]},
            "scouting": OFF, "transport": {"link": {"tls": {
                "root_ca_certificate": str(certificates / "ca" / "ca.pem")}}}}))
    except zenoh.ZError as exc:
        assert "Unable to connect" in str(exc)
        got_in = False
    else:
        got_in = any(r.ok is not None for r in stranger.get("rota/sim/config", timeout=5))
        stranger.close()
    finally:
        answer.undeclare()
        vehicle.close()
    assert got_in == bool(flagged), (suffix, flagged)
    assert got_in == ("#enable_mtls=false" in suffix)


def _netns_ready() -> str | None:
    if os.geteuid() != 0 or not (shutil.which("unshare") and shutil.which("ip")
                                 and shutil.which("nsenter")):
        return "needs root, unshare, nsenter and ip (network namespaces)"
    done = subprocess.run(["unshare", "-n", "true"], capture_output=True)
    return None if done.returncode == 0 else "cannot make a network namespace here"


def _stranger_reaches(config: zenoh.Config, window_s: float) -> float | None:
    """Seconds until the stranger reached the vehicle (None: not within window_s)."""
    script = ROOT / "tests" / "helpers" / "zenoh_netns.py"
    done = subprocess.run(["unshare", "-n", sys.executable, str(script), "vehicle",
                           str(config), str(window_s)], capture_output=True,
                          text=True, timeout=window_s + 90,
                          env=os.environ | {"PYTHONPATH": str(ROOT)})
    out = json.loads(done.stdout.strip().splitlines()[-1])
    assert "error" not in out, out
    return out["reached_after_s"]


@pytest.mark.timeout(240)
def test_a_stranger_on_the_network_reaches_only_the_scouting_service():
    """Issue 25's item 2 replayed on two network namespaces joined by a link: a
    service whose Zenoh file listens on loopback only but leaves scouting to
    Zenoh finds the stranger by multicast and connects to it, and the stranger
    (no credentials) gets the service's answers; the check refuses that file.
    The embedded default (both scoutings off) is not reached, and passes."""
    why = _netns_ready()
    if why:
        pytest.skip(why)
    scouting = _config({"mode": "peer", "listen": {"endpoints": ["tcp/127.0.0.1:7447"]}})
    embedded = zenoh_config(from_dict({}))
    assert any("multicast scouting is on" in p for p in zenoh_exposure(scouting))
    assert zenoh_exposure(embedded) == []
    t0 = time.monotonic()
    reached = _stranger_reaches(scouting, 20.0)
    assert reached is not None, "the stranger should have reached the scouting service"
    # Measured: reached within 0.0-0.5 s of trying (the service scouts at once); the
    # embedded default gets ten times as long, and at least 5 s, to be reached.
    window = max(5.0, 10 * reached)
    assert _stranger_reaches(embedded, window) is None, (reached, time.monotonic() - t0)


@pytest.mark.e2e
@pytest.mark.timeout(300)
def test_an_insecure_service_says_so_on_every_status(tmp_path):
    """``insecure = true`` with a plain listener on every interface (no traffic
    leaves this machine: the ground station connects on loopback): the service
    starts, and every status it sends names each way in as INSECURE."""
    from sitl.proving import Flight

    path = tmp_path / "zenoh.json5"
    flight = Flight(workdir=str(tmp_path / "run"),
                    zenoh={"config_file": str(path), "insecure": True})
    path.write_text(json.dumps({"mode": "peer", "scouting": OFF, "listen": {
        "endpoints": [f"tcp/0.0.0.0:{flight.zenoh_port}"]}}))
    expected = exposure(flight.cfg)
    assert len(expected) == 2  # the plain listener, and no access control

    async def until_ready(f: Flight) -> None:
        await f.gs.wait_for(lambda s: s["state"] == "ready", 90, "the vehicle to be ready")
        await f.gs.wait_for(lambda s: True, 10, "one more status", fresh=True)

    import asyncio

    with flight:
        asyncio.run(until_ready(flight))
        statuses = list(flight.gs.statuses)
    assert len(statuses) >= 2
    for s in statuses:
        assert s["insecure"] == expected, s
        assert s["warnings"][:2] == [f"INSECURE: {p}" for p in expected], s["warnings"]
