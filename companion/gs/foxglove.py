"""Foxglove for the ground station: the vehicle's flight served live over Foxglove's
WebSocket protocol (``rota-gs foxglove``), the layout file that arranges it
(``docs/foxglove/layout.json``), and a picture of a record's Foxglove channels drawn
with matplotlib (``rota-gs foxglove --render``), for where Foxglove cannot run.

The live server is a Zenoh client of the service like every ``rota-gs`` command; it
turns what the service publishes (status, telemetry, re-timed results, the map)
into the same topics as the flight record (:mod:`companion.recording.foxglove`) and serves
them on ``127.0.0.1:8765`` by default (this machine only: the protocol has no
authentication). Foxglove: *Open connection*, *Foxglove WebSocket*,
``ws://127.0.0.1:8765``.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import foxglove
from foxglove import layouts as fl

from companion.gs.client import GroundStation, GroundStationError
from companion.recording.foxglove import (
    BODY_FRAME,
    LATCHED,
    MAP_FRAME,
    TOPICS,
    Out,
    Scene,
    schema_of,
)

log = logging.getLogger("rota.gs.foxglove")

DEFAULT_PORT = 8765
#: How often (s) the live view asks again for a configuration the service did not give.
CONFIG_RETRY_S = 5.0
#: A status event's level as a log level (an audit is a change made at run time)
EVENT_LEVELS = {"error": "ERROR", "warning": "WARNING", "audit": "WARNING", "event": "INFO"}


class LiveView:
    """A Foxglove WebSocket server showing one vehicle. Messages arrive on Zenoh's
    threads and are turned into Foxglove's in one worker thread (a 1 MB map takes
    tens of milliseconds), then logged to the server's channels."""

    def __init__(self, gs: GroundStation, host: str = "127.0.0.1", port: int = DEFAULT_PORT,
                 name: str | None = None) -> None:
        self.gs = gs
        self.scene = Scene()
        self.context = foxglove.Context()
        self._channels: dict[str, foxglove.Channel] = {}
        self._last: dict[str, Out] = {}
        self._q: queue.Queue[tuple[str, Any, float] | None] = queue.Queue(maxsize=2000)
        self.dropped = 0
        # every channel before any client: advertised to each on connecting
        for topic, kind in TOPICS.items():
            s = schema_of(kind)
            self._channels[topic] = foxglove.Channel(
                topic, schema=foxglove.Schema(name=s.name, encoding=s.encoding, data=s.data),
                message_encoding=s.message_encoding, context=self.context)
        self._seq = 0  # the newest status event shown (the service numbers them)
        self.server = foxglove.start_server(name=name or f"rota {gs.vehicle}", host=host,
                                            port=port, context=self.context,
                                            server_listener=_Listener(self._resend))
        self._worker = threading.Thread(target=self._run, name="foxglove-live", daemon=True)
        self._worker.start()
        #: the service's configuration as last read (None: not yet); its v_max follows the
        #: limit in force that every status carries (a run-time tightening)
        self.config: dict[str, Any] | None = None
        self._asked = time.monotonic()
        self._fetch_config()
        gs.on_message = self._on_message
        self._map_sub = gs.session.declare_subscriber(gs.key("map"), self._on_map)

    @property
    def port(self) -> int:
        return self.server.port

    def put(self, channel: str, payload: Any, stamp: float) -> None:
        """Queue one of the service's messages; never blocks (a full queue drops)."""
        try:
            self._q.put_nowait((channel, payload, stamp))
        except queue.Full:
            self.dropped += 1

    def _on_message(self, name: str, obj: dict[str, Any]) -> None:
        now = time.time()
        if name == "telemetry" and obj.get("setpoint"):
            sp = obj["setpoint"]
            status = self.gs.status
            self.put("setpoint", {"p": sp.get("position"), "v": sp.get("velocity"),
                                  "a": sp.get("acceleration"), "yaw": sp.get("yaw_ned_deg"),
                                  "source": status.get("trajectory_id")
                                  or status.get("command") or ""}, now)
        if name in ("telemetry", "retimed"):
            self.put(name, obj, now)
        if name == "status":
            self._events(obj)
            self._follow_limits(obj)

    def _fetch_config(self) -> None:
        """Read the service's configuration (at start, and again while it has not
        answered: a service still starting may not answer in time)."""
        try:
            config = self.gs.config()
        except GroundStationError as exc:
            log.warning("no configuration from the service yet (%s): no v_max on the plots "
                        "until it answers", exc)
            return
        self.config = config
        self.put("config", config, time.time())

    def _follow_limits(self, status: dict[str, Any]) -> None:
        """The configuration once more if it is missing (every ``CONFIG_RETRY_S``), and
        the speed limit in force from the status when it changed."""
        if self.config is None:
            if time.monotonic() - self._asked >= CONFIG_RETRY_S:
                self._asked = time.monotonic()  # (not on Zenoh's thread: a query waits)
                threading.Thread(target=self._fetch_config, daemon=True).start()
            return
        v_max = (status.get("limits") or {}).get("v_max")
        cfg = self.config.get("config", self.config)
        limits = cfg.setdefault("limits", {})
        if isinstance(v_max, int | float) and v_max != limits.get("v_max"):
            limits["v_max"] = v_max
            self.put("config", self.config, time.time())

    def _events(self, status: dict[str, Any]) -> None:
        """The status's events not shown yet, to ``/foxglove/log`` as the record has the
        service's log (a restarted service numbers from 1 again: shown from there)."""
        events = [e for e in status.get("events") or () if isinstance(e, dict)
                  and isinstance(e.get("seq"), int)]
        if events and events[-1]["seq"] < self._seq:
            self._seq = 0
        for e in events:
            if e["seq"] > self._seq:
                self._seq = e["seq"]
                level = EVENT_LEVELS.get(str(e.get("level")), "INFO")
                self.put("log", {"level": level, "message": str(e.get("message", "")),
                                 "logger": f"rota.companion ({e.get('source', '')})"},
                         float(e.get("stamp") or time.time()))

    def _on_map(self, sample: Any) -> None:
        self.put("map", sample.payload.to_bytes(), time.time())

    def _run(self) -> None:
        while (item := self._q.get()) is not None:
            channel, payload, stamp = item
            try:
                for out in self.scene.translate(channel, payload, stamp):
                    self._log(out, stamp)
            except Exception as exc:  # noqa: BLE001 - one bad message must not end the view
                log.warning("cannot show a %s message: %s: %s", channel, type(exc).__name__,
                            exc)

    def _log(self, out: Out, stamp: float) -> None:
        ch = self._channels[out.topic]
        if out.topic in LATCHED:
            self._last[out.topic] = out
        ch.log(out.data, log_time=int(stamp * 1e9))

    def _resend(self, topic: str) -> None:
        """A client subscribed: send it the latched topic's last message again."""
        out = self._last.get(topic)
        if out is not None:
            self._channels[topic].log(out.data, log_time=time.time_ns())

    def close(self) -> None:
        self.gs.on_message = None
        self._map_sub.undeclare()
        self._q.put(None)
        self._worker.join(5)
        self.server.stop()


class _Listener(foxglove.ServerListener):
    """Foxglove's server callbacks (on its own threads): a new subscription to a
    latched topic gets its last message again."""

    def __init__(self, resend: Callable[[str], None]) -> None:
        self._resend = resend

    def on_subscribe(self, client: Any, channel: Any) -> None:  # noqa: ARG002
        if channel.topic in LATCHED:
            threading.Thread(target=self._resend, args=(channel.topic,), daemon=True).start()


def serve(make_station: Callable[[str], GroundStation], vehicle: str, host: str,
          port: int) -> None:
    """``rota-gs foxglove``: serve until Ctrl-C."""
    gs = make_station(vehicle)
    view = LiveView(gs, host, port)
    print(f"Foxglove WebSocket server on ws://{host}:{view.port} for vehicle {vehicle} "
          "(Foxglove: Open connection, Foxglove WebSocket; layout: docs/foxglove/layout.json)."
          " Ctrl-C ends.", flush=True)
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        view.close()
        gs.close()


# ------------------------------------------------------------------ layout
def layout() -> fl.Layout:
    """The Foxglove layout: the 3D scene following the vehicle, the plots of speed
    against its limits and of the tracking error, and the event log."""
    scene_topics = ("/foxglove/map", "/foxglove/plan", "/foxglove/body")
    topics: dict[str, Any] = {t: fl.BaseRendererSceneUpdateTopicSettings(visible=True)
                              for t in scene_topics}
    topics["/foxglove/setpoint"] = fl.BaseRendererPoseTopicSettings(
        visible=True, type="arrow", arrow_scale=(0.5, 0.08, 0.08), color="#1f77b4")
    topics["/foxglove/vehicle"] = fl.BaseRendererPoseTopicSettings(visible=False)
    three_d = fl.ThreeDeePanel(title="Flight (map frame, ENU)", config=fl.ThreeDeeConfig(
        follow_tf=BODY_FRAME, fixed_frame=MAP_FRAME, follow_mode="follow-position",
        topics=topics))

    def series(path: str, label: str, color: str, style: str = "solid") -> fl.PlotSeries:
        return fl.PlotSeries(value=path, label=label, color=color, line_style=style,
                             enabled=True, timestamp_method="receiveTime")

    speed = fl.PlotPanel(title="Speed (m/s)", config=fl.PlotConfig(paths=[
        series("/plot/command.speed", "commanded", "#1f77b4"),
        series("/plot/vehicle.speed", "reported (PX4)", "#222222"),
        series("/plot/command.v_max", "v_max", "#d62728"),
        series("/plot/command.chance_limit", "chance-constrained limit", "#9400d3", "dashed"),
    ], show_legend=True))
    tracking = fl.PlotPanel(title="Tracking error (m)", config=fl.PlotConfig(paths=[
        series("/plot/vehicle.tracking_error", "tracking error", "#222222"),
        series("/plot/vehicle.brake_threshold", "brake threshold", "#d62728", "dashed"),
    ], show_legend=True))
    logs = fl.LogPanel(title="Events", config=fl.LogConfig(topic_to_render="/foxglove/log"))
    right = fl.SplitContainer(direction="column", items=[
        fl.SplitItem(proportion=2, content=speed), fl.SplitItem(proportion=1, content=tracking),
        fl.SplitItem(proportion=1, content=logs)])
    return fl.Layout(content=fl.SplitContainer(direction="row", items=[
        fl.SplitItem(proportion=3, content=three_d), fl.SplitItem(proportion=2, content=right)]))


def layout_json() -> str:
    """:func:`layout` as the JSON Foxglove imports (``docs/foxglove/layout.json``)."""
    import json

    return json.dumps(json.loads(layout().to_json()), indent=1) + "\n"


# ------------------------------------------------------------------ render
def decoded(paths: Iterable[str | Path]) -> dict[str, list[tuple[float, Any]]]:
    """The Foxglove channels of flight records, each message decoded by its own
    schema: protobuf ones from the schema's descriptors, JSON ones as JSON."""
    import json

    from mcap_protobuf.decoder import DecoderFactory

    from companion.recording.record import read_raw

    factory, decoders = DecoderFactory(), {}
    out: dict[str, list[tuple[float, Any]]] = {}
    for schema, channel, message in read_raw(paths):
        if schema is None or schema.name.startswith("rota/"):
            continue  # the service's own channels
        if channel.message_encoding == "protobuf":
            dec = decoders.setdefault(channel.id, factory.decoder_for("protobuf", schema))
            obj = dec(message.data)
        else:
            obj = json.loads(message.data)
        out.setdefault(channel.topic, []).append((message.log_time / 1e9, obj))
    return out
