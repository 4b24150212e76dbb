"""Commands and the service's state: what the operator may ask for in each
state, and what the autopilot's telemetry says the state is.

The autopilot has the last word: the state follows PX4's telemetry (armed,
landed state, flight mode). A loss of the link, a disarm, a landing or an exit
from offboard for any reason stops the setpoint stream at once, with the reason
on status. Commands that change PX4's state reply once its telemetry confirms
the change (or say that it did not); one such command runs at a time, while
hold, land and abort are never kept waiting.
"""

from __future__ import annotations

import asyncio
import time
from collections import deque
from collections.abc import Callable
from enum import StrEnum

import numpy as np

from companion.flight.autopilot import Autopilot, AutopilotError
from companion.flight.plan import Brake, Hold, Plan
from companion.flight.replanner import Replanner
from companion.flight.stream import SetpointStream
from companion.protocol import COMMANDS
from companion.settings.config import Config, short
from companion.status import Reporter, after_setpoint

#: Commands that never wait for another command to finish.
SAFETY_COMMANDS = ("hold", "land", "abort")


class State(StrEnum):
    CONNECTING = "connecting"  # waiting for the autopilot
    NOT_READY = "not_ready"  # connected, health checks not passed
    READY = "ready"  # healthy, disarmed
    ARMED = "armed"  # armed on the ground
    AIRBORNE = "airborne"  # in the air under PX4's own modes (takeoff, hold)
    PRESTREAM = "prestream"  # streaming setpoints before the offboard switch
    OFFBOARD = "offboard"  # following trajectories / holding in offboard
    LANDING = "landing"
    LINK_LOST = "link_lost"
    STOPPING = "stopping"


class Commander:
    """The state machine: commands in, state from telemetry, safety checks at 10 Hz."""

    def __init__(self, cfg: Callable[[], Config], autopilot: Autopilot, stream: SetpointStream,
                 replanner: Replanner, report: Reporter) -> None:
        self._cfg = cfg
        self.autopilot = autopilot
        self.stream = stream
        self.replanner = replanner
        self.report = report
        self.state = State.CONNECTING
        self.track_errors: deque[np.ndarray] = deque(maxlen=10)  # 1 s at the monitor rate
        self._offboard_seen = False
        self._auto_starting = False
        self._busy = ""  # the state-changing command in progress
        self._background: set[asyncio.Task] = set()

    def flying(self) -> bool:
        """Streaming in offboard, not halted: new plans may take over."""
        return (self.stream.streaming and self.state == State.OFFBOARD
                and self.stream.halted is None)

    def halted(self, reason: str, ended: bool) -> None:  # noqa: ARG002 - the stream's on_halt
        self.replanner.drop()
        if ended and self.state in (State.OFFBOARD, State.PRESTREAM):
            self.state = self._derive_state()

    def spawn(self, coro) -> None:  # noqa: ANN001
        """Run ``coro`` as a task, keeping a reference until it is done."""
        task = asyncio.create_task(coro)
        self._background.add(task)
        task.add_done_callback(self._background.discard)

    # ================================================================ commands
    async def run(self, name: str) -> str:
        """Run the command ``name``; raises AutopilotError saying why it failed."""
        if name not in COMMANDS:
            raise AutopilotError(f"unknown command {short(name)!r} (known: "
                                 f"{', '.join(COMMANDS)})")
        if name in SAFETY_COMMANDS:
            return await getattr(self, f"cmd_{name}")()
        if self._busy:
            raise AutopilotError(f"busy: {self._busy!r} is in progress")
        self._busy = name
        try:
            return await getattr(self, f"cmd_{name}")()
        finally:
            self._busy = ""

    async def _confirm(self, predicate, what: str, timeout_s: float = 3.0) -> None:  # noqa: ANN001
        """Wait until PX4's telemetry shows ``what``."""
        try:
            await self._wait_until(predicate, timeout_s, what)
        except AutopilotError:
            tel = self.autopilot.telemetry
            raise AutopilotError(f"PX4 accepted the command but its telemetry does not show "
                                 f"{what} after {timeout_s:.0f} s (armed {tel.armed}, mode "
                                 f"{tel.flight_mode}, landed state {tel.landed_state})") from None

    def _require(self, *states: State) -> None:
        if self.state not in states:
            raise AutopilotError(f"not possible in state {self.state.value} (needs "
                                 f"{' or '.join(s.value for s in states)})")

    async def cmd_arm(self) -> str:
        self._require(State.READY)
        tel = self.autopilot.telemetry
        if tel.flight_mode == "OFFBOARD":  # left there by a disarm in the air: PX4 would
            await self.autopilot.hold()    # refuse to arm without a setpoint stream
        await self.autopilot.arm()
        await self._confirm(lambda: tel.armed, "the vehicle armed")
        self.state = State.ARMED
        return "armed"

    async def cmd_disarm(self) -> str:
        tel = self.autopilot.telemetry
        if not tel.armed:
            return "already disarmed"
        if tel.landed_state != "ON_GROUND":
            raise AutopilotError("refusing to disarm: PX4 does not report the vehicle on the "
                                 f"ground (landed state {tel.landed_state})")
        await self.autopilot.disarm()
        await self._confirm(lambda: not tel.armed, "the vehicle disarmed")
        return "disarmed"

    async def cmd_takeoff(self) -> str:
        self._require(State.ARMED)
        tel = self.autopilot.telemetry
        await self.autopilot.takeoff(self._cfg().stream.takeoff_altitude_m)
        await self._confirm(lambda: tel.flight_mode == "TAKEOFF" or tel.landed_state in (
            "TAKING_OFF", "IN_AIR"), "the takeoff")
        return f"taking off to {self._cfg().stream.takeoff_altitude_m} m"

    async def cmd_start(self) -> str:
        """Hold where the vehicle is, pre-stream, switch to offboard, then fly the
        newest trajectory (if any). In offboard after a halt: fly trajectories
        again (the newest one that arrives from now on)."""
        if self.state == State.OFFBOARD and self.stream.halted is not None:
            self.stream.resume()
            self.report.event("start: flying new trajectories again")
            return "offboard: holding until the next trajectory"
        self._require(State.AIRBORNE)
        pos = self.autopilot.telemetry.position
        if pos is None:
            raise AutopilotError("no position telemetry")
        fence = self._cfg().safety
        if np.any(pos < fence.geofence_min) or np.any(pos > fence.geofence_max):
            raise AutopilotError(f"the vehicle at {np.round(pos, 2).tolist()} is outside the "
                                 f"geofence {list(fence.geofence_min)} to "
                                 f"{list(fence.geofence_max)}")
        self.stream.begin(pos, self.stream.vehicle_yaw(), "start")
        self.state = State.PRESTREAM
        await asyncio.sleep(self._cfg().stream.prestream_s)
        if self.state != State.PRESTREAM:
            raise AutopilotError(f"start interrupted ({self.state.value})")
        for attempt in range(3):  # PX4 may want a little more stream history
            try:
                await self.autopilot.start_offboard()
                break
            except AutopilotError:
                if attempt == 2 or self.state != State.PRESTREAM:
                    self.stream.stop()
                    self.state = State.AIRBORNE
                    raise
                await asyncio.sleep(0.5)
        tel = self.autopilot.telemetry
        try:
            await self._confirm(lambda: tel.flight_mode == "OFFBOARD"
                                or self.state != State.PRESTREAM, "OFFBOARD")
        except AutopilotError:
            self.stream.stop()
            self.state = self._derive_state()
            raise
        if self.state != State.PRESTREAM:
            raise AutopilotError(f"start interrupted ({self.state.value})")
        self._offboard_seen = True
        self.state = State.OFFBOARD
        if self.replanner.latest is not None:
            self.replanner.kick()
        return "offboard: holding" if self.replanner.latest is None else "offboard: flying"

    async def cmd_hold(self) -> str:
        self._require(State.OFFBOARD)
        self.stream.brake("hold command")
        self.replanner.drop()
        return "braking to a hold"

    async def cmd_abort(self) -> str:
        self.replanner.drop()
        self.stream.drop_next()
        if self.stream.streaming:
            self.stream.stop()
            await self.autopilot.hold()
            self.state = State.AIRBORNE
            return "offboard left: PX4 Hold"
        return "nothing to abort"

    async def cmd_land(self) -> str:
        tel = self.autopilot.telemetry
        if not tel.armed:
            return "disarmed: nothing to land"
        self.replanner.drop()
        self.stream.stop()
        await self.autopilot.land()
        self.state = State.LANDING
        await self._confirm(lambda: tel.flight_mode == "LAND" or tel.landed_state in (
            "LANDING", "ON_GROUND"), "the landing")
        return "landing"

    async def auto_start(self) -> None:
        """Arm, take off and start, each step once the telemetry confirms the last."""
        if self._auto_starting or self.state != State.READY:
            return
        self._auto_starting = True
        try:
            await self.cmd_arm()
            await self._wait_until(lambda: self.state == State.ARMED, 5.0, "armed")
            await self.cmd_takeoff()
            # AIRBORNE: in the air and PX4's takeoff finished (it switched to Hold)
            await self._wait_until(lambda: self.state == State.AIRBORNE, 30.0, "takeoff")
            await self.cmd_start()
        except AutopilotError as exc:
            self.report.error("auto-start", str(exc))
        finally:
            self._auto_starting = False

    async def _wait_until(self, predicate, timeout_s: float, what: str) -> None:  # noqa: ANN001
        end = time.monotonic() + timeout_s
        while not predicate():
            if time.monotonic() > end:
                raise AutopilotError(f"timed out waiting for {what} ({self.state.value})")
            await asyncio.sleep(0.05)

    # =============================================================== monitoring
    async def monitor(self) -> None:
        """10 Hz: link, health, PX4 mode, tracking error, planner silence."""
        last = time.monotonic()
        while True:
            await asyncio.sleep(0.08)
            await after_setpoint(self.stream.beat, 0.05)  # in the stream's idle time
            now = time.monotonic()
            stalled, last = now - last > 0.5, now
            if stalled:  # the process was frozen: telemetry is stale until it catches up
                continue
            self.check()

    def check(self) -> None:
        cfg, tel = self._cfg(), self.autopilot.telemetry
        if self.state in (State.CONNECTING, State.STOPPING) and tel.position_time == 0.0:
            return
        if not self.autopilot.link_ok(cfg.mavlink.link_timeout_s):
            if self.state != State.LINK_LOST:
                if self.stream.streaming:
                    self.report.error("mavlink", "link lost: setpoint stream stopped, "
                                      "trajectory dropped; a new 'start' is needed after "
                                      "reconnection")
                else:
                    self.report.error("mavlink", "link lost")
                self.replanner.drop()
                self.stream.stop()
                self.state = State.LINK_LOST
            return
        if self.state in (State.PRESTREAM, State.OFFBOARD):
            why = ""
            if not tel.armed:
                why = "PX4 reports the vehicle disarmed"
            elif tel.landed_state == "ON_GROUND":
                why = "PX4 reports the vehicle on the ground"
            elif (self.state == State.OFFBOARD and tel.flight_mode != "OFFBOARD"
                    and self._offboard_seen):
                why = f"PX4 left offboard (now {tel.flight_mode})"
            if why:
                self.replanner.drop()
                self.stream.stop()
                self.report.error("px4", f"{why}: setpoint stream stopped; a new 'start' is "
                                  "needed")
                self.state = self._derive_state()
                return
            if not self.stream.streaming:  # the stream ended itself (a long stall)
                self.state = self._derive_state()
                return
            if self.state == State.OFFBOARD and tel.position is not None:
                error = self.stream.tracking_error(tel.position, tel.position_time)
                if error is not None:
                    self.track_errors.append(error)
                    err = float(np.linalg.norm(error))
                    if err > cfg.safety.max_tracking_error_m and not isinstance(
                            self.stream.source, Hold | Brake):
                        self.stream.brake(f"tracking error {err:.2f} m over "
                                          f"{cfg.safety.max_tracking_error_m} m")
            silence = self.replanner.silence()
            if (cfg.safety.planner_timeout_s > 0 and isinstance(self.stream.source, Plan)
                    and silence > cfg.safety.planner_timeout_s):
                self.stream.brake(f"no trajectory from the planner for {silence:.1f} s")
            return
        if self.state == State.LANDING and tel.landed_state == "ON_GROUND" and not tel.armed:
            self.state = State.READY
        new = self._derive_state()
        if new != self.state and self.state != State.LANDING:
            self.state = new
        elif self.state == State.LANDING and not tel.armed:
            self.state = new

    def _derive_state(self) -> State:
        tel = self.autopilot.telemetry
        if not tel.armed:
            return State.READY if tel.healthy else State.NOT_READY
        if tel.landed_state == "IN_AIR" and tel.flight_mode != "TAKEOFF":
            return State.AIRBORNE
        if tel.landed_state == "LANDING":
            return State.LANDING
        return State.ARMED
