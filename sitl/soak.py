"""``rota-sitl soak --minutes N``: the service flies the proving circle for
N minutes while a planner replans at 10 Hz (every replan re-timed and flown),
and reports what a long flight does to it: memory (the service process after a
warm-up minute, then at the end), errors, replans flown, and the setpoint
stream as the vehicle received it; and the footprint of the service's whole
process tree (:mod:`sitl.footprint`): CPU and memory while replanning after the
warm-up, and while holding with no replans afterwards.
"""

from __future__ import annotations

import asyncio
import time
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from sitl.floor import measure_floor
from sitl.footprint import Meter, Usage
from sitl.proving import Flight, statuses_errors

REPLAN_HZ = 10.0
WARM_UP_S = 60.0
#: How long the footprint is measured while holding, after the replans, s.
HOLD_S = 30.0


@dataclass
class SoakFigures:
    minutes: float
    replans_sent: int = 0
    replans_flown: int = 0
    errors: list[str] = field(default_factory=list)
    rss_mb: list[tuple[float, float]] = field(default_factory=list)  # (s since start, MB)
    stream: dict[str, Any] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)
    collisions: int = 0
    replanning: Usage | None = None  #: the service's tree while replanning (after warm-up)
    holding: Usage | None = None  #: the same, holding with no replans
    floor: Usage | None = None  #: the floor (sitl.floor): 50 Hz setpoints and nothing else
    reaction_ms: dict[str, Any] | None = None  #: the service's reaction times (status)

    @property
    def rss_growth(self) -> float:
        """RSS growth from the end of the warm-up to the end (fraction)."""
        after = [mb for t, mb in self.rss_mb if t >= WARM_UP_S]
        if len(after) < 2:
            return float("nan")
        return after[-1] / after[0] - 1.0

    def summary(self) -> str:
        return (f"{self.minutes:g} min: {self.replans_sent} replans sent, {self.replans_flown} "
                f"flown; {len(self.errors)} errors; RSS "
                f"{self.rss_mb[0][1] if self.rss_mb else float('nan'):.0f} MB at start, growth "
                f"{100 * self.rss_growth:.1f} % after the {WARM_UP_S:.0f} s warm-up; "
                f"{self.collisions} collisions; stream: {self.stream.get('summary', '')}")


def run_soak(minutes: float, speed: float = 2.0, seed: int = 0) -> SoakFigures:
    figures = SoakFigures(minutes)
    # a long flight: the simulated battery must not be the limit
    flight = Flight(speed=speed, seed=seed, sim_params={"battery_flight_time_s": 1e6})

    async def soak() -> tuple[float, float]:
        gs = flight.gs
        await flight.take_off()
        await flight.circle("soak-0", duration_s=30.0)
        start = time.monotonic()
        end = start + 60.0 * minutes
        flown: set[str] = set()
        next_rss = start
        k = 0
        meter = Meter(flight.service.pid)
        metered = False
        while (now := time.monotonic()) < end:
            if not metered and now - start >= min(WARM_UP_S, 0.3 * (end - start)):
                meter.start()
                metered = True
            k += 1
            flight.replan(f"soak-{k}", duration_s=30.0)
            figures.replans_sent += 1
            flown.add(gs.status.get("trajectory_id") or "")
            if now >= next_rss:
                figures.rss_mb.append((round(now - start, 1), round(flight.service.rss_mb(), 1)))
                next_rss += 30.0
            await asyncio.sleep(max(0.0, start + k / REPLAN_HZ - time.monotonic()))
        figures.rss_mb.append((round(time.monotonic() - start, 1),
                               round(flight.service.rss_mb(), 1)))
        figures.replanning = meter.stop() if metered else None
        figures.reaction_ms = gs.status.get("reaction_ms")
        figures.replans_flown = len(flown - {""})
        figures.errors = statuses_errors(gs.statuses)
        reply = await flight.gs.command("hold")
        if not reply["ok"]:  # (the flight above broke a promise: it is in the errors)
            figures.problems.append(f"could not hold for the footprint: {reply['message']}")
            return start, end
        await asyncio.sleep(2.0)  # (the last re-time and its hand-over settle)
        meter.start()
        await asyncio.sleep(HOLD_S)
        figures.holding = meter.stop()
        return start, end

    with flight:
        window = asyncio.run(soak())
    figures.floor = measure_floor(HOLD_S)  # (after the flight: not beside it)
    report = flight.sim.report
    stream = flight.figures(window, report.setpoints)
    figures.stream = asdict(stream) | {"summary": stream.summary()}
    figures.problems += stream.problems()
    figures.collisions = len(report.collisions)
    if not np.isfinite(figures.rss_growth) or figures.rss_growth > 0.05:
        figures.problems.append(f"RSS grew {100 * figures.rss_growth:.1f} % after warm-up")
    if figures.errors:
        figures.problems.append(f"{len(figures.errors)} errors")
    return figures
