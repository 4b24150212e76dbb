"""Statistics of the collision experiment (:mod:`sitl.experiment`): Wilson intervals, exact
McNemar tests on paired flights, and the per-cell summary.

Outcome: a **crash** is a tree collision or a ground strike (the first ends the flight, so the
two are exclusive); rates, intervals and tests are on crashes, tree collisions and ground
strikes are also reported apart. Pairing: every arm of a trial flies the same path in the same
world with the same noise draws, so arms are compared trial by trial with the exact McNemar
test (two-sided): only discordant trials count, ``b`` (only the first arm crashed) against
``c`` (only the second), ``p = P(|X - (b+c)/2| >= |b - (b+c)/2|)`` for ``X ~ Bin(b + c, 1/2)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from scipy import stats

if TYPE_CHECKING:
    from sitl.experiment import ExperimentConfig

#: The claim: ROTA with memory crashes significantly less than its equal-time uniform
#: slow-down (two-sided exact McNemar p below this) wherever the planner's timing crashes
#: more often than CLAIM_RATE.
CLAIM_P = 0.01
CLAIM_RATE = 0.05


def wilson(k: int, n: int, z: float = 1.959963984540054) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion ``k / n`` (default 95 %)."""
    if n == 0:
        return (0.0, 1.0)
    p = k / n
    den = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    lo = 0.0 if k == 0 else max(0.0, centre - half)  # exact ends (no rounding residue)
    hi = 1.0 if k == n else min(1.0, centre + half)
    return (lo, hi)


def mcnemar(first: NDArray[np.bool_], second: NDArray[np.bool_]) -> tuple[int, int, float]:
    """Exact two-sided McNemar test on paired outcomes: ``(b, c, p)``; ``b`` = only
    ``first`` crashed, ``c`` = only ``second``. p = 1 without discordant pairs."""
    b = int(np.sum(first & ~second))
    c = int(np.sum(~first & second))
    if b + c == 0:
        return b, c, 1.0
    return b, c, float(stats.binomtest(b, b + c, 0.5, alternative="two-sided").pvalue)


@dataclass(frozen=True)
class PairTest:
    """A paired comparison of two arms in one cell."""

    first: str
    second: str
    only_first: int
    only_second: int
    p: float


@dataclass(frozen=True)
class CellResult:
    """Statistics of one (error model, density, speed) cell over the trials in the comparison
    (planned, and accepted by ROTA at every memory time unless ``rejected == "fallback"``).

    Attributes:
        crashes / collisions / ground: per arm, flights with a crash / a tree collision / a
            ground strike (crashes = collisions + ground).
        rate, ci95: crash rate and its 95 % Wilson interval per arm.
        mean_duration: mean commanded trajectory duration per arm (s).
        closest_median: median closest approach (true distance to a trunk surface minus the
            robot radius, m; negative = collision) per arm.
        pairs: exact two-sided McNemar tests between the relevant pairs of arms.
        claim: ``"holds"``, ``"fails"`` or ``"n/a"`` (the planner's timing crashes at most
            5 % here, or the run has no memory arm with its uniform control).
    """

    kind: str
    density: float
    v_max: float
    a_max: float
    n: int
    arms: tuple[str, ...]
    crashes: dict[str, int]
    collisions: dict[str, int]
    ground: dict[str, int]
    rate: dict[str, float]
    ci95: dict[str, tuple[float, float]]
    mean_duration: dict[str, float]
    closest_median: dict[str, float]
    pairs: tuple[PairTest, ...]
    retime_status: dict[str, int]
    rejected_planned_crashes: int
    plan_failures: int
    claim: str

    def pair(self, first: str, second: str) -> PairTest:
        return next(p for p in self.pairs if (p.first, p.second) == (first, second))


def rota_arm(memory_s: float) -> str:
    """The name of the ROTA arm with this memory time."""
    return f"rota:{memory_s:g}"


def uniform_arm(memory_s: float) -> str:
    """The name of its equal-time uniform slow-down."""
    return f"uniform:{memory_s:g}"


def relevant_pairs(config: ExperimentConfig) -> list[tuple[str, str]]:
    """Planner vs each ROTA arm, each ROTA arm vs its equal-time uniform slow-down, the
    paper's ROTA vs each memory arm."""
    mem = config.memories
    pairs = [("planned", rota_arm(t)) for t in mem]
    if config.uniform:
        pairs += [(uniform_arm(t), rota_arm(t)) for t in mem]
    if 0.0 in mem:
        pairs += [(rota_arm(0.0), rota_arm(t)) for t in mem if t > 0.0]
    return pairs


def claim_memory(config: ExperimentConfig) -> float | None:
    """The memory time the claim is about: the largest one above 0 (None: no memory arm)."""
    positive = [t for t in config.memories if t > 0.0]
    return max(positive) if positive and config.uniform else None


def cell_stats(config: ExperimentConfig, kind: str, density_index: int, speed_index: int,
               data: dict) -> CellResult:
    """Statistics of one cell from the merged per-trial data (see :mod:`sitl.experiment`)."""
    planned_ok = np.array(data["planned"], dtype=bool)
    status = {k: np.array(v) for k, v in data["status"].items()}
    rejected = planned_ok & np.any([s == "rejected" for s in status.values()], axis=0)
    keep = planned_ok & ~rejected if config.rejected == "exclude" else planned_ok
    n = int(keep.sum())
    arms = config.arms
    flights = data["flights"][kind]
    col = {a: np.array(flights[a]["collided"], dtype=bool)[keep] for a in arms}
    gnd = {a: np.array(flights[a]["ground"], dtype=bool)[keep] for a in arms}
    crash = {a: col[a] | gnd[a] for a in arms}
    k = {a: int(crash[a].sum()) for a in arms}
    dur = {a: np.array(data["duration"][a], dtype=float)[keep] for a in arms}
    closest = {a: np.array(flights[a]["closest"], dtype=float)[keep] for a in arms}
    pairs = tuple(PairTest(a, b, *mcnemar(crash[a], crash[b]))
                  for a, b in relevant_pairs(config))
    rate = {a: k[a] / n if n else math.nan for a in arms}
    t_claim = claim_memory(config)
    claim = "n/a"
    if t_claim is not None and n and rate["planned"] > CLAIM_RATE:
        test = next(p for p in pairs if (p.first, p.second) == (uniform_arm(t_claim),
                                                                rota_arm(t_claim)))
        claim = "holds" if test.only_first > test.only_second and test.p < CLAIM_P else "fails"
    first_status = [s for s, ok in zip(data["status"][f"{config.memories[0]:g}"], planned_ok,
                                       strict=True) if ok]
    planned_crash = (np.array(flights["planned"]["collided"], dtype=bool)
                     | np.array(flights["planned"]["ground"], dtype=bool))
    v = config.speeds[speed_index]
    with np.errstate(all="ignore"):
        return CellResult(
            kind=kind, density=config.densities[density_index], v_max=v, a_max=config.a_max(v),
            n=n, arms=arms, crashes=k,
            collisions={a: int(col[a].sum()) for a in arms},
            ground={a: int(gnd[a].sum()) for a in arms},
            rate=rate, ci95={a: wilson(k[a], n) for a in arms},
            mean_duration={a: float(np.mean(dur[a])) if n else math.nan for a in arms},
            closest_median={a: float(np.nanmedian(closest[a])) if n else math.nan
                            for a in arms},
            pairs=pairs,
            retime_status={s: first_status.count(s) for s in sorted(set(first_status))},
            rejected_planned_crashes=int(np.sum(planned_crash[rejected])),
            plan_failures=int((~planned_ok).sum()), claim=claim)
