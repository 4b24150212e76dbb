"""The ground station's web page and terminal views against a stand-in for the
service's side of the keys they use (status and telemetry put at 10 Hz, command
queries answered and recorded), on real Zenoh and real HTTP over loopback:

* who may use the page: nothing without this session's token, with a foreign
  ``Host`` or ``Origin`` or from another site, whatever the client; with the token
  it works; beyond loopback only over TLS (``rota-gs web`` as a user runs it);
* ``rota-gs watch`` turns to NO CONTACT within 2 s of silence and back when the
  service speaks again, with whole lines (no cut at 80 columns);
* the text view: ages, the limits in force, wrapping.

The full flight with the page in a browser is in ``test_gs_live.py``.
"""

from __future__ import annotations

import http.client
import json
import shutil
import signal
import ssl
import stat
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zenoh

from companion.gs import GroundStation
from companion.gs.view import NO_CONTACT_S, render_status
from companion.gs.web import WebStation, page_url, start, stop
from companion.gs.webauth import access_for, check_bind
from rota.errors import InputError
from sitl.demo import free_tcp_port

VEHICLE = "v1"
LONG_REASON = ("tracking error 1.7 m over 1.5 m: the vehicle strayed from its path, far beyond "
               "what the estimator expects at this speed (wind?)")


class FakeService:
    """The service's Zenoh side for the ground station: ``status`` (every 5th tick)
    and ``telemetry`` every 0.1 s while ``talking`` is set, named as from this
    session, which answers ``config`` (the ground station takes status only from
    the session that does); ``cmd/*`` queries are recorded in ``commands`` and
    answered ok."""

    def __init__(self) -> None:
        self.endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
        cfg = zenoh.Config()
        cfg.insert_json5("mode", '"peer"')
        cfg.insert_json5("listen/endpoints", json.dumps([self.endpoint]))
        cfg.insert_json5("scouting/multicast/enabled", "false")
        self.session = zenoh.open(cfg)
        self.commands: list[str] = []
        self.talking = threading.Event()
        self.talking.set()
        self.status = {"schema": "rota/status", "vehicle": VEHICLE, "state": "offboard",
                       "link": True, "armed": True, "flight_mode": "OFFBOARD",
                       "landed_state": "IN_AIR", "command": "hold", "hold_reason": LONG_REASON,
                       "limits": {"v_max": 1.2, "a_max": [2.0, 2.0, 1.5]}}
        self._queryable = self.session.declare_queryable(f"rota/{VEHICLE}/cmd/*", self._on_cmd)
        self._config = self.session.declare_queryable(
            f"rota/{VEHICLE}/config", lambda q: q.reply(q.key_expr, json.dumps(
                {"schema": "rota/config", "ok": True, "message": "", "config": {}})))
        self._sn = 0
        self._closed = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _on_cmd(self, query: zenoh.Query) -> None:
        name = str(query.key_expr).rsplit("/", 1)[1]
        self.commands.append(name)
        query.reply(query.key_expr, json.dumps({"schema": "rota/reply", "ok": True,
                                                "command": name, "message": "ok"}))

    def _run(self) -> None:
        k = 0
        while not self._closed.wait(0.1):
            if not self.talking.is_set():
                continue
            self.session.put(f"rota/{VEHICLE}/telemetry", json.dumps(
                {"position": [1.0, 2.0, 3.0], "velocity": [0.9, 0.2, 0.0], "setpoint": None}),
                source_info=self._source())
            if k % 5 == 0:
                self.session.put(f"rota/{VEHICLE}/status", json.dumps(self.status),
                                 source_info=self._source())
            k += 1

    def _source(self) -> zenoh.SourceInfo:
        self._sn += 1
        return zenoh.SourceInfo(self.session.id, self._sn)

    def close(self) -> None:
        self._closed.set()
        self._thread.join(2)
        self._queryable.undeclare()
        self._config.undeclare()
        self.session.close()


@pytest.fixture(scope="module")
def service():
    svc = FakeService()
    yield svc
    svc.close()


@pytest.fixture
def page(service):
    station = WebStation(GroundStation(VEHICLE, connect=[service.endpoint], wait_s=10))
    server = start(station, VEHICLE, "127.0.0.1", 0)
    station.gs.wait_status(10)
    yield server
    stop(server)
    station.close()


def request(server, method: str, path: str, headers: dict[str, str] | None = None,
            timeout: float = 5.0) -> tuple[int, bytes]:
    """(status, the first 4 kB of the body) from a plain HTTP client; the default
    ``Host`` is the page's own, the other headers only those given."""
    port = server.server_address[1]
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=timeout)
    hdrs = {"Host": f"127.0.0.1:{port}"} | (headers or {})
    conn.putrequest(method, path, skip_host=True, skip_accept_encoding=True)
    for k, v in hdrs.items():
        conn.putheader(k, v)
    conn.endheaders()
    r = conn.getresponse()
    body = r.read(4096) if r.status != 200 or path != "/api/events" else _first_events(r)
    conn.close()
    return r.status, body


def _first_events(r: http.client.HTTPResponse) -> bytes:
    """The event stream until a status has come, whole (the stream never ends)."""
    got = b""
    while b"event: status" not in got:
        got += r.fp.readline()
    return got + r.fp.readline()


API = [("GET", "/api/events"), ("GET", "/api/info"), ("POST", "/api/cmd/arm")]


def test_nothing_without_the_token_or_from_a_foreign_host_or_origin(service, page):
    port = page.server_address[1]
    token = page.access.token
    bearer = {"Authorization": f"Bearer {token}"}
    refused = {
        "no token": ({}, 401),
        "the old header alone": ({"X-Rota-GS": "1"}, 401),
        "a wrong token": ({"Authorization": "Bearer " + "A" * len(token)}, 401),
        "the token as a cookie": ({"Cookie": f"token={token}"}, 401),
        "a foreign Host (DNS rebinding)": (bearer | {"Host": f"evil.example:{port}"}, 403),
        "the right name, another port": (bearer | {"Host": f"127.0.0.1:{port + 1}"}, 403),
        "no Host": (bearer | {"Host": ""}, 403),
        "a foreign Origin": (bearer | {"Origin": "http://evil.example"}, 403),
        "another local page's Origin": (bearer | {"Origin": f"http://127.0.0.1:{port + 1}"}, 403),
        "Origin null": (bearer | {"Origin": "null"}, 403),
        "another site (Sec-Fetch-Site)": (bearer | {"Sec-Fetch-Site": "cross-site"}, 403),
        "a same-site page on another port": (bearer | {"Sec-Fetch-Site": "same-site"}, 403),
    }
    for why, (headers, code) in refused.items():
        for method, path in API:
            got, body = request(page, method, path, headers)
            assert got == code, (why, method, path, got, body)
            assert b"vehicle" not in body and b"state" not in body and b"event:" not in body, why
    for why in ("a foreign Host (DNS rebinding)", "a foreign Origin",
                "another site (Sec-Fetch-Site)"):
        headers = {k: v for k, v in refused[why][0].items() if k != "Authorization"}
        assert request(page, "GET", "/", headers)[0] == 403, why  # the page itself too
        assert request(page, "GET", "/app.js", headers)[0] == 403, why
    time.sleep(0.3)  # (a command that got through would have reached the service by now)
    assert service.commands == []
    # with the token, from the page's own host names and origin
    got, body = request(page, "GET", "/api/info", bearer | {"Host": f"localhost:{port}"})
    assert got == 200 and json.loads(body)["vehicle"] == VEHICLE
    got, body = request(page, "GET", "/api/events", bearer)
    assert got == 200 and b"event: ages" in body and b'"state": "offboard"' in body
    got, body = request(page, "POST", "/api/cmd/arm",
                        bearer | {"Origin": f"http://127.0.0.1:{port}",
                                  "Sec-Fetch-Site": "same-origin"})
    assert got == 200 and json.loads(body)["ok"] and service.commands == ["arm"]
    # the page (public code, no data) loads without the token; opening it from a link
    # on another site is a navigation, allowed for the page only
    assert request(page, "GET", "/")[0] == 200
    assert request(page, "GET", "/", {"Sec-Fetch-Site": "cross-site",
                                      "Sec-Fetch-Mode": "navigate"})[0] == 200


def test_host_names_a_page_answers_to():
    a = access_for("127.0.0.1", 8470, "t")
    assert all(a.host_ok(h) for h in ("127.0.0.1:8470", "localhost:8470", "[::1]:8470",
                                      "LOCALHOST:8470"))
    assert not any(a.host_ok(h) for h in ("127.0.0.1", "127.0.0.1:8471", "evil:8470",
                                          "127.0.0.1:8470:1", "127.0.0.1:x", ""))
    b = access_for("10.0.0.5", 443, "t", tls=True, names=("gs.example",))
    assert b.host_ok("10.0.0.5") and b.host_ok("gs.example:443") and not b.host_ok("localhost")
    assert b.origin_ok("https://gs.example", "gs.example") and not b.origin_ok(
        "http://gs.example", "gs.example")
    check_bind("127.0.0.1", tls=False)
    check_bind("::1", tls=False)
    for host in ("0.0.0.0", "::", "10.0.0.5", "gs.example", ""):  # noqa: S104
        with pytest.raises(InputError, match="TLS"):
            check_bind(host, tls=False)


def rota_gs(*args: str, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "companion.gs.cli", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)


def test_beyond_loopback_without_tls_is_refused_in_one_line(tmp_path):
    for host in ("0.0.0.0", "192.0.2.7"):  # noqa: S104
        p = rota_gs("web", "--host", host, "--port", str(free_tcp_port()),
                    "--token-file", str(tmp_path / "t"))
        out, err = p.communicate(timeout=60)
        assert p.returncode == 2 and out == "" and err.count("\n") == 1, err
        assert err.startswith("rota-gs web: bad input: --host: ") and "TLS" in err
    assert not (tmp_path / "t").exists()


def test_web_over_tls_on_all_addresses_with_its_token_file(service, tmp_path):
    if shutil.which("openssl") is None:
        pytest.skip("no openssl command to make a test certificate")
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "ec", "-pkeyopt",
                    "ec_paramgen_curve:P-256", "-nodes", "-days", "1", "-subj", "/CN=localhost",
                    "-addext", "subjectAltName=DNS:localhost,IP:127.0.0.1",
                    "-keyout", str(key), "-out", str(cert)], check=True, capture_output=True)
    port, token_file = free_tcp_port(), tmp_path / "run" / "web.token"
    p = rota_gs("web", "--host", "0.0.0.0", "--port", str(port), "--tls-cert", str(cert),  # noqa: S104
                "--tls-key", str(key), "--token-file", str(token_file),
                "--connect", service.endpoint, "-V", VEHICLE, "--timeout", "20")
    try:
        said = [p.stdout.readline(), p.stdout.readline()]
        assert "served over HTTPS (TLS)" in said[0] and str(token_file) in said[0], said
        url = said[1].strip()
        assert url.startswith("https://") and f":{port}/#token=" in url, said
        token = url.split("#token=")[1]
        assert token_file.read_text().strip() == token and len(token) >= 43
        assert stat.S_IMODE(token_file.stat().st_mode) == 0o600
        ctx = ssl.create_default_context(cafile=str(cert))

        def get(path: str, headers: dict[str, str]) -> int:
            conn = http.client.HTTPSConnection("127.0.0.1", port, context=ctx, timeout=10)
            conn.request("GET", path, headers={"Host": f"localhost:{port}"} | headers)
            status = conn.getresponse().status
            conn.close()
            return status

        assert get("/api/info", {}) == 401
        assert get("/api/info", {"Authorization": f"Bearer {token}"}) == 200
        assert get("/api/info", {"Authorization": f"Bearer {token}",
                                 "Origin": f"http://localhost:{port}"}) == 403  # not https
    finally:
        p.send_signal(signal.SIGINT)
        _ends(p, 30)
    assert p.returncode == 0
    assert not token_file.exists()  # the token dies with the session


def _ends(p: subprocess.Popen, timeout_s: float) -> None:
    """``p`` ends within ``timeout_s``; else it is killed (no orphan outlives the test)
    and the timeout raised."""
    try:
        p.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        p.kill()
        p.communicate()
        raise


def test_ctrl_c_handed_to_another_thread_still_stops_it(service, tmp_path):
    """The kernel may hand a process's SIGINT to any of its threads (Zenoh's, the web
    server's): Python then only sets a flag for its main thread. rota-gs web stops
    within a second all the same (an hour-long sleep once kept it running)."""
    import ctypes
    import os

    token_file = tmp_path / "web.token"
    p = rota_gs("web", "--port", str(free_tcp_port()), "--token-file", str(token_file),
                "--connect", service.endpoint, "-V", VEHICLE, "--timeout", "20")
    try:
        said = [p.stdout.readline(), p.stdout.readline()]
        assert "Ctrl-C stops" in said[0], said
        threads = sorted(int(t) for t in os.listdir(f"/proc/{p.pid}/task"))
        other = next(t for t in threads if t != p.pid)
        libc = ctypes.CDLL(None, use_errno=True)
        tgkill = 234 if os.uname().machine == "x86_64" else 131  # (aarch64: 131)
        assert libc.syscall(tgkill, p.pid, other, signal.SIGINT) == 0
        t0 = time.monotonic()
        _ends(p, 10)
        took = time.monotonic() - t0
    finally:
        if p.poll() is None:
            p.kill()
            p.communicate()
    assert p.returncode == 0 and not token_file.exists()
    assert took < 5.0, took  # (0.2 s sleeps: well under a second when quiet)


def test_watch_says_no_contact_within_2_s_of_silence_and_recovers(service):
    p = rota_gs("watch", "--duration", "30", "--connect", service.endpoint, "-V", VEHICLE,
                "--timeout", "20")
    screens: list[tuple[float, str]] = []

    def read() -> None:
        block: list[str] = []
        for line in p.stdout:
            if line.strip():
                block.append(line.rstrip("\n"))
            elif block:
                screens.append((time.monotonic(), "\n".join(block)))
                block = []

    threading.Thread(target=read, daemon=True).start()

    def wait_screen(pred, timeout: float, what: str) -> tuple[float, str]:  # noqa: ANN001
        end = time.monotonic() + timeout
        seen = len(screens)
        while time.monotonic() < end:
            for when, text in screens[seen:]:
                if pred(text):
                    return when, text
            time.sleep(0.05)
        raise AssertionError(f"no screen with {what} in {timeout} s: {screens[-2:]}")

    try:
        wait_screen(lambda t: t.startswith("contact: status"), 30, "contact")
        _, text = wait_screen(lambda t: "limit 1.2" in t, 5, "the limit in force")
        assert LONG_REASON in text  # a whole line in a pipe: not cut at 80 columns
        service.talking.clear()
        silent_at = time.monotonic()
        when, text = wait_screen(lambda t: t.startswith("NO CONTACT"), 10, "NO CONTACT")
        # the silence watch itself measured when it turned (it counts from the last
        # message, 0-0.1 s before the stop): over NO_CONTACT_S, under 2 s; its loop
        # wakes every 0.2 s and prints at once on the change
        silence = float(text.split("nothing from the service for ")[1].split(" s")[0])
        assert NO_CONTACT_S < silence < 2.0, text
        assert when - silent_at < 4.0, text  # (reading it back: a loaded machine)
        assert "last known: vehicle v1   state OFFBOARD" in text and "(1." in text
        assert "NO CONTACT" in text.split("events:")[1]
        service.talking.set()
        _, text = wait_screen(lambda t: t.startswith("contact: status"), 10, "contact again")
        assert "contact again" in text and "last known" not in text
    finally:
        p.send_signal(signal.SIGINT)
        p.communicate(timeout=30)
        service.talking.set()
    assert p.returncode == 0


def test_status_wraps_at_the_width_given_and_shows_the_limit_in_force(service):
    p = rota_gs("status", "--width", "60", "--connect", service.endpoint, "-V", VEHICLE,
                "--timeout", "20")
    out, err = p.communicate(timeout=60)
    assert p.returncode == 0, err
    lines = out.splitlines()
    assert lines[0].startswith("contact: status") and all(len(x) <= 60 for x in lines)
    assert " ".join(x.strip() for x in lines).count(LONG_REASON) == 1  # every word kept
    assert "limit 1.2" in out


def test_the_text_view_follows_the_status_and_says_how_old_it_is():
    status = {"vehicle": "v", "state": "offboard", "limits": {"v_max": 1.0}, "command": None}
    tel = {"position": [0.0, 0.0, 1.0], "velocity": [0.5, 0.0, 0.0]}
    # the status's limits beat the configuration read at start (v_max=2.0)
    text = render_status(status, tel, [], v_max=2.0, ages={"status": 0.2, "telemetry": 0.1})
    assert text.splitlines()[0] == "contact: status 0.2 s ago, telemetry 0.1 s ago"
    assert "limit 1" in text and "limit 2" not in text
    assert "limit 2" in render_status({"state": "ready"}, tel, [], v_max=2.0)
    text = render_status(status, tel, [], ages={"status": 3.0, "telemetry": 2.9}, ansi=True)
    first = text.splitlines()[0]
    assert "NO CONTACT: nothing from the service for 2.9 s" in first and "\x1b[1;7;31m" in first
    assert all(x.startswith("\x1b[2m") for x in text.splitlines()[1:])  # the rest dimmed
    assert "speed 0.50 m/s (2.9 s ago)" in text
    text = render_status(status, {}, [], ages={"status": None, "telemetry": None})
    assert text.startswith("NO CONTACT: nothing from the service yet")


def test_the_page_url_carries_the_token_after_the_fragment(page):
    url = page_url(page, "127.0.0.1")
    assert url == f"http://127.0.0.1:{page.server_address[1]}/#token={page.access.token}"


def test_a_token_file_is_its_owners_only(tmp_path):
    from companion.gs.webauth import write_token

    path = tmp_path / "new" / "dir" / "t.token"
    write_token(path, "abc")
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert stat.S_IMODE(path.parent.stat().st_mode) == 0o700
    assert path.read_text() == "abc\n"
    Path(path).chmod(0o644)
    write_token(path, "def")  # an old file of ours is made private again
    assert stat.S_IMODE(path.stat().st_mode) == 0o600 and path.read_text() == "def\n"


def test_foxglove_beyond_loopback_is_refused_in_one_line():
    """Foxglove's protocol has no authentication: the live view stays on loopback."""
    done = subprocess.run([sys.executable, "-m", "companion.gs.cli", "foxglove", "--host",
                           "0.0.0.0", "-V", VEHICLE], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 2, done
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "no authentication" in lines[0] and "ssh -L" in lines[0]
