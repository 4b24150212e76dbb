"""Error memory in the flight service: [uncertainty] memory_s reaches the re-time through
the model the replanner hands the worker, and the demo says which braking model flew."""

from __future__ import annotations

import numpy as np
import pytest

from companion.flight import retimer
from companion.flight.retimer import ReplanJob
from companion.settings.config import ConfigError, from_dict
from rota.chance import DEFAULT_MEMORY_S
from sitl.demo import braking_model
from tests.helpers.scenes import line, pillar


def _job(cfg, trajectory) -> ReplanJob:
    return ReplanJob(id="t", stamp=None, trajectory=trajectory, limits=cfg.rota_limits(),
                     smoothness=0.02, dtau=0.05, uncertainty=cfg.uncertainty_model(),
                     chance=cfg.chance_params(), braking=cfg.braking_params())


def test_configured_memory_reaches_the_retime():
    base = {"limits": {"v_max": 3.0, "a_max": [3.0, 3.0, 3.0]},
            "uncertainty": {"semi_axes": [0.15, 0.15, 0.15], "obstacle_std": 0.015,
                            "v_floor": 0.3}}
    assert from_dict(base).uncertainty_model().memory_s == DEFAULT_MEMORY_S
    retimer._set_map(pillar())
    try:
        out = {}
        for t in (0.0, 1.5):
            cfg = from_dict(base | {"uncertainty": base["uncertainty"] | {"memory_s": t}})
            res = retimer._replan(_job(cfg, line(0.0, 10.0))).result
            assert res.ok, res.message
            out[t] = res
        assert out[1.5].diagnostics.memory_s == 1.5 and out[0.0].diagnostics.memory_s == 0.0
        assert out[1.5].diagnostics.approach_mask.any()
        assert not out[0.0].diagnostics.approach_mask.any()
        assert out[1.5].duration > out[0.0].duration
        assert np.all(out[1.5].speed_limits <= out[0.0].speed_limits)
    finally:
        retimer._set_map(None)


def test_bad_memory_is_a_config_error():
    with pytest.raises(ConfigError, match=r"\[uncertainty\] memory_s"):
        from_dict({"uncertainty": {"memory_s": -1.0}})


def test_demo_states_the_braking_model():
    cfg = from_dict({"uncertainty": {"memory_s": 2.0}})
    configured = braking_model({"uncertainty": {"source": "config", "m": 0.2, "b": -0.1}}, cfg)
    assert configured["memory_s"] == 2.0 and configured["name"] == "error memory"
    assert configured["text"] == "ROTA with error memory, T = 2 s (configured)"
    learned = braking_model({"uncertainty": {"in_use": "estimate", "memory_s": 0.0}}, cfg)
    assert learned["name"] == "paper" and "in-flight estimate" in learned["text"]


def test_estimator_set_takes_memory_inside_the_envelope(tmp_path):
    """The estimator query's set may lengthen the memory time, never below the file's."""
    from companion.status import Reporter
    from companion.uncertainty.estimator import UncertaintyEstimator
    from companion.uncertainty.learning import Learning

    cfg = from_dict({"uncertainty": {"memory_s": 1.0}})
    est = UncertaintyEstimator(cfg.uncertainty_model(), cfg.estimator, tmp_path / "u.json")
    learning = Learning(est, None, lambda: False, lambda: [], lambda: 1.0, Reporter())
    ok, message, body = learning.answer({"set": {"m": 0.3, "b": 0.0, "memory_s": 0.5}},
                                        file_cfg=cfg)
    assert not ok and "memory_s=0.5 refused" in message and body["memory_s"] == 1.0
    ok, message, body = learning.answer({"set": {"m": 0.3, "b": 0.0, "memory_s": 2.0}},
                                        file_cfg=cfg)
    assert ok and body["memory_s"] == 2.0 and est.model().memory_s == 2.0
    ok, _, body = learning.answer({"set": {"m": 0.3, "b": 0.0}}, file_cfg=cfg)
    assert ok and body["memory_s"] == 2.0  # memory_s optional: unchanged
    assert not learning.answer({"set": {"m": 0.3, "b": 0.0, "memory_s": "long"}})[0]
    again = UncertaintyEstimator(cfg.uncertainty_model(), cfg.estimator, tmp_path / "u.json")
    assert again.model().memory_s == 2.0  # saved with the estimate
