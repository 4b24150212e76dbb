"""Every CLI error is one clear line on stderr with a documented exit status,
never a traceback; --version everywhere; help text without raw markup."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import time

import pytest

from sitl.demo import free_tcp_port
from tests.helpers.cli import PY, TOOLS, one_line_error, run, write_config


@pytest.mark.parametrize("tool", sorted(TOOLS))
def test_version_and_help_without_markup(tool):
    r = run(tool, "--version")
    assert r.returncode == 0 and r.stdout.startswith(f"{tool} ") and r.stdout.strip()[-1].isdigit()
    r = run(tool, "--help")
    assert r.returncode == 0
    for markup in ("``", ":class:", ":func:", "issue #", "Done-when", "::\n"):
        assert markup not in r.stdout, (markup, r.stdout)


def test_rota_retime_rejects_bad_options_before_work(example, tmp_path):
    out = str(tmp_path / "r.json")
    one_line_error(run("rota", "retime", str(example), "-o", out, "--rate", "0"), 2, "--rate")
    one_line_error(run("rota", "retime", str(example), "-o", out, "--rate", "1e7"), 2,
                   "--rate", "--max-points")
    one_line_error(run("rota", "retime", str(example), "-o", out, "--plot", "x.xyz"), 2,
                   "--plot", ".png")
    one_line_error(run("rota", "retime", str(example), "-o", out, "--dtau", "1e-7"), 2,
                   "grid nodes", "--max-points")
    assert not os.path.exists(out)
    # the cap is an override, not a wall: a larger --max-points runs it
    r = run("rota", "retime", str(example), "-o", out, "--rate", "2000", "--max-points",
            "1000000")
    assert r.returncode == 0, r.stderr
    assert len(json.loads(open(out).read())["setpoints"]["t"]) > 2000


def test_rota_retime_huge_coordinates_and_too_many_points(example, tmp_path):
    msg = json.loads(example.read_text())
    msg["control_points"][3][0] = 1e300
    bad = tmp_path / "huge.json"
    bad.write_text(json.dumps(msg))
    out = tmp_path / "r.json"
    one_line_error(run("rota", "retime", str(bad), "-o", str(out)), 2, "wrong units")
    assert not out.exists()
    n = 100_001
    big = {"schema": "rota/trajectory", "version": 1, "type": "samples",
           "t": [0.01 * k for k in range(n)], "p": [[0.001 * k, 0.0, 1.0] for k in range(n)]}
    path = tmp_path / "big.json"
    path.write_text(json.dumps(big))
    one_line_error(run("rota", "retime", str(path), "-o", str(out)), 2, "100001 points",
                   "--max-points")


def test_rota_retime_prints_progress_for_long_runs(example, tmp_path):
    r = run("rota", "retime", str(example), "-o", str(tmp_path / "r.json"), "--dtau", "0.002")
    assert r.returncode == 0, r.stderr
    assert "grid nodes ..." in r.stderr and "done in" in r.stderr


def test_rota_sitl_bench_without_the_bench_extra_says_what_to_install():
    code = ("import sys; sys.modules['cvxpy'] = None; sys.modules['copp'] = None; "
            "sys.modules['toppra'] = None; from sitl.experiment_cli import main; "
            "sys.exit(main(['bench', '--quick', '--out', '/tmp/rota-bench-none']))")
    r = subprocess.run([PY, "-c", code], capture_output=True, text=True, timeout=120)
    one_line_error(r, 1, "rota-companion[bench]")


def test_rota_sim_unknown_world():
    one_line_error(run("rota-sim", "--world", "bogus"), 2, "unknown world 'bogus'")


@pytest.mark.parametrize("args", [("bench-stream", "--seconds", "0"), ("soak", "--minutes", "-1"),
                                  ("fuzz", "--examples", "0")])
def test_rota_sitl_flight_bad_numbers(args):
    """Refused before any flight starts, in one line, naming the option."""
    one_line_error(run("rota-sitl", *args), 2, args[1], "must be positive")


def test_rota_sitl_bad_numbers():
    one_line_error(run("rota-sitl", "experiment", "collision-rate", "--trials", "0"), 2,
                   "--trials")


def test_check_config_catches_a_missing_zenoh_file_and_a_bad_url(tmp_path):
    cfg = write_config(tmp_path, zenoh={"config_file": str(tmp_path / "nope.json5")})
    one_line_error(run("rota-companion", "check-config", cfg), 2, "[zenoh] config_file",
                   "no such file")
    one_line_error(run("rota-companion", "run", "--config", cfg), 2, "[zenoh] config_file")
    cfg = write_config(tmp_path, mavlink={"url": "bogus"})
    one_line_error(run("rota-companion", "check-config", cfg), 2, "[mavlink] url", "bogus")
    ok = write_config(tmp_path, mavlink={"url": "serial:///dev/ttyAMA0:921600"})
    assert run("rota-companion", "check-config", ok).returncode == 0


def test_run_with_the_zenoh_port_taken_says_so(tmp_path):
    port = free_tcp_port()
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", port))
        taken.listen()
        cfg = write_config(tmp_path, service={"state_dir": str(tmp_path)},
                      zenoh={"listen": [f"tcp/127.0.0.1:{port}"]},
                      mavlink={"url": f"udpin://127.0.0.1:{free_tcp_port()}"})
        r = run("rota-companion", "run", "--config", cfg)
    assert r.returncode == 1, r
    assert "Traceback" not in r.stdout + r.stderr
    assert f"cannot open Zenoh (tcp/127.0.0.1:{port})" in r.stderr and "in use" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert not list(tmp_path.rglob("*.mcap"))  # a failed start leaves no (empty) record


def test_ctrl_c_on_run_stops_cleanly_without_a_traceback(tmp_path):
    cfg = write_config(tmp_path, service={"state_dir": str(tmp_path)},
                  zenoh={"listen": [f"tcp/127.0.0.1:{free_tcp_port()}"]},
                  mavlink={"url": f"udpin://127.0.0.1:{free_tcp_port()}"})
    # a terminal's Ctrl-C goes to the whole process group: the service and its worker
    proc = subprocess.Popen([PY, "-m", "companion.cli", "run", "--config", cfg],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    end = time.monotonic() + 60
    lines = []
    while time.monotonic() < end:
        line = proc.stdout.readline()
        lines.append(line)
        if "service up" in line or not line:
            break
    time.sleep(1.0)  # the worker process starts right after "service up"
    os.killpg(proc.pid, signal.SIGINT)
    out, _ = proc.communicate(timeout=30)
    text = "".join(lines) + out
    assert proc.returncode == 0, text
    assert "Traceback" not in text and "KeyboardInterrupt" not in text, text
    assert "service stopped" in text


def test_rota_gs_errors(tmp_path):
    one_line_error(run("rota-gs", "status", "--connect", f"tcp/127.0.0.1:{free_tcp_port()}",
                       "--timeout", "0.5"), 3, "cannot reach")
    bad = tmp_path / "t.json"
    bad.write_text('{"schema": "rota/trajectory", "version": 1, "type": "bspline"}')
    one_line_error(run("rota-gs", "send", str(bad), "--timeout", "0.5"), 2, "bad input")
    one_line_error(run("rota-gs", "replay", str(tmp_path / "none.mcap")), 2, "no such file")
    one_line_error(run("rota-gs", "status", "--zenoh-config", str(tmp_path / "no.json5")), 3,
                   "no.json5")
