"""The service's flight record written in a child process: what is put arrives in
order, in a readable file; the child's death stops the record, not the caller; and
the service's death (its pipe closed without a word) still leaves a finished file."""

from __future__ import annotations

import logging
import os
import signal
import time

import numpy as np
from mcap.reader import make_reader

from companion.recording.record import RecordSettings, read
from companion.recording.record_process import RecordProcess, recorder_for
from rota.voxelmap import VoxelMap


def _until(pred, timeout_s: float = 30.0) -> bool:
    end = time.monotonic() + timeout_s
    while not pred() and time.monotonic() < end:
        time.sleep(0.02)
    return pred()


def test_every_put_arrives_in_order_in_a_finished_file(tmp_path, caplog):
    caplog.set_level(logging.INFO, logger="rota")  # (the child logs at the service's level)
    rec = recorder_for(RecordSettings(dir=str(tmp_path)), str(tmp_path), "p").start()
    assert isinstance(rec, RecordProcess)
    for k in range(500):
        rec.put("setpoint", {"t": k * 0.02, "p": np.array([k, 0.0, 2.0]), "source": "x"},
                100.0 + k * 0.02)
    rec.put("retimed", b'{"schema":"rota/result","status":"rejected"}', 111.0)
    rec.show("map", VoxelMap.from_points(np.array([[1.0, 1.0, 1.0]]), 0.5), 111.0)
    handler = rec.log_handler()
    logging.getLogger("rota.companion").addHandler(handler)
    try:
        logging.getLogger("rota.companion").warning("braking to a hold: %s", "test")
    finally:
        logging.getLogger("rota.companion").removeHandler(handler)
    rec.close()
    assert rec.stats()["dropped"] == 0 and rec.stats()["written"] == 502
    assert len(rec.files) == 1 and rec.files[0].exists()
    # the child's own log lines came back here (its file, under rota.record)
    assert any("flight record:" in r.getMessage() for r in caplog.records)
    got = list(read(rec.files))
    assert [m["p"][0] for c, _, m in got if c == "setpoint"] == list(range(500))
    assert any(c == "log" and "braking to a hold: test" in m["message"] for c, _, m in got)
    with open(rec.files[0], "rb") as fh:  # finished: it has its index
        topics = {c.topic for c in make_reader(fh).get_summary().channels.values()}
    assert "/foxglove/map" in topics and "/retimed" in topics


def test_a_dead_writer_stops_the_record_not_the_caller(tmp_path):
    said: list[str] = []
    rec = RecordProcess(RecordSettings(dir=str(tmp_path)), str(tmp_path), "d",
                        on_error=said.append).start()
    rec.put("status", {"k": 0})
    assert _until(lambda: rec.stats()["written"] >= 1)
    os.kill(rec._proc.pid, signal.SIGKILL)
    assert _until(lambda: rec.error is not None)
    for k in range(100):
        rec.put("status", {"k": k})  # never blocks, never raises
    start = time.monotonic()
    rec.close()
    assert time.monotonic() - start < 5.0
    assert "killed by SIGKILL" in rec.error
    assert rec.stats()["dropped"] >= 100
    # (the service's status channel gets it: on_error is its Reporter's error)
    assert said == [f"flight record stopped: {rec.error}; the flight goes on unrecorded"]


def test_a_service_gone_without_a_word_still_leaves_a_finished_file(tmp_path):
    rec = RecordProcess(RecordSettings(dir=str(tmp_path)), str(tmp_path), "g").start()
    for k in range(50):
        rec.put("status", {"k": k})
    assert _until(lambda: rec.stats()["written"] >= 50)
    # systemd's stop reaches the whole group: the child ignores it and goes on (the
    # signal is delivered before it wakes for the next batch)
    os.kill(rec._proc.pid, signal.SIGTERM)
    rec.put("status", {"k": 50})
    assert _until(lambda: rec.stats()["written"] >= 51) and rec._proc.is_alive()
    rec._send.close()  # the service died: its end of the pipe closes with it
    # (it finishes the file and exits: seconds on a busy machine). The record's own
    # listener waits for the exit and says how it ended; a second wait from here
    # would race it for the exit status (the loser sees none).
    assert _until(lambda: rec.error is not None, 60), rec.stats()
    assert rec.error.endswith("(exit code 0)"), rec.error
    with open(rec.files[0], "rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None and summary.statistics.message_count >= 50
