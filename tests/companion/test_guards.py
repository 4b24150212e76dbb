"""The pieces that keep the setpoint stream safe, one at a time: input caps and
rate limits, the setpoint check (jumps, the fence, NaN), stalls, and supervised
worker processes."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import threading
import time

import numpy as np
import pytest

from companion import messages as msgs
from companion.flight.autopilot import Telemetry
from companion.flight.plan import Command, Hold, Plan
from companion.flight.stream import LOSS_SHARE, SetpointStream
from companion.network.decoder import Decoder
from companion.network.inputs import RateLimit
from companion.settings.config import from_dict
from companion.status import Reporter
from companion.worker import Worker, WorkerDied, describe_exit, worker_nice
from rota import Limits, RetimeInput, retime
from rota.trajectory import SampledTrajectory

CFG = from_dict({"limits": {"v_max": 2.0}, "safety": {"geofence_min": [-10.0, -10.0, 0.0],
                                                       "geofence_max": [10.0, 10.0, 5.0]}})


# ------------------------------------------------------------------ inputs
def test_rate_limit_allows_a_burst_then_refuses():
    lim = RateLimit(rate=100.0, burst=5)
    assert [lim.allow() for _ in range(6)] == [True] * 5 + [False]
    time.sleep(0.05)  # 100 per second: five more tokens
    assert lim.allow()


def test_json_depth_and_size_are_capped_before_parsing():
    with pytest.raises(msgs.Rejected, match="nested deeper than 16"):
        msgs.decode(b"[" * 5000 + b"]" * 5000, "x")
    with pytest.raises(msgs.Rejected, match="over the cap of 100"):
        msgs.decode(json.dumps(list(range(500))).encode(), "x", max_items=100)
    # brackets and commas inside strings are text, not structure
    assert msgs.decode(json.dumps({"id": "[[[[,,,," * 100}).encode(), "x", max_depth=2,
                       max_items=10)["id"].startswith("[[[[")


def _trajectory(**extra) -> bytes:
    d = {"schema": "rota/trajectory", "version": 1, "id": "t", "stamp": time.time(),
         "type": "samples", "t": [0.0, 1.0, 2.0], "p": [[0, 0, 1], [1, 0, 1], [2, 0, 1]]}
    return json.dumps(d | extra).encode()


@pytest.mark.parametrize(("extra", "words"), [
    ({"type": "polynomial", "durations": [1.0], "coefficients": [[[0.0] * 50] * 3]},
     "degree 49 is over the cap of 15"),
    ({"t": list(range(200_001))}, "t: 200001 entries is over the cap"),
    ({"id": "x" * 500}, "id: 500 characters"),
    ({"stamp": None}, "no stamp"),
])
def test_trajectory_counts_are_capped(extra, words):
    with pytest.raises(msgs.Rejected, match=words):
        msgs.parse_trajectory(_trajectory(**extra), CFG)


def test_map_voxels_are_capped_before_the_map_is_built():
    cfg = from_dict({"inputs": {"max_map_voxels": 10}})
    body = {"schema": "rota/map", "version": 1, "frame": "ENU", "resolution": 0.1,
            "origin": [0, 0, 0], "occupied": [[0.05, 0.05, 0.05 + 0.1 * i] for i in range(11)]}
    with pytest.raises(msgs.Rejected, match="11 voxels is over the cap of 10"):
        msgs.parse_map(json.dumps(body).encode(), cfg)


def test_any_decoder_failure_comes_back_as_rejected_in_words():
    async def main():
        decoder = Decoder(lambda: CFG)
        try:
            # as the service does before READY: the workers (niced) spawn and import
            # here, not inside the first decode's 5 s budget
            await decoder.start()
            with pytest.raises(msgs.Rejected, match="nested"):
                await decoder.decode("trajectory", b'{"a":' * 20000 + b"1" + b"}" * 20000)
            with pytest.raises(msgs.Rejected, match="not valid JSON"):
                await decoder.decode("query", b"\xff\xfe")
            return await decoder.decode("trajectory", _trajectory())
        finally:
            decoder.close()

    incoming = asyncio.run(main())
    assert incoming.id == "t" and incoming.frame == "ENU"


# ------------------------------------------------------------------ the stream
class _Autopilot:
    """What the stream reads of the autopilot: telemetry and its loss timeout."""

    def __init__(self) -> None:
        self.telemetry = Telemetry(position=np.zeros(3), position_time=time.monotonic())
        self.offboard_loss_timeout_s = 1.0

    def cancel_sends(self) -> None:
        pass

    def sent(self) -> list:
        return []


def _stream(last: np.ndarray, velocity=(0.0, 0.0, 0.0)) -> SetpointStream:
    s = SetpointStream(lambda: CFG, _Autopilot(), Reporter())
    s.streaming = True
    s.last_sent = Command(np.asarray(last, float), np.asarray(velocity, float))
    s.last_send_time = 100.0
    return s


def test_a_setpoint_may_move_no_farther_than_the_speed_limit_allows():
    s = _stream([0.0, 0.0, 1.0])
    allowed = s.max_speed() * 0.02
    assert s.check(Command(np.array([allowed, 0, 1.0])), 100.02) == ""
    assert "jump" in s.check(Command(np.array([allowed + 0.02, 0, 1.0])), 100.02)


def test_nan_and_a_step_out_of_the_fence_are_refused_but_the_fence_never_traps():
    s = _stream([9.99, 0.0, 1.0])
    assert "non-finite" in s.check(Command(np.array([np.nan, 0, 1.0])), 100.02)
    assert "geofence" in s.check(Command(np.array([10.02, 0, 1.0])), 100.02)
    outside = _stream([11.0, 0.0, 1.0])  # already outside: moving back in is fine
    assert outside.check(Command(np.array([10.98, 0, 1.0])), 100.02) == ""
    assert "geofence" in outside.check(Command(np.array([11.02, 0, 1.0])), 100.02)


def _line_plan(t0: float) -> Plan:
    """A re-timed 10 m line along x at 1 m height, its time 0 at ``t0``."""
    t = np.linspace(0.0, 10.0, 11)
    traj = SampledTrajectory(t=t, p=np.column_stack([t, 0 * t, 0 * t + 1.0]))
    result = retime(RetimeInput(trajectory=traj, limits=Limits(2.0, 2.0), dtau=0.1))
    return Plan("line", result, t0)


def test_a_stall_brakes_from_the_last_setpoint_sent_along_the_path_and_a_long_one_ends():
    plan = _line_plan(100.0)
    sent = plan.command(102.0)  # the last setpoint before a stall, at 102 s
    s = _stream(sent.position, sent.velocity)
    s.last_send_time = 102.0
    s.source = plan
    halts = []
    s.on_halt = lambda reason, ended: halts.append(ended)
    s._stalled(0.5, 102.5)
    first = s.commanded(102.5)  # not plan.command(102.5): that has run ahead
    assert np.allclose(first.position, sent.position) and s.halted and halts == [False]
    assert np.allclose(first.velocity, sent.velocity, atol=1e-6)
    stop = s.commanded(110.0).position  # it stops on the path it was flying
    assert abs(stop[1]) < 1e-9 and abs(stop[2] - 1.0) < 1e-9 and stop[0] > sent.position[0]
    s._stalled(LOSS_SHARE * 1.0 + 0.01, 111.0)
    assert not s.streaming and halts == [False, True]


def test_a_stall_the_send_times_prove_px4_has_not_timed_out_on_holds_in_offboard():
    """The decision is made on the time since the last setpoint sent, against PX4's
    timeout minus the margin measured on PX4 (1.0 - 0.3 s by default): just under it the
    stream brakes to a hold and goes on sending; past it, the stream ends."""
    limit = 1.0 - CFG.mavlink.offboard_loss_margin_s
    for gap, ends in [(limit - 0.01, False), (limit + 0.001, True)]:
        plan = _line_plan(100.0)
        sent = plan.command(102.0)
        s = _stream(sent.position, sent.velocity)
        s.last_send_time, s.source = 102.0, plan
        halts = []
        s.on_halt = lambda reason, ended, halts=halts: halts.append(ended)
        s._stalled(gap, 102.0 + gap)
        assert s.resume_limit() == limit
        assert s.streaming is not ends and halts == [ends], (gap, s.halted)


def test_no_setpoint_is_sent_later_than_px4_is_sure_to_wait_for_it():
    s = _stream([0.0, 0.0, 1.0])
    s.source = Hold(np.array([0.0, 0.0, 1.0]), "test")
    s.autopilot.telemetry.position_time = 100.5
    t = 100.001 + s.resume_limit()  # nothing went out since 100.0: too late to resume
    s._step(t, t)
    assert not s.streaming and "no setpoint sent for" in s.halted


def test_no_setpoint_goes_out_once_the_vehicle_is_silent():
    s = _stream([0.0, 0.0, 1.0])
    s.autopilot.telemetry.position_time = time.monotonic() - 1.0  # PX4 silent for 1 s
    s._step(time.monotonic(), time.monotonic())
    assert not s.streaming and "no telemetry" in s.halted


# ------------------------------------------------------------------ workers
def test_exit_causes_in_words():
    assert describe_exit(-9) == "killed by SIGKILL" and describe_exit(3) == "exit code 3"
    assert describe_exit(None) == "still running"


def _sleep(seconds: float) -> int:
    time.sleep(seconds)
    return os.getpid()


def test_a_dead_worker_is_seen_idle_and_during_a_call():
    async def main():
        w = Worker("test")
        try:
            pid = await w.call(60.0, _sleep, 0.0)
            os.kill(pid, signal.SIGKILL)
            deadline = time.monotonic() + 5.0
            while w.dead() is None and time.monotonic() < deadline:
                await asyncio.sleep(0.02)
            idle = w.dead()
            w.restart()
            busy = asyncio.ensure_future(w.call(60.0, _sleep, 30.0))
            while not w.pids():  # the call has started its process
                await asyncio.sleep(0.01)
            os.kill(w.pids()[0], signal.SIGKILL)
            with pytest.raises(WorkerDied, match="killed by SIGKILL after"):
                await busy
            again = await w.call(60.0, _sleep, 0.0)
            return idle, pid, again
        finally:
            w.close()

    idle, pid, again = asyncio.run(main())
    assert idle == "killed by SIGKILL" and again != pid


def _nice() -> int:
    return os.getpriority(os.PRIO_PROCESS, 0)


def test_workers_run_below_the_service_but_not_below_ordinary_work():
    assert worker_nice(-5) == 0 and worker_nice(0) == 5 and worker_nice(-20) == 0

    async def main():
        w = Worker("test")
        try:
            return await w.call(60.0, _nice)
        finally:
            w.close()

    assert asyncio.run(main()) == worker_nice(_nice())


def test_the_stream_ticks_in_its_own_thread_above_the_service_and_stops_when_cancelled():
    s = _stream([0.0, 0.0, 1.0])
    s.streaming = False  # ticking, nothing to send
    ticks = []

    async def main():
        task = asyncio.ensure_future(s.run(lambda: ticks.append(threading.get_ident())))
        while len(ticks) < 3:
            await asyncio.wait_for(s.beat.wait(), 5.0)
            s.beat.clear()
        thread = next(t for t in threading.enumerate() if t.name == "setpoint-stream")
        policy = os.sched_getscheduler(thread.native_id)
        nice = os.getpriority(os.PRIO_PROCESS, thread.native_id)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        return thread, policy, nice

    thread, policy, nice = asyncio.run(main())
    here = os.getpriority(os.PRIO_PROCESS, 0)
    # the beat (and the watchdog with it) comes on the event loop, the stream's own thread
    # ends with its task
    assert set(ticks) == {threading.get_ident()} and not thread.is_alive()
    # real-time where allowed, else five nice levels up, else said on status
    assert policy == os.SCHED_FIFO or nice == max(here - 5, -20) or \
        "neither real-time" in s.priority
