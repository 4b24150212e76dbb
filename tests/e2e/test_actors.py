"""Every actor on record: each command, configuration and estimator request and
each trajectory and map, accepted or refused, is logged (and so in the flight
record's ``log`` channel) with the sender's Zenoh id and, under mutual TLS, the
certificate's common name; Zenoh's access-control denials reach the log. Flown
against ``rota-companion run`` with a fleet made by ``rota-companion fleet``,
over real mutual-TLS Zenoh on loopback."""

from __future__ import annotations

import json
import os
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh

from companion.network.actors import Actor, Link
from companion.network.fleet import Fleet, make_fleet
from companion.network.zenoh_log import Denials, handle
from companion.recording.record import read
from companion.settings.config import from_dict, to_toml
from sitl.demo import free_tcp_port

#: A denial as Zenoh 1.10.2 writes it at TRACE (colours included), with the zid,
#: the link's subject (interface, transport, certificate) and the key.
DENIAL = ("\x1b[2m2026-11-27T07:33:45.891061Z\x1b[0m \x1b[35mTRACE\x1b[0m rx-0 ThreadId(08) "
          "\x1b[2mzenoh::net::routing::interceptor::access_control\x1b[0m\x1b[2m:\x1b[0m "
          "22028d05fee82a21f68c863222d5da8c on Interface(lo)+Transport(Tcp)+"
          "22028d05fee82a21f68c863222d5da8c is unauthorized to Put (ingress) on a/bad\n")
ALLOWED = DENIAL.replace("is unauthorized", "is authorized")


def test_denials_are_grouped_counted_and_allowed_lines_dropped(caplog):
    denials = Denials()
    query = DENIAL.replace("Put (ingress)", "Query (ingress)")
    with caplog.at_level("INFO", logger="rota.companion"):
        assert handle(DENIAL, denials, 100.0) and handle(query, denials, 100.01)
        assert handle(ALLOWED, denials, 100.02)
        denials.flush(100.05)
        assert not caplog.records  # (still gathering)
        denials.flush(100.2)
        for t in (100.3, 100.6, 100.9):  # the same group again, within a second
            handle(DENIAL, denials, t)
            denials.flush(t + 0.15)
        handle(DENIAL, denials, 101.5)
        denials.flush(101.7)
        assert not handle("Traceback (most recent call last):\n", denials, 101.8)
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 2, lines
    assert "denied Put, Query (ingress) on a/bad to peer 22028d05" in lines[0]
    assert "Interface(lo)" in lines[0]
    assert "and 3 more times" in lines[1]


def test_an_actor_names_its_certificate_or_says_what_is_unknown():
    link = Link("ab" * 16, "gs", "tls/127.0.0.1:5555")
    assert str(Actor("ab" * 16, link)) == f"gs (Zenoh peer {'ab' * 16})"
    unnamed = str(Actor(None, None, (link,)))
    assert "declared no id" in unnamed and "gs (abababab) over tls/127.0.0.1:5555" in unnamed
    assert len(str(Actor(None, None, (link,) * 10))) < 400  # many links: the first three


def _service(tmp: Path, fleet: Path) -> tuple[subprocess.Popen, Path]:
    cfg = from_dict({"service": {"vehicle_id": "sim", "state_dir": str(tmp / "state"),
                                 "nice": 0},
                     "mavlink": {"url": f"udpin://127.0.0.1:{free_tcp_port()}"},
                     "zenoh": {"config_file": str(fleet / "sim" / "zenoh.json5")}})
    path = tmp / "companion.toml"
    path.write_text(to_toml(cfg))
    log = tmp / "service.log"
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    env.pop("RUST_LOG", None)
    proc = subprocess.Popen([sys.executable, "-m", "companion.cli", "run", "--config", str(path)],
                            stdout=log.open("w"), stderr=subprocess.STDOUT, env=env)
    return proc, log


def _ask(session: zenoh.Session, key: str, payload: dict | None = None,
         timeout: float = 10.0) -> list[dict]:
    body = None if payload is None else json.dumps(payload).encode()
    source = zenoh.SourceInfo(session.id, 1)
    return [json.loads(r.ok.payload.to_bytes()) for r in
            session.get(key, payload=body, timeout=timeout, source_info=source)
            if r.ok is not None]


def _open(path: Path) -> zenoh.Session | None:
    try:
        return zenoh.open(zenoh.Config.from_file(str(path)))
    except zenoh.ZError:  # not listening yet
        return None


def _wait(what: str, ok, timeout: float = 120.0):  # noqa: ANN001
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        got = ok()
        if got:
            return got
        time.sleep(0.1)
    raise AssertionError(f"timed out waiting for {what}")


@pytest.mark.e2e
@pytest.mark.timeout(300)
def test_every_request_is_on_record_with_its_sender(tmp_path):
    fleet = tmp_path / "fleet"
    make_fleet(Fleet(vehicles=("sim",), hosts={"sim": "127.0.0.1"},
                     loopback_port=free_tcp_port(), tls_port=free_tcp_port()), fleet)
    proc, log_path = _service(tmp_path, fleet)
    gs = planner = None
    try:
        gs = _wait("the service's listener", lambda: _open(fleet / "gs" / "zenoh-sim.json5"))
        planner = zenoh.open(zenoh.Config.from_file(str(fleet / "planner-sim" / "zenoh.json5")))
        # the service answers once its queryables are declared (before warm-up ends)
        _wait("the service's config reply", lambda: _ask(gs, "rota/sim/config", timeout=2.0))
        refused = _ask(gs, "rota/sim/config", {"set": {"limits": {"v_max": 15.0}}})
        assert refused and not refused[0]["ok"]
        assert _ask(gs, "rota/sim/cmd/hold")  # refused: not flying, but answered
        assert _ask(gs, "rota/sim/estimator", {"reset": True})
        # a trajectory that the service refuses (it is not valid), from the planner, and
        # an arm that the access rules deny it
        pub = planner.declare_publisher("rota/sim/trajectory")

        def refused_in_log() -> str | None:
            # both sent again at each look, as a 10 Hz planner does: what is sent before
            # the planner's session has its link to the service goes nowhere (on a busy
            # machine the TLS link may still be coming up), and the arm query is then
            # unanswered without reaching the access control that logs the denial
            pub.put(b'{"type": "rota/trajectory", "version": 1}',
                    source_info=zenoh.SourceInfo(pub.id, 1))
            assert _ask(planner, "rota/sim/cmd/arm", timeout=0.5) == []  # never answered
            t = log_path.read_text()
            return t if "(from planner-sim" in t and "denied" in t else None

        text = _wait("the refused trajectory in the log", refused_in_log)
    finally:  # (the service is stopped whatever happened: no orphan outlives the test)
        for session in (gs, planner):
            if session is not None:
                session.close()
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(60)
        except subprocess.TimeoutExpired:
            proc.kill()
    gs_id = "gs (Zenoh peer"
    assert f"config from {gs_id}" in text and "refused: " in text, text[-3000:]
    assert f"cmd/hold from {gs_id}" in text
    assert f"estimator from {gs_id}" in text
    assert "trajectory: " in text and "(from planner-sim (Zenoh peer" in text
    assert "Zenoh access control denied Query (ingress) on rota/sim/cmd/arm" in text
    assert "connected" in text and "planner-sim (" in text  # the link events
    # the same, in the flight record's log channel
    records = sorted((tmp_path / "state").rglob("*.mcap"))
    assert records
    logged = [m["message"] for c, _, m in read(records, ["log"])]
    assert any(f"config from {gs_id}" in m for m in logged)
    assert any("access control denied" in m for m in logged)
    # outside systemd too, what the service writes is the operator's alone
    for path in [tmp_path / "state", *records]:
        mode = stat.S_IMODE(path.stat().st_mode)
        assert mode & 0o077 == 0, f"{path}: {oct(mode)}"
