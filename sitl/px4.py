"""Real PX4 SITL (the SIH quadrotor, headless) for the same end-to-end tests,
when a PX4 build is available. This project contains no PX4 code and no recipe
to build it: point ``ROTA_PX4_BUILD`` at an existing ``build/px4_sitl_default``
directory (made with PX4's own ``make px4_sitl``).

PX4's SITL offboard link sends to UDP 14540 on localhost, so MAVSDK connects with
``udpin://127.0.0.1:14540``; only one PX4 instance can run at a time this way.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

PX4_ENV = "ROTA_PX4_BUILD"
PX4_PORT = 14540


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


class Px4Sitl:
    """``with Px4Sitl(build) as px4:`` runs PX4 SITL with the SIH quadrotor (airframe
    10040), parameters set at boot through ``PX4_PARAM_<NAME>``."""

    def __init__(self, build: Path, params: dict[str, float] | None = None,
                 speed_factor: float = 1.0, boot_s: float = 8.0) -> None:
        self.build = build
        self.params = {"COM_OF_LOSS_T": 1.0, **(params or {})}
        self.speed_factor = speed_factor
        self.boot_s = boot_s
        self.port = PX4_PORT
        self.home_enu = np.zeros(3)
        self._dir: str | None = None
        self._proc: subprocess.Popen | None = None

    def __enter__(self) -> Px4Sitl:
        self._dir = tempfile.mkdtemp(prefix="rota-px4-")
        env = dict(os.environ, PX4_SYS_AUTOSTART="10040", PX4_SIMULATOR="sihsim",
                   PX4_SIM_MODEL="sihsim_quadx", HEADLESS="1",
                   PX4_SIM_SPEED_FACTOR=str(self.speed_factor))
        env.update({f"PX4_PARAM_{k}": str(v) for k, v in self.params.items()})
        log = open(Path(self._dir) / "px4.log", "w")  # noqa: SIM115 - closed in __exit__
        self._log = log
        self._proc = subprocess.Popen(
            [str(self.build / "bin" / "px4"), "-d", "-w", self._dir, str(self.build / "etc")],
            env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        time.sleep(self.boot_s)
        if self._proc.poll() is not None:
            raise RuntimeError(f"PX4 SITL exited at boot; see {Path(self._dir) / 'px4.log'}")
        return self

    def __exit__(self, *exc: object) -> None:
        if self._proc is not None and self._proc.poll() is None:
            self._proc.terminate()
            try:
                self._proc.wait(10)
            except subprocess.TimeoutExpired:
                self._proc.kill()
        self._log.close()
        if self._dir is not None:
            shutil.rmtree(self._dir, ignore_errors=True)
