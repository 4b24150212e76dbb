"""The commander (companion/flight/commander.py) against a fake autopilot whose telemetry
answers each command as PX4 does: commands allowed only in their states, replies
only once the telemetry confirms, and the safety checks at 10 Hz (link loss, PX4
leaving offboard, a disarm in the air, the tracking error)."""

from __future__ import annotations

import asyncio
import time

import numpy as np
import pytest

from companion.flight.autopilot import AutopilotError, Telemetry
from companion.flight.commander import Commander, State
from companion.flight.plan import Brake, Plan
from companion.flight.stream import SetpointStream
from companion.settings.config import from_dict
from companion.status import Reporter
from rota import Limits, RetimeInput, SampledTrajectory, retime

CFG = from_dict({"stream": {"prestream_s": 0.5}})


class FakeAutopilot:
    """PX4 as the commander sees it: telemetry, and commands that change it."""

    offboard_loss_timeout_s = 1.0

    def __init__(self) -> None:
        self.telemetry = Telemetry(position=np.array([0.0, 0.0, 2.0]), healthy=True,
                                   landed_state="ON_GROUND", flight_mode="HOLD",
                                   position_time=time.monotonic())
        self.calls: list[str] = []
        self.refuse: set[str] = set()

    def _do(self, name: str) -> None:
        self.calls.append(name)
        if name in self.refuse:
            raise AutopilotError(f"{name} failed: PX4 answered denied")

    def link_ok(self, timeout_s: float) -> bool:
        return time.monotonic() - self.telemetry.position_time <= timeout_s

    async def arm(self) -> None:
        self._do("arm")
        self.telemetry.armed = True

    async def disarm(self) -> None:
        self._do("disarm")
        self.telemetry.armed = False

    async def takeoff(self, altitude_m: float) -> None:
        self._do("takeoff")
        self.telemetry.flight_mode, self.telemetry.landed_state = "TAKEOFF", "TAKING_OFF"

    async def hold(self) -> None:
        self._do("hold")
        self.telemetry.flight_mode = "HOLD"

    async def land(self) -> None:
        self._do("land")
        self.telemetry.flight_mode = "LAND"

    async def start_offboard(self) -> None:
        self._do("offboard")
        self.telemetry.flight_mode = "OFFBOARD"

    def cancel_sends(self) -> None:
        pass

    def sent(self) -> list:
        return []


class FakeReplanner:
    latest = None

    def __init__(self) -> None:
        self.dropped = 0

    def drop(self) -> None:
        self.dropped += 1

    def kick(self) -> None:
        pass

    def silence(self) -> float:
        return 0.0


def make(cfg=CFG) -> tuple[Commander, FakeAutopilot, Reporter]:  # noqa: ANN001
    ap, report = FakeAutopilot(), Reporter()
    stream = SetpointStream(lambda: cfg, ap, report,
                            on_halt=lambda why, ended: commander.halted(why, ended))
    commander = Commander(lambda: cfg, ap, stream, FakeReplanner(), report)
    commander.check()
    return commander, ap, report


def errors(report: Reporter) -> list[str]:
    return [e["message"] for e in report.events if e.get("level") == "error"]


def in_the_air(ap: FakeAutopilot) -> None:
    ap.telemetry.armed, ap.telemetry.landed_state, ap.telemetry.flight_mode = \
        True, "IN_AIR", "HOLD"


def test_each_command_only_in_its_state_and_only_once_px4_shows_it():
    async def main():
        c, ap, _ = make()
        assert c.state == State.READY
        with pytest.raises(AutopilotError, match="not possible in state ready"):
            await c.run("takeoff")
        assert await c.run("arm") == "armed" and c.state == State.ARMED
        assert (await c.run("takeoff")).startswith("taking off to")
        in_the_air(ap)
        c.check()
        assert c.state == State.AIRBORNE
        with pytest.raises(AutopilotError, match="refusing to disarm"):
            await c.run("disarm")
        assert await c.run("start") == "offboard: holding" and c.state == State.OFFBOARD
        assert c.stream.streaming and c.flying()
        assert ap.calls == ["arm", "takeoff", "offboard"]
        with pytest.raises(AutopilotError, match="unknown command 'fly'"):
            await c.run("fly")

    asyncio.run(main())


def test_a_refused_command_says_why_and_changes_nothing():
    async def main():
        c, ap, _ = make()
        ap.refuse.add("arm")
        with pytest.raises(AutopilotError, match="arm failed: PX4 answered denied"):
            await c.run("arm")
        assert c.state == State.READY and not ap.telemetry.armed

    asyncio.run(main())


def test_one_state_changing_command_at_a_time_but_hold_land_abort_never_wait():
    async def main():
        c, ap, _ = make()
        in_the_air(ap)
        c.check()
        start = asyncio.create_task(c.run("start"))  # pre-streams for 0.5 s
        await asyncio.sleep(0.05)
        with pytest.raises(AutopilotError, match="busy: 'start' is in progress"):
            await c.run("arm")
        assert await c.run("abort") == "offboard left: PX4 Hold"  # does not wait
        with pytest.raises(AutopilotError, match="start interrupted"):
            await start
        assert not c.stream.streaming and c.state == State.AIRBORNE

    asyncio.run(main())


async def _flying(cfg=CFG) -> tuple[Commander, FakeAutopilot, Reporter]:  # noqa: ANN001
    c, ap, report = make(cfg)
    in_the_air(ap)
    c.check()
    await c.run("start")
    return c, ap, report


def test_px4_leaving_offboard_or_disarming_stops_the_stream_at_once_with_the_reason():
    async def main():
        for change, words in [(("flight_mode", "POSCTL"), "PX4 left offboard (now POSCTL)"),
                              (("armed", False), "PX4 reports the vehicle disarmed")]:
            c, ap, report = await _flying()
            setattr(ap.telemetry, *change)
            c.check()
            assert not c.stream.streaming and c.state != State.OFFBOARD
            assert any(words in e for e in errors(report)), errors(report)
            assert c.replanner.dropped

    asyncio.run(main())


def test_a_lost_link_stops_the_stream_and_says_a_new_start_is_needed():
    async def main():
        c, ap, report = await _flying()
        ap.telemetry.position_time -= CFG.mavlink.link_timeout_s + 0.1
        c.check()
        assert c.state == State.LINK_LOST and not c.stream.streaming
        assert any("link lost" in e and "'start'" in e for e in errors(report))

    asyncio.run(main())


def _flying_a_line(c: Commander) -> float:
    """Fly a 10 m line along x at 2 m high from now; returns now (taken after the
    re-time, which may take a while on a busy machine)."""
    t = np.linspace(0.0, 10.0, 11)
    line = SampledTrajectory(t=t, p=np.column_stack([t, 0 * t, 0 * t + 2.0]))
    result = retime(RetimeInput(trajectory=line, limits=Limits(2.0, 2.0)))
    now = time.monotonic()
    c.stream.source = Plan("line", result, now)
    return now


def test_a_tracking_error_over_the_limit_brakes_along_the_path():
    async def main():
        c, ap, _ = await _flying()
        now = _flying_a_line(c)
        sent = c.stream.commanded(now)
        c.stream.sent.append(now, sent.position)
        c.stream.last_sent, c.stream.last_send_time = sent, now
        off = CFG.safety.max_tracking_error_m + 0.5
        ap.telemetry.position = sent.position + [0.0, off, 0.0]
        ap.telemetry.position_time = time.monotonic()  # (the re-time above took a while)
        c.check()
        assert float(np.linalg.norm(c.track_errors[-1])) == pytest.approx(off)
        assert isinstance(c.stream.source, Brake) and "tracking error" in c.stream.source.reason

    asyncio.run(main())


def test_the_tracking_error_is_measured_against_the_setpoints_sent_before_the_position():
    """A position is compared with the setpoints sent in the ``tracking_lag_s`` before it
    arrived, not with later ones it could not yet follow: on a busy computer it is read
    a while after it arrived (until ``link_timeout_s`` the link counts as up)."""
    lag = 0.3  # s: a short lag, so that a position older than it is far from link loss
    cfg = from_dict({"stream": {"prestream_s": 0.5}, "safety": {"tracking_lag_s": lag}})

    async def main():
        c, ap, _ = await _flying(cfg)
        now = _flying_a_line(c)
        speed, period = 10.0, 0.02  # what was sent: x at 10 m/s for the last 4 s
        for k in range(201):
            c.stream.sent.append(now - 4.0 + k * period, [speed * k * period, 0.0, 2.0])
        c.stream.last_sent, c.stream.last_send_time = c.stream.commanded(now), now
        age = 0.5  # s: over the lag, 1 s under the link timeout (on a setpoint's send time)
        assert lag < age and age + 0.9 < cfg.mavlink.link_timeout_s
        assert (age - lag) * speed > cfg.safety.max_tracking_error_m
        # on track when it arrived: (age - lag) x speed behind the setpoints of the last lag
        ap.telemetry.position = np.array([speed * (4.0 - age), 0.0, 2.0])
        ap.telemetry.position_time = now - age
        c.check()
        assert float(np.linalg.norm(c.track_errors[-1])) < 1e-9
        assert isinstance(c.stream.source, Plan)

    asyncio.run(main())
