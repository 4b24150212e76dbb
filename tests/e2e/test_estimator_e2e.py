"""The estimator in flight: a sitl vehicle whose estimation error is m = 0.3, b = -0.1 (the
prior says 0.2, -0.1); the service learns the deviation model from what it sees (tracking
error and the reported std), agrees with the same evidence replayed from the vehicle's own
record, is more cautious than the true deviation, slows down in braking zones accordingly,
and restores the estimate after a restart."""

from __future__ import annotations

import asyncio
import json
import tempfile
from pathlib import Path

import numpy as np
import pytest

from companion.service import Service
from companion.uncertainty.estimator import EstimatorSettings, UncertaintyEstimator
from rota import Limits, RetimeInput, retime
from rota.chance import UncertaintyModel
from rota.robust import Safety
from rota.voxelmap import VoxelMap
from sitl.demo import (
    demo_config,
    free_tcp_port,
    map_message,
    plan_async,
    running,
    start_holding,
    take_off,
    to_local,
    trajectory_message,
)
from sitl.estimator_replay import path_deviation
from sitl.mavsdk_util import free_udp_port
from sitl.planner import plan
from sitl.process import SimProcess
from sitl.world import get_world

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(300)]
TRUE_M, TRUE_B = 0.3, -0.1


def replayed(report, prior: UncertaintyModel) -> tuple[UncertaintyEstimator,
                                                        UncertaintyEstimator]:
    """The flight from the vehicle's record at 5 Hz in OFFBOARD: an estimator fed what the
    companion sees (the estimate off the commanded path of the last second, the error
    model's sigma as the reported std) and one fed the true deviation off that path; both
    start from the service's ``prior``."""
    sp = report.setpoints
    t = report.time_s
    keep = (report.mode == "OFFBOARD") & (t >= sp["time_s"][0]) & (t <= sp["time_s"][-1])
    idx = np.flatnonzero(keep)[::10]  # the record is 50 Hz
    speed = np.linalg.norm(report.velocity[idx], axis=1)
    sigma = np.maximum(TRUE_M * speed + TRUE_B, 0.02)
    seen_dev = path_deviation(t[idx], report.estimated_position[idx, :2], sp["time_s"],
                              sp["position"][:, :2])
    true_dev = path_deviation(t[idx], report.true_position[idx, :2], sp["time_s"],
                              sp["position"][:, :2])
    seen = UncertaintyEstimator(prior, EstimatorSettings())
    truth = UncertaintyEstimator(prior, EstimatorSettings())
    for j, i in enumerate(idx):
        seen.observe(float(speed[j]), seen_dev[j], np.full(2, sigma[j]), t=float(t[i]))
        truth.observe(float(speed[j]), true_dev[j], None, t=float(t[i]))
    return seen, truth


def test_estimator_learns_in_flight_slows_braking_zones_and_survives_restart():
    world = get_world("forest", seed=5)
    mav, zport = free_udp_port(), free_tcp_port()
    with tempfile.TemporaryDirectory() as state:
        # This vehicle's estimation error is large by design: sigma = 0.5 m per axis at
        # 2 m/s, so the tracking-error brake at its default 1.5 m (3 sigma) would cut a leg
        # short now and then (once in CI: the service's estimate then differed from the
        # replay's by 25 % at 1 m/s). The brake has its own tests; here it acts at 6 sigma.
        cfg = demo_config(mav, zport, 2.0, state, safety={"max_tracking_error_m": 3.0})

        async def fly(sim):
            home = sim.home_enu
            async with running(cfg) as (_, gs):
                await take_off(gs, world, home)
                await start_holding(gs)
                ends = [np.asarray(world.start), np.asarray(world.goal)]
                first = None
                for k in range(4):  # there and back, twice
                    # like a planner: from the commanded state (the hold)
                    here = np.asarray(gs.telemetry["setpoint"]["position"]) + home
                    traj = await plan_async(world, v_max=2.0, a_max=2.0, start=here,
                                            goal=ends[(k + 1) % 2])
                    first = first or traj
                    gs.publish("trajectory", trajectory_message(to_local(traj, home), f"leg{k}"))
                    await gs.wait_for(lambda s, k=k: s.get("trajectory_id") == f"leg{k}", 20,
                                      f"leg {k}")
                    await gs.wait_for(lambda s: s.get("command") == "hold", 60, "leg end")
                return gs.status["uncertainty"], first

        with SimProcess(port=mav, world="forest", seed=5,
                        estimation={"slope_s": TRUE_M, "offset_m": TRUE_B}) as sim:
            learned, first = asyncio.run(fly(sim))
            home = sim.home_enu

        est = learned["estimate"]
        seen, truth = replayed(sim.report, cfg.uncertainty_model())
        print("learned uncertainty:", learned, "replayed:", seen.describe()["estimate"],
              "truth-fed:", truth.describe()["estimate"])
        assert learned["in_use"] == "estimate" and learned["samples"] > 50
        for v in (1.0, 2.0):
            s_flight = est["m"] * v + est["b"]
            # The service learned what the vehicle's record shows it saw ...
            assert s_flight == pytest.approx(seen.m * v + seen.b, rel=0.15), (v, learned)
            # ... which is more than the true deviation off the path at a steady speed (the
            # vehicle cannot follow the error's fast part: it low-passes it).
            assert s_flight >= truth.m * v + truth.b, (v, learned)
        # The memory: never shorter than the config file's, longer only on the evidence of
        # what the companion saw (log-likelihood gain of at least memory_evidence). One
        # minute of flight on this vehicle does not pin the memory down (its most likely
        # value varies from run to run, docs/estimator.md), so the check is the rule's.
        # The rule is checked on the service's own evidence (its telemetry, sampled when
        # the service got it; the replay of the vehicle's record differs in timing, and on
        # a busy machine its gain was seen at 1.2 where the service's passed 3).
        configured = cfg.uncertainty.memory_s
        assert est["memory_s"] >= configured
        gain = est["memory_gain"]
        print("memory: log-likelihood gain of lengthening it, the service's", gain,
              "the replay's", round(seen.memory_gain, 2), "; most likely (seen, truth):",
              min(seen.fits(), key=lambda f: f.nll).memory_s,
              min(truth.fits(), key=lambda f: f.nll).memory_s)
        if gain < cfg.estimator.memory_evidence:
            assert est["memory_s"] == configured, (gain, est)
        else:
            assert est["memory_s"] > configured, (gain, est)

        # Braking-zone speeds with the learned model are lower than with the prior, on the
        # first leg planned with 0.6 m of margin instead of 1 m (the flown legs keep 1 m
        # from the trees, beyond the braking-zone distance d_th).
        vmap = VoxelMap.from_dict(map_message(world, home) | {"stamp": None})
        traj = to_local(plan(world, 2.0, 2.0, start=first.position(0.0)[0], goal=world.goal,
                              clearance=0.6), home)

        def zone_speed(model):
            safety = Safety(map=vmap, uncertainty=model, chance=cfg.chance_params(),
                            braking=cfg.braking_params())
            r = retime(RetimeInput(trajectory=traj, limits=Limits(2.0, (2.0, 2.0, 1.5)),
                                   dtau=0.05, safety=safety))
            mask = r.diagnostics.braking_mask
            assert r.ok and mask.any()
            return r.speed_limits[mask].mean(), r.duration

        prior_speed, prior_time = zone_speed(cfg.uncertainty_model())
        learned_speed, learned_time = zone_speed(UncertaintyModel(
            m=est["m"], b=est["b"], memory_s=est["memory_s"]))
        assert learned_speed < 0.95 * prior_speed and learned_time > prior_time

        # A restart restores the estimate from the state directory.
        # (the service saves it when it stops: it may have learned a little more since
        # the last status)
        saved = json.loads((Path(state) / "uncertainty-sim.json").read_text())
        from_file = UncertaintyEstimator(cfg.uncertainty_model(), cfg.estimator,
                                         Path(state) / "uncertainty-sim.json")
        restarted = Service(demo_config(free_udp_port(), free_tcp_port(), 2.0, state))
        again = restarted.uncertainty.describe()
        assert again["estimate"] == from_file.describe()["estimate"]
        assert again["estimate"]["m"] == pytest.approx(est["m"], abs=0.01)
        assert again["samples"] == saved["samples"] >= learned["samples"]
