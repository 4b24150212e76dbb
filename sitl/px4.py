"""Real PX4 SITL (the SIH quadrotor, headless) for the same end-to-end tests, when a PX4 build
is available. This project contains no PX4 code and no recipe to build it: point
``ROTA_PX4_BUILD`` at an existing ``build/px4_sitl_default`` directory (made with PX4's own
``make px4_sitl``).

Several instances can run at once: each takes the first free PX4 *instance* number ``i``
(``px4 -i i``), whose offboard link sends to UDP ``14540 + i`` on localhost, so MAVSDK connects
with ``udpin://127.0.0.1:<Px4Sitl.port>`` (PX4's ``px4-rc.mavlink`` assigns the ports). Boot is
complete when PX4's onboard link reports that it can arm (SYS_STATUS pre-arm check healthy)
and has a local position, not after a fixed time. PX4's console log (``px4.log``) and its
flight logs (``log/**/*.ulg``) stay in the working directory, which is kept (and its path
printed) when the ``with`` block raises or ``keep=True``; set ``ROTA_PX4_KEEP=1`` to keep it
always.

PX4's start-up script runs its commands (``px4-param``, ``px4-commander``...) through the
``px4-*`` links beside ``bin/px4``. A build copied without its symbolic links (each
``px4-*`` then a small text file naming ``px4``, not executable) cannot boot from there, so
PX4 always runs from a ``bin/`` of links in its working directory: the build itself is only
read.
"""

from __future__ import annotations

import fcntl
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

PX4_ENV = "ROTA_PX4_BUILD"
KEEP_ENV = "ROTA_PX4_KEEP"
PX4_PORT = 14540  #: the offboard link's UDP port of instance 0 (instance i: 14540 + i)
#: local UDP ports PX4 instance i binds (px4-rc.mavlink): base + i
_BOUND_PORTS = (14580, 18570, 14280, 13030, 19450, 19410)  # 19410: SIH's truth, to us
_MAX_INSTANCES = 10  # PX4 reuses 14549 for instances above 9


def px4_build() -> Path | None:
    """The PX4 build directory named by ``ROTA_PX4_BUILD``, if it looks usable."""
    value = os.environ.get(PX4_ENV)
    if not value:
        return None
    build = Path(value)
    return build if (build / "bin" / "px4").exists() and (build / "etc").is_dir() else None


def skip_reason() -> str:
    value = os.environ.get(PX4_ENV)
    if not value:
        return (f"real PX4 SITL not configured: set {PX4_ENV} to a PX4 build directory "
                "(build/px4_sitl_default) to run these tests against PX4's SIH quadrotor")
    return f"{PX4_ENV}={value} has no bin/px4 and etc/ (not a PX4 SITL build directory)"


def _udp_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


_IN_USE: set[int] = set()  # instances of this process (still booting ones bind nothing yet)


def _claim(instance: int) -> int | None:
    """An exclusive lock on PX4 instance ``instance`` across processes (a PX4 still booting
    binds nothing yet, so two test workers could otherwise pick the same one): the open
    lock file's descriptor, or None if another process holds it."""
    path = Path(tempfile.gettempdir()) / f"rota-px4-instance-{instance}.lock"
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        return None
    return fd


def free_instance() -> tuple[int, int]:
    """The first PX4 instance number no process of ours uses whose UDP ports are all free
    on 127.0.0.1, and the descriptor of its lock (close it to release the instance)."""
    for i in range(_MAX_INSTANCES):
        if i in _IN_USE:
            continue
        fd = _claim(i)
        if fd is None:
            continue
        if all(_udp_free(base + i) for base in (PX4_PORT, *_BOUND_PORTS)):
            return i, fd
        os.close(fd)
    raise RuntimeError(f"no free PX4 SITL instance (ports 14540-{14540 + _MAX_INSTANCES - 1})")


def _link_commands(build: Path, workdir: Path) -> Path:
    """``workdir/bin``: ``px4`` (a link to the build's) and its ``px4-*`` command links, made
    afresh (a copied build may have lost its links); the ``px4`` to run."""
    bin_dir = workdir / "bin"
    bin_dir.mkdir()
    px4 = bin_dir / "px4"
    px4.symlink_to((build / "bin" / "px4").resolve())
    for entry in (build / "bin").iterdir():
        if entry.name.startswith("px4-"):
            # px4-alias.sh is a script of its own; every other px4-* is px4 by another name
            target = entry.resolve() if entry.suffix == ".sh" else Path("px4")
            (bin_dir / entry.name).symlink_to(target)
    return px4


class Px4Sitl:
    """``with Px4Sitl(build) as px4:`` runs PX4 SITL with the SIH quadrotor (airframe
    10040), parameters set at boot through ``PX4_PARAM_<NAME>``; MAVSDK connects to
    ``udpin://127.0.0.1:<px4.port>``.

    Args:
        build: the PX4 build directory (``bin/px4``, ``etc/``).
        params: PX4 parameters to set at boot.
        speed_factor: ``PX4_SIM_SPEED_FACTOR``.
        boot_timeout_s: how long to wait for PX4 to be ready to arm.
        keep: keep the working directory (logs) even when nothing failed.
    """

    def __init__(self, build: Path, params: dict[str, float] | None = None,
                 speed_factor: float = 1.0, boot_timeout_s: float = 90.0,
                 keep: bool = False) -> None:
        self.build = Path(build)
        self.params = {"COM_OF_LOSS_T": 1.0, **(params or {})}
        self.speed_factor = speed_factor
        self.boot_timeout_s = boot_timeout_s
        self.keep = keep or os.environ.get(KEEP_ENV, "") not in ("", "0")
        self.instance = 0
        self.port = PX4_PORT
        self.home_enu = np.zeros(3)
        self.workdir: Path | None = None
        self._proc: subprocess.Popen | None = None
        self._log = None
        self._lock_fd: int | None = None

    @property
    def log_path(self) -> Path | None:
        """PX4's console output."""
        return None if self.workdir is None else self.workdir / "px4.log"

    def flight_logs(self) -> list[Path]:
        """PX4's ULog flight logs written so far."""
        return sorted(self.workdir.glob("**/*.ulg")) if self.workdir is not None else []

    def __enter__(self) -> Px4Sitl:
        self.instance, self._lock_fd = free_instance()
        _IN_USE.add(self.instance)
        self.port = PX4_PORT + self.instance
        self.workdir = Path(tempfile.mkdtemp(prefix=f"rota-px4-{self.instance}-"))
        env = dict(os.environ, PX4_SYS_AUTOSTART="10040", PX4_SIMULATOR="sihsim",
                   PX4_SIM_MODEL="sihsim_quadx", HEADLESS="1",
                   PX4_SIM_SPEED_FACTOR=str(self.speed_factor))
        env.update({f"PX4_PARAM_{k}": str(v) for k, v in self.params.items()})
        self._log = open(self.workdir / "px4.log", "w")  # noqa: SIM115 - closed in __exit__
        self._proc = subprocess.Popen(
            [str(_link_commands(self.build, self.workdir)), "-i", str(self.instance), "-d",
             "-w", str(self.workdir), str(self.build / "etc")],
            env=env, stdout=self._log, stderr=subprocess.STDOUT, start_new_session=True)
        try:
            self._wait_ready()
        except BaseException:
            self.__exit__(*sys.exc_info())
            raise
        return self

    def _wait_ready(self) -> None:
        """Listen on the offboard port until PX4 says it can arm and has a local position."""
        mav = mavlink2.MAVLink(None)
        mav.robust_parsing = True
        deadline = time.monotonic() + self.boot_timeout_s
        armable = positioned = False
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            sock.bind(("127.0.0.1", self.port))
            sock.settimeout(0.2)
            while not (armable and positioned):
                assert self._proc is not None
                if self._proc.poll() is not None:
                    raise RuntimeError(f"PX4 SITL exited at boot; see {self.log_path}")
                if time.monotonic() > deadline:
                    raise TimeoutError(f"PX4 SITL not ready to arm after {self.boot_timeout_s}"
                                       f" s; see {self.log_path}")
                try:
                    data = sock.recv(65535)
                except TimeoutError:
                    continue
                for msg in mav.parse_buffer(data) or []:
                    if msg.get_type() == "SYS_STATUS":
                        armable = bool(msg.onboard_control_sensors_health
                                       & mavlink2.MAV_SYS_STATUS_PREARM_CHECK)
                    elif msg.get_type() == "LOCAL_POSITION_NED":
                        positioned = True

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if self._proc is not None and self._proc.poll() is None:
            self._proc.terminate()
            try:
                self._proc.wait(10)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait(5)
        self._proc = None
        _IN_USE.discard(self.instance)
        if self._lock_fd is not None:
            os.close(self._lock_fd)
            self._lock_fd = None
        if self._log is not None:
            self._log.close()
            self._log = None
        if self.workdir is None:
            return
        if exc_type is not None or self.keep:
            logs = ", ".join(str(p) for p in self.flight_logs()) or "none"
            print(f"PX4 SITL logs kept in {self.workdir} (console: px4.log; flight logs: "
                  f"{logs})", file=sys.stderr)
        else:
            shutil.rmtree(self.workdir, ignore_errors=True)
