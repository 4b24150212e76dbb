"""Flight records: MCAP files written off the event loop, read back, rotated,
capped; a full queue drops and counts instead of blocking."""

from __future__ import annotations

import json
import logging
import shutil

import numpy as np
import pytest
from mcap.reader import make_reader

from companion.recording.record import Recorder, RecordSettings, read


def test_messages_round_trip_in_order_with_numpy_and_raw_bytes(tmp_path):
    rec = Recorder(tmp_path, "t").start()
    raw = json.dumps({"schema": "rota/trajectory", "id": "plan-0"}).encode()
    rec.put("trajectory", raw, 100.0)
    for k in range(200):
        rec.put("setpoint", {"t": k * 0.02, "p": np.array([k, 0.0, 2.0]),
                             "v": np.zeros(3), "source": "plan-0"}, 100.0 + k * 0.02)
    logging.getLogger("rota.companion").addHandler(h := rec.log_handler())
    try:
        logging.getLogger("rota.companion").warning("braking to a hold: %s", "test")
    finally:
        logging.getLogger("rota.companion").removeHandler(h)
    rec.close()
    assert rec.dropped == 0 and rec.written == 202
    got = list(read(rec.files))
    channels = [c for c, _, _ in got]
    assert channels.count("setpoint") == 200 and "trajectory" in channels and "log" in channels
    sps = [m for c, _, m in got if c == "setpoint"]
    assert [s["p"][0] for s in sps] == list(range(200))
    assert got[0][2]["id"] == "plan-0" and got[0][1] == pytest.approx(100.0)
    msg = next(m for c, _, m in got if c == "log")
    assert msg["level"] == "WARNING" and "braking to a hold: test" in msg["message"]
    # a standard MCAP file: its summary lists the channels with JSON encoding, and
    # their Foxglove views (tests/companion/test_foxglove.py)
    with open(rec.files[0], "rb") as fh:
        summary = make_reader(fh).get_summary()
    topics = {c.topic: c.message_encoding for c in summary.channels.values()}
    assert topics == {"/trajectory": "json", "/setpoint": "json", "/log": "json",
                      "/foxglove/setpoint": "protobuf", "/plot/command": "json",
                      "/foxglove/log": "protobuf"}


def test_files_rotate_at_the_size_cap_and_the_oldest_go_beyond_the_total(tmp_path):
    rec = Recorder(tmp_path, "t", max_file_mb=0.1, max_total_mb=0.35).start()
    rng = np.random.default_rng(0)
    for k in range(6000):  # incompressible payloads, about 1.5 MB in all
        rec.put("telemetry", {"k": k, "noise": rng.random(16)}, 1000.0 + k)
    rec.close()
    assert len(rec.files) >= 6
    left = sorted(tmp_path.glob("t-*.mcap"))
    assert 2 <= len(left) < len(rec.files)
    assert left == sorted(rec.files)[-len(left):]  # the newest survive
    assert sum(p.stat().st_size for p in left) <= 0.35e6 + 0.1e6
    for p in left[:-1]:
        assert 0.1e6 <= p.stat().st_size < 0.1e6 + 80_000  # one chunk over the cap at most
    ks = [m["k"] for _, _, m in read(left)]
    assert ks == sorted(ks) and ks[-1] == 5999  # continuous up to the last message


def test_a_full_queue_drops_and_counts_instead_of_blocking(tmp_path, caplog):
    rec = Recorder(tmp_path, "t", queue=50)  # writer not started yet: nothing drains
    for k in range(500):
        rec.put("setpoint", {"k": k})
    assert rec.dropped == 450 and rec.stats()["queued"] == 50
    with caplog.at_level(logging.WARNING, "rota.record"):
        rec.start()
        rec.close()
    assert "450 messages dropped" in caplog.text
    assert [m["k"] for _, _, m in read(rec.files)] == list(range(50))


def test_a_record_cut_short_still_reads(tmp_path):
    rec = Recorder(tmp_path, "t").start()
    for k in range(20000):
        rec.put("telemetry", {"k": k, "x": k * 0.5}, 10.0 + k * 0.05)
    rec.close()
    cut = tmp_path / "cut.mcap"
    data = rec.files[0].read_bytes()
    cut.write_bytes(data[: len(data) * 2 // 3])  # no footer, no summary: a power loss
    got = [m["k"] for _, _, m in read([cut])]
    assert 0 < len(got) < 20000 and got == list(range(len(got)))


def test_settings_default_to_the_state_directory(tmp_path):
    rec = Recorder.from_settings(RecordSettings(), str(tmp_path), "drone1")
    assert rec.dir == tmp_path / "records"
    with pytest.raises(ValueError, match="max_total_mb"):
        Recorder(tmp_path, max_file_mb=10, max_total_mb=5)
    shutil.rmtree(tmp_path / "records", ignore_errors=True)
