"""The same end-to-end flight through the flight service against each vehicle
backend: the `sitl` vehicle (calibrated to PX4's SIH quadrotor) always, real PX4
SITL (SIH) when ``ROTA_PX4_BUILD`` names a PX4 build; otherwise that case is
skipped and says why. Assertions run inside the vehicle's ``with`` block, so a
failure keeps PX4's console and flight logs (see sitl/px4.py)."""

from __future__ import annotations

import asyncio
import contextlib
import tempfile

import numpy as np
import pytest

from sitl.demo import (
    demo_config,
    free_tcp_port,
    hovering,
    running,
    start_holding,
    take_off,
    trajectory_message,
)
from sitl.mavsdk_util import free_udp_port
from sitl.planner import straight_line
from sitl.process import SimProcess
from sitl.px4 import Px4Sitl, px4_build, skip_reason

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(240)]


@contextlib.contextmanager
def vehicle(backend: str):
    if backend == "sim":
        port = free_udp_port()
        with SimProcess(port=port, seed=1):
            yield port
    else:
        build = px4_build()
        if build is None:
            pytest.skip(skip_reason())
        with Px4Sitl(build) as px4:
            yield px4.port


async def mean_position(gs, samples: int = 20, timeout_s: float = 20.0) -> np.ndarray:
    """The mean of the next ``samples`` reported positions: where the vehicle holds,
    without the hover wander of any one report (PX4 wanders 0.2-0.3 m, docs/sitl.md)."""
    seen, last = [], None
    end = asyncio.get_running_loop().time() + timeout_s
    while len(seen) < samples:
        if asyncio.get_running_loop().time() > end:
            raise TimeoutError(f"{len(seen)} of {samples} telemetry messages")
        tel = gs.telemetry
        if tel is not last and tel.get("position") is not None:
            seen.append(tel["position"])
            last = tel
        await asyncio.sleep(0.01)
    return np.mean(seen, axis=0)


async def rest_point(gs, window_s: float = 10.0) -> np.ndarray:
    """Where the vehicle holds: the mean reported position over ``window_s`` once it
    hovers. PX4 (SIH) does not come to rest at a hold: its estimate wanders around the
    setpoint by up to 0.65 m at 0.3-0.5 m/s with a period of about 10 s (measured here,
    setpoint exactly at the goal), so a 1-s mean stopped at a random phase of that
    wander (this test's earlier measure) missed by 0.52-0.88 m in 4 runs; the mean
    over a whole period averages it out."""
    return await mean_position(gs, samples=int(20 * window_s), timeout_s=window_s + 20.0)


#: End miss allowed (m). sitl: 0.5 m, as always. PX4: its rest point measured as above
#: (rest_point, a 10-s mean) in 8 runs on this 2-core machine, other PX4 instances and
#: tests running beside it (load average 2-5): 0.295, 0.305, 0.325, 0.327, 0.331, 0.333,
#: 0.340, 0.599 m (mean 0.36, sd 0.10; mean + 3 sd 0.65 m). The limit stays 0.8 m. (With a
#: 1-s mean stopped at a random phase of the hover wander: 0.16-0.88 m, and CI saw 0.853.)
#: A frame error or a dropped trajectory misses by metres.
END_MISS_M = {"sim": 0.5, "px4": 0.8}


def fly_10_m(backend: str) -> float:
    """Take off, fly 10 m east, hold, land: how far from the goal the vehicle held (m)."""
    with vehicle(backend) as port, tempfile.TemporaryDirectory() as state:
        cfg = demo_config(port, free_tcp_port(), 2.0, state,
                          stream={"takeoff_altitude_m": 2.0})

        async def main():
            async with running(cfg) as (_, gs):
                await take_off(gs)
                p0 = await start_holding(gs)
                traj = straight_line(p0, p0 + [10.0, 0.0, 0.0], v_max=2.0, a_max=1.5)
                gs.publish("trajectory", trajectory_message(traj, "ten"))
                await gs.wait_for(lambda s: s.get("trajectory_id") == "ten", 10, "the plan")
                await gs.wait_for(lambda s: s.get("command") == "hold", 40, "the end")
                await hovering(gs)  # the overshoot past the end is over
                p1 = await rest_point(gs)
                assert (await gs.command("land"))["ok"]
                await gs.wait_for(lambda s: s["state"] == "ready" and not s["armed"], 60,
                                  "landed and disarmed")
                return p0, p1

        p0, p1 = asyncio.run(main())
        miss = float(np.linalg.norm(p1 - (p0 + [10.0, 0.0, 0.0])))
        print(f"{backend}: end miss {miss:.3f} m")
        return miss


@pytest.mark.parametrize("backend", ["sim", "px4"])
def test_service_flies_10_m_and_lands(backend):
    assert fly_10_m(backend) < END_MISS_M[backend]


def test_a_frame_error_fails_this_test(monkeypatch):
    """The tolerance catches a real defect: setpoints sent without ENU -> NED's x/y swap
    (z still flipped, so the take-off works) fly the 10 m north, not east; the service's
    tracking-error check brakes it and the vehicle holds metres from the goal."""
    import companion.flight.autopilot

    monkeypatch.setattr(companion.flight.autopilot, "enu_to_ned",
                        lambda v: np.asarray(v, float) * [1.0, 1.0, -1.0])
    try:
        failed = f"missed by {fly_10_m('sim'):.1f} m"
        caught = float(failed.split()[2]) >= END_MISS_M["sim"]
    except (TimeoutError, AssertionError) as exc:  # (no hold, or no landing: caught too)
        failed, caught = f"{type(exc).__name__}: {exc}", True
    print("with the defect:", failed)
    assert caught, failed
