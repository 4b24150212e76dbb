"""``[estimator]`` of the service's configuration, apart from the estimator itself
(:mod:`companion.uncertainty.estimator`, built on filterpy, which loads scipy.stats): the
configuration, and so every process that reads it (the decode workers among them), needs
only these numbers."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class EstimatorSettings:
    enabled: bool = True  # learn in flight (false: the configured model only)
    min_samples: int = 150  # accepted samples before the estimate may be less cautious
    min_speed: float = 0.5  # m/s; the low speed at which "as cautious" is judged
    m_min: float = 0.0
    m_max: float = 1.0
    b_min: float = -0.5
    b_max: float = 1.0
    prior_std_m: float = 0.15  # prior standard deviation of m (s)
    prior_std_b: float = 0.15  # prior standard deviation of b (m)
    prior_weight_s: float = 10.0  # evidence rule: the configured model weighs this much flight (s)
    sample_weight: float = 0.2  # weight of one 5 Hz sample (about one independent per second)
    forget_s: float = 1200.0  # statistics fade with this time constant (s of flight)
    max_deviation_m: float = 5.0  # a larger deviation is a glitch, not uncertainty
    gate: float = 5.0  # once trusted: deviations beyond gate x the model's std are outliers
    learn_memory: bool = True  # learn T (false: keep [uncertainty] memory_s)
    memory_max_s: float = 3.0  # learned T at most this (s)
    memory_evidence: float = 3.0  # log-likelihood gain needed to replace the configured T
    frozen: bool = False
