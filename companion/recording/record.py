"""Flight records: everything the service receives, computes and sends, in MCAP
files (the log format that Foxglove and the ROS 2 tools open), JSON messages on
one channel per kind.

The service calls ``put`` from its event loop, also for every setpoint at the
stream rate, so ``put`` only appends to a bounded queue (well under a
microsecond); a writer thread drains the queue, encodes and writes. The service
runs this :class:`Recorder` in a process of its own
(:mod:`companion.recording.record_process`): its encoding would hold the GIL the setpoint
stream needs. When
the writer falls behind and the queue is full, messages are dropped, counted
and reported (a warning in the log, and ``dropped`` in :meth:`Recorder.stats`);
the flight never waits for the disk. Files rotate at ``max_file_mb``; the
oldest records are deleted when the directory holds more than ``max_total_mb``.

Channels (topic ``/<name>``, message encoding ``json``): ``trajectory`` and
``map`` (as received), ``retimed`` (``rota/result``), ``setpoint`` (every one
sent: ``t`` monotonic, ``p``, ``v``, ``a`` ENU, ``yaw``, ``source``),
``telemetry``, ``status``, ``log`` (events, warnings and errors) and ``config``.
Beside them, the same flight in Foxglove's well-known schemas (the map, the paths,
the setpoints and the vehicle in 3D, and figures to plot: :mod:`companion.recording.foxglove`),
made in the writer thread too. Replay: ``rota-gs replay FILE``; formats in
``docs/groundstation.md``.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections import deque
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from mcap.reader import NonSeekingReader, make_reader
from mcap.writer import CompressionType, Writer

from companion.recording.foxglove import Scene, Schema
from companion.recording.settings import RecordSettings

log = logging.getLogger("rota.record")

#: Chunk size: a crash loses at most one unfinished chunk (a few seconds of flight).
CHUNK_BYTES = 64 * 1024
LIBRARY = "rota-companion"


def _jsonable(x: Any) -> Any:
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, tuple | set | deque):
        return list(x)
    raise TypeError(f"not JSON serialisable: {type(x).__name__}")


def encode(payload: bytes | dict[str, Any]) -> bytes:
    if isinstance(payload, bytes | bytearray | memoryview):
        return bytes(payload)
    return json.dumps(payload, default=_jsonable, separators=(",", ":")).encode()


class _File:
    """One open MCAP file with its schemas and channels registered on demand."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._fh: BinaryIO = open(path, "wb")  # noqa: SIM115 - closed in close()
        self.writer = Writer(self._fh, chunk_size=CHUNK_BYTES, compression=CompressionType.ZSTD)
        self.writer.start(profile="", library=LIBRARY)
        self._channels: dict[str, int] = {}
        self._seq = 0

    def write(self, channel: str, data: bytes, stamp: float, schema: Schema | None = None) -> None:
        """One message on ``channel`` (topic ``/<channel>``, JSON), or with ``schema``
        on the topic ``channel`` as that schema says (a Foxglove message)."""
        cid = self._channels.get(channel)
        if cid is None:
            if schema is None:
                schema = Schema(f"rota/{channel}", "jsonschema", json.dumps(
                    {"title": f"rota/{channel}", "type": "object"}).encode(), "json")
                topic = f"/{channel}"
            else:
                topic = channel
            sid = self.writer.register_schema(name=schema.name, encoding=schema.encoding,
                                              data=schema.data)
            cid = self._channels[channel] = self.writer.register_channel(
                topic=topic, message_encoding=schema.message_encoding, schema_id=sid)
        ns = int(stamp * 1e9)
        self._seq += 1
        self.writer.add_message(channel_id=cid, log_time=ns, data=data, publish_time=ns,
                                sequence=self._seq)

    def size(self) -> int:
        return self._fh.tell()

    def close(self) -> None:
        try:
            self.writer.finish()
        finally:
            self._fh.close()


class Recorder:
    """``put(channel, payload, stamp)`` from anywhere, never blocking; a writer
    thread writes MCAP files named ``<name>-<UTC time>-<n>.mcap`` in ``directory``.

    ``share_gil``: the writer hands the GIL over between messages (and a large
    Foxglove scene between batches), for a process whose other threads must not wait
    for it (the service's setpoint stream); the record's own process
    (:mod:`companion.recording.record_process`) has none and writes without."""

    def __init__(self, directory: str | Path, name: str = "rota", max_file_mb: float = 100.0,
                 max_total_mb: float = 2000.0, queue: int = 20000, foxglove: bool = True,
                 share_gil: bool = True) -> None:
        if max_file_mb <= 0 or max_total_mb < max_file_mb or queue < 1:
            raise ValueError("record: need max_file_mb > 0, max_total_mb >= max_file_mb, "
                             "queue >= 1")
        self.dir = Path(directory)
        self.name = name
        self.max_file = int(max_file_mb * 1e6)
        self.max_total = int(max_total_mb * 1e6)
        self._cap = queue
        self._q: deque[tuple[str, Any, float, bool]] = deque()
        self.dropped = 0
        self.written = 0
        self.files: list[Path] = []
        self._reported_drops = 0
        self._last_report = 0.0
        self._file: _File | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.error: str | None = None
        #: Foxglove's messages for each one recorded (None: not written)
        self.share_gil = share_gil
        self.scene: Scene | None = (Scene(_pause) if share_gil else Scene()) if foxglove \
            else None
        self.scene_errors = 0
        #: channels drawn for Foxglove from what :meth:`show` gives, not as recorded:
        #: the map (its JSON would be parsed again) and, where the service gives plan
        #: views, the re-timed results (drawing one needs ``rota``)
        self.drawn_apart: frozenset[str] = frozenset({"map"})

    @classmethod
    def from_settings(cls, settings: RecordSettings, state_dir: str, name: str,
                      share_gil: bool = True) -> Recorder:
        return cls(settings.dir or Path(state_dir) / "records", name, settings.max_file_mb,
                   settings.max_total_mb, settings.queue, settings.foxglove, share_gil)

    # ------------------------------------------------------------ the hot path
    def put(self, channel: str, payload: bytes | dict[str, Any],
            stamp: float | None = None) -> None:
        """Queue one message (``stamp``: UNIX time, default now). Never blocks: a
        full queue drops the message and counts it."""
        if len(self._q) >= self._cap:
            self.dropped += 1
            return
        self._q.append((channel, payload, time.time() if stamp is None else stamp, False))

    def show(self, channel: str, obj: Any, stamp: float | None = None) -> None:
        """Queue ``obj`` for the Foxglove view only (not recorded as JSON): the map in
        use as decoded (a :class:`rota.voxelmap.VoxelMap`), whatever it came as. The
        recorded ``map`` channel (JSON bytes, or a ROS message) is not parsed again
        here: 1 MB of JSON would hold the GIL for tens of milliseconds in one go."""
        if self.scene is None:
            return
        if len(self._q) >= self._cap:
            self.dropped += 1
            return
        self._q.append((channel, obj, time.time() if stamp is None else stamp, True))

    # ------------------------------------------------------------ the writer
    def start(self) -> Recorder:
        self.dir.mkdir(parents=True, exist_ok=True)
        self._open()
        self._thread = threading.Thread(target=self._run, name="flight-record", daemon=True)
        self._thread.start()
        return self

    def _open(self) -> None:
        """The next part of this run's record: ``<name>-<start, UTC>-<part>.mcap``."""
        if not self.files:
            self._stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime())
            self._part = 0
        while (path := self.dir / f"{self.name}-{self._stamp}-{self._part:03d}.mcap").exists():
            self._part += 1
        self._part += 1
        self._file = _File(path)
        self.files.append(path)
        log.info("flight record: %s", path)

    def _run(self) -> None:
        while not self._stop.is_set():
            self._stop.wait(0.05)
            try:
                self._drain(until=self._stop)
            except Exception as exc:  # noqa: BLE001 - a full disk must not stop the flight
                self.error = f"{type(exc).__name__}: {exc}"
                log.error("flight record stopped: %s", self.error)
                self._cap = 0  # from now on every put is dropped (and counted)
                self._q.clear()
                return

    def _drain(self, until: threading.Event | None = None) -> None:
        """Write what is queued (the thread stops early once ``until`` is set: then
        :meth:`close` writes the rest, never both at once)."""
        q, f = self._q, self._file
        while q and not (until is not None and until.is_set()):
            channel, payload, stamp, view_only = q.popleft()
            if not view_only:
                try:
                    data = encode(payload)
                except (TypeError, ValueError) as exc:
                    data = encode({"unencodable": str(exc)})
                f.write(channel, data, stamp)
                self.written += 1
            if self.scene is not None and (view_only or channel not in self.drawn_apart):
                self._write_scene(f, channel, payload, stamp)
            # Hand the GIL over between messages: a thread waiting for it (the event
            # loop, the setpoint stream) gets it now, not after Python's 5 ms switch
            # interval while this thread goes on encoding.
            if self.share_gil:
                time.sleep(0)
            if f.size() >= self.max_file:
                f.close()
                self._open()
                f = self._file
                self._prune()
                if self.scene is not None:  # each part shows the map and plan on its own
                    for m in self.scene.latched.values():
                        f.write(m.topic, m.data, stamp, m.schema)
        if self.dropped > self._reported_drops and time.monotonic() - self._last_report > 5.0:
            log.warning("flight record: %d messages dropped so far (the writer fell behind)",
                        self.dropped)
            self._reported_drops, self._last_report = self.dropped, time.monotonic()

    def _write_scene(self, f: _File, channel: str, payload: Any, stamp: float) -> None:
        """The message in Foxglove's schemas; a message it cannot show is counted and
        reported once, and the record goes on."""
        try:
            out = self.scene.translate(channel, payload, stamp)
        except Exception as exc:  # noqa: BLE001 - a bad message must not stop the record
            self.scene_errors += 1
            if self.scene_errors == 1:
                log.warning("flight record: no Foxglove view of a %s message (%s: %s)",
                            channel, type(exc).__name__, exc)
            return
        for m in out:
            f.write(m.topic, m.data, stamp, m.schema)

    def _prune(self) -> None:
        """Delete the oldest records while the directory holds more than the cap."""
        current = self._file.path if self._file else None
        records = sorted(self.dir.glob(f"{self.name}-*.mcap"))
        total = sum(p.stat().st_size for p in records)
        for p in records:
            if total <= self.max_total or p == current:
                break
            total -= p.stat().st_size
            p.unlink(missing_ok=True)
            log.info("flight record: deleted %s (over %d MB in total)", p,
                     self.max_total // 1_000_000)

    def close(self) -> None:
        """Write what is queued, finish the file (its index), stop the thread."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(10)
        if self._file is not None:
            try:
                if self.error is None:
                    self._drain()
                self._file.close()
            except Exception as exc:  # noqa: BLE001
                log.error("flight record: closing %s failed: %s", self._file.path, exc)
            self._file = None
        if self.dropped:
            log.warning("flight record: %d messages dropped in all", self.dropped)

    def stats(self) -> dict[str, Any]:
        return {"file": str(self._file.path) if self._file else None, "written": self.written,
                "dropped": self.dropped, "queued": len(self._q), "error": self.error,
                "foxglove_errors": self.scene_errors}

    def log_handler(self, level: int = logging.INFO) -> logging.Handler:
        """A logging handler that records events, warnings and errors (``log``)."""
        return _LogHandler(self, level)


def _pause() -> None:
    """Between batches of a large Foxglove scene: let the event loop run."""
    time.sleep(0.0005)


class NoRecorder:
    """What the service holds when recording is disabled: ``put`` does nothing."""

    def put(self, channel: str, payload: Any, stamp: float | None = None) -> None:
        pass

    def show(self, channel: str, obj: Any, stamp: float | None = None) -> None:
        pass

    def start(self) -> NoRecorder:
        return self

    def close(self) -> None:
        pass

    def log_handler(self, level: int = logging.INFO) -> logging.Handler:
        return logging.NullHandler()


class _LogHandler(logging.Handler):
    def __init__(self, recorder: Recorder, level: int) -> None:
        super().__init__(level)
        self._rec = recorder

    def emit(self, record: logging.LogRecord) -> None:
        if record.name == log.name:
            return  # the recorder's own lines would feed back
        self._rec.put("log", {"level": record.levelname, "logger": record.name,
                              "message": record.getMessage()}, record.created)


def read(paths: Iterable[str | Path],
         channels: Iterable[str] | None = None) -> Iterator[tuple[str, float, Any]]:
    """``(channel, stamp, message)`` from flight records, in time order per file;
    a file cut short (power loss) yields what it holds. Only the service's own
    channels (JSON, schema ``rota/<channel>``), not their Foxglove views."""
    topics = None if channels is None else [f"/{c}" for c in channels]
    for schema, channel, message in read_raw(paths, topics):
        if schema is None or not schema.name.startswith("rota/") \
                or channel.message_encoding != "json":
            continue  # not one of ours (a foreign MCAP, or a Foxglove view)
        try:
            data = json.loads(message.data)
        except ValueError:
            continue
        yield channel.topic[1:], message.log_time / 1e9, data


def read_raw(paths: Iterable[str | Path], topics: Iterable[str] | None = None,
             ) -> Iterator[tuple[Any, Any, Any]]:
    """MCAP's ``(schema, channel, message)`` of every message on ``topics`` (default
    all), in time order per file; a file cut short yields what its whole chunks hold."""
    topics = None if topics is None else list(topics)
    for path in paths:
        with open(path, "rb") as fh:
            try:  # a finished file: through its index
                messages = list(make_reader(fh).iter_messages(topics=topics))
            except Exception:  # noqa: BLE001 - no footer: read linearly as far as it goes
                fh.seek(0)
                messages = []
                try:
                    for item in NonSeekingReader(fh).iter_messages(topics=topics,
                                                                  log_time_order=False):
                        messages.append(item)
                except Exception as exc:  # noqa: BLE001
                    log.warning("%s: cut short after %d messages (%s)", path, len(messages),
                                type(exc).__name__)
        yield from messages
