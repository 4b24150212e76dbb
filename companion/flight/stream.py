"""The setpoint stream: what is commanded at every instant, sent to PX4 at
``stream.rate_hz`` on absolute deadlines.

The stream owns the commanded source (a :class:`~companion.flight.plan.Plan`, a
:class:`~companion.flight.plan.Brake` or a :class:`~companion.flight.plan.Hold`), swaps in the
next plan at its takeover time, and records every setpoint it sends. Nothing
here decodes, solves or waits on the network: one tick is a few array
operations and one pipe write.

It runs in a thread of its own, not on the event loop, at a higher CPU priority
than the rest of the service when it may (:func:`companion.flight.sender.raise_priority`):
a tick then waits for no callback of the loop (a status being built, a reply, telemetry),
only, at worst, for Python's GIL. That wait no longer delays the vehicle: each
setpoint is computed :data:`LEAD_PERIODS` periods ahead and put on the wire at its
deadline by the setpoint sender, a process of its own that needs no GIL of the service's
(:mod:`companion.flight.sender`).
The loop and the stream share the commanded state under one lock; what the
stream tells the loop (a halt, its beat) it hands over with
``call_soon_threadsafe``. The loop's own life feeds systemd's watchdog from the
beat, so a stuck loop is still restarted.

Two promises are kept here, whatever happens elsewhere:

* **No jump.** Every setpoint is checked against the one sent before it (finite,
  inside the geofence, no farther than the speed limit allows over their spacing,
  plus the takeover blend); a setpoint that fails is not sent: the stream brakes
  from the last setpoint it sent instead, and reports why.
* **No stale stream.** Plans run on the monotonic clock, so after a stall of the
  loop (or of the whole process) the plan's "now" has run ahead. A stall longer
  than ``stream.stall_budget_s`` is detected before anything is sent: the stream
  brakes from the last setpoint it sent and holds, and a new ``start`` is needed
  to fly trajectories again, in OFFBOARD, as long as the stream's own send times prove
  that PX4 has not timed out: the last setpoint went out less than PX4's offboard-loss
  timeout minus ``mavlink.offboard_loss_margin_s`` ago (:meth:`SetpointStream.resume_limit`;
  no setpoint is sent later than that either). A longer gap ends the stream altogether:
  PX4's failsafe may have the vehicle, and resumed setpoints would take PX4 back into
  OFFBOARD by themselves.
"""

from __future__ import annotations

import asyncio
import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from companion import messages as msgs
from companion.flight.autopilot import Autopilot
from companion.flight.heading import Heading
from companion.flight.lateness import TickClock
from companion.flight.plan import (
    Brake,
    Command,
    Hold,
    Plan,
    blend_speed,
    blend_time,
    brake_along,
)
from companion.flight.reaction import Reactions
from companion.flight.sender import raise_priority
from companion.frames import heading_ned_deg
from companion.settings.config import Config
from companion.status import Reporter

log = logging.getLogger("rota.companion")

#: Share of the smallest acceleration limit used to brake to a hold.
BRAKE_SHARE = 0.7
#: Telemetry older than this share of PX4's offboard-loss timeout ends the stream.
LOSS_SHARE = 0.8
#: Slack (m) on the step between consecutive setpoints (float rounding, brake ends).
STEP_SLACK_M = 0.01
#: A tick this late (s) is logged with the kernel's account of why
#: (:mod:`companion.flight.lateness`).
LATE_TICK_S = 0.06
#: The kernel's counters are read every this many ticks (and at a late one): each read
#: of a /proc file hands the GIL over and back (open, read), and under contention every
#: hand-back waits up to the 1 ms switch interval, so reading them at every tick cost the
#: stream milliseconds per tick. A late tick's account covers the time since the last
#: reading (at most this many periods before it).
CLOCK_EVERY = 10
#: Each setpoint is computed this many periods before its deadline and handed to the
#: sender process, which sends it at the deadline: a tick of the stream's thread may
#: come this many periods late, less a little, and the vehicle sees nothing. One period
#: was not enough in CI (two test workers on two cores beside real PX4): the vehicle saw
#: two 47 ms gaps, as a tick held up some 27 ms (the GIL's holder waiting for a CPU) leaves. The
#: price: a brake or a new plan reaches the wire one period later (20 ms at 50 Hz, 4 cm
#: at 2 m/s); :meth:`SetpointStream.stop` still drops what waits at once.
LEAD_PERIODS = 2

Source = Plan | Hold | Brake


class SentLog:
    """The last ``size`` setpoints sent, (monotonic time, ENU position), in a fixed
    ring: its memory does not grow with the flight."""

    def __init__(self, size: int = 30000) -> None:
        self.size = size
        self._t = np.zeros(size)
        self._p = np.zeros((size, 3))
        self._n = 0

    def append(self, t: float, p: np.ndarray) -> None:
        i = self._n % self.size
        self._t[i], self._p[i] = t, p
        self._n += 1

    def __len__(self) -> int:
        return min(self._n, self.size)

    def _last(self, k: int) -> np.ndarray:
        """Ring indices of the newest ``k`` entries, oldest first."""
        k = min(k, len(self))
        return (np.arange(self._n - k, self._n)) % self.size

    def __iter__(self):  # noqa: ANN204 - (time, position) pairs, oldest first
        idx = self._last(len(self))
        return zip(self._t[idx].tolist(), self._p[idx].copy(), strict=True)

    def between(self, t0: float, t1: float, most: int = 512) -> np.ndarray:
        """Positions sent from ``t0`` to ``t1`` (of the newest ``most``); else the newest
        one sent by ``t1``, else the oldest kept."""
        idx = self._last(most)
        if not len(idx):
            return np.zeros((0, 3))
        t = self._t[idx]
        keep = idx[(t >= t0) & (t <= t1)]
        if not len(keep):
            keep = idx[t <= t1][-1:] if np.any(t <= t1) else idx[:1]
        return self._p[keep]


class SetpointStream:
    """Streams the commanded state to the autopilot while ``streaming``.

    ``record(channel, payload)`` puts each setpoint sent in the flight record;
    ``on_halt(reason, ended)`` is called (on the event loop) when a stall or a
    refused setpoint halts the flight: ``ended`` when the stream stopped
    altogether (PX4's failsafe has the vehicle), else it brakes to a hold.

    Every method that changes the commanded state takes :attr:`lock`, which the
    stream's thread holds for a tick.
    """

    def __init__(self, cfg: Callable[[], Config], autopilot: Autopilot, report: Reporter,
                 record: Callable[[str, Any], None] | None = None,
                 on_halt: Callable[[str, bool], None] | None = None) -> None:
        self._cfg = cfg
        self.autopilot = autopilot
        self.report = report
        self.source: Source | None = None  # what is commanded
        self.next_plan: Plan | None = None  # takes over at its t0
        self.streaming = False
        self.started = 0.0
        self.yaw_ned = 0.0  # the yaw streamed (NED, deg)
        self.heading = Heading(0.0)  # ... and its rate (companion/flight/heading.py)
        self.yaw_target = 0.0  # where it turns to (the path's direction, or the start's)
        self.halted: str | None = None  # why plans may not fly until the next start
        self.on_halt: Callable[[str, bool], None] = on_halt or (lambda reason, ended: None)
        self.send_times: deque[float] = deque(maxlen=3000)  # when setpoints went out
        self.dropped = 0  # setpoints the sender did not send (late after a stall)
        self._unsent: dict[str, tuple[int, float]] = {}  # why: (not logged, last logged)
        self.sent = SentLog()  # (time, position) of the setpoints sent
        self.last_sent: Command | None = None  # the last handed to the sender ...
        self.last_send_time = 0.0  # ... for this deadline
        #: handed over, not yet reported on: (deadline, setpoint), oldest first
        self._handed: deque[tuple[float, Command]] = deque(maxlen=4 * LEAD_PERIODS + 64)
        #: the last the sender reported out: (deadline, setpoint)
        self.last_out: tuple[float, Command] | None = None
        self.last_tick = 0.0  # monotonic time of the last loop iteration (supervision)
        self.stalls = 0
        self.reactions = Reactions()  # from a trajectory's arrival to its first setpoint
        self.longest_stall_s = 0.0
        #: the flight record (``record(channel, payload)``)
        self.record: Callable[[str, Any], None] = record or (lambda channel, payload: None)
        #: set (on the event loop) after every tick (a setpoint sent, or nothing to
        #: send): other periodic work waits for it and so runs just after a setpoint,
        #: in the stream's idle time, not across its next deadline
        self.beat = asyncio.Event()
        self.lock = threading.RLock()
        #: how the stream's thread reaches the event loop (direct when it runs alone)
        self._call: Callable[..., None] = lambda fn, *args: fn(*args)
        self.priority: str = ""  # why the stream runs at the service's priority, if it does
        #: the kernel's account of the stream thread's ticks (why a tick came late)
        self.clock = TickClock()

    # ------------------------------------------------------------ commanding
    def commanded(self, now: float) -> Command:
        """The commanded state at ``now`` (the vehicle's position when idle)."""
        with self.lock:
            if self.source is None:
                pos = self.autopilot.telemetry.position
                return Command(np.zeros(3) if pos is None else pos.copy())
            return self.source.command(now)

    def begin(self, position: np.ndarray, yaw_ned: float, reason: str) -> None:
        """Start streaming a hold at ``position``."""
        with self.lock:
            self.source, self.next_plan = Hold(position.copy(), reason), None
            self.yaw_ned = self.yaw_target = yaw_ned
            self.heading = Heading(yaw_ned)
            self.halted, self.last_sent, self.last_out = None, None, None
            self._handed.clear()
            self.streaming, self.started = True, time.monotonic()

    def stop(self) -> None:
        """Stop streaming and forget the source (at once: a status sent after it
        never says streaming)."""
        with self.lock:
            self.streaming = False
            self.source, self.next_plan = None, None
        self.autopilot.cancel_sends()

    def offer(self, plan: Plan) -> None:
        """Fly ``plan`` from its ``t0`` on (ignored while halted)."""
        with self.lock:
            if self.halted is None:
                self.next_plan = plan

    def resume(self) -> None:
        """Fly trajectories again after a halt (the ``start`` command)."""
        with self.lock:
            self.halted = None

    def drop_next(self) -> None:
        """Forget the plan waiting to take over."""
        with self.lock:
            self.next_plan = None

    def take_over(self, now: float) -> None:
        """Swap in the next plan at its start time, carrying the position gap (at most
        the stitch tolerance: a larger one is refused, the current command goes on)."""
        plan = self.next_plan
        self.next_plan = None
        old = self.commanded(now)
        new = plan.command(now)
        gap = old.position - new.position
        size, tolerance = float(np.linalg.norm(gap)), self._cfg().safety.stitch_tolerance_m
        if size > tolerance:
            self.report.error("stream", f"trajectory {plan.id!r} not flown: at takeover it "
                              f"is {size:.2f} m from the command (tolerance {tolerance} m)")
            return
        self.source = replace(plan, offset=gap, blend_s=blend_time(size), blend_t0=now)
        self.reactions.flown(plan.timing, now)  # (this tick's setpoint is the plan's first)

    def _decel(self) -> float:
        return BRAKE_SHARE * min(self._cfg().limits.a_max)

    def brake(self, reason: str) -> None:
        """Stop along the path being flown (or hold) and report why."""
        with self.lock:
            now = time.monotonic()
            self.next_plan = None
            if isinstance(self.source, Plan):
                self.source = brake_along(self.source, now, self._decel(), reason)
            elif isinstance(self.source, Brake):
                return
            else:
                self.source = Hold(self.commanded(now).position, reason)
        self.report.warn(f"braking to a hold: {reason}")

    def halt(self, reason: str, now: float | None = None) -> None:
        """Brake from the last setpoint sent (never from where the clock says the plan
        now is), along the path being flown (the path was checked against the map; a
        straight line off it was not), and refuse plans until the next ``begin``."""
        now = time.monotonic() if now is None else now
        with self.lock:
            self.next_plan = None
            self.halted = reason
            late = now - self.last_send_time
            if isinstance(self.source, Plan) and self.last_sent is not None:
                brake = brake_along(self.source, self.last_send_time, self._decel(), reason)
                self.source = replace(brake, t0=now)
            elif isinstance(self.source, Brake):  # go on braking from where it was
                self.source = replace(self.source, t0=self.source.t0 + late, reason=reason)
            elif self.last_sent is not None:
                self.source = Hold(self.last_sent.position.copy(), reason)
        self.report.error("stream", f"{reason}: braking from the last setpoint sent to a "
                          "hold; a new 'start' is needed")
        self._call(self.on_halt, reason, False)

    def _end(self, reason: str) -> None:
        with self.lock:
            self.streaming = False
            self.source, self.next_plan = None, None
            self.halted = reason
        self.autopilot.cancel_sends()
        self.report.error("stream", f"{reason}: setpoint stream stopped, PX4's offboard-loss "
                          "failsafe has the vehicle; a new 'start' is needed")
        self._call(self.on_halt, reason, True)

    # ------------------------------------------------------------ the loop
    async def run(self, tick: Callable[[], None] = lambda: None) -> None:
        """Run the stream in its thread until cancelled (then stop the thread); an
        exception in the thread ends this with it (the supervisor restarts it).
        ``tick`` runs on the event loop after every tick of the stream (systemd's
        watchdog: fed only while the loop runs too)."""
        loop = asyncio.get_running_loop()
        ended: asyncio.Future[None] = loop.create_future()
        stop = threading.Event()

        def beat() -> None:
            tick()
            self.beat.set()

        def settle(exc: BaseException | None) -> None:
            if ended.done():
                return
            if exc is None:
                ended.set_result(None)
            else:
                ended.set_exception(exc)

        def main() -> None:
            try:
                self._raise_priority()
                self._loop(stop, lambda: loop.call_soon_threadsafe(beat))
            except BaseException as exc:  # noqa: BLE001 - handed to the supervisor
                loop.call_soon_threadsafe(settle, exc)
            else:
                loop.call_soon_threadsafe(settle, None)

        self._call = loop.call_soon_threadsafe
        thread = threading.Thread(target=main, name="setpoint-stream", daemon=True)
        thread.start()
        try:
            await ended
        finally:
            stop.set()
            thread.join(1.0)  # it sees ``stop`` within one period

    def _raise_priority(self) -> None:
        """This thread real-time where allowed, else a few nice levels above the
        service (:func:`companion.flight.sender.raise_priority`); status says if neither was
        allowed."""
        why = raise_priority(threading.get_native_id())
        self.priority = f"setpoint stream {why}" if why else ""
        if why:
            self._call(self.report.warn, self.priority)

    def _loop(self, stop: threading.Event, beat: Callable[[], None]) -> None:
        """Setpoints at ``rate_hz`` on absolute deadlines (no drift), while streaming;
        ``beat()`` after every tick. Each setpoint is computed :data:`LEAD_PERIODS`
        periods before its deadline and handed to the sender process, which sends it at
        the deadline (:mod:`companion.flight.sender`): a tick of this thread may come up to
        that late (waiting for the GIL or a CPU) and the setpoint still goes out on time."""
        period = 1.0 / self._cfg().stream.rate_hz
        lead = LEAD_PERIODS * period
        deadline = time.monotonic() + lead - period
        self.last_tick = time.monotonic()
        self.clock.tick()
        ticks = 0
        while not stop.is_set():
            deadline += period
            delay = deadline - lead - time.monotonic()
            if delay < -5 * period:  # fell far behind (stalled): resynchronise
                deadline = time.monotonic() + period
            if delay > 0:
                time.sleep(delay)
            wall = time.monotonic()
            at = max(deadline, wall)  # when this tick's setpoint goes out
            stall, self.last_tick = wall - self.last_tick, wall
            budget = self._cfg().stream.stall_budget_s
            late = stall > min(LATE_TICK_S, budget)
            ticks += 1
            if late or ticks % CLOCK_EVERY == 0:
                self.clock.tick()
            why = self.clock.explain() if late else ""
            if stall > LATE_TICK_S:
                log.warning("setpoint stream late: %.0f ms since the last tick (%s)",
                            1e3 * stall, why or "no kernel figures")
            self._account()
            with self.lock:
                if self.streaming:
                    if stall > budget:
                        self._stalled(stall, at, why)
                    if self.streaming:
                        self._step(at, wall)
            beat()

    def _account(self) -> None:
        """Take in what the sender did with the setpoints handed to it (setpoints not
        sent are logged, at most once a second for each reason, with their count)."""
        now = time.monotonic()
        for sent in self.autopilot.sent():
            while self._handed and self._handed[0][0] < sent.at:
                self._handed.popleft()  # (handed before a begin: no report to wait for)
            if self._handed and self._handed[0][0] == sent.at:
                handed = self._handed.popleft()
                if sent.sent_at is not None:
                    self.last_out = handed
            if sent.sent_at is not None:
                self.send_times.append(sent.sent_at)
                continue
            self.dropped += 1
            count, since = self._unsent.get(sent.why, (0, 0.0))
            if now - since >= 1.0:
                log.warning("setpoint for %.3f not sent: %s%s", sent.at, sent.why,
                            f" ({count} more since the last such line)" if count else "")
                self._unsent[sent.why] = (0, now)
            else:
                self._unsent[sent.why] = (count + 1, since)

    def loss_timeout(self) -> float:
        """PX4's offboard-loss timeout: the smaller of the configured and PX4's own."""
        cfg = self._cfg().mavlink.offboard_loss_timeout_s
        px4 = self.autopilot.offboard_loss_timeout_s
        return cfg if px4 is None or not px4 > 0 else min(cfg, px4)

    def resume_limit(self) -> float:
        """The longest time (s) since the last setpoint sent after which the stream may
        still send: PX4 cannot have timed out (its offboard-loss timeout minus the margin
        measured on PX4, ``mavlink.offboard_loss_margin_s``)."""
        return self.loss_timeout() - self._cfg().mavlink.offboard_loss_margin_s

    def _stalled(self, stall: float, now: float, why: str = "") -> None:
        """``why``: the kernel's account of the stall (:meth:`TickClock.explain`). Brakes to
        a hold (in OFFBOARD) if the last setpoint went out less than :meth:`resume_limit`
        ago, else ends the stream."""
        self.stalls += 1
        self.longest_stall_s = max(self.longest_stall_s, stall)
        if self.last_out is not None and self.last_out[0] < self.last_send_time:
            # What waited in the sender was computed before the stall, more than the
            # budget ago: past its ``not_after``, it never goes out (:meth:`_step`), and
            # the brake starts from the last setpoint that did, not from one the vehicle
            # never received. (The sender writes its report just after a send: one sent
            # within microseconds of this tick may be missed, and the brake then starts
            # a period back along the path, a step the spacing allows.)
            self.last_send_time, self.last_sent = self.last_out
        what = f"the service was stalled for {stall:.2f} s" + (f" ({why})" if why else "")
        gap = now - self.last_send_time if self.last_sent is not None else stall
        if gap >= self.resume_limit():
            self._end(f"{what}, {gap:.2f} s since the last setpoint (PX4's offboard-loss "
                      f"timeout is {self.loss_timeout():.2f} s; the stream resumes only within "
                      f"{self.resume_limit():.2f} s)")
        elif self.halted is None or not isinstance(self.source, Hold):
            self.halt(f"{what} (budget {self._cfg().stream.stall_budget_s} s)", now)

    def tracking_error(self, position: np.ndarray, at: float) -> np.ndarray | None:
        """The reported ``position`` (received at monotonic ``at``) minus the nearest of
        the setpoints sent in the ``safety.tracking_lag_s`` before ``at`` (PX4's position
        loop lags its setpoint by up to half a second at 2-3 m/s: a lag is no divergence;
        a setpoint sent after the position was measured is no measure of it, and on a busy
        computer the position may be read a while after it arrived). None if none was
        sent."""
        with self.lock:
            recent = self.sent.between(at - self._cfg().safety.tracking_lag_s, at)
        if not len(recent):
            return None
        d = position - recent
        return d[int(np.argmin(np.einsum("ij,ij->i", d, d)))]

    def _step(self, now: float, wall: float) -> None:
        """The setpoint for ``now`` (when it is to go out), computed at ``wall``."""
        age = now - self.autopilot.telemetry.position_time
        if age > LOSS_SHARE * self.loss_timeout():
            # deaf to the vehicle for nearly PX4's offboard-loss timeout: a link that
            # comes back must not find setpoints still flowing (PX4 would return to
            # OFFBOARD on the first one)
            self._end(f"no telemetry from PX4 for {age:.2f} s")
            return
        gap = now - self.last_send_time
        if self.last_sent is not None and gap >= self.resume_limit():
            # (a stall of the stream's thread alone, or a send held up: nothing went out
            # for as long as PX4 may take to time out)
            self._end(f"no setpoint sent for {gap:.2f} s (PX4's offboard-loss timeout is "
                      f"{self.loss_timeout():.2f} s)")
            return
        if self.next_plan is not None and now >= self.next_plan.t0:
            self.take_over(now)
        if isinstance(self.source, Plan | Brake) and self.source.finished(now):
            end = self.source.command(now).position
            # a finished brake keeps its reason (why the vehicle holds)
            reason = self.source.reason if isinstance(self.source, Brake) else \
                "end of trajectory"
            self.source = Hold(end, reason)
            self.report.event(f"{reason}: holding at {msgs.vec(end, 2)}")
        cmd = self.commanded(now)
        problem = self.check(cmd, now)
        if problem:
            self.halt(problem, now)
            cmd = self.commanded(now)
            if self.check(cmd, now):  # nothing safe to send: stop, PX4's failsafe acts
                self._end(f"no safe setpoint after: {problem}")
                return
        self._update_yaw(cmd, now)
        not_after, silence = wall + self._cfg().stream.stall_budget_s, math.inf
        if self.last_sent is not None:
            silence = self.resume_limit()
            not_after = min(not_after, self.last_send_time + silence)
        try:
            # a setpoint computed before a stall is not sent after it (the next tick
            # sees the stall), nor later than PX4 is sure to be waiting for it
            sent = self.autopilot.send(cmd.position, cmd.velocity, cmd.acceleration,
                                       self.yaw_ned, now, not_after, silence,
                                       LEAD_PERIODS / self._cfg().stream.rate_hz)
        except Exception as exc:  # noqa: BLE001 - the link monitor reports a dead link
            log.warning("setpoint send failed: %s", exc)
            return
        if sent:
            self.sent.append(now, cmd.position)
            self._handed.append((now, cmd))
            self.last_sent, self.last_send_time = cmd, now
            self.record("setpoint", {"t": now, "p": cmd.position, "v": cmd.velocity,
                                     "a": cmd.acceleration, "yaw": self.yaw_ned,
                                     "source": getattr(self.source, "id", None)
                                     or type(self.source).__name__.lower()})

    def check(self, cmd: Command, now: float) -> str:
        """Why ``cmd`` must not be sent after the last setpoint ("" if it may):
        non-finite, outside the geofence, or a jump from the last one."""
        if not (np.all(np.isfinite(cmd.position)) and np.all(np.isfinite(cmd.velocity))
                and np.all(np.isfinite(cmd.acceleration))):
            return "non-finite setpoint computed"
        cfg = self._cfg()
        lo, hi = np.asarray(cfg.safety.geofence_min), np.asarray(cfg.safety.geofence_max)
        if np.any(cmd.position < lo) or np.any(cmd.position > hi):
            last = self.last_sent
            # the fence never traps a vehicle already outside it: only a step outward
            # from the last setpoint is refused
            if last is None or np.any((cmd.position < np.minimum(lo, last.position))
                                      | (cmd.position > np.maximum(hi, last.position))):
                return (f"setpoint {msgs.vec(cmd.position, 2)} outside the geofence "
                        f"{list(lo)} to {list(hi)}")
        if self.last_sent is None:
            return ""
        dt = now - self.last_send_time
        allowed = self.max_speed() * dt + STEP_SLACK_M
        step = float(np.linalg.norm(cmd.position - self.last_sent.position))
        if step > allowed:
            return (f"setpoint jump of {step:.2f} m in {dt * 1e3:.0f} ms refused (at most "
                    f"{allowed:.2f} m)")
        return ""

    def max_speed(self) -> float:
        """The fastest a setpoint may move: v_max plus the largest takeover blend."""
        cfg = self._cfg()
        return cfg.limits.v_max + blend_speed(cfg.safety.stitch_tolerance_m)

    def _update_yaw(self, cmd: Command, now: float) -> None:
        """The next yaw: toward the planner's heading if the plan flown has one, else
        the path's direction (or the start's), within the yaw rate and acceleration
        limits (:mod:`companion.flight.heading`); ``[stream] yaw = "hold"`` keeps the
        start's."""
        s = self._cfg().stream
        if s.yaw == "path":
            planned = self.source.yaw_ned_deg(now) if isinstance(self.source, Plan) else None
            if planned is not None:
                self.yaw_target = planned
            elif np.linalg.norm(cmd.velocity[:2]) > 0.3:
                self.yaw_target = heading_ned_deg(cmd.velocity)
        self.heading = self.heading.toward(self.yaw_target, 1.0 / s.rate_hz,
                                           s.yaw_rate_max_deg_s, s.yaw_accel_max_deg_s2)
        self.yaw_ned = self.heading.yaw_deg

    def vehicle_yaw(self) -> float:
        """The vehicle's heading now (NED yaw, deg): the yaw to hold at first."""
        yaw = self.autopilot.telemetry.yaw_ned_deg
        return self.yaw_ned if yaw is None or not math.isfinite(yaw) else yaw

    # ------------------------------------------------------------ figures
    def jitter_p99_ms(self) -> float | None:
        """99th percentile of |period - nominal| of the setpoint stream (ms)."""
        with self.lock:
            t = np.asarray(self.send_times)
        if len(t) < 20:
            return None
        dt = np.diff(t)
        dt = dt[dt < 0.5]  # gaps between streaming sessions are not jitter
        if not len(dt):
            return None
        return round(float(np.percentile(np.abs(dt - 1.0 / self._cfg().stream.rate_hz), 99))
                     * 1e3, 3)
