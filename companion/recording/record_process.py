"""The flight record, written in a process of its own.

Writing the record costs Python work that holds the GIL in long single calls:
JSON encoding, Foxglove's scene for every re-timed plan (a ``json.loads`` of the
whole result, one C call), MCAP chunk compression. In the service's own process
that work made the setpoint stream wait for the GIL for up to 110 ms on a busy
2-core machine (measured with ``py-spy --gil`` on ``rota-sitl soak``: the
record's writer thread held the GIL in 49 % of the samples, the stream in 16 %).

So the service holds a :class:`RecordProcess`: ``put`` and ``show`` only append
to a bounded queue, as :class:`~companion.recording.record.Recorder`'s do; a feeder thread
hands small pickled batches through a pipe (the write itself releases the GIL) to
a child process that runs the :class:`~companion.recording.record.Recorder`. What the child
logs comes back and is logged here (logger ``rota.record``: the journal, never the
record itself), with its counts and the files it has written.

When the service dies, the child sees the pipe close, writes what it has and
finishes the file. When the child dies, the service flies on: the record stops,
the error is logged and every later message is counted as dropped.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import pickle
import signal
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

from companion.recording.record import NoRecorder, Recorder, RecordSettings, _LogHandler
from companion.worker import describe_exit, worker_nice

log = logging.getLogger("rota.record")

#: Messages per batch handed to the child: one ``pickle.dumps`` holds the GIL for
#: the whole batch (about 15 us per setpoint), so batches stay small.
BATCH = 32
#: How often (s) the feeder hands the queue over.
FEED_S = 0.05
#: How often (s) the child reports its counts.
STATS_S = 1.0


class RecordProcess:
    """The service's recorder: :class:`~companion.recording.record.Recorder`'s ``put``,
    ``show``, ``start``, ``close`` and ``stats``, with the writing done in a child
    process."""

    def __init__(self, settings: RecordSettings, state_dir: str, name: str,
                 on_error: Callable[[str], None] | None = None) -> None:
        self._args = (settings, state_dir, name)
        #: called (from a thread of this class) with every error of the record, in words:
        #: the service puts them on its status channel
        self.on_error = on_error or (lambda message: log.error("%s", message))
        self.foxglove = settings.foxglove
        self._cap = settings.queue
        self._q: deque[tuple[str, Any, float, bool]] = deque()
        self._closing = False
        self.dropped = 0  # here (the queue was full, or the child is gone)
        self.files: list[Path] = []
        self.error: str | None = None
        self._child: dict[str, Any] = {}  # the child's last counts
        self._proc: Any = None
        self._send: Any = None
        self._threads: list[threading.Thread] = []

    # ------------------------------------------------------------ the hot path
    def put(self, channel: str, payload: Any, stamp: float | None = None) -> None:
        """Queue one message (``stamp``: UNIX time, default now); never blocks."""
        self._queue(channel, payload, stamp, False)

    def show(self, channel: str, obj: Any, stamp: float | None = None) -> None:
        """Queue ``obj`` for the Foxglove view only (see :meth:`Recorder.show`)."""
        if self.foxglove:
            self._queue(channel, obj, stamp, True)

    def _queue(self, channel: str, payload: Any, stamp: float | None, view: bool) -> None:
        if len(self._q) >= self._cap or self.error is not None:
            self.dropped += 1
            return
        self._q.append((channel, payload, time.time() if stamp is None else stamp, view))

    # ------------------------------------------------------------ life
    def start(self) -> RecordProcess:
        ctx = multiprocessing.get_context("spawn")  # (the parent runs Zenoh and MAVSDK threads)
        recv, self._send = ctx.Pipe(duplex=False)
        back_recv, back_send = ctx.Pipe(duplex=False)
        self._proc = ctx.Process(target=_child, name="flight-record", daemon=True,
                                 args=(recv, back_send, *self._args,
                                       logging.getLogger("rota").getEffectiveLevel()))
        self._proc.start()
        recv.close()
        back_send.close()
        self._threads = [threading.Thread(target=self._feed, name="record-feed", daemon=True),
                         threading.Thread(target=self._listen, args=(back_recv,),
                                          name="record-back", daemon=True)]
        for t in self._threads:
            t.start()
        return self

    def _feed(self) -> None:
        """Hand the queue to the child in small batches until closed and empty."""
        while True:
            closing = self._closing
            time.sleep(0 if closing else FEED_S)  # (no wake-up per put: an Event.set costs)
            while self._q:
                batch = [self._q.popleft() for _ in range(min(BATCH, len(self._q)))]
                try:
                    data = pickle.dumps(batch, protocol=5)
                except Exception as exc:  # noqa: BLE001 - one bad payload, not the record
                    data = pickle.dumps([(c, {"unrecordable": f"{type(exc).__name__}: {exc}"},
                                          s, v) for c, _, s, v in batch])
                try:
                    self._send.send_bytes(data)
                except OSError:
                    self.dropped += len(batch) + len(self._q)
                    self._q.clear()
                    return
                time.sleep(0)  # (the GIL to whoever waits for it, between batches)
            if closing:
                self._send.close()
                return

    def _listen(self, conn: Any) -> None:
        """What the child says: its log lines, files and counts."""
        while True:
            try:
                kind, *rest = conn.recv()
            except (EOFError, OSError):
                break
            if kind == "log":
                level, name, message = rest
                if level >= logging.ERROR:  # (a full disk: the record stops, the flight not)
                    self.on_error(f"flight record: {message}")
                else:
                    logging.getLogger(name if name.startswith(log.name) else log.name).log(
                        level, "%s", message)
            elif kind == "stats":
                self._child, files = rest
                self.files = [Path(f) for f in files]
        if not self._closing:
            self._proc.join(5.0)  # (it has closed its pipe: it is exiting)
            self.error = f"the record's writer process ended ({describe_exit(self._proc.exitcode)})"
            self.on_error(f"flight record stopped: {self.error}; the flight goes on unrecorded")

    def close(self) -> None:
        """Hand over what is queued, let the child finish the file, and wait for it."""
        if self._proc is None:
            return
        self._closing = True
        self._threads[0].join(10)
        self._proc.join(15)
        if self._proc.is_alive():
            log.error("flight record: the writer process did not finish in 15 s; killed")
            self._proc.kill()
        self._threads[1].join(2)
        if self.dropped:
            log.warning("flight record: %d messages dropped before the writer process",
                        self.dropped)
        self._proc = None

    def stats(self) -> dict[str, Any]:
        child = self._child
        return {"file": child.get("file"), "written": child.get("written", 0),
                "dropped": self.dropped + int(child.get("dropped", 0)),
                "queued": len(self._q) + int(child.get("queued", 0)),
                "error": self.error or child.get("error"),
                "foxglove_errors": child.get("foxglove_errors", 0)}

    def log_handler(self, level: int = logging.INFO) -> logging.Handler:
        """A logging handler that records events, warnings and errors (``log``)."""
        return _LogHandler(self, level)


class _Back(logging.Handler):
    """In the child: log records back to the service."""

    def __init__(self, conn: Any) -> None:
        super().__init__()
        self.conn = conn

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self.conn.send(("log", record.levelno, record.name, record.getMessage()))
        except OSError:
            pass


def _child(recv: Any, back: Any, settings: RecordSettings, state_dir: str, name: str,
           level: int) -> None:
    """The writer process: a :class:`Recorder` fed from the pipe until it closes."""
    # Ctrl-C and systemd's SIGTERM reach the whole group: this process ends when the
    # service closes the pipe (or dies), after it has finished the file.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    try:
        parent = os.getpriority(os.PRIO_PROCESS, 0)  # (inherited)
        os.nice(worker_nice(parent) - parent)
    except OSError:
        pass
    rlog = logging.getLogger("rota")
    rlog.handlers[:] = [_Back(back)]
    rlog.setLevel(level)
    rlog.propagate = False
    # (no stream here to hand the GIL to: the writer need not yield between messages)
    rec = Recorder.from_settings(settings, state_dir, name, share_gil=False)
    # the service shows every re-timed plan as a PlanView made in the re-time worker:
    # this process draws it without loading rota (numba, scipy: 150 MB more)
    rec.drawn_apart = frozenset({"map", "retimed"})
    rec.start()

    def report() -> None:
        back.send(("stats", rec.stats(), [str(p) for p in rec.files]))

    last = 0.0
    try:
        while True:
            if recv.poll(STATS_S):
                try:
                    batch = pickle.loads(recv.recv_bytes())
                except EOFError:
                    break
                for channel, payload, stamp, view in batch:
                    (rec.show if view else rec.put)(channel, payload, stamp)
            if time.monotonic() - last >= STATS_S:
                last = time.monotonic()
                report()
    finally:
        rec.close()
        try:
            report()
        except OSError:
            pass


def recorder_for(settings: RecordSettings, state_dir: str, name: str,
                 on_error: Callable[[str], None] | None = None) -> RecordProcess | NoRecorder:
    """The service's recorder from its ``[record]`` settings."""
    if not settings.enabled:
        return NoRecorder()
    return RecordProcess(settings, state_dir, name, on_error)
