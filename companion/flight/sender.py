"""The setpoint sender: a small process of its own that puts each offboard setpoint
on the wire at its deadline, so that no thread of the service, and not Python's GIL,
can hold a setpoint up.

Why a process. The stream's thread (:mod:`companion.flight.stream`) needs the GIL to wake
up and to send. On a busy companion computer the thread holding the GIL (the event
loop, a Zenoh or MAVSDK callback) can itself be waiting for a CPU, and then the
setpoint waits with it: the kernel gives no priority to a thread for the lock it
holds. In the project's CI (two test workers on two cores) that put the 99th
percentile of the stream's gaps at 26 ms against its 25 ms budget, and beside two
busy loops at 33 ms. This process holds nothing but the next setpoints: it sleeps to
a deadline, checks it and sends.

How. The stream computes each setpoint a few periods ahead
(:data:`companion.flight.stream.LEAD_PERIODS`), for the deadline it is to go out at,
and writes it here through a pipe (:meth:`SetpointSender.put`, one ``os.write`` of
:data:`RECORD` bytes). This process packs it as a MAVLink 2
SET_POSITION_TARGET_LOCAL_NED (pymavlink) stamped with the moment it really sends it
(``time_boot_ms`` on the service's clock: a late send shows as a late stamp) and
sends it over UDP on loopback to a link of the service's own MAVSDK with forwarding
on; MAVSDK's C++ threads forward it to PX4 over whatever link PX4 is on (UDP or
serial). The vehicle still receives exactly what the stream computed, nothing else.

What it promises, whatever the service does meanwhile:

* a setpoint is never sent after its ``not_after`` (a setpoint computed before a
  stall is never sent after it);
* never later than ``max_silence`` after the last setpoint it really sent (PX4's
  offboard-loss timeout minus the margin: resumed setpoints would take PX4 back into
  OFFBOARD by themselves);
* :meth:`SetpointSender.cancel` drops what waits (the stream stopped);
* nothing is sent while the service process is stopped (SIGSTOP, a debugger): its
  MAVSDK would hold the datagram and forward it to PX4 only when the service runs
  again, after PX4's offboard-loss timeout perhaps (the state is read from
  ``/proc/<service>/stat`` just before each send; a stop landing between that read
  and MAVSDK's read of the datagram, microseconds on a quiet machine and up to
  milliseconds on a busy one, still lets one setpoint out late);
* it ends when the service's end of the pipe closes (the service exited or died),
  and ignores SIGINT and SIGTERM, which the service handles for it.

Every setpoint is accounted for: the process writes back, per setpoint, when it went
out or why not (:meth:`SetpointSender.reports`).
"""

from __future__ import annotations

import contextlib
import math
import os
import select
import signal
import socket
import struct
import subprocess
import sys
import time
from collections import deque
from dataclasses import dataclass

#: One setpoint in the pipe: deadline, not_after, max_silence, max_shift (s; the first
#: two on the monotonic clock), position, velocity, acceleration (NED, 9 values), yaw
#: (rad). A NaN deadline cancels.
RECORD = struct.Struct("<14d")
#: One report back: the setpoint's deadline, and when it went out (>= 0) or a code < 0.
REPORT = struct.Struct("<dd")
LATE, SILENT, FAILED, CANCELLED, FROZEN, SUPERSEDED = -1.0, -2.0, -3.0, -4.0, -5.0, -6.0
#: What a code < 0 means, in words.
WHY = {LATE: "computed before a stall and not sent after it",
       SILENT: "too long after the last setpoint sent (PX4 may have timed out)",
       FAILED: "the UDP send to MAVSDK failed", CANCELLED: "dropped: the stream stopped",
       FROZEN: "the service was stopped (SIGSTOP or a debugger): its MAVSDK would "
               "forward the setpoint only once it runs again",
       SUPERSEDED: "held up past the next setpoint's deadline: the next one went instead"}
#: The handshake: the process's UDP port (first report), then ready (it has heard MAVSDK).
HELLO, READY = -10.0, -11.0
#: The sender runs real-time at this SCHED_FIFO priority (the lowest) where it may, else
#: this many nice levels above the service, as the stream's thread does (both need
#: CAP_SYS_NICE, as the service's own priority does; without it, at the service's
#: priority, and the stream's warning on status says why).
RT_PRIORITY = 1
NICE_STEP = 5
#: The sender's own MAVLink component id (MAV_COMP_ID_ONBOARD_COMPUTER2): not MAVSDK's.
COMPONENT_ID = 194
TYPE_MASK_PVA_YAW = 2048  # position, velocity, acceleration and yaw; yaw rate ignored
MAV_FRAME_LOCAL_NED = 1


class SenderError(RuntimeError):
    """The sender process is gone or did not start; the message says why."""


@dataclass(frozen=True)
class Sent:
    """What became of one setpoint: ``at`` its deadline, ``sent_at`` when it went out
    (None if not: ``why`` says why)."""

    at: float
    sent_at: float | None
    why: str = ""


class SetpointSender:
    """The service's handle on the sender process (see the module's docstring)."""

    def __init__(self, proc: subprocess.Popen, port: int) -> None:
        self._proc = proc
        self.port = port  # the sender's UDP port on 127.0.0.1 (MAVSDK: udpout to it)
        self._buf = b""
        self._killed = ""  # why this side killed the process, if it did
        os.set_blocking(proc.stdout.fileno(), False)
        # never wait on the pipe: a sender that stops reading (stopped, or blocked on its
        # own report pipe) must not hold up the stream's thread (:meth:`_write`)
        os.set_blocking(proc.stdin.fileno(), False)

    @classmethod
    def spawn(cls, boot: float, source: tuple[int, int], target: tuple[int, int],
              wait_s: float = 20.0) -> SetpointSender:
        """Start the process (``boot``: the monotonic time of ``time_boot_ms`` 0;
        ``source``: its MAVLink system and component id; ``target``: PX4's) and wait
        for its port."""
        proc = subprocess.Popen(
            [sys.executable, "-m", "companion.flight.sender", repr(boot), *map(str, source),
             *map(str, target)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
            close_fds=True)
        try:
            (port, code), = _read_exactly(proc, 1, wait_s)
        except SenderError:
            proc.kill()
            raise
        if code != HELLO:
            proc.kill()
            raise SenderError(f"the setpoint sender answered {code} instead of its port")
        return cls(proc, int(port))

    def wait_ready(self, wait_s: float = 10.0) -> None:
        """Wait until the process has heard from MAVSDK (so it knows where to send)."""
        end = time.monotonic() + wait_s
        while time.monotonic() < end:
            select.select([self._proc.stdout], [], [], 0.05)
            if any(code == READY for _, code in self._drain()):
                return
            if self._proc.poll() is not None:
                break
        raise SenderError(self.exit_reason() or f"the setpoint sender heard nothing from MAVSDK "
                          f"within {wait_s:.0f} s")

    @property
    def alive(self) -> bool:
        return self._proc.poll() is None

    def exit_reason(self) -> str:
        """Why the process ended ("" while it runs)."""
        code = self._proc.poll()
        why = f"; killed: {self._killed}" if self._killed else ""
        return "" if code is None else f"the setpoint sender process exited (code {code}{why})"

    def put(self, at: float, not_after: float, max_silence: float, max_shift: float,
            values: tuple[float, ...]) -> None:
        """Send ``values`` (position, velocity, acceleration NED, yaw rad) at ``at``,
        not after ``not_after`` nor ``max_silence`` after the last setpoint sent; if it
        goes out late, its position moved on to the moment it does by at most ``max_shift``
        (:func:`shifted`)."""
        self._write(RECORD.pack(at, not_after, max_silence, max_shift, *values))

    def cancel(self) -> None:
        """Drop every setpoint not yet sent."""
        self._write(RECORD.pack(math.nan, *([0.0] * 13)))

    def _write(self, data: bytes) -> None:
        """One record into the pipe, at once or not at all (a record is far below
        PIPE_BUF, so a write is atomic). A full pipe means the process stopped reading
        (twelve seconds of setpoints wait in it): it is killed, so that the autopilot's
        watcher restarts it, and the caller sends from its own thread meanwhile."""
        try:
            os.write(self._proc.stdin.fileno(), data)
        except BlockingIOError:
            self._killed = "it had stopped reading its pipe"
            with contextlib.suppress(OSError):
                self._proc.kill()
            raise SenderError("the setpoint sender stopped reading its pipe (full); "
                              "killed, to be restarted") from None
        except (OSError, ValueError) as exc:  # (ValueError: the pipe closed here)
            raise SenderError(self.exit_reason() or f"the setpoint sender's pipe: {exc}") from exc

    def reports(self) -> list[Sent]:
        """What became of the setpoints since the last call."""
        return [Sent(at, code if code >= 0 else None, WHY.get(code, ""))
                for at, code in self._drain() if code >= 0 or code in WHY]

    def _drain(self) -> list[tuple[float, float]]:
        with contextlib.suppress(BlockingIOError, OSError, ValueError):
            while chunk := os.read(self._proc.stdout.fileno(), 65536):
                self._buf += chunk
        n = len(self._buf) // REPORT.size * REPORT.size
        out, self._buf = list(REPORT.iter_unpack(self._buf[:n])), self._buf[n:]
        return out

    def close(self, wait_s: float = 2.0) -> None:
        """Close the pipe (the process ends by itself) and reap it."""
        with contextlib.suppress(OSError):
            self._proc.stdin.close()
        try:
            self._proc.wait(wait_s)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        with contextlib.suppress(OSError):
            self._proc.stdout.close()


def _read_exactly(proc: subprocess.Popen, count: int, wait_s: float,
                  ) -> list[tuple[float, float]]:
    data, end = b"", time.monotonic() + wait_s
    fd = proc.stdout.fileno()
    while len(data) < count * REPORT.size:
        left = end - time.monotonic()
        if left <= 0 or not select.select([fd], [], [], left)[0]:
            raise SenderError(f"the setpoint sender did not start within {wait_s:.0f} s")
        chunk = os.read(fd, count * REPORT.size - len(data))
        if not chunk:
            raise SenderError(f"the setpoint sender process exited at start (code "
                              f"{proc.wait()})")
        data += chunk
    return list(REPORT.iter_unpack(data))


# ---------------------------------------------------------------- the process itself
def serve(boot: float, source: tuple[int, int], target: tuple[int, int]) -> None:
    """The sender process: read setpoints from stdin, send each at its deadline."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    raise_priority()
    from pymavlink.dialects.v20 import common as mavlink2

    mav = mavlink2.MAVLink(None, srcSystem=source[0], srcComponent=source[1])
    service = f"/proc/{os.getppid()}/stat"
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))

    def report(at: float, code: float) -> None:
        os.write(1, REPORT.pack(at, code))

    report(float(sock.getsockname()[1]), HELLO)
    # MAVSDK (udpout to this port) sends first (a heartbeat or what it forwards): its
    # address is where setpoints go. Then the socket is made small: what MAVSDK goes on
    # forwarding here is dropped by the kernel, unread.
    _, mavsdk = sock.recvfrom(65536)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1)
    report(0.0, READY)
    pending: deque[tuple[float, ...]] = deque()
    buf, last = b"", -math.inf
    while True:
        timeout = max(0.0, pending[0][0] - time.monotonic()) if pending else None
        if select.select([0], [], [], timeout)[0]:
            chunk = os.read(0, 65536)
            if not chunk:
                return  # the service is gone
            buf += chunk
            n = len(buf) // RECORD.size * RECORD.size
            for rec in RECORD.iter_unpack(buf[:n]):
                if math.isnan(rec[0]):
                    while pending:
                        report(pending.popleft()[0], CANCELLED)
                else:
                    pending.append(rec)
            buf = buf[n:]
            continue
        at, not_after, max_silence, max_shift, *values = pending.popleft()
        now = time.monotonic()
        if now > not_after:
            report(at, LATE)
            continue
        if pending and pending[0][0] <= now:
            report(at, SUPERSEDED)
            continue
        if last > -math.inf and now - last > max_silence:  # (a new sender: not_after holds)
            report(at, SILENT)
            continue
        packed = mav.set_position_target_local_ned_encode(
            int(round((now - boot) * 1e3)) & 0xFFFFFFFF, target[0], target[1],
            MAV_FRAME_LOCAL_NED, TYPE_MASK_PVA_YAW,
            *shifted(values, min(now - at, max_shift)), 0.0).pack(mav)
        if _stopped(service):
            report(at, FROZEN)
            continue
        if time.monotonic() > not_after:  # (held up while packing)
            report(at, LATE)
            continue
        try:
            sock.sendto(packed, mavsdk)
        except OSError:
            report(at, FAILED)
            continue
        last = now
        report(at, now)


def shifted(values: tuple[float, ...] | list[float], dt: float) -> tuple[float, ...]:
    """A setpoint (position, velocity, acceleration, yaw) computed for a time ``dt``
    earlier, its position moved on to now along its velocity: a setpoint held up in
    the sender by a busy CPU then says where the plan is when it goes out (its stamp
    says when), not where it was (a 15 ms delay at 2 m/s is 3 cm, and the next
    setpoint, on time, would seem to leap). Velocity and acceleration are left as
    computed (checked against the limits; the plan's change over ``dt`` is under a
    millimetre of position at 3 m/s^2). A negative ``dt`` moves it back (a setpoint
    sent before its time: the stream's own stand-in while the sender restarts); 0 or
    NaN: unchanged. The caller bounds ``dt`` by the stream's lead (two periods: at 2 m/s
    and 50 Hz, 8 cm from the position the stream checked)."""
    if not (dt > 0 or dt < 0):
        return tuple(values)
    return (*(values[i] + values[3 + i] * dt for i in range(3)), *values[3:])


def raise_priority(tid: int = 0) -> str:
    """Real-time (SCHED_FIFO at :data:`RT_PRIORITY`) for the thread ``tid`` (0: the
    calling process) where allowed (root, CAP_SYS_NICE, or ``LimitRTPRIO``): it then
    runs the moment it wakes, before any ordinary work (the setpoint sender and the
    stream's thread sleep most of each period; the kernel's real-time throttling would
    still leave ordinary work 5 % of each CPU if one spun). Else :data:`NICE_STEP`
    nice levels above its own, if allowed. Returns "" or why neither was allowed."""
    try:
        os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(RT_PRIORITY))
        return ""
    except (OSError, AttributeError):
        pass
    here = os.getpriority(os.PRIO_PROCESS, tid)
    want = max(here - NICE_STEP, -20)
    try:
        os.setpriority(os.PRIO_PROCESS, tid, want)
        return ""
    except OSError as exc:
        return (f"at the service's priority (nice {here}): neither real-time (SCHED_FIFO "
                f"{RT_PRIORITY}) nor nice {want} allowed ({exc.strerror}; grant "
                "CAP_SYS_NICE, or LimitRTPRIO=1 as the shipped unit does)")


def _stopped(stat: str) -> bool:
    """The process of this ``/proc/<pid>/stat`` is stopped or traced (or gone)."""
    try:
        with open(stat, "rb") as f:
            raw = f.read(512)
    except OSError:
        return True
    return raw[raw.rindex(b")") + 2:][:1] in (b"T", b"t")


if __name__ == "__main__":
    _boot, *_ids = sys.argv[1:]
    _n = [int(x) for x in _ids]
    serve(float(_boot), (_n[0], _n[1]), (_n[2], _n[3]))
