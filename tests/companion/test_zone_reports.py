"""A model that makes every point of a path a braking point, or none ever, is flown but
said on status, once per model, with where the model came from; a rejection names the
model's origin (issue 27). Real re-times (no mocked solver) on a pillar beside a path."""

from __future__ import annotations

import numpy as np

from companion.flight.replanner import Replanner
from companion.flight.retimer import ReplanJob, Retimer
from companion.status import Reporter
from companion.uncertainty.source import ConfiguredUncertainty, origin
from rota import Limits, RetimeInput, SampledTrajectory, retime
from rota.braking import BrakingParams
from rota.chance import ChanceParams, UncertaintyModel
from rota.robust import Safety
from rota.voxelmap import VoxelMap

RES = 0.1


def _case(model: UncertaintyModel, chance: ChanceParams, pillar_x: float = 3.0):
    """A 6 m straight path 0.8 m beside a pillar; the re-time, its job and a replanner."""
    x = np.linspace(0.0, 6.0, 13)
    traj = SampledTrajectory(t=x / 2.0, p=np.column_stack([x, np.zeros_like(x), np.ones_like(x)]))
    z = np.arange(0.0, 2.0, RES)
    pillar = np.column_stack([np.full_like(z, pillar_x), np.full_like(z, 0.8), z])
    vmap = VoxelMap.from_points(pillar, RES)
    limits = Limits(v_max=2.0, a_max=2.0)
    result = retime(RetimeInput(trajectory=traj, limits=limits, safety=Safety(
        map=vmap, uncertainty=model, chance=chance, braking=BrakingParams())))
    job = ReplanJob(id="p", stamp=0.0, trajectory=traj, limits=limits, smoothness=0.0,
                    dtau=0.05, uncertainty=model, chance=chance, braking=BrakingParams())
    report = Reporter()
    retimer = Retimer()  # (its worker is never started here: only the map is read)
    retimer._map = vmap
    rp = Replanner(lambda: None, retimer, None, lambda: ConfiguredUncertainty(model), report,
                   lambda *a: None)
    return rp, result, job, report


def test_a_model_that_makes_every_point_a_braking_point_is_said_once():
    model = UncertaintyModel(m=0.3, b=1.5, floor=0.1)  # 1.5 m of error at rest
    chance = ChanceParams(delta=1e-3, semi_axes=(0.2,) * 3, v_floor=0.3, v_max=2.0)
    # (the pillar at the end: it is ahead of every point, and within the 6.7 m reach)
    rp, result, job, report = _case(model, chance, pillar_x=6.3)
    assert np.all(result.diagnostics.braking_mask)
    rp._report_zones("p", result, job)
    rp._report_zones("p", result, job)  # the same model again: not repeated
    said = [w for w in report.warnings if "every point" in w]
    assert len(said) == 1, report.warnings
    assert "m=0.3 s, b=1.5 m" in said[0] and "configured ([uncertainty])" in said[0]


def test_a_model_that_can_never_brake_before_an_obstacle_is_said():
    model = UncertaintyModel(m=0.0, b=0.0, floor=0.0)
    chance = ChanceParams(delta=1e-3, semi_axes=(0.2,) * 3, obstacle_std=(0.0,) * 3,
                          v_floor=0.3, v_max=2.0)
    rp, result, job, report = _case(model, chance)
    assert not np.any(result.diagnostics.braking_mask)
    rp._report_zones("p", result, job)
    assert any("no braking zone can come before" in w for w in report.warnings), report.warnings


def test_a_sensible_model_is_not_reported():
    model = UncertaintyModel(m=0.1, b=0.1, floor=0.05)
    chance = ChanceParams(delta=1e-3, semi_axes=(0.2,) * 3, v_floor=0.3, v_max=2.0)
    rp, result, job, report = _case(model, chance)
    mask = result.diagnostics.braking_mask
    assert mask.any() and not mask.all()  # zones near the pillar only
    rp._report_zones("p", result, job)
    assert report.warnings == [] or not any("braking" in w for w in report.warnings)


def test_the_origin_of_the_model_in_words():
    assert origin({"source": "config"}) == "configured ([uncertainty])"
    assert "not yet trusted" in origin({"source": "estimator", "in_use": "prior"})
    said = origin({"source": "estimator", "in_use": "estimate", "evidence_s": 42.0,
                   "samples": 900})
    assert said.startswith("learned in flight") and "42 s" in said and "900 samples" in said
