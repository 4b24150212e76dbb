"""The real-PX4 harness (``sitl.px4``) without PX4: a stand-in ``bin/px4`` that runs the sitl
vehicle on PX4's ports. Checks the readiness wait (no fixed sleep), the free instance/port per
run (two at once), and that PX4's console and flight logs are kept when the run fails."""

from __future__ import annotations

import socket
import stat
import sys
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from sitl.px4 import PX4_PORT, Px4Sitl

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(120)]

FAKE_PX4 = """#!{python}
# Stand-in for PX4 SITL: takes -i INSTANCE -d -w WORKDIR ETC like px4, writes a console line
# and a flight log, and runs the sitl vehicle on instance i's offboard ports.
import sys, time
from pathlib import Path
args = sys.argv[1:]
instance = int(args[args.index("-i") + 1])
workdir = Path(args[args.index("-w") + 1])
mode = "{mode}"
print("INFO  [px4] instance", instance, flush=True)
if mode == "crash":
    print("ERROR [px4] boot failed", flush=True)
    sys.exit(3)
(workdir / "log" / "2025-01-01").mkdir(parents=True)
(workdir / "log" / "2025-01-01" / "00_00_00.ulg").write_bytes(b"ULog")
time.sleep({boot_s})
from sitl.vehicle import SimVehicle
# Said before the vehicle starts streaming: the harness may see readiness on MAVLink and
# stop this process before a line printed afterwards is written.
print("INFO  [commander] Ready for takeoff!", flush=True)
with SimVehicle(port=14540 + instance, bind_port=14580 + instance, seed=instance):
    time.sleep(60)
"""


def _fake_build(tmp_path: Path, mode: str = "ok", boot_s: float = 1.0) -> Path:
    build = tmp_path / f"build-{mode}"
    (build / "bin").mkdir(parents=True)
    (build / "etc").mkdir()
    exe = build / "bin" / "px4"
    exe.write_text(FAKE_PX4.format(python=sys.executable, mode=mode, boot_s=boot_s))
    exe.chmod(exe.stat().st_mode | stat.S_IEXEC)
    return build


def _heartbeat(port: int, timeout: float = 5.0) -> bool:
    mav = mavlink2.MAVLink(None)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", port))
        sock.settimeout(0.2)
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            try:
                data = sock.recv(65535)
            except TimeoutError:
                continue
            if any(m.get_type() == "HEARTBEAT" for m in mav.parse_buffer(data) or []):
                return True
    return False


def test_two_instances_wait_for_readiness_on_their_own_ports(tmp_path):
    build = _fake_build(tmp_path, boot_s=1.5)
    t0 = time.monotonic()
    with Px4Sitl(build) as a, Px4Sitl(build) as b:
        assert time.monotonic() - t0 >= 1.5  # waited for the vehicle, not a fixed time
        assert a.port != b.port and {a.port, b.port} <= set(range(PX4_PORT, PX4_PORT + 10))
        assert a.port == PX4_PORT + a.instance
        assert _heartbeat(a.port) and _heartbeat(b.port)
        dirs = [a.workdir, b.workdir]
        assert "Ready for takeoff" in a.log_path.read_text()
    assert not any(d.exists() for d in dirs)  # nothing failed: cleaned up


def test_logs_are_kept_when_the_run_fails(tmp_path, capsys):
    build = _fake_build(tmp_path)
    with pytest.raises(AssertionError), Px4Sitl(build) as px4:
        workdir = px4.workdir
        raise AssertionError("the flight failed")
    assert (workdir / "px4.log").read_text().count("Ready for takeoff") == 1
    assert [p.name for p in px4.flight_logs()] == ["00_00_00.ulg"]
    assert str(workdir) in capsys.readouterr().err


def test_a_crashing_px4_fails_at_once_and_keeps_its_log(tmp_path):
    build = _fake_build(tmp_path, mode="crash")
    px4 = Px4Sitl(build, boot_timeout_s=30.0)
    t0 = time.monotonic()
    with pytest.raises(RuntimeError, match="exited at boot"):
        px4.__enter__()
    assert time.monotonic() - t0 < 10.0
    assert "boot failed" in px4.log_path.read_text()
