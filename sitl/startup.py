"""``rota-sitl startup``: how long the flight service takes from its start to systemd's
``READY=1``, with the solver's compiled kernels in the cache (as after ``rota-companion
warm-up`` at install time) and without them (a first start that compiles).

Each start is ``rota-companion run`` in a process of its own, as systemd starts it, with
systemd's notification socket (:class:`sitl.proving.Notes`); the clock runs from the
moment the process is spawned to the moment ``READY=1`` arrives. The service is then
stopped with SIGTERM. No vehicle is needed: the service reports ready once Zenoh is open
and its workers are warm, and connects to PX4 after. The warm cache is made first by
``rota-companion warm-up --cache-dir`` (the command the deployment guide runs), which is
timed too.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from sitl.demo import demo_config, free_tcp_port
from sitl.mavsdk_util import free_udp_port
from sitl.proving import Notes, ServiceProcess

#: A start that takes longer than this failed (a cold compile takes about a minute on
#: a quiet 2-core machine, several on a Raspberry Pi).
START_TIMEOUT_S = 900.0


def time_to_ready(cache_dir: Path, workdir: Path) -> float:
    """Seconds from spawning ``rota-companion run`` to its ``READY=1`` (the kernels'
    cache in ``cache_dir``)."""
    cfg = demo_config(free_udp_port(), free_tcp_port(), 2.0, str(workdir / "state"))
    workdir.mkdir(parents=True, exist_ok=True)
    service = ServiceProcess(cfg, workdir, notify_socket=workdir / "notify")
    before = os.environ.get("ROTA_CACHE_DIR")
    os.environ["ROTA_CACHE_DIR"] = str(cache_dir)
    try:
        with Notes(workdir / "notify") as notes:
            t0 = time.monotonic()
            service.start()
            while "READY=1" not in notes.seen():
                if not service.alive():
                    raise RuntimeError(f"the service exited before READY=1:\n"
                                       f"{service.output()[-2000:]}")
                if time.monotonic() - t0 > START_TIMEOUT_S:
                    raise TimeoutError(f"no READY=1 within {START_TIMEOUT_S:.0f} s")
                time.sleep(0.005)
            seconds = time.monotonic() - t0
            service.stop()
    finally:
        if before is None:
            os.environ.pop("ROTA_CACHE_DIR", None)
        else:
            os.environ["ROTA_CACHE_DIR"] = before
        if service.alive():
            service.stop()
    return seconds


def warm_up_seconds(cache_dir: Path) -> float:
    """``rota-companion warm-up --cache-dir`` as the installer runs it: its wall time."""
    t0 = time.monotonic()
    subprocess.run([sys.executable, "-m", "companion.cli", "warm-up", "--cache-dir",
                    str(cache_dir)], check=True, capture_output=True, text=True,
                   timeout=START_TIMEOUT_S)
    return time.monotonic() - t0


def run_startup(warm_runs: int = 5, cold: bool = True) -> dict[str, Any]:
    """The warm-up's time into an empty cache, ``warm_runs`` starts on that cache and (with
    ``cold``) one start on an empty cache; printed and returned."""
    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="rota-startup-") as tmp:
        cache = Path(tmp) / "cache"
        out["warm_up_s"] = round(warm_up_seconds(cache), 2)
        print(f"rota-companion warm-up into an empty cache: {out['warm_up_s']} s", flush=True)
        warm = [time_to_ready(cache, Path(tmp) / f"warm{k}") for k in range(warm_runs)]
        out["warm_s"] = [round(s, 2) for s in warm]
        print(f"start to READY=1, cache warm ({warm_runs} starts): median "
              f"{statistics.median(warm):.2f} s, max {max(warm):.2f} s "
              f"({', '.join(f'{s:.2f}' for s in warm)})", flush=True)
        if cold:
            out["cold_s"] = round(time_to_ready(Path(tmp) / "empty", Path(tmp) / "cold"), 2)
            print(f"start to READY=1, cache empty (it compiles): {out['cold_s']} s", flush=True)
    return out
