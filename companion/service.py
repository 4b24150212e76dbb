"""The flight service: Zenoh in, ROTA, MAVSDK offboard out.

Thin glue over the modules beside this one:

* :mod:`companion.network.inputs`: trajectories, maps, commands and configuration from Zenoh,
  with byte caps and rate limits;
* :mod:`companion.network.decoder`: their decoding and validation (:mod:`companion.messages`)
  in worker processes, never on the event loop;
* :mod:`companion.flight.replanner` and :mod:`companion.flight.retimer`: stitching and ROTA in a
  worker process;
* :mod:`companion.flight.stream`: the setpoint stream to PX4 (:mod:`companion.flight.autopilot`);
* :mod:`companion.flight.commander`: commands and the state, from PX4's telemetry;
* :mod:`companion.supervisor`: the tasks and worker processes, restarted when one
  dies; systemd;
* :mod:`companion.status`: status and telemetry out.

Protocol: ``docs/protocol.md``; behaviour: ``docs/service.md``.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import gc
import itertools
import logging
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from companion import memory
from companion import messages as msgs
from companion.flight.autopilot import Autopilot, AutopilotError
from companion.flight.commander import Commander, State
from companion.flight.plan import Brake, Hold, Plan
from companion.flight.replanner import Replanner
from companion.flight.retimer import Retimer
from companion.flight.stream import SetpointStream
from companion.network.decoder import Decoder
from companion.network.inputs import Handlers, Inputs
from companion.network.outbox import Outbox
from companion.network.security import check_exposure, zenoh_config
from companion.recording.record_process import recorder_for
from companion.ros2.link import Ros2Link
from companion.settings.config import Config, ConfigError, short
from companion.settings.reconfigure import Reconfigure
from companion.status import Publisher, Reporter, Retimed
from companion.supervisor import Notifier, Supervisor
from companion.uncertainty.estimator import UncertaintyEstimator
from companion.uncertainty.learning import Learning
from companion.uncertainty.source import ConfiguredUncertainty, UncertaintySource
from companion.worker import Worker
from rota.voxelmap import VoxelMap

log = logging.getLogger("rota.companion")

def _estimator(cfg: Config) -> UncertaintyEstimator | None:
    if not cfg.estimator.enabled:
        return None
    path = Path(cfg.service.state_dir) / f"uncertainty-{cfg.service.vehicle_id}.json"
    try:
        return UncertaintyEstimator(cfg.uncertainty_model(), cfg.estimator, path,
                                    v_check=cfg.limits.v_max)
    except ValueError as exc:  # a corrupt file: start from the prior, keep the file
        log.error("%s; starting from the configured model", exc)
        path.rename(path.with_suffix(".corrupt"))
        return UncertaintyEstimator(cfg.uncertainty_model(), cfg.estimator, path,
                                    v_check=cfg.limits.v_max)


class Service:
    """The running service. ``await Service(cfg).run(stop)`` until ``stop`` is set."""

    def __init__(self, cfg: Config, uncertainty: UncertaintySource | None = None) -> None:
        self.cfg = cfg
        self.estimator = _estimator(cfg) if uncertainty is None else None
        self.uncertainty = (uncertainty or self.estimator
                            or ConfiguredUncertainty(cfg.uncertainty_model()))
        self.report = Reporter()
        self.recorder = recorder_for(cfg.record, cfg.service.state_dir, cfg.service.vehicle_id,
                                     lambda message: self.report.error("record", message))
        self.autopilot = Autopilot(cfg.mavlink.url,
                                   on_error=lambda text: self.report.error("mavlink", text),
                                   on_status_text=self._px4_text)
        self.retimer = Retimer()
        self.retimed = Retimed(self.recorder)  # where re-timed plans go
        self.decoder = Decoder(lambda: self.cfg)
        # (the stream, the replanner and the commander answer each other: the two calls
        # back into the commander, built last, are bound here, where all three are known)
        self.stream = SetpointStream(lambda: self.cfg, self.autopilot, self.report,
                                     record=self.recorder.put,
                                     on_halt=lambda why, ended: self.commander.halted(why, ended))
        self.replanner = Replanner(lambda: self.cfg, self.retimer, self.stream,
                                   lambda: self.uncertainty, self.report, self.retimed.put,
                                   flying=lambda: self.commander.flying())
        self.commander = Commander(lambda: self.cfg, self.autopilot, self.stream,
                                   self.replanner, self.report)
        self.learning = Learning(self.estimator, self.autopilot, self.commander.flying,
                                 lambda: list(self.commander.track_errors),
                                 lambda: self.cfg.mavlink.link_timeout_s, self.report,
                                 self.stream.beat)
        self.reconfigure = Reconfigure(cfg, lambda: self.cfg, self._use_config, self.report)
        self.exposed: list[str] = []  # what [zenoh] insecure lets through
        self.supervisor = Supervisor(self.report)
        self.notifier = Notifier(self.supervisor.all_alive)
        self.map: VoxelMap | None = None
        self.session: zenoh.Session | None = None
        self.outbox: Outbox | None = None
        self.publisher: Publisher | None = None
        self.inputs: Inputs | None = None
        self.ros2: Ros2Link | None = None

    # what the tests and the demo read
    @property
    def state(self) -> State:
        return self.commander.state

    @property
    def streaming(self) -> bool:
        return self.stream.streaming

    @property
    def sent(self):  # noqa: ANN201
        return self.stream.sent

    def jitter_p99_ms(self) -> float | None:
        return self.stream.jitter_p99_ms()

    # ===================================================================== run
    async def run(self, stop: asyncio.Event) -> None:
        # MAVSDK, Zenoh and the worker pool run Python threads too; hand the GIL
        # over every 1 ms (default 5 ms) so the setpoint loop is not kept waiting.
        sys.setswitchinterval(0.001)
        memory.fix_mmap_threshold()  # (a large input's memory goes back when it is freed)
        z = zenoh_config(self.cfg)
        self.exposed = check_exposure(self.cfg, z)  # refuses an exposed service
        for problem in self.exposed:
            self.report.warn(f"INSECURE: {problem}")
        self._set_priority()  # before any thread starts: threads inherit it
        # The record is queued from here on but its file opens only once Zenoh is
        # open and the workers are warm: a start that fails leaves no empty record.
        self._log_to_record = self.recorder.log_handler()
        logging.getLogger("rota").addHandler(self._log_to_record)
        self.recorder.put("config", self.cfg.to_dict())
        self._open_zenoh(z)
        starting = asyncio.create_task(self.notifier.starting(
            "compiling or loading the solver"))
        try:
            warm, _ = await asyncio.gather(self.retimer.start(), self.decoder.start())
        finally:
            starting.cancel()
        log.info("re-time worker warm (solver compiled or loaded in %.1f s)", warm)
        self.recorder.start()
        # What start-up made (modules, configuration, Zenoh and MAVSDK objects) lives
        # as long as the service: out of the garbage collector's sight, a full
        # collection walks only what came since (in a full collection every thread
        # waits, the setpoint stream too).
        gc.collect()
        gc.freeze()
        sup, z = self.supervisor, self.cfg.zenoh
        sup.start("connection", self._connection, forever=False)
        sup.start("stream", lambda: self.stream.run(self.notifier.watchdog))
        sup.start("monitor", self.commander.monitor)
        sup.start("replan", self.replanner.run)
        sup.start("publish", lambda: self.publisher.run(z.telemetry_rate_hz, z.status_rate_hz,
                                                        self.stream.beat))
        sup.start("estimator", self.learning.run, forever=False)
        for kind in self.inputs.kinds():
            sup.start(f"input-{kind}", lambda kind=kind: self.inputs.consume(kind))
        sup.start("input-drops", self.inputs.report_drops)
        sup.start("workers", lambda: sup.watch([self.retimer.worker, self.decoder.worker],
                                               self._respawned))
        self.notifier.notify("READY=1")
        log.info("service up: vehicle %s, MAVLink %s, Zenoh keys %s/**",
                 self.cfg.service.vehicle_id, self.cfg.mavlink.url, self.cfg.key())
        try:
            await stop.wait()
        finally:
            await self._shutdown()

    def _set_priority(self) -> None:
        """Run at ``[service] nice`` (a companion computer runs other work too; the
        setpoint stream goes first). Without the right to, say so and go on."""
        want = self.cfg.service.nice
        try:
            if os.getpriority(os.PRIO_PROCESS, 0) > want:
                os.setpriority(os.PRIO_PROCESS, 0, want)
        except OSError as exc:
            self.report.warn(f"running at normal CPU priority: cannot set nice {want} "
                             f"({exc.strerror}; grant CAP_SYS_NICE, docs/deploy.md)")

    async def _shutdown(self) -> None:
        """SIGTERM/SIGINT: in flight, hand the vehicle to PX4's Hold, report, exit."""
        was = self.commander.state
        self.commander.state = State.STOPPING
        self.notifier.notify("STOPPING=1")
        if self.stream.streaming or was in (State.OFFBOARD, State.PRESTREAM):
            try:
                await asyncio.wait_for(self.autopilot.hold(), 3.0)
                self.report.event("service stopping: vehicle handed to PX4 Hold")
            except (AutopilotError, TimeoutError) as exc:
                self.report.error("shutdown", f"could not switch PX4 to Hold: {exc}")
        self.stream.stop()
        with contextlib.suppress(Exception):
            self.publisher.publish_status()
        await self.supervisor.close()
        await self.autopilot.close()
        self.retimer.close()
        self.decoder.close()
        self.learning.save()
        if self.outbox is not None:  # what is queued goes out before the undeclaring
            self.outbox.close()
        if self.inputs is not None:
            self.inputs.close()
        if self.ros2 is not None:
            self.ros2.close()
        if self.publisher is not None:
            self.publisher.close()
        if self.session is not None:
            self.session.close()
        gc.unfreeze()
        log.info("service stopped")
        logging.getLogger("rota").removeHandler(self._log_to_record)
        self.recorder.close()

    async def _respawned(self, worker: Worker) -> None:
        """A worker process was restarted after dying: bring it up to date."""
        if worker is self.retimer.worker:
            await self.retimer.start()  # with the current map
            if self.replanner.latest is not None:
                self.replanner.kick()
        else:
            await self.decoder.start()

    def _px4_text(self, severity: str, text: str) -> None:
        """PX4's STATUSTEXT, to the log and the status channel."""
        if severity in ("emergency", "alert", "critical", "error"):
            self.report.error("px4", f"[{severity}] {text}")
        else:
            self.report.event(f"[{severity}] {text}", source="px4")

    async def _connection(self) -> None:
        backoff = 1.0
        while True:
            try:
                await self.autopilot.connect(self.cfg.mavlink.connect_timeout_s)
                self.report.event(f"autopilot connected on {self.cfg.mavlink.url}")
                return
            except Exception as exc:  # noqa: BLE001 - keep retrying, report
                self.report.error("mavlink", f"connect failed: {exc}; retrying")
                await self.autopilot.close()
                await asyncio.sleep(backoff)
                backoff = min(backoff * 2, 10.0)

    # =================================================================== zenoh
    def _open_zenoh(self, z: zenoh.Config) -> None:
        self.session = s = zenoh.open(z)
        self.outbox = Outbox()
        k = self.cfg.key
        json_enc = zenoh.Encoding.APPLICATION_JSON
        pubs = {name: s.declare_publisher(k(name), encoding=json_enc)
                for name in ("status", "telemetry", "retimed")}
        # ``rota-gs list`` finds the vehicles alive by these tokens
        self._alive = s.liveliness().declare_token(k("alive"))
        self.publisher = Publisher(pubs, self._recorded("status", self.status),
                                   self._recorded("telemetry", self.telemetry),
                                   self._on_status, self.outbox.send,
                                   source=self._source_info(s))
        self.inputs = Inputs(s, lambda: self.cfg, asyncio.get_running_loop(), Handlers(
            trajectory=self._on_trajectory, map=self._on_map, command=self._on_command,
            config=self._on_config, estimator=self._on_estimator), self.decoder, self.report,
            self.outbox.send, record=self._record_input)
        if self.cfg.ros2.enabled:
            self.ros2 = Ros2Link(s, self.cfg.ros2, self.inputs.put_ros2, self.outbox.send,
                                 warn=self.report.warn)
        self.retimed.open(self.publisher, self.ros2)

    @staticmethod
    def _source_info(s: zenoh.Session):  # noqa: ANN205
        """Each output names this session as its source (a ground station ignores
        status and telemetry from any other session: docs/security.md)."""
        sn = itertools.count(1)
        return lambda: zenoh.SourceInfo(s.id, next(sn))

    def _record_input(self, channel: str, payload: Any) -> None:
        """Puts as received. A ROS message (CDR: its encapsulation header begins with a
        zero byte, which JSON never does) goes to the ``ros2`` channel in base64, so the
        JSON channels stay JSON."""
        if isinstance(payload, bytes) and payload[:1] == b"\x00":
            payload, channel = {"input": channel, "cdr_base64":
                                base64.b64encode(payload).decode()}, "ros2"
        self.recorder.put(channel, payload)

    def _recorded(self, name: str, make):  # noqa: ANN001, ANN202
        def made() -> dict[str, Any]:
            obj = make()
            self.recorder.put(name, obj)
            return obj

        return made

    def _on_trajectory(self, incoming: msgs.Incoming) -> None:
        self.replanner.offer(incoming)  # (a refusal raises: the inputs report it, with the sender)
        if self.cfg.stream.auto_start and self.commander.state == State.READY:
            self.commander.spawn(self.commander.auto_start())

    def _on_map(self, vmap: VoxelMap) -> None:
        self.commander.spawn(self._use_map(vmap))

    async def _use_map(self, vmap: VoxelMap) -> None:
        await self.retimer.set_map(vmap)
        self.map = vmap
        self.recorder.show("map", vmap)  # the map in use, drawn for Foxglove
        log.info("map: %d occupied voxels at %.2f m", len(vmap), vmap.resolution)

    async def _on_command(self, name: str, request: Any, peer: str) -> bytes:  # noqa: ARG002
        name = short(name)  # (a 10,000-character name is not copied into status and log)
        try:
            message = await self.commander.run(name)
            answer = msgs.reply(name, True, message or "", state=self.commander.state.value)
        except AutopilotError as exc:
            self.report.error(f"command {name}", str(exc))
            answer = msgs.reply(name, False, str(exc), state=self.commander.state.value)
        self.recorder.put("command", answer)
        return answer

    async def _on_config(self, name: str, request: Any, peer: str) -> bytes:  # noqa: ARG002
        ok, message = True, ""
        if request is not None:
            try:
                message = self.reconfigure.apply(request, peer)
            except ConfigError as exc:
                ok, message = False, str(exc)
                self.report.error("config", message)
        return msgs.dumps(msgs.envelope(msgs.CONFIG, ok=ok, message=message,
                                        config=self.cfg.to_dict(),
                                        envelope=self.reconfigure.file_cfg.to_dict()))

    def _use_config(self, new: Config) -> None:
        """A run-time configuration change (inside the file's envelope)."""
        uncertainty_changed = new.uncertainty != self.cfg.uncertainty
        self.cfg = new
        if uncertainty_changed:
            if isinstance(self.uncertainty, ConfiguredUncertainty):
                self.uncertainty = ConfiguredUncertainty(self.cfg.uncertainty_model())
            elif self.estimator is not None:
                self.estimator.prior = self.cfg.uncertainty_model()

    async def _on_estimator(self, name: str, request: Any, peer: str) -> bytes:  # noqa: ARG002
        ok, message, body = self.learning.answer(request, peer, self.reconfigure.file_cfg)
        return msgs.dumps(msgs.envelope("rota/estimator", ok=ok, message=message,
                                        estimator=body))

    # ================================================================= status
    def status(self) -> dict[str, Any]:
        now = time.monotonic()
        said = self.report.snapshot()
        tel = self.autopilot.telemetry
        src = self.stream.source
        plan = src if isinstance(src, Plan) else None
        return msgs.envelope(
            msgs.STATUS, vehicle=self.cfg.service.vehicle_id,
            state=self.commander.state.value,
            link=self.autopilot.link_ok(self.cfg.mavlink.link_timeout_s),
            armed=tel.armed, flight_mode=tel.flight_mode, landed_state=tel.landed_state,
            healthy=tel.healthy, streaming=self.stream.streaming,
            command=("plan" if plan else "brake" if isinstance(src, Brake)
                     else "hold" if isinstance(src, Hold) else None),
            hold_reason=getattr(src, "reason", None) if not plan else None,
            trajectory_id=plan.id if plan else None,
            progress=round(plan.progress(now), 4) if plan else None,
            remaining_s=round(max(plan.end_time - now, 0.0), 3) if plan else None,
            last_retime=self.replanner.last_result_summary or None,
            retiming=self.replanner.retiming,
            map_voxels=None if self.map is None else len(self.map),
            limits={"v_max": self.cfg.limits.v_max, "a_max": list(self.cfg.limits.a_max)},
            uncertainty=self.uncertainty.describe(),
            setpoint_jitter_p99_ms=self.stream.jitter_p99_ms(),
            reaction_ms=self.stream.reactions.summary(),
            halted=self.stream.halted,
            insecure=self.exposed or None,
            last_error=said["last_error"],
            warnings=[f"INSECURE: {p}" for p in self.exposed] + said["warnings"],
            events=said["events"], counts=said["counts"],
            supervision={"task_restarts": dict(self.supervisor.restarts),
                         "worker_restarts": {w.name: w.restarts for w in (
                             self.retimer.worker, self.decoder.worker)},
                         "worker_pids": {w.name: w.pids() for w in (
                             self.retimer.worker, self.decoder.worker)},
                         "stalls": self.stream.stalls,
                         "longest_stall_s": round(self.stream.longest_stall_s, 3),
                         "dropped_inputs": dict(self.inputs.dropped) if self.inputs else {}})

    def _on_status(self, status: dict[str, Any]) -> None:
        self._notify_status(status)
        if self.ros2 is not None:
            self.ros2.publish_status(status)

    def _notify_status(self, status: dict[str, Any]) -> None:
        self.notifier.notify(f"STATUS={status['state']}"
                             + (f" {status['trajectory_id']} {status['progress']:.0%}"
                                if status["trajectory_id"] else ""))

    def telemetry(self) -> dict[str, Any]:
        tel = self.autopilot.telemetry
        cmd = self.stream.last_sent if self.stream.streaming else None
        error = (self.stream.tracking_error(tel.position, tel.position_time)
                 if cmd is not None and tel.position is not None else None)
        err = None if error is None else float(np.linalg.norm(error))
        return msgs.envelope(
            msgs.TELEMETRY, frame="ENU", state=self.commander.state.value,
            position=msgs.vec(tel.position), velocity=msgs.vec(tel.velocity),
            setpoint=None if cmd is None else {
                "position": msgs.vec(cmd.position), "velocity": msgs.vec(cmd.velocity),
                "acceleration": msgs.vec(cmd.acceleration),
                "yaw_ned_deg": self.stream.yaw_ned},
            tracking_error=None if err is None else round(err, 4))
