"""The replanner (companion/flight/replanner.py) with a real re-time worker and a fake
autopilot behind the stream: stamp order, superseding, joining onto the commanded
state, and what it publishes and offers."""

from __future__ import annotations

import asyncio
import time

import numpy as np
import pytest

from companion import messages as msgs
from companion.flight.autopilot import Telemetry
from companion.flight.replanner import Replanner
from companion.flight.retimer import Retimer
from companion.flight.stream import SetpointStream
from companion.settings.config import from_dict
from companion.status import Reporter
from companion.uncertainty.source import ConfiguredUncertainty
from rota import SampledTrajectory

CFG = from_dict({})


class FakeAutopilot:
    offboard_loss_timeout_s = 1.0

    def __init__(self) -> None:
        self.telemetry = Telemetry(position=np.array([0.0, 0.0, 2.0]),
                                   position_time=time.monotonic())

    def cancel_sends(self) -> None:
        pass


def line(ident: str, stamp: float | None, x0: float = 0.0) -> msgs.Incoming:
    t = np.linspace(0.0, 5.0, 6)
    traj = SampledTrajectory(t=t, p=np.column_stack([x0 + t, 0 * t, 0 * t + 2.0]))
    return msgs.Incoming(ident, traj, "ENU", stamp)


def make(retimer: Retimer | None = None):  # noqa: ANN201
    report = Reporter()
    stream = SetpointStream(lambda: CFG, FakeAutopilot(), report)
    published: list = []
    r = Replanner(lambda: CFG, retimer or Retimer(), stream,
                  lambda: ConfiguredUncertainty(CFG.uncertainty_model()), report,
                  lambda payload, ros2, view: published.append(payload))
    return r, stream, report, published


def test_a_trajectory_stamped_no_later_than_the_newest_is_refused_in_words():
    r, *_ = make()
    r.offer(line("a", 100.0))
    for stamp in (100.0, 99.0):
        with pytest.raises(msgs.Rejected, match="out of order or repeated"):
            r.offer(line("b", stamp))
    assert r.latest.id == "a"
    r.offer(line("c", None))  # unstamped: no order to keep (the config may refuse them)
    r.drop()
    assert r.latest is None


def test_flying_it_is_joined_onto_the_command_re_timed_published_and_offered():
    async def main():
        retimer = Retimer()
        await retimer.start()
        try:
            r, stream, report, published = make(retimer)
            stream.begin(np.array([0.0, 0.0, 2.0]), 0.0, "test")  # holding at the start
            r.flying = lambda: True
            task = asyncio.create_task(r.run())
            r.offer(line("first", time.time(), x0=0.3))  # 0.3 m off the command
            end = time.monotonic() + 60
            while stream.next_plan is None and time.monotonic() < end:
                await asyncio.sleep(0.05)
            task.cancel()
            plan = stream.next_plan
            assert plan is not None and plan.id == "first", report.events
            assert len(published) == 1 and b'"first"' in published[0]
            assert r.last_result_summary["id"] == "first"
            assert r.last_result_summary["status"] == "optimal"
            # joined where the hold is at the takeover: no gap to stitch
            gap = plan.command(plan.t0).position - stream.commanded(plan.t0).position
            assert float(np.linalg.norm(gap)) < 1e-6
        finally:
            retimer.close()

    asyncio.run(main())
