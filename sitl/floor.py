"""The floor of the footprint: the least a Python offboard companion on MAVSDK costs.

A process that does only what the setpoint path must: the service's own
:class:`companion.flight.autopilot.Autopilot` connected to a vehicle (the same telemetry at
the same rates), sending one setpoint at the stream's 50 Hz on absolute deadlines, and
nothing else (no Zenoh, no re-timing, no record, no status). ``rota-sitl soak`` measures
it beside the service, on a second simulated vehicle, so the service's figures are
printed as a ratio to a floor measured in the same run on the same machine.
"""

from __future__ import annotations

import subprocess
import sys
import time

from sitl.footprint import Meter, Usage
from sitl.mavsdk_util import free_udp_port
from sitl.process import SimProcess

#: The floor's own program (run as ``python -c``): connect, then 50 Hz of setpoints.
PROGRAM = """
import asyncio, sys, time
import numpy as np
from companion.flight.autopilot import Autopilot

async def main(url, seconds):
    ap = Autopilot(url)
    await ap.connect(60.0)
    print("connected", flush=True)
    p, zero = np.array([0.0, 0.0, 2.0]), np.zeros(3)
    period, deadline = 0.02, time.monotonic()
    end = deadline + seconds
    while deadline < end:
        deadline += period
        await asyncio.sleep(max(0.0, deadline - time.monotonic()))
        ap.send(p, zero, zero, 0.0, time.monotonic())
    await ap.close()

asyncio.run(main(sys.argv[1], float(sys.argv[2])))
"""


def measure_floor(seconds: float = 30.0, settle_s: float = 5.0) -> Usage:
    """The floor process's CPU and memory over ``seconds``, after ``settle_s`` connected."""
    port = free_udp_port()
    with SimProcess(port=port, world="none", seed=0):
        proc = subprocess.Popen([sys.executable, "-c", PROGRAM, f"udpin://127.0.0.1:{port}",
                                 str(seconds + settle_s + 5.0)], stdout=subprocess.PIPE,
                                text=True)
        try:
            line = proc.stdout.readline() if proc.stdout else ""
            if "connected" not in line:
                raise RuntimeError(f"the floor process did not connect ({line!r})")
            time.sleep(settle_s)  # (its start-up is not the floor)
            meter = Meter(proc.pid)
            meter.start()
            time.sleep(seconds)
            return meter.stop()
        finally:
            proc.kill()
            proc.wait(10)

