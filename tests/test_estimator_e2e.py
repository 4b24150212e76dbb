"""The estimator in flight (issue #7): a sitl vehicle whose estimation error is
m = 0.3, b = -0.1 (the prior says 0.2, -0.1); the service learns it, slows down
in braking zones accordingly, and restores the estimate after a restart."""

from __future__ import annotations

import asyncio
import tempfile

import numpy as np
import pytest

from companion.demo import (
    demo_config,
    free_tcp_port,
    map_message,
    running,
    take_off,
    to_local,
    trajectory_message,
)
from companion.service import Service
from rota import Limits, RetimeInput, retime
from rota.robust import Safety
from rota.voxelmap import VoxelMap
from sitl.mavsdk_util import free_udp_port
from sitl.planner import plan
from sitl.process import SimProcess
from sitl.world import get_world

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(300)]
TRUE_M, TRUE_B = 0.3, -0.1


def test_estimator_learns_in_flight_slows_braking_zones_and_survives_restart():
    world = get_world("forest", seed=5)
    mav, zport = free_udp_port(), free_tcp_port()
    with tempfile.TemporaryDirectory() as state:
        cfg = demo_config(mav, zport, 2.0, state)

        async def fly(sim):
            home = sim.home_enu
            async with running(cfg) as (_, gs):
                await take_off(gs, world, home)
                ends = [np.asarray(world.start), np.asarray(world.goal)]
                first = None
                for k in range(4):  # there and back, twice
                    here = np.asarray(gs.telemetry["position"]) + home
                    traj = plan(world, v_max=2.0, a_max=2.0, start=here, goal=ends[(k + 1) % 2])
                    first = first or traj
                    gs.publish("trajectory", trajectory_message(to_local(traj, home), f"leg{k}"))
                    if k == 0:
                        assert (await gs.command("start"))["ok"]
                    await gs.wait_for(lambda s, k=k: s.get("trajectory_id") == f"leg{k}", 20,
                                      f"leg {k}")
                    await gs.wait_for(lambda s: s.get("command") == "hold", 60, "leg end")
                return gs.status["uncertainty"], first

        with SimProcess(port=mav, world="forest", seed=5,
                        estimation={"slope_s": TRUE_M, "offset_m": TRUE_B}) as sim:
            learned, first = asyncio.run(fly(sim))
            home = sim.home_enu

        est = learned["estimate"]
        print("learned uncertainty:", learned)
        assert est["m"] == pytest.approx(TRUE_M, rel=0.15), learned
        assert abs(est["b"] - TRUE_B) <= 0.15 * abs(TRUE_B) + 0.02, learned
        assert learned["in_use"] == "estimate" and learned["samples"] > 50

        # Braking-zone speeds with the learned model are lower than with the prior.
        vmap = VoxelMap.from_dict(map_message(world, home) | {"stamp": None})
        traj = to_local(first, home)

        def zone_speed(model):
            safety = Safety(map=vmap, uncertainty=model, chance=cfg.chance_params(),
                            braking=cfg.braking_params())
            r = retime(RetimeInput(trajectory=traj, limits=Limits(2.0, (2.0, 2.0, 1.5)),
                                   dtau=0.05, safety=safety))
            mask = r.extras["braking_mask"]
            assert r.ok and mask.any()
            return r.speed_limits[mask].mean(), r.duration

        prior_speed, prior_time = zone_speed(cfg.uncertainty_model())
        from rota.chance import UncertaintyModel

        learned_speed, learned_time = zone_speed(UncertaintyModel(m=est["m"], b=est["b"]))
        assert learned_speed < 0.95 * prior_speed and learned_time > prior_time

        # A restart restores the estimate from the state directory.
        restarted = Service(demo_config(free_udp_port(), free_tcp_port(), 2.0, state))
        again = restarted.uncertainty.describe()
        assert again["estimate"]["m"] == pytest.approx(est["m"], abs=1e-3)
        assert again["samples"] == learned["samples"]
