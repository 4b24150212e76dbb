"""The flight service: Zenoh in, ROTA, MAVSDK offboard out.

Thin glue over :mod:`rota` and the small modules beside this one:
trajectories and maps arrive on Zenoh (validated by :mod:`companion.messages`),
are re-timed in a worker process (:mod:`companion.retimer`), stitched onto the
commanded state (:mod:`companion.plan`), and streamed to PX4 as position,
velocity and acceleration setpoints (:mod:`companion.autopilot`). Status and
telemetry go out on Zenoh; commands and configuration come in as Zenoh queries.
Protocol: ``docs/protocol.md``.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import sys
import time
from collections import deque
from dataclasses import replace
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np
import sdnotify
import zenoh

from companion import messages as msgs
from companion.autopilot import Autopilot, AutopilotError
from companion.config import Config, ConfigError, from_dict
from companion.estimator import UncertaintyEstimator, evidence, tracking_std
from companion.frames import heading_ned_deg
from companion.plan import Brake, Command, Hold, Plan, blend_time, brake_along
from companion.retimer import ReplanJob, Retimer
from companion.uncertainty import ConfiguredUncertainty, UncertaintySource
from rota.result import FALLBACK, REJECTED
from rota.voxelmap import VoxelMap

log = logging.getLogger("rota.companion")

#: Settings that can change at run time through the config queryable.
RUNTIME_SECTIONS = ("limits", "uncertainty", "safety")  # [estimator]: the estimator query
#: Share of the smallest acceleration limit used to brake to a hold.
BRAKE_SHARE = 0.7


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


class Notifier:
    """sd_notify (READY, STATUS, WATCHDOG, STOPPING) that can never block the
    event loop: the socket is non-blocking (a busy systemd drops a message rather
    than stalling the setpoint stream) and the watchdog is petted at most 4 Hz."""

    def __init__(self) -> None:
        self._sd = sdnotify.SystemdNotifier()
        if self._sd.socket is not None:
            self._sd.socket.setblocking(False)
        self._last_watchdog = 0.0

    def notify(self, state: str) -> None:
        self._sd.notify(state)  # sdnotify swallows errors (e.g. BlockingIOError)

    def watchdog(self) -> None:
        now = time.monotonic()
        if now - self._last_watchdog >= 0.25:
            self._last_watchdog = now
            self.notify("WATCHDOG=1")


def zenoh_config(cfg: Config) -> zenoh.Config:
    """The Zenoh configuration: a file if given, else the embedded loopback default
    (peer mode, listening on the configured endpoints, no multicast scouting, so
    nothing leaves the machine unless configured to)."""
    if cfg.zenoh.config_file:
        return zenoh.Config.from_file(cfg.zenoh.config_file)
    z = zenoh.Config()
    z.insert_json5("mode", json.dumps(cfg.zenoh.mode))
    z.insert_json5("scouting/multicast/enabled", "false")
    z.insert_json5("listen/endpoints", json.dumps(list(cfg.zenoh.listen)))
    z.insert_json5("connect/endpoints", json.dumps(list(cfg.zenoh.connect)))
    return z


class Service:
    """The running service. ``await Service(cfg).run(stop)`` until ``stop`` is set."""

    def __init__(self, cfg: Config, uncertainty: UncertaintySource | None = None) -> None:
        self.cfg = cfg
        self.estimator: UncertaintyEstimator | None = None
        if uncertainty is None and cfg.estimator.enabled:
            path = Path(cfg.service.state_dir) / f"uncertainty-{cfg.service.vehicle_id}.json"
            try:
                self.estimator = UncertaintyEstimator(cfg.uncertainty_model(), cfg.estimator,
                                                      path, v_check=cfg.limits.v_max)
            except ValueError as exc:  # a corrupt file: start from the prior, keep the file
                log.error("%s; starting from the configured model", exc)
                path.rename(path.with_suffix(".corrupt"))
                self.estimator = UncertaintyEstimator(cfg.uncertainty_model(), cfg.estimator,
                                                      path, v_check=cfg.limits.v_max)
        self.uncertainty = (uncertainty or self.estimator
                            or ConfiguredUncertainty(cfg.uncertainty_model()))
        self.track_errors: deque[np.ndarray] = deque(maxlen=10)  # 1 s at the monitor rate
        self.autopilot = Autopilot(cfg.mavlink.url)
        self.retimer = Retimer()
        self.state = State.CONNECTING
        self.source: Plan | Hold | Brake | None = None  # what is commanded
        self.next_plan: Plan | None = None  # takes over at its t0
        self.streaming = False
        self.stream_started = 0.0
        self.map: VoxelMap | None = None
        self.latest: msgs.Incoming | None = None  # newest accepted trajectory
        self.last_trajectory_time = 0.0
        self.last_error: dict[str, Any] | None = None
        self.warnings: deque[str] = deque(maxlen=5)
        self.last_result_summary: dict[str, Any] = {}
        self.solve_latency = 0.25  # s, running estimate used to pick the takeover time
        self.send_times: deque[float] = deque(maxlen=3000)
        self.sent: deque[tuple[float, np.ndarray]] = deque(maxlen=30000)  # (time, position)
        self.yaw_ned = 0.0
        self._last_sent = Command(np.zeros(3))
        self._offboard_seen = False
        self.session: zenoh.Session | None = None
        self.notifier = Notifier()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._replan = asyncio.Event()
        self._zenoh_objs: list[Any] = []
        self._tasks: list[asyncio.Task] = []
        self._pub: dict[str, Any] = {}
        self._background: set[asyncio.Task] = set()
        self._auto_starting = False

    # ===================================================================== run
    async def run(self, stop: asyncio.Event) -> None:
        # MAVSDK, Zenoh and the worker pool run Python threads too; hand the GIL
        # over every 1 ms (default 5 ms) so the setpoint loop is not kept waiting.
        sys.setswitchinterval(0.001)
        self._loop = asyncio.get_running_loop()
        self._open_zenoh()
        await self.retimer.start()
        self._tasks = [asyncio.create_task(c, name=n) for n, c in (
            ("connection", self._connection()), ("stream", self._stream_loop()),
            ("monitor", self._monitor()), ("replan", self._replanner()),
            ("publish", self._publisher()), ("estimator", self._learn()))]
        self.notifier.notify("READY=1")
        log.info("service up: vehicle %s, MAVLink %s, Zenoh keys %s/**",
                 self.cfg.service.vehicle_id, self.cfg.mavlink.url, self.cfg.key(""))
        try:
            await stop.wait()
        finally:
            await self._shutdown()

    async def _shutdown(self) -> None:
        """SIGTERM/SIGINT: in flight, hand the vehicle to PX4's Hold, report, exit."""
        was = self.state
        self.state = State.STOPPING
        self.notifier.notify("STOPPING=1")
        if self.streaming or was in (State.OFFBOARD, State.PRESTREAM):
            try:
                await asyncio.wait_for(self.autopilot.hold(), 3.0)
                self._event("service stopping: vehicle handed to PX4 Hold")
            except (AutopilotError, TimeoutError) as exc:
                self._error("shutdown", f"could not switch PX4 to Hold: {exc}")
        await self._stop_stream()
        with contextlib.suppress(Exception):
            self._publish_status()
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        await self.autopilot.close()
        self.retimer.close()
        if self.estimator is not None:
            with contextlib.suppress(OSError):
                self.estimator.save()
        for obj in self._zenoh_objs:
            with contextlib.suppress(Exception):
                obj.undeclare()
        if self.session is not None:
            self.session.close()
        log.info("service stopped")

    # =================================================================== zenoh
    def _open_zenoh(self) -> None:
        self.session = zenoh.open(zenoh_config(self.cfg))
        k = self.cfg.key
        s = self.session
        json_enc = zenoh.Encoding.APPLICATION_JSON
        for name in ("status", "telemetry", "retimed"):
            self._pub[name] = s.declare_publisher(k(name), encoding=json_enc)
        self._zenoh_objs = [
            *self._pub.values(),
            s.declare_subscriber(k("trajectory"), self._threadsafe(self._on_trajectory)),
            s.declare_subscriber(k("map"), self._threadsafe(self._on_map)),
            s.declare_queryable(k("cmd", "*"), self._threadsafe(self._on_command)),
            s.declare_queryable(k("config"), self._threadsafe(self._on_config)),
            s.declare_queryable(k("estimator"), self._threadsafe(self._on_estimator)),
        ]

    def _spawn(self, coro) -> None:  # noqa: ANN001
        """Run ``coro`` as a task, keeping a reference until it is done."""
        task = asyncio.create_task(coro)
        self._background.add(task)
        task.add_done_callback(self._background.discard)

    def _threadsafe(self, handler):  # noqa: ANN001, ANN202
        """Zenoh calls back on its own threads: hop onto the event loop."""
        loop = self._loop

        def callback(item: Any) -> None:
            loop.call_soon_threadsafe(handler, item)

        return callback

    def _put(self, name: str, obj: dict[str, Any]) -> None:
        self._put_bytes(name, msgs.dumps(obj))

    def _put_bytes(self, name: str, payload: bytes) -> None:
        try:
            self._pub[name].put(payload)
        except Exception as exc:  # noqa: BLE001 - never let publishing take the service down
            log.warning("publishing %s failed: %s", name, exc)

    # ================================================================= inputs
    def _on_trajectory(self, sample: zenoh.Sample) -> None:
        try:
            incoming = msgs.parse_trajectory(sample.payload.to_bytes(), self.cfg)
        except msgs.Rejected as exc:
            self._error("trajectory", str(exc))
            return
        self.latest = incoming
        self.last_trajectory_time = time.monotonic()
        self._replan.set()
        if self.cfg.stream.auto_start and self.state == State.READY and not self._auto_starting:
            self._spawn(self._auto_start())

    def _on_map(self, sample: zenoh.Sample) -> None:
        try:
            vmap = msgs.parse_map(sample.payload.to_bytes(), self.cfg)
        except msgs.Rejected as exc:
            self._error("map", str(exc))
            return
        self._spawn(self._use_map(vmap))

    async def _use_map(self, vmap: VoxelMap) -> None:
        await self.retimer.set_map(vmap)
        self.map = vmap
        log.info("map: %d occupied voxels at %.2f m", len(vmap), vmap.resolution)

    def _on_command(self, query: zenoh.Query) -> None:
        name = str(query.key_expr).rsplit("/", 1)[-1]
        self._spawn(self._answer(query, name))

    async def _answer(self, query: zenoh.Query, name: str) -> None:
        try:
            if name not in msgs.COMMANDS:
                raise AutopilotError(f"unknown command {name!r} (known: "
                                     f"{', '.join(msgs.COMMANDS)})")
            message = await getattr(self, f"cmd_{name}")()
            payload = msgs.reply(name, True, message or "", state=self.state.value)
        except AutopilotError as exc:
            self._error(f"command {name}", str(exc))
            payload = msgs.reply(name, False, str(exc), state=self.state.value)
        _reply(query, payload)

    def _on_config(self, query: zenoh.Query) -> None:
        ok, message = True, ""
        if query.payload is not None and len(query.payload.to_bytes()):
            try:
                request = msgs.decode(query.payload.to_bytes(), "config")
                if not isinstance(request, dict) or not isinstance(request.get("set"), dict):
                    raise ConfigError('config request must be {"set": {section: {name: '
                                      'value}}}')
                for section in request["set"]:
                    if section not in RUNTIME_SECTIONS:
                        raise ConfigError(f"[{section}]: cannot change at run time "
                                          f"(only {', '.join(RUNTIME_SECTIONS)}); restart")
                self.cfg = from_dict(request["set"], base=self.cfg)
                if "uncertainty" in request["set"]:
                    if isinstance(self.uncertainty, ConfiguredUncertainty):
                        self.uncertainty = ConfiguredUncertainty(self.cfg.uncertainty_model())
                    elif self.estimator is not None:
                        self.estimator.prior = self.cfg.uncertainty_model()
                message = "configuration updated"
                self._event(f"configuration updated: {json.dumps(request['set'])}")
            except (ConfigError, msgs.Rejected) as exc:
                ok, message = False, str(exc)
                self._error("config", message)
        payload = msgs.dumps(msgs.envelope(msgs.CONFIG, ok=ok, message=message,
                                           config=self.cfg.to_dict()))
        _reply(query, payload)

    def _on_estimator(self, query: zenoh.Query) -> None:
        """Read (no payload), or ``{"reset": true}``, ``{"freeze": bool}``,
        ``{"set": {"m": .., "b": ..}}``."""
        ok, message = True, ""
        est = self.estimator
        try:
            if est is None:
                raise ValueError("the in-flight estimator is disabled ([estimator] enabled)")
            raw = query.payload.to_bytes() if query.payload is not None else b""
            if raw:
                request = msgs.decode(raw, "estimator")
                if not isinstance(request, dict):
                    raise ValueError("request must be a JSON object")
                if request.get("reset"):
                    est.reset()
                    message = "estimate reset to the configured model"
                if "freeze" in request:
                    est.freeze(bool(request["freeze"]))
                    message = f"estimator {'frozen' if request['freeze'] else 'learning'}"
                if "set" in request:
                    values = request["set"]
                    est.set(float(values["m"]), float(values["b"]))
                    message = f"estimate set to m={values['m']}, b={values['b']}"
                est.save()
                self._event(message)
        except (ValueError, KeyError, TypeError, msgs.Rejected, OSError) as exc:
            ok, message = False, str(exc)
            self._error("estimator", message)
        body = est.describe() if est is not None else None
        payload = msgs.dumps(msgs.envelope("rota/estimator", ok=ok, message=message,
                                           estimator=body))
        _reply(query, payload)

    async def _learn(self) -> None:
        """5 Hz: feed the estimator while flying in offboard; save every 10 s."""
        k = 0
        while True:
            await asyncio.sleep(0.2)
            k += 1
            est, tel = self.estimator, self.autopilot.telemetry
            if est is None:
                return
            if k % 50 == 0 and est.samples:
                with contextlib.suppress(OSError):
                    est.save()
            if not (self.streaming and self.state == State.OFFBOARD and tel.velocity is not None
                    and self.autopilot.link_ok(self.cfg.mavlink.link_timeout_s)):
                continue
            s_track = tracking_std(np.asarray(self.track_errors))
            s_px4 = (float(np.sqrt(np.mean(tel.position_std ** 2)))
                     if tel.position_std is not None else float("nan"))
            z = evidence(s_px4, s_track, est.settings.include_tracking)
            if np.isfinite(z):
                est.observe(float(np.linalg.norm(tel.velocity)), z)

    # =============================================================== commands
    def _require(self, *states: State) -> None:
        if self.state not in states:
            raise AutopilotError(f"not possible in state {self.state.value} (needs "
                                 f"{' or '.join(s.value for s in states)})")

    async def cmd_arm(self) -> str:
        self._require(State.READY)
        await self.autopilot.arm()
        return "armed"

    async def cmd_disarm(self) -> str:
        if self.autopilot.telemetry.landed_state != "ON_GROUND":
            raise AutopilotError("refusing to disarm: PX4 does not report the vehicle on the "
                                 f"ground (landed state {self.autopilot.telemetry.landed_state})")
        await self.autopilot.disarm()
        return "disarmed"

    async def cmd_takeoff(self) -> str:
        self._require(State.ARMED)
        await self.autopilot.takeoff(self.cfg.stream.takeoff_altitude_m)
        return f"taking off to {self.cfg.stream.takeoff_altitude_m} m"

    async def cmd_start(self) -> str:
        """Hold where the vehicle is, pre-stream, switch to offboard, then fly the
        newest trajectory (if any)."""
        self._require(State.AIRBORNE)
        pos = self.autopilot.telemetry.position
        if pos is None:
            raise AutopilotError("no position telemetry")
        self.source, self.next_plan = Hold(pos.copy(), "start"), None
        self.yaw_ned = self._vehicle_yaw()
        self.streaming, self.stream_started = True, time.monotonic()
        self.state = State.PRESTREAM
        await asyncio.sleep(self.cfg.stream.prestream_s)
        if self.state != State.PRESTREAM:
            raise AutopilotError(f"start interrupted ({self.state.value})")
        for attempt in range(3):  # PX4 may want a little more stream history
            try:
                await self.autopilot.start_offboard()
                break
            except AutopilotError:
                if attempt == 2 or self.state != State.PRESTREAM:
                    await self._stop_stream()
                    self.state = State.AIRBORNE
                    raise
                await asyncio.sleep(0.5)
        self._offboard_seen = False  # telemetry confirms the mode a moment later
        self.state = State.OFFBOARD
        if self.latest is not None:
            self.last_trajectory_time = time.monotonic()
            self._replan.set()
        return "offboard: holding" if self.latest is None else "offboard: flying"

    async def cmd_hold(self) -> str:
        self._require(State.OFFBOARD)
        self._brake("hold command")
        self.latest = None
        return "braking to a hold"

    async def cmd_abort(self) -> str:
        self.latest, self.next_plan = None, None
        if self.streaming:
            await self._stop_stream()
            await self.autopilot.hold()
            self.state = State.AIRBORNE
            return "offboard left: PX4 Hold"
        return "nothing to abort"

    async def cmd_land(self) -> str:
        self.latest, self.next_plan = None, None
        await self._stop_stream()
        await self.autopilot.land()
        self.state = State.LANDING
        return "landing"

    async def _stop_stream(self) -> None:
        """Stop our stream and MAVSDK's own re-sending of the last setpoint."""
        self.streaming = False
        self.source, self.next_plan = None, None
        await self.autopilot.stop_stream()

    async def _auto_start(self) -> None:
        """Arm, take off and start, each step once the telemetry confirms the last."""
        self._auto_starting = True
        try:
            await self.cmd_arm()
            await self._wait_until(lambda: self.state == State.ARMED, 5.0, "armed")
            await self.cmd_takeoff()
            # AIRBORNE: in the air and PX4's takeoff finished (it switched to Hold)
            await self._wait_until(lambda: self.state == State.AIRBORNE, 30.0, "takeoff")
            await self.cmd_start()
        except AutopilotError as exc:
            self._error("auto-start", str(exc))
        finally:
            self._auto_starting = False

    async def _wait_until(self, predicate, timeout_s: float, what: str) -> None:  # noqa: ANN001
        end = time.monotonic() + timeout_s
        while not predicate():
            if time.monotonic() > end:
                raise AutopilotError(f"timed out waiting for {what} ({self.state.value})")
            await asyncio.sleep(0.05)

    # ========================================================= replanning
    def _commanded(self, now: float) -> Command:
        if self.source is None:
            pos = self.autopilot.telemetry.position
            return Command(np.zeros(3) if pos is None else pos.copy())
        return self.source.command(now)

    async def _replanner(self) -> None:
        """Re-time the newest trajectory, one at a time; older ones are superseded."""
        while True:
            await self._replan.wait()
            self._replan.clear()
            incoming = self.latest
            if incoming is None:
                continue
            try:
                await self._retime_and_stitch(incoming)
            except msgs.Rejected as exc:
                self._error("trajectory", str(exc))
            except TimeoutError as exc:
                self._error("retime", f"{incoming.id}: {exc}; keeping the current command")

    async def _retime_and_stitch(self, incoming: msgs.Incoming) -> None:
        """Replan in the worker: join the trajectory onto the commanded state at the
        predicted takeover time, re-time it; then schedule the takeover."""
        cfg = self.cfg
        flying = self.streaming and self.state == State.OFFBOARD
        t_take = time.monotonic() + self.solve_latency
        take = self._commanded(t_take) if flying else None
        job = ReplanJob(
            id=incoming.id, stamp=incoming.stamp, trajectory=incoming.trajectory,
            limits=cfg.rota_limits(), smoothness=cfg.limits.smoothness, dtau=cfg.limits.dtau,
            uncertainty=self.uncertainty.model(), chance=cfg.chance_params(),
            braking=cfg.braking_params(), stitch_tolerance=cfg.safety.stitch_tolerance_m,
            take_position=None if take is None else take.position,
            take_velocity=None if take is None else take.velocity)
        out = await self.retimer.replan(job, cfg.limits.max_solve_s)
        if out.rejected:
            raise msgs.Rejected(f"trajectory {incoming.id!r}: {out.rejected}")
        result, seconds = out.result, out.seconds
        self.solve_latency = 0.7 * self.solve_latency + 0.3 * (1.5 * seconds + 0.05)
        self.last_result_summary = {
            "id": incoming.id, "status": result.status, "message": result.message,
            "duration": round(result.duration, 3),
            "input_duration": round(result.trajectory.duration, 3),
            "solve_time": round(seconds, 4),
            "braking_zones": [[round(a, 3), round(b, 3)]
                              for a, b in result.extras.get("intervals", ())],
        }
        self._put_bytes("retimed", out.payload)
        for w in result.warnings:
            self._warn(f"{incoming.id}: {w}")
        if result.status == REJECTED:
            raise msgs.Rejected(f"trajectory {incoming.id!r}: {result.message}")
        if result.status == FALLBACK:
            self._warn(f"{incoming.id}: re-time failed ({result.message}); flying the "
                       f"uniformly slowed fallback")
        if incoming is not self.latest or not (self.streaming and self.state == State.OFFBOARD):
            return  # superseded, or not flying: the result was published, nothing to fly
        if take is None:  # offboard began while we solved: start from the hold
            t_take = time.monotonic()
        self.next_plan = Plan(incoming.id, result, max(t_take, time.monotonic()))

    def _take_over(self, now: float) -> None:
        """Swap in the next plan at its start time, carrying the position gap."""
        plan = self.next_plan
        self.next_plan = None
        old = self._commanded(now)
        new = plan.command(now)
        gap = old.position - new.position
        self.source = replace(plan, offset=gap,
                              blend_s=blend_time(float(np.linalg.norm(gap))))

    def _brake(self, reason: str) -> None:
        now = time.monotonic()
        self.next_plan = None
        decel = BRAKE_SHARE * min(self.cfg.limits.a_max)
        if isinstance(self.source, Plan):
            self.source = brake_along(self.source, now, decel, reason)
        elif isinstance(self.source, Brake):
            return
        else:
            self.source = Hold(self._commanded(now).position, reason)
        self._warn(f"braking to a hold: {reason}")

    # ========================================================= the stream
    async def _stream_loop(self) -> None:
        """Setpoints at ``rate_hz`` on absolute deadlines (no drift), while streaming."""
        period = 1.0 / self.cfg.stream.rate_hz
        loop = asyncio.get_running_loop()
        deadline = loop.time()
        while True:
            deadline += period
            delay = deadline - loop.time()
            if delay < -5 * period:  # fell far behind (suspended?): resynchronise
                deadline = loop.time()
            await asyncio.sleep(max(delay, 0.0))
            self.notifier.watchdog()
            if not self.streaming:
                continue
            now = time.monotonic()
            if self.next_plan is not None and now >= self.next_plan.t0:
                self._take_over(now)
            if isinstance(self.source, Plan | Brake) and self.source.finished(now):
                end = self.source.command(now).position
                # a finished brake keeps its reason (why the vehicle holds)
                reason = self.source.reason if isinstance(self.source, Brake) else \
                    "end of trajectory"
                self.source = Hold(end, reason)
                self._event(f"{reason}: holding at {msgs.vec(end, 2)}")
            cmd = self._commanded(now)
            if not (np.all(np.isfinite(cmd.position)) and np.all(np.isfinite(cmd.velocity))
                    and np.all(np.isfinite(cmd.acceleration))):
                self._error("stream", "non-finite setpoint computed: holding")
                self.source = Hold(self._last_sent.position, "non-finite setpoint")
                cmd = self.source.command(now)
            self._update_yaw(cmd)
            self.send_times.append(now)
            self.sent.append((now, cmd.position))
            self._last_sent = cmd
            try:
                await self.autopilot.send(cmd.position, cmd.velocity, cmd.acceleration,
                                          self.yaw_ned)
            except Exception as exc:  # noqa: BLE001
                log.warning("setpoint send failed: %s", exc)

    def _update_yaw(self, cmd: Command) -> None:
        if self.cfg.stream.yaw == "path" and np.linalg.norm(cmd.velocity[:2]) > 0.3:
            self.yaw_ned = heading_ned_deg(cmd.velocity)

    def _vehicle_yaw(self) -> float:
        """The vehicle's heading now (NED yaw, deg): the yaw to hold at first."""
        yaw = self.autopilot.telemetry.yaw_ned_deg
        return self.yaw_ned if yaw is None or not math.isfinite(yaw) else yaw

    # ====================================================== monitoring
    async def _connection(self) -> None:
        backoff = 1.0
        while True:
            try:
                await self.autopilot.connect(self.cfg.mavlink.connect_timeout_s)
                self._event(f"autopilot connected on {self.cfg.mavlink.url}")
                return
            except Exception as exc:  # noqa: BLE001 - keep retrying, report
                self._error("mavlink", f"connect failed: {exc}; retrying")
                await self.autopilot.close()
                await asyncio.sleep(backoff)
                backoff = min(backoff * 2, 10.0)

    async def _monitor(self) -> None:
        """10 Hz: link, health, PX4 mode, tracking error, planner silence."""
        while True:
            await asyncio.sleep(0.1)
            self._check()

    def _check(self) -> None:
        cfg, tel = self.cfg, self.autopilot.telemetry
        if self.state in (State.CONNECTING, State.STOPPING) and tel.position_time == 0.0:
            return
        if not self.autopilot.link_ok(cfg.mavlink.link_timeout_s):
            if self.state != State.LINK_LOST:
                if self.streaming:
                    self._error("mavlink", "link lost: setpoint stream stopped, trajectory "
                                "dropped; a new 'start' is needed after reconnection")
                else:
                    self._error("mavlink", "link lost")
                self.latest = None
                self._spawn(self._stop_stream())
                self.state = State.LINK_LOST
            return
        if self.state in (State.PRESTREAM, State.OFFBOARD):
            if self.state == State.OFFBOARD and tel.flight_mode == "OFFBOARD":
                self._offboard_seen = True
            if (self.state == State.OFFBOARD and tel.flight_mode != "OFFBOARD"
                    and self._offboard_seen):
                self.latest = None
                self._spawn(self._stop_stream())
                self._error("px4", f"PX4 left offboard (now {tel.flight_mode}); stream "
                            "stopped, a new 'start' is needed")
                self.state = State.AIRBORNE
                return
            if self.state == State.OFFBOARD and tel.position is not None:
                error = tel.position - self._commanded(time.monotonic()).position
                self.track_errors.append(error)
                err = float(np.linalg.norm(error))
                if err > cfg.safety.max_tracking_error_m and not isinstance(self.source,
                                                                            Hold | Brake):
                    self._brake(f"tracking error {err:.2f} m over "
                                f"{cfg.safety.max_tracking_error_m} m")
            silence = time.monotonic() - self.last_trajectory_time
            if (cfg.safety.planner_timeout_s > 0 and isinstance(self.source, Plan)
                    and silence > cfg.safety.planner_timeout_s):
                self._brake(f"no trajectory from the planner for {silence:.1f} s")
            return
        if self.state in (State.LANDING,) and tel.landed_state == "ON_GROUND" and not tel.armed:
            self.state = State.READY
        new = self._derive_state()
        if new != self.state and self.state not in (State.LANDING,):
            self.state = new
        elif self.state == State.LANDING and not tel.armed:
            self.state = new

    def _derive_state(self) -> State:
        tel = self.autopilot.telemetry
        if not tel.armed:
            return State.READY if tel.healthy else State.NOT_READY
        if tel.landed_state in ("IN_AIR",) and tel.flight_mode not in ("TAKEOFF",):
            return State.AIRBORNE
        if tel.landed_state == "LANDING":
            return State.LANDING
        return State.ARMED

    # ======================================================= publishing
    async def _publisher(self) -> None:
        cfg = self.cfg
        tel_period = 1.0 / cfg.zenoh.telemetry_rate_hz
        status_every = max(1, round(cfg.zenoh.telemetry_rate_hz / cfg.zenoh.status_rate_hz))
        k = 0
        while True:
            await asyncio.sleep(tel_period)
            self._publish_telemetry()
            k += 1
            if k % status_every == 0:
                self._publish_status()

    def status(self) -> dict[str, Any]:
        now = time.monotonic()
        tel = self.autopilot.telemetry
        src = self.source
        plan = src if isinstance(src, Plan) else None
        return msgs.envelope(
            msgs.STATUS, vehicle=self.cfg.service.vehicle_id, state=self.state.value,
            link=self.autopilot.link_ok(self.cfg.mavlink.link_timeout_s),
            armed=tel.armed, flight_mode=tel.flight_mode, landed_state=tel.landed_state,
            healthy=tel.healthy, streaming=self.streaming,
            command=("plan" if plan else "brake" if isinstance(src, Brake)
                     else "hold" if isinstance(src, Hold) else None),
            hold_reason=getattr(src, "reason", None) if not plan else None,
            trajectory_id=plan.id if plan else None,
            progress=round(plan.progress(now), 4) if plan else None,
            remaining_s=round(max(plan.end_time - now, 0.0), 3) if plan else None,
            last_retime=self.last_result_summary or None,
            map_voxels=None if self.map is None else len(self.map),
            uncertainty=self.uncertainty.describe(),
            setpoint_jitter_p99_ms=self.jitter_p99_ms(),
            last_error=self.last_error, warnings=list(self.warnings))

    def _publish_status(self) -> None:
        status = self.status()
        self._put("status", status)
        self.notifier.notify(f"STATUS={status['state']}"
                             + (f" {status['trajectory_id']} {status['progress']:.0%}"
                                if status["trajectory_id"] else ""))

    def _publish_telemetry(self) -> None:
        tel = self.autopilot.telemetry
        cmd = self._commanded(time.monotonic()) if self.streaming else None
        err = (float(np.linalg.norm(tel.position - cmd.position))
               if cmd is not None and tel.position is not None else None)
        self._put("telemetry", msgs.envelope(
            msgs.TELEMETRY, frame="ENU", state=self.state.value,
            position=msgs.vec(tel.position), velocity=msgs.vec(tel.velocity),
            setpoint=None if cmd is None else {
                "position": msgs.vec(cmd.position), "velocity": msgs.vec(cmd.velocity),
                "acceleration": msgs.vec(cmd.acceleration), "yaw_ned_deg": self.yaw_ned},
            tracking_error=None if err is None else round(err, 4)))

    def jitter_p99_ms(self) -> float | None:
        """99th percentile of |period - nominal| of the setpoint stream (ms)."""
        t = np.asarray(self.send_times)
        if len(t) < 20:
            return None
        dt = np.diff(t)
        dt = dt[dt < 0.5]  # gaps between streaming sessions are not jitter
        if not len(dt):
            return None
        return round(float(np.percentile(np.abs(dt - 1.0 / self.cfg.stream.rate_hz), 99))
                     * 1e3, 3)

    # ============================================================ reporting
    def _error(self, source: str, message: str) -> None:
        log.error("%s: %s", source, message)
        self.last_error = {"stamp": time.time(), "source": source, "message": message}
        if self.session is not None and self._pub:
            self._publish_status()

    def _warn(self, message: str) -> None:
        log.warning("%s", message)
        self.warnings.append(message)

    def _event(self, message: str) -> None:
        log.info("%s", message)


def _reply(query: zenoh.Query, payload: bytes) -> None:
    """Answer a Zenoh query with JSON and finalise it."""
    try:
        query.reply(query.key_expr, payload, encoding=zenoh.Encoding.APPLICATION_JSON)
    finally:
        query.drop()
