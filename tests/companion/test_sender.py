"""The setpoint sender process (companion/flight/sender.py), real process and real UDP on
loopback: a socket here stands in for MAVSDK's forwarding link."""

from __future__ import annotations

import math
import os
import signal
import socket
import subprocess
import sys
import time

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from companion.flight.sender import (
    CANCELLED,
    LATE,
    RECORD,
    SILENT,
    SUPERSEDED,
    WHY,
    SenderError,
    SetpointSender,
)

BOOT = time.monotonic() - 10.0
VALUES = (1.0, 2.0, -3.0, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.25)


@pytest.fixture
def link():
    """(sender, the MAVSDK stand-in socket, a parser) with the handshake done."""
    sender = SetpointSender.spawn(BOOT, (245, 194), (1, 1))
    mavsdk = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    mavsdk.bind(("127.0.0.1", 0))
    mavsdk.sendto(b"\xfd hello", ("127.0.0.1", sender.port))  # MAVSDK speaks first
    sender.wait_ready()
    yield sender, mavsdk, mavlink2.MAVLink(None)
    sender.close()
    mavsdk.close()


def _receive(mavsdk: socket.socket, parser, timeout: float = 5.0):
    mavsdk.settimeout(timeout)
    data, _ = mavsdk.recvfrom(4096)
    return time.monotonic(), parser.decode(bytearray(data))


def _reports(sender: SetpointSender, count: int, timeout: float = 5.0):
    got, end = [], time.monotonic() + timeout
    while len(got) < count and time.monotonic() < end:
        got += sender.reports()
        time.sleep(0.005)
    return got


def _not_sent(sender: SetpointSender, mavsdk: socket.socket, code: float,
              quiet_s: float) -> None:
    """The next report says not sent, for ``code``; nothing arrives for ``quiet_s``."""
    (report,) = _reports(sender, 1)
    assert report.sent_at is None and report.why == WHY[code]
    mavsdk.settimeout(quiet_s)
    with pytest.raises(TimeoutError):
        mavsdk.recvfrom(4096)


def test_a_setpoint_goes_out_at_its_deadline_stamped_when_it_went():
    # (the fixture is not used: this test checks the handshake as well)
    sender = SetpointSender.spawn(BOOT, (245, 194), (1, 1))
    mavsdk = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    mavsdk.bind(("127.0.0.1", 0))
    try:
        mavsdk.sendto(b"\xfd", ("127.0.0.1", sender.port))
        sender.wait_ready()
        at = time.monotonic() + 0.2
        sender.put(at, at + 1.0, math.inf, 0.0, VALUES)
        arrived, msg = _receive(mavsdk, mavlink2.MAVLink(None))
        assert msg.get_type() == "SET_POSITION_TARGET_LOCAL_NED"
        assert (msg.get_srcSystem(), msg.get_srcComponent()) == (245, 194)
        assert (msg.target_system, msg.target_component, msg.coordinate_frame) == (1, 1, 1)
        assert (msg.x, msg.y, msg.z, msg.vx, msg.yaw) == (1.0, 2.0, -3.0, 0.5, 0.25)
        (report,) = _reports(sender, 1)
        assert report.at == at and report.sent_at is not None
        # never early; the stamp is the moment it went out (whole ms of time since boot)
        assert report.sent_at >= at and arrived >= report.sent_at
        assert abs(msg.time_boot_ms - (report.sent_at - BOOT) * 1e3) <= 0.5
    finally:
        sender.close()
        mavsdk.close()


def test_setpoints_go_out_in_order_each_at_its_own_deadline(link):
    sender, mavsdk, parser = link
    t0 = time.monotonic() + 0.1
    for k in range(5):
        sender.put(t0 + 0.02 * k, t0 + 1.0, math.inf, 0.0, (float(k), *VALUES[1:]))
    xs = [_receive(mavsdk, parser)[1].x for _ in range(5)]
    assert xs == [0.0, 1.0, 2.0, 3.0, 4.0]
    sent = [r.sent_at for r in _reports(sender, 5)]
    assert all(s >= t0 + 0.02 * k for k, s in enumerate(sent))


def test_a_setpoint_past_its_not_after_or_after_too_long_a_silence_is_dropped(link):
    sender, mavsdk, parser = link
    now = time.monotonic()
    sender.put(now - 0.1, now - 0.05, math.inf, 0.0, VALUES)  # computed before a stall
    (late,) = _reports(sender, 1)
    assert late.sent_at is None and late.why == WHY[LATE]
    sender.put(now, now + 1.0, math.inf, 0.0, VALUES)
    _receive(mavsdk, parser)
    _reports(sender, 1)
    time.sleep(0.15)  # (the silence to be refused: real time must pass)
    at = time.monotonic()
    sender.put(at, at + 1.0, 0.1, 0.0, VALUES)  # 0.15 s since the last one went out > 0.1 s
    _not_sent(sender, mavsdk, SILENT, 0.3)


def test_cancel_drops_what_waits(link):
    sender, mavsdk, _ = link
    at = time.monotonic() + 0.5
    sender.put(at, at + 1.0, math.inf, 0.0, VALUES)
    sender.cancel()
    _not_sent(sender, mavsdk, CANCELLED, 0.8)


def test_it_ignores_sigterm_and_sigint_and_ends_when_the_service_does(link):
    sender, mavsdk, parser = link
    for sig in (signal.SIGTERM, signal.SIGINT):
        os.kill(sender._proc.pid, sig)
    at = time.monotonic() + 0.05
    sender.put(at, at + 1.0, math.inf, 0.0, VALUES)
    _receive(mavsdk, parser)  # still sending
    sender._proc.stdin.close()  # the service's end of the pipe closes (as when it dies)
    assert sender._proc.wait(5) == 0


def test_a_dead_sender_says_so():
    sender = SetpointSender.spawn(BOOT, (245, 194), (1, 1))
    sender._proc.kill()
    sender._proc.wait()
    assert not sender.alive and "exited (code -9)" in sender.exit_reason()
    with pytest.raises(SenderError, match="exited"):
        for _ in range(100):  # (the pipe's buffer may take some writes first)
            sender.put(0.0, 0.0, math.inf, 0.0, VALUES)
    sender.close()


def test_a_sender_that_stops_reading_is_killed_not_waited_for(link):
    # the stream's thread writes into the pipe: a stopped sender must never block it
    sender, _, _ = link
    os.kill(sender._proc.pid, signal.SIGSTOP)
    t0 = time.monotonic()
    with pytest.raises(SenderError, match="stopped reading its pipe"):
        for _ in range(2000):  # the pipe holds 585 records (64 KiB)
            sender.put(time.monotonic() + 60.0, math.inf, math.inf, 0.0, VALUES)
    assert time.monotonic() - t0 < 5.0  # (milliseconds; blocked forever before)
    assert sender._proc.wait(5) == -signal.SIGKILL
    assert "killed: it had stopped reading its pipe" in sender.exit_reason()


def test_nothing_is_sent_while_the_service_is_stopped():
    """The sender's parent here is this test process; a child of it stands in for the
    service: a sender spawned from a process that then stops itself sends nothing."""
    import subprocess
    import sys
    program = (
        "import math, os, signal, socket, sys, time\n"
        "from companion.flight.sender import SetpointSender\n"
        "s = SetpointSender.spawn(time.monotonic(), (245, 194), (1, 1))\n"
        "m = socket.socket(socket.AF_INET, socket.SOCK_DGRAM); m.bind(('127.0.0.1', 0))\n"
        "m.sendto(b'x', ('127.0.0.1', s.port)); s.wait_ready()\n"
        "print(m.getsockname()[1], flush=True)\n"
        "at = time.monotonic() + 0.3\n"
        "s.put(at, at + 5.0, math.inf, 0.0, (0.0,) * 10)\n"
        "os.kill(os.getpid(), signal.SIGSTOP)\n"  # frozen before the deadline
        "print(s.reports()[0].why, flush=True)\n"
        "m.settimeout(0.5)\n"
        "try:\n    m.recvfrom(4096); print('received', flush=True)\n"
        "except TimeoutError:\n    print('nothing', flush=True)\n"
        "s.close()\n")
    proc = subprocess.Popen([sys.executable, "-c", program], stdout=subprocess.PIPE,
                            text=True)
    try:
        proc.stdout.readline()  # ready
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:  # wait for the state, not a time
            with open(f"/proc/{proc.pid}/stat") as f:
                if f.read().rsplit(")", 1)[1].split()[0] == "T":
                    break
            time.sleep(0.01)
        time.sleep(0.6)  # the fault itself: frozen past the setpoint's deadline
        os.kill(proc.pid, signal.SIGCONT)
        why, received = proc.stdout.readline().strip(), proc.stdout.readline().strip()
    finally:
        proc.kill()
        proc.wait()
    assert "the service was stopped" in why and received == "nothing"


def test_a_late_setpoint_is_moved_on_to_when_it_goes_and_a_superseded_one_dropped(link):
    sender, mavsdk, parser = link
    # held up 50 ms (here: handed over late), allowed to move on by up to 20 ms
    now = time.monotonic()
    p_v_a = (0.0, 0.0, -2.0, 2.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
    sender.put(now - 0.05, now + 1.0, math.inf, 0.02, p_v_a)
    _, msg = _receive(mavsdk, parser)
    assert math.isclose(msg.x, 2.0 * 0.02, rel_tol=1e-6)  # along the velocity, 20 ms
    assert (msg.vx, msg.afx) == (2.0, 1.0)  # as computed (and checked) by the stream
    # two handed over after both deadlines (in one write, so that the sender reads
    # them together): only the newer goes
    now = time.monotonic()
    sender._write(RECORD.pack(now - 0.04, now + 1.0, math.inf, 0.0, 1.0, *VALUES[1:])
                  + RECORD.pack(now - 0.02, now + 1.0, math.inf, 0.0, 2.0, *VALUES[1:]))
    _, msg = _receive(mavsdk, parser)
    assert msg.x == 2.0
    reports = _reports(sender, 3)
    assert [r.why for r in reports[1:]] == [WHY[SUPERSEDED], ""]


def test_it_runs_real_time_where_it_may_else_above_the_service():
    """SCHED_FIFO where the process may (root or CAP_SYS_NICE), else NICE_STEP nice
    levels above its parent where it may, else at its parent's priority."""
    from companion.flight.sender import NICE_STEP, RT_PRIORITY

    def may(code: str) -> bool:  # (a child of this test tries it)
        return subprocess.run([sys.executable, "-c", f"import os; {code}"],
                              capture_output=True).returncode == 0

    here = os.getpriority(os.PRIO_PROCESS, 0)
    rt = may(f"os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param({RT_PRIORITY}))")
    nicer = may(f"os.setpriority(os.PRIO_PROCESS, 0, {max(here - 1, -20)})")
    sender = SetpointSender.spawn(BOOT, (245, 194), (1, 1))
    try:
        pid = sender._proc.pid

        def state() -> tuple[int, int]:
            return os.sched_getscheduler(pid), os.getpriority(os.PRIO_PROCESS, pid)

        if rt:
            want = (os.SCHED_FIFO, here)
        else:
            want = (os.SCHED_OTHER, max(here - NICE_STEP, -20) if nicer else here)
        end = time.monotonic() + 10
        while state() != want and time.monotonic() < end:  # (set as it starts)
            time.sleep(0.01)
        assert state() == want
        if rt:
            assert os.sched_getparam(pid).sched_priority == RT_PRIORITY
    finally:
        sender.close()


def test_shifted_moves_a_position_along_its_velocity_either_way_and_nothing_else():
    from companion.flight.sender import shifted

    v = (1.0, 2.0, 3.0, 2.0, -1.0, 0.5, 0.3, 0.0, 0.0, 0.7)
    assert shifted(v, 0.01)[:3] == pytest.approx((1.02, 1.99, 3.005))
    assert shifted(v, -0.01)[:3] == pytest.approx((0.98, 2.01, 2.995))  # sent early
    assert shifted(v, 0.01)[3:] == v[3:] and shifted(v, 0.0) == v
    assert shifted(v, float("nan")) == v
