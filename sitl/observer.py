"""A passive MAVLink observer of a vehicle: what the autopilot itself reports, recorded with
wall-clock times, beside the flight service's own account.

On real PX4 SITL it listens on PX4's GCS link (instance ``i``: PX4 binds UDP ``18570 + i``)
and SIH's display link (PX4 sends ``HIL_STATE_QUATERNION``, the simulator's ground truth, to
UDP ``19410 + i``); on the ``sitl`` vehicle, on its MAVLink endpoint, which streams the same
messages on request. It sends nothing that commands the vehicle: one ``PARAM_REQUEST_READ``
to make itself known (PX4 then sends the GCS link's stream to it) and
``SET_MESSAGE_INTERVAL`` requests: ``CURRENT_MODE`` at 50 Hz, so a mode change is seen within
20 ms (PX4 refuses a faster HEARTBEAT: it stays at 1 Hz, so arming is seen up to 1 s late);
the ground truth at 25 Hz. Only :meth:`kill` acts: a forced disarm, the kill switch of the
fault tests.

Frames: positions are local NED (PX4's origin); the ground truth is converted from latitude,
longitude and altitude to NED about the first truth sample (the vehicle at rest at its local
origin, where PX4's estimator set that origin at boot).
"""

from __future__ import annotations

import math
import socket
import threading
import time
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import development as mavlink2  # common + CURRENT_MODE

from sitl.commander import Px4Mode

_M = mavlink2
#: Earth radius (m) of the flat-earth conversion (as sitl.mavlink_link)
_EARTH_RADIUS_M = 6371000.0
#: UDP ports of PX4 SITL instance i: its GCS link binds GCS_PORT + i, SIH's display link
#: sends HIL_STATE_QUATERNION to TRUTH_PORT + i (px4-rc.mavlink)
GCS_PORT, TRUTH_PORT = 18570, 19410
FORCE_DISARM_MAGIC = 21196

_MODES = {m.value: m.name for m in Px4Mode}


def mode_name(custom_mode: int) -> str:
    """PX4's mode name of a HEARTBEAT's ``custom_mode`` (``(4, 3)`` -> ``AUTO_LOITER``)."""
    main, sub = (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
    return _MODES.get((main, sub if main == 4 else 0), f"MODE_{main}_{sub}")


@dataclass
class Observed:
    """Everything the observer saw, wall-clock (``time.monotonic``) stamped."""

    modes: list[tuple[float, str, bool]] = field(default_factory=list)  # changes only
    position: list[tuple[float, np.ndarray]] = field(default_factory=list)  # estimate, NED
    truth: list[tuple[float, np.ndarray]] = field(default_factory=list)  # ground truth, NED
    truth_velocity: list[tuple[float, np.ndarray]] = field(default_factory=list)  # NED, m/s
    landed: list[tuple[float, int]] = field(default_factory=list)  # changes only
    texts: list[tuple[float, str]] = field(default_factory=list)
    params: dict[str, float] = field(default_factory=dict)


class Observer:
    """``with Observer(port, truth_port) as obs:`` records what the vehicle reports.

    Args:
        port: the vehicle's MAVLink port to make itself known to (PX4: ``GCS_PORT + i``;
            the ``sitl`` vehicle: its bound port).
        truth_port: a port to listen on for ``HIL_STATE_QUATERNION`` (PX4:
            ``TRUTH_PORT + i``); None: ask for it on ``port``'s link.
        system_id: the vehicle's MAVLink system id (PX4 instance i: i + 1).
    """

    def __init__(self, port: int, truth_port: int | None = None, system_id: int = 1) -> None:
        self.port, self.truth_port, self.system_id = port, truth_port, system_id
        self.seen = Observed()
        self.lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._origin: tuple[float, float, float] | None = None
        self._heard = threading.Event()
        self._armed = False
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.bind(("127.0.0.1", 0))
        self._sock.settimeout(0.1)
        self._mav = mavlink2.MAVLink(None, srcSystem=246, srcComponent=191)
        self._mav.robust_parsing = True

    @classmethod
    def px4(cls, instance: int) -> Observer:
        """The observer of PX4 SITL instance ``instance``."""
        return cls(GCS_PORT + instance, TRUTH_PORT + instance, instance + 1)

    # ------------------------------------------------------------ life
    def __enter__(self) -> Observer:
        socks = [self._sock]
        if self.truth_port is not None:
            truth = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            truth.bind(("127.0.0.1", self.truth_port))
            truth.settimeout(0.1)
            socks.append(truth)
        for sock in socks:
            parser = mavlink2.MAVLink(None)
            parser.robust_parsing = True
            # (only the truth from the second link: its HEARTBEATs, read in another thread,
            # can be taken in after a newer mode from the first and seem a mode change)
            only = ("HIL_STATE_QUATERNION",) if sock is not self._sock else None
            thread = threading.Thread(target=self._listen, args=(sock, parser, only),
                                      daemon=True, name="mavlink-observer")
            thread.start()
            self._threads.append(thread)
        end = time.monotonic() + 30.0
        while not self._heard.wait(0.5):  # hello until the vehicle answers
            if time.monotonic() > end:
                self.__exit__()
                raise TimeoutError(f"no MAVLink from the vehicle on UDP {self.port}")
            self._hello()
        self._hello()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(2.0)
        self._sock.close()

    def _send(self, msg: object) -> None:
        try:
            self._sock.sendto(msg.pack(self._mav), ("127.0.0.1", self.port))  # type: ignore[attr-defined]
        except OSError:
            pass

    def _command(self, command: int, *params: float) -> None:
        p = [*params, *[0.0] * (7 - len(params))]
        self._send(self._mav.command_long_encode(self.system_id, 1, command, 0, *p))

    def _hello(self) -> None:
        self._send(self._mav.param_request_read_encode(self.system_id, 1, b"COM_OF_LOSS_T", -1))
        self._command(_M.MAV_CMD_SET_MESSAGE_INTERVAL, _M.MAVLINK_MSG_ID_CURRENT_MODE, 20_000)
        self._command(_M.MAV_CMD_SET_MESSAGE_INTERVAL, _M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
                      100_000)
        if self.truth_port is None:
            self._command(_M.MAV_CMD_SET_MESSAGE_INTERVAL,
                          _M.MAVLINK_MSG_ID_HIL_STATE_QUATERNION, 40_000)

    def kill(self) -> None:
        """Force a disarm now, in the air too (a kill switch)."""
        self._command(_M.MAV_CMD_COMPONENT_ARM_DISARM, 0.0, FORCE_DISARM_MAGIC)

    # ------------------------------------------------------------ receiving
    def _listen(self, sock: socket.socket, parser: object,
                only: tuple[str, ...] | None = None) -> None:
        """Take in what arrives on ``sock`` (with ``only``: just those messages)."""
        while not self._stop.is_set():
            try:
                data = sock.recv(65535)
            except (TimeoutError, OSError):
                continue
            now = time.monotonic()
            for msg in parser.parse_buffer(data) or []:  # type: ignore[attr-defined]
                if msg.get_srcSystem() == self.system_id and (
                        only is None or msg.get_type() in only):  # type: ignore[attr-defined]
                    self._on(msg, now)

    def _on(self, msg: object, now: float) -> None:
        kind = msg.get_type()  # type: ignore[attr-defined]
        s = self.seen
        with self.lock:
            if kind == "HEARTBEAT" and msg.get_srcComponent() == 1:  # type: ignore[attr-defined]
                self._heard.set()
                mode = mode_name(msg.custom_mode)  # type: ignore[attr-defined]
                self._armed = bool(msg.base_mode & _M.MAV_MODE_FLAG_SAFETY_ARMED)  # type: ignore[attr-defined]
                self._mode(now, mode)
            elif kind == "CURRENT_MODE":
                self._mode(now, mode_name(msg.custom_mode))  # type: ignore[attr-defined]
            elif kind == "LOCAL_POSITION_NED":
                s.position.append((now, np.array([msg.x, msg.y, msg.z])))  # type: ignore[attr-defined]
            elif kind == "HIL_STATE_QUATERNION":
                s.truth.append((now, self._ned(msg)))
                s.truth_velocity.append((now, np.array(  # cm/s, NED
                    [msg.vx, msg.vy, msg.vz], dtype=float) / 100.0))  # type: ignore[attr-defined]
            elif kind == "EXTENDED_SYS_STATE":
                landed = int(msg.landed_state)  # type: ignore[attr-defined]
                if not s.landed or s.landed[-1][1] != landed:
                    s.landed.append((now, landed))
            elif kind == "STATUSTEXT":
                s.texts.append((now, str(msg.text)))  # type: ignore[attr-defined]
            elif kind == "PARAM_VALUE":
                s.params[str(msg.param_id)] = float(msg.param_value)  # type: ignore[attr-defined]

    def _mode(self, now: float, mode: str) -> None:
        s = self.seen
        if not s.modes or s.modes[-1][1:] != (mode, self._armed):
            s.modes.append((now, mode, self._armed))

    def _ned(self, msg: object) -> np.ndarray:
        lat, lon = msg.lat * 1e-7, msg.lon * 1e-7  # type: ignore[attr-defined]
        alt = msg.alt * 1e-3  # type: ignore[attr-defined]
        if self._origin is None:
            self._origin = (lat, lon, alt)
        lat0, lon0, alt0 = self._origin
        return np.array([math.radians(lat - lat0) * _EARTH_RADIUS_M,
                         math.radians(lon - lon0) * _EARTH_RADIUS_M * math.cos(math.radians(lat0)),
                         alt0 - alt])

    # ------------------------------------------------------------ reading
    def mode(self) -> tuple[str, bool]:
        """The latest (mode, armed)."""
        with self.lock:
            return self.seen.modes[-1][1:] if self.seen.modes else ("", False)

    def modes_between(self, t0: float, t1: float = math.inf) -> list[str]:
        """Every mode PX4 reported between ``t0`` and ``t1`` (monotonic), the one in force at
        ``t0`` first."""
        with self.lock:
            modes = list(self.seen.modes)
        before = [m for t, m, _ in modes if t <= t0]
        return before[-1:] + [m for t, m, _ in modes if t0 < t <= t1]

    def mode_changes(self, since: float = 0.0) -> list[tuple[float, str, bool]]:
        with self.lock:
            return [m for m in self.seen.modes if m[0] >= since]

    def positions(self, t0: float = 0.0, t1: float = math.inf) -> np.ndarray:
        """Reported (estimated) positions, local NED, between ``t0`` and ``t1``."""
        with self.lock:
            return _between(self.seen.position, t0, t1)

    def truth(self, t0: float = 0.0, t1: float = math.inf) -> np.ndarray:
        """Ground-truth positions, local NED, between ``t0`` and ``t1``."""
        with self.lock:
            return _between(self.seen.truth, t0, t1)

    def truth_velocities(self, t0: float = 0.0, t1: float = math.inf
                         ) -> tuple[np.ndarray, np.ndarray]:
        """Ground-truth velocities (NED, m/s; SIH sends them to 1 cm/s) between ``t0`` and
        ``t1``, with the times they arrived (monotonic)."""
        with self.lock:
            keep = [(t, v) for t, v in self.seen.truth_velocity if t0 <= t <= t1]
        return (np.array([t for t, _ in keep]),
                np.array([v for _, v in keep]) if keep else np.zeros((0, 3)))

    def truth_hole(self, t0: float, t1: float) -> float:
        """The longest time (s) between ``t0`` and ``t1`` without a ground-truth sample
        (the edges count: a truth stream that stopped shows as a hole to ``t1``)."""
        with self.lock:
            t = [s for s, _ in self.seen.truth if t0 <= s <= t1]
        return float(np.max(np.diff([t0, *t, t1])))

    def texts(self, since: float = 0.0) -> list[str]:
        with self.lock:
            return [x for t, x in self.seen.texts if t >= since]

    def wait(self, predicate, timeout_s: float, what: str) -> float:  # noqa: ANN001
        """Wait (in this thread) until ``predicate(self)``; the time it held."""
        end = time.monotonic() + timeout_s
        while not predicate(self):
            if time.monotonic() > end:
                raise TimeoutError(f"PX4 did not report {what} within {timeout_s:g} s "
                                   f"(modes: {self.mode_changes()[-6:]})")
            time.sleep(0.02)
        return time.monotonic()


def _between(samples: list[tuple[float, np.ndarray]], t0: float, t1: float) -> np.ndarray:
    keep = [p for t, p in samples if t0 <= t <= t1]
    return np.array(keep) if keep else np.zeros((0, 3))
