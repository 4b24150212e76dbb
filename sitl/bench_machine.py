"""The machine a benchmark runs on (:mod:`sitl.bench`): what it is, how fast it is
this run (a fixed calibration workload), what its host took, and the start-up costs
of ``import rota`` and :func:`rota.warm_up`."""

from __future__ import annotations

import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from importlib import metadata
from pathlib import Path

import numpy as np


def machine() -> dict[str, str]:
    model = ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import os

    versions = {}
    for pkg in ("numba", "clarabel", "numpy", "scipy", "toppra", "copp-py", "cvxpy"):
        try:
            versions[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            versions[pkg] = "-"
    u = platform.uname()
    return {"cpu": model, "cores": str(os.cpu_count()), "system": f"{u.system} {u.release}",
            "python": platform.python_version(),
            "packages": ", ".join(f"{k} {v}" for k, v in versions.items())}


def calibration_s() -> float:
    """Median seconds of a fixed piece of CPU work (Python loop, small numpy calls,
    a 200 x 200 solve): how fast the machine was in this run. This shared machine's
    speed varies by up to 2x between runs; the ratios against the paper move with
    it, those against the peers of the same run do not."""
    rng = np.random.default_rng(0)
    a = rng.normal(size=(200, 200)) + 200 * np.eye(200)
    b = rng.normal(size=200)
    times = []
    for _ in range(7):
        t0 = time.perf_counter()
        acc = 0.0
        for i in range(100_000):
            acc += i * 0.5
        for _ in range(1000):
            np.minimum(b, acc)
        np.linalg.solve(a, b)
        times.append(time.perf_counter() - t0)
    return float(statistics.median(times))


def host_steal_s() -> float:
    """Seconds the hypervisor has taken from this machine's CPUs (``steal`` of
    ``/proc/stat``, summed over CPUs; 0 where there is none)."""
    try:
        fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()
        return int(fields[8]) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return 0.0


def startup_costs() -> dict[str, float]:
    """Seconds for ``import rota``, and for :func:`rota.warm_up` with a cold (empty)
    and a warm numba cache, each in a fresh Python process."""
    code = ("import time, sys; t0 = time.perf_counter(); import rota; t1 = time.perf_counter(); "
            "s = rota.warm_up(sys.argv[1]); print(t1 - t0, s)")
    out: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as cache:
        for label in ("cold", "warm"):
            env = dict(os.environ)
            r = subprocess.run([sys.executable, "-c", code, cache], capture_output=True,
                               text=True, env=env, check=True)
            imp, warm = (float(x) for x in r.stdout.split())
            out["import_rota_s"] = min(out.get("import_rota_s", imp), imp)
            out[f"warm_up_{label}_s"] = warm
    return out
