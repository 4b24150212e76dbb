"""Every failure is one line with a documented exit status (unwritable state and
record directories, failed starts, records that are not flights), and rejected
plans are shown as rejected (the rota plot, rota-gs replay). Issue 29."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from rota.cli import example_path
from rota.voxelmap import VoxelMap
from tests.helpers.cli import one_line_error, run, write_config

#: A voxel on the example's path (at tau 3.3 s): its re-time is rejected.
ON_PATH = [[2.05, 1.25, 1.55]]


@pytest.mark.parametrize(("section", "setting"), [("service", "state_dir"), ("record", "dir")])
def test_unwritable_directories_are_caught_by_check_config_and_run(tmp_path, section, setting):
    """A directory that cannot be created (its parent is a file: even root cannot)."""
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    values = {"service": {"state_dir": str(tmp_path / "state")}, "record": {}}
    values[section][setting] = str(blocker / "sub")
    cfg = write_config(tmp_path, **values)
    for args in (["check-config", cfg], ["run", "--config", cfg]):
        one_line_error(run("rota-companion", *args), 2, f"[{section}] {setting}",
                       "cannot be created")


def test_shipped_config_as_a_user_who_cannot_write_var_lib(tmp_path):
    """The shipped configuration with /var/lib replaced by a directory this user
    cannot write (a file's child: root cannot either) is one line, exit 2."""
    blocker = tmp_path / "var-lib"
    blocker.write_text("")
    text = open("configs/companion.toml").read()
    assert 'state_dir = "/var/lib/rota-companion"' in text
    cfg = tmp_path / "companion.toml"
    cfg.write_text(text.replace("/var/lib/rota-companion", str(blocker / "rota-companion")))
    one_line_error(run("rota-companion", "run", "--config", str(cfg)), 2,
                   "[service] state_dir")


def _results(tmp_path):
    """A flown (optimal) and a rejected re-time of the example, as the service sends them."""
    from rota import Limits, RetimeInput, retime
    from rota.robust import Safety
    from rota.schema import result_to_dict, trajectory_from_dict

    msg = trajectory_from_dict(json.loads(example_path().read_text()))
    ok = retime(RetimeInput(trajectory=msg.trajectory, limits=Limits(1.5, 2.0)))
    bad = retime(RetimeInput(trajectory=msg.trajectory, limits=Limits(1.5, 2.0),
                             safety=Safety(map=VoxelMap(0.1, np.array(ON_PATH)))))
    assert ok.status == "optimal" and bad.status == "rejected", bad.message
    return (ok, result_to_dict(ok, msg.__class__(msg.trajectory, id="p1")),
            bad, result_to_dict(bad, msg.__class__(msg.trajectory, id="p2")))


def _record(tmp_path, *, telemetry=True):
    from companion.recording.record import Recorder

    ok, flown, _, rejected = _results(tmp_path)
    rec = Recorder(tmp_path / "rec", "drone1")
    t0 = time.time()
    rec.put("config", {"limits": {"v_max": 1.5}}, t0)
    rec.put("retimed", flown, t0 + 0.1)
    rec.put("retimed", rejected, t0 + 0.5)
    for k, t in enumerate(np.linspace(0.0, ok.duration, 50)):
        sp = ok.sample(np.array([t]))
        rec.put("setpoint", {"t": t0 + 0.2 + t, "p": sp.position[0].tolist(),
                             "v": sp.velocity[0].tolist(), "a": sp.acceleration[0].tolist(),
                             "source": "p1"}, t0 + 0.2 + t)
        if telemetry:
            rec.put("telemetry", {"position": sp.position[0].tolist(),
                                  "velocity": sp.velocity[0].tolist(), "tracking_error": 0.01},
                    t0 + 0.2 + t + 1e-4 * k)
    rec.start()
    rec.close()
    return rec.files, rejected


def test_replay_lists_and_draws_rejected_plans(tmp_path):
    from companion.gs import replay

    files, rejected = _record(tmp_path)
    flight = replay.load(files)
    figures = replay.stats(flight)
    assert figures["plans_flown"] == ["p1"]
    assert figures["plans_rejected"] == [{"id": "p2", "reason": rejected["message"]}]
    assert "unsafe" in rejected["message"]
    fig = replay.figure(flight)
    labels = [ln.get_label() for ax in fig.axes for ln in ax.get_lines()]
    texts = [t.get_text() for t in fig.texts] + [t.get_text() for ax in fig.axes
                                                 for t in ax.texts]
    assert "rejected plan (not flown)" in labels
    assert not any(lb.startswith("p2:") for lb in labels)  # not drawn as a flown plan
    assert any("p2 rejected at" in t and "unsafe" in t for t in texts), texts
    r = run("rota-gs", "replay", *map(str, files))
    assert r.returncode == 0, r.stderr
    assert "plans_rejected: 1" in r.stdout and "p2 rejected: the path is unsafe" in r.stdout


def test_rota_plot_draws_a_rejected_path_as_rejected(tmp_path):
    from rota import Limits
    from rota.plot import figure

    ok, _, bad, _ = _results(tmp_path)
    labels = {ln.get_label() for ax in figure(ok, Limits(1.5, 2.0)).axes
              for ln in ax.get_lines()}
    assert "re-timed" in labels
    fig = figure(bad, Limits(1.5, 2.0))
    labels = {ln.get_label() for ax in fig.axes for ln in ax.get_lines()}
    texts = [t.get_text() for ax in fig.axes for t in ax.texts]
    assert "re-timed" not in labels and "rejected path" in labels
    assert any(t.startswith("REJECTED") and "unsafe" in t for t in texts), texts
    vmap = tmp_path / "map.json"
    vmap.write_text(json.dumps(VoxelMap(0.1, np.array(ON_PATH)).to_dict()))
    r = run("rota", "retime", str(example_path()), "-o", str(tmp_path / "r.json"), "--map",
            str(vmap), "--plot", str(tmp_path / "p.png"))
    assert r.returncode == 4, r.stderr
    assert "rejected, not to be flown: the path is unsafe" in r.stdout
    assert "->" not in r.stdout  # no re-timed duration for a path never to be flown


def test_replay_of_what_is_no_flight_is_one_line(tmp_path):
    from mcap.writer import Writer

    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    one_line_error(run("rota-gs", "replay", str(empty)), 2, "empty")
    text = tmp_path / "notes.mcap"
    text.write_text("not a record\n")
    one_line_error(run("rota-gs", "replay", str(text)), 2, "not an MCAP file")
    foreign = tmp_path / "camera.mcap"
    with open(foreign, "wb") as fh:
        w = Writer(fh)
        w.start()
        sid = w.register_schema(name="foo.Image", encoding="protobuf", data=b"\x00")
        cid = w.register_channel(topic="/camera", message_encoding="protobuf", schema_id=sid)
        w.add_message(channel_id=cid, log_time=1, data=b"\x08\x96\x01", publish_time=1)
        w.finish()
    one_line_error(run("rota-gs", "replay", str(foreign)), 2, "no flight-record channels")
    from companion.recording.record import Recorder

    rec = Recorder(tmp_path / "idle", "drone1")
    rec.put("config", {"limits": {"v_max": 1.5}})
    rec.put("status", {"state": "not_ready"})
    rec.put("telemetry", {"position": None, "velocity": None})
    rec.start()
    rec.close()
    one_line_error(run("rota-gs", "replay", *map(str, rec.files)), 2, "without a vehicle")
