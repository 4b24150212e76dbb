"""The ground station against a running service (a process, as systemd runs it)
and the sitl vehicle, over real Zenoh on loopback: ``rota-gs`` commands as a
user types them, and the web page in a real headless Chromium, one flight from
arming to landing; then the flight record it left, replayed.

The browser is Debian's ``chromium`` with its ``chromedriver``; without them
(``make test`` installs them where it can) the page's test is skipped, saying so.
It opens the page at the address ``rota-gs web`` prints (with the session's
token); mid-flight it stops the service (SIGSTOP) to see the page turn to "no
contact" and back, changes ``v_max`` to see the page follow, and sends a plan
through a tree to see it drawn as rejected.
"""

from __future__ import annotations

import asyncio
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from companion.gs import GroundStation
from companion.settings.config import to_toml
from rota.trajectory import BSplineTrajectory
from rota.voxelmap import VoxelMap
from sitl.demo import (
    PLANNER_CLEARANCE_M,
    demo_config,
    free_tcp_port,
    map_message,
    to_local,
    trajectory_message,
)
from sitl.mavsdk_util import free_udp_port
from sitl.planner import plan
from sitl.process import SimProcess
from sitl.world import get_world

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(300)]
CHROMIUM, CHROMEDRIVER = "/usr/bin/chromium", "/usr/bin/chromedriver"


@dataclass
class Live:
    endpoint: str
    gs: GroundStation
    sim: SimProcess
    world: object
    record_dir: Path
    service: subprocess.Popen
    tmp: Path

    def rota_gs(self, *args: str, timeout: float = 120) -> subprocess.CompletedProcess:
        """``rota-gs ARGS --connect ENDPOINT -V sim`` as a user runs it."""
        conn = [] if args[0] == "replay" else ["--connect", self.endpoint, "-V", "sim"]
        return subprocess.run([sys.executable, "-m", "companion.gs.cli", *args, *conn],
                              capture_output=True, text=True, timeout=timeout)

    def wait(self, predicate, timeout_s: float, what: str) -> dict:  # noqa: ANN001
        return asyncio.run(self.gs.wait_for(predicate, timeout_s, what))


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("gs")
    mav, zport = free_udp_port(), free_tcp_port()
    cfg = demo_config(mav, zport, 2.0, str(tmp / "state"), record={"dir": str(tmp / "rec")})
    (tmp / "companion.toml").write_text(to_toml(cfg))
    endpoint = f"tcp/127.0.0.1:{zport}"
    with SimProcess(port=mav, world="forest", seed=3) as sim:
        service = subprocess.Popen(
            [sys.executable, "-m", "companion.cli", "run", "--config", str(tmp / "companion.toml")],
            stdout=open(tmp / "service.log", "w"), stderr=subprocess.STDOUT)  # noqa: SIM115
        gs = GroundStation("sim", connect=[endpoint], wait_s=30)
        live = Live(endpoint, gs, sim, get_world("forest", seed=3), tmp / "rec", service, tmp)
        try:
            live.wait(lambda s: s["state"] == "ready", 60, "the vehicle to be ready")
            yield live
        finally:
            gs.close()
            if service.poll() is None:
                service.send_signal(signal.SIGTERM)
                service.wait(30)


def test_list_status_and_a_refused_command(live):
    r = live.rota_gs("list")
    assert r.returncode == 0 and "sim\trota/sim/" in r.stdout, r
    r = live.rota_gs("status")
    assert r.returncode == 0, r.stderr
    assert "state READY" in r.stdout and "not streaming" in r.stdout
    r = live.rota_gs("status", "--json")
    assert json.loads(r.stdout)["schema"] == "rota/status"
    r = live.rota_gs("cmd", "start")  # not airborne: refused, one line, exit 1
    assert r.returncode == 1 and r.stderr.count("\n") == 1
    assert "start refused: not possible in state ready" in r.stderr
    r = live.rota_gs("config", "get", "limits")
    assert r.returncode == 0 and json.loads(r.stdout)["v_max"] == 2.0
    r = live.rota_gs("config", "set", "limits.v_max=1.5")  # tightening: allowed
    assert r.returncode == 0 and json.loads(r.stdout.split("\n", 1)[1])["limits"]["v_max"] == 1.5
    r = live.rota_gs("config", "set", "limits.v_max=2.5")  # beyond the file: refused
    assert r.returncode == 1 and "allowed: at most 2.0" in r.stderr
    r = live.rota_gs("config", "set", "stream.rate_hz=10")
    assert r.returncode == 1 and "cannot change at run time" in r.stderr
    assert live.rota_gs("config", "set", "limits.v_max=2").returncode == 0
    r = live.rota_gs("estimator", "get")
    assert r.returncode == 0 and "m" in json.loads(r.stdout)


def _browser(tmp: Path):
    if not (os.path.exists(CHROMIUM) and os.path.exists(CHROMEDRIVER)):
        pytest.skip(f"no headless browser: install Debian's chromium and chromium-driver "
                    f"({CHROMIUM}, {CHROMEDRIVER}); `make test` does where it can")
    webdriver = pytest.importorskip("selenium.webdriver")
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for flag in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                 "--disable-background-networking", "--disable-extensions",
                 "--no-first-run", "--window-size=1400,950", f"--user-data-dir={tmp / 'ud'}"):
        opts.add_argument(flag)
    from selenium.webdriver.chrome.service import Service as DriverService

    return webdriver.Chrome(service=DriverService(CHROMEDRIVER), options=opts)


def test_web_page_and_cli_fly_a_flight(live):
    from companion.gs.web import WebStation, page_url, start, stop

    station = WebStation(GroundStation("sim", connect=[live.endpoint]))
    server = start(station, "sim", "127.0.0.1", free_tcp_port())
    url = page_url(server, "127.0.0.1")  # what `rota-gs web` prints: the token after '#'
    driver = None
    try:
        driver = _browser(live.tmp)
        from selenium.common.exceptions import TimeoutException
        from selenium.webdriver.common.by import By
        from selenium.webdriver.support.ui import WebDriverWait

        def text(el_id: str) -> str:
            return driver.find_element(By.ID, el_id).text

        def until(fn, timeout: float, what: str):  # noqa: ANN001, ANN202
            return WebDriverWait(driver, timeout, 0.1).until(lambda d: fn(), message=what)

        def click(el_id: str) -> None:
            driver.find_element(By.ID, el_id).click()

        driver.get(url)
        until(lambda: text("state") == "ready", 20, "the page to show the state")
        assert "token" not in driver.current_url  # out of the address bar once read
        assert text("contact").startswith("heard") and "limit 2" in text("speed-now")
        home = live.sim.home_enu
        live.gs.send_map(map_message(live.world, home))
        js_cells = "return (rotaGs.map && rotaGs.map.cells.length) || 0"
        until(lambda: driver.execute_script(js_cells) > 100, 20,
              f"the map on the page {list(station.hub.items)} {text('log')}")
        _rejected_plan_is_drawn_as_rejected(live, home, text, until, driver)
        # arm needs a confirmation: cancel first (nothing happens), then confirm
        click("btn-arm")
        assert driver.find_element(By.ID, "confirm").is_displayed()
        assert "motors will spin" in text("confirm-text")
        click("confirm-no")
        assert not driver.find_element(By.ID, "confirm").is_displayed()
        seen = live.gs.status_count
        live.wait(lambda s: live.gs.status_count >= seen + 3, 5, "three more statuses")
        assert live.gs.status["state"] == "ready"
        click("btn-arm")
        click("confirm-yes")
        until(lambda: text("state") == "armed", 15, "armed on the page")
        r = live.rota_gs("cmd", "takeoff")  # the CLI waits until PX4 reports airborne
        assert r.returncode == 0 and "(state airborne)" in r.stdout, r
        asyncio.run(_hover(live.gs))
        # a trajectory from the held position, sent from a file by the CLI
        here = np.asarray(live.gs.telemetry["position"]) + home
        goal = [live.world.goal[0], live.world.goal[1], here[2]]
        traj = plan(live.world, v_max=2.0, a_max=2.0, start=here, goal=goal,
                    clearance=PLANNER_CLEARANCE_M)
        map_voxels = live.gs.status["map_voxels"]
        # a fence in the map (not in the world) 0.5 m beside the middle of the path: the
        # page must show the braking zone it makes
        _, v, _ = traj.evaluate(np.array([0.5 * traj.duration]))
        ahead = v[0] / np.linalg.norm(v[0])
        side = np.cross(ahead, [0.0, 0.0, 1.0])
        mid = traj.position(0.5 * traj.duration)[0]
        fence = [mid + 0.5 * side + k * 0.5 * ahead + [0.0, 0.0, z]
                 for k in (-1.5, -0.5, 0.5, 1.5) for z in np.arange(-1.0, 1.0, 0.1)]
        pts = np.vstack([live.world.voxel_points(0.1), fence]) - home
        live.gs.send_map(VoxelMap.from_points(pts, 0.1, origin=-home).to_dict()
                         | {"stamp": time.time()})
        live.wait(lambda s: (s.get("map_voxels") or 0) > map_voxels, 10, "the map with the fence")
        path = live.tmp / "plan-0.json"
        path.write_text(json.dumps(trajectory_message(to_local(traj, home), "plan-0")))
        r = live.rota_gs("send", str(path))
        assert r.returncode == 0 and r.stdout.startswith("plan-0: optimal"), r
        zones = int(r.stdout.split(" braking zone")[0].rsplit(" ", 1)[1])
        until(lambda: driver.execute_script("return rotaGs.latestPlan && rotaGs.latestPlan.id")
              == "plan-0", 10, "the plan on the page")
        click("btn-start")
        assert "Start offboard" in text("confirm-text")
        click("confirm-yes")
        try:
            until(lambda: text("plan-id").startswith("plan-0:"), 20, "flying plan-0")
        except TimeoutException:  # say why: the service's own account
            st = live.gs.status
            raise AssertionError(f"plan-0 not flying on the page; service state "
                                 f"{st.get('state')}, last error {st.get('last_error')}, "
                                 f"page log {text('log')!r}") from None
        watch = live.rota_gs("watch", "--duration", "2.5")
        assert watch.returncode == 0 and "plan plan-0:" in watch.stdout, watch
        assert "braking zones ahead:" in watch.stdout and "state OFFBOARD" in watch.stdout
        # the page draws the newest re-time (plan-0 again, from the hold, at start)
        newest = live.gs.retimed[-1]
        assert zones > 0 and newest["id"] == "plan-0" and driver.execute_script(
            "return rotaGs.latestPlan.zones.length") == len(newest["braking_zones"]) > 0
        until(lambda: "in " in text("zones") or "none ahead" in text("zones"), 5, "zones")
        time.sleep(0.3)  # one more frame drawn: the screenshot is for people
        shot = os.environ.get("ROTA_GS_SCREENSHOT") or str(live.tmp / "page.png")
        driver.save_screenshot(shot)
        until(lambda: text("command").startswith("hold"), 40, "the end of the trajectory")
        log = text("log")
        assert "state offboard" in log and "re-timed plan-0: optimal" in log
        assert "start: ok" in log and "arm: ok" in log
        click("btn-abort")
        assert "Abort?" in text("confirm-text")
        click("confirm-yes")
        until(lambda: text("state") == "airborne", 15, "PX4 Hold after abort")
        _limits_shown_are_those_in_force(live, text, until, driver)
        _no_contact_when_the_service_stops(live, text, until, driver)
        r = live.rota_gs("cmd", "land")
        assert r.returncode == 0 and "(state ready)" in r.stdout, r
    finally:
        if driver is not None:
            driver.quit()
        stop(server)
        station.close()


def _rejected_plan_is_drawn_as_rejected(live, home, text, until, driver) -> None:  # noqa: ANN001
    """A plan straight through a tree: rejected, and the page draws it apart (no
    speeds, no braking zones), with the reason."""
    from selenium.webdriver.common.by import By

    trunk = live.world.voxel_points(0.1) - home
    p = trunk[np.argmin(np.abs(trunk[:, 2] - 1.5))]  # a voxel of a tree 1.5 m up
    ctrl = p + np.linspace(-2.5, 2.5, 8)[:, None] * [1.0, 0.0, 0.0]
    path = live.tmp / "through-a-tree.json"
    path.write_text(json.dumps(trajectory_message(
        BSplineTrajectory(control_points=ctrl, degree=3, knot_span=0.8), "through-a-tree")))
    r = live.rota_gs("send", str(path))
    assert r.returncode == 1 and r.stdout.startswith("through-a-tree: rejected"), r
    until(lambda: driver.execute_script("return rotaGs.drawn.rejected") == "through-a-tree",
          10, "the rejected plan on the map")
    drawn = driver.execute_script("return rotaGs.drawn")
    assert drawn["plan"] is None and drawn["zones"] == 0, drawn  # not in the flown style
    assert driver.execute_script("return rotaGs.plans['through-a-tree'] === undefined")
    reason = live.gs.retimed[-1]["message"]
    assert reason and text("rejected") == f"through-a-tree: {reason}"
    assert f"REJECTED through-a-tree: {reason}" in driver.find_element(By.ID, "log").text


def _limits_shown_are_those_in_force(live, text, until, driver) -> None:  # noqa: ANN001
    """After a run-time change of v_max the page (table, chart line) and the
    terminal views show the new limit."""
    r = live.rota_gs("config", "set", "limits.v_max=1.2")
    assert r.returncode == 0, r
    until(lambda: "v_max 1.2 m/s" in text("limits"), 5, "the new limit on the page")
    until(lambda: driver.execute_script("return rotaGs.drawn.vMaxLine") == 1.2, 5,
          "the chart's v_max line at the new limit")
    assert "(limit 1.2)" in text("speed-now")
    r = live.rota_gs("status")
    assert r.returncode == 0 and "limit 1.2" in r.stdout and "limit 2" not in r.stdout, r
    assert live.rota_gs("config", "set", "limits.v_max=2").returncode == 0
    until(lambda: "v_max 2 m/s" in text("limits"), 5, "the limit back on the page")


def _no_contact_when_the_service_stops(live, text, until, driver) -> None:  # noqa: ANN001
    """The service stopped in the air (SIGSTOP: silent, as a crashed or hung one;
    PX4 holds on its own after the abort): within 2 s the page says NO CONTACT,
    greys the state, mode and speed and disables the commands that need a live
    service; when the service runs again the page recovers."""
    from selenium.webdriver.common.by import By

    def cls(el_id: str) -> str:
        return driver.find_element(By.ID, el_id).get_attribute("class")

    def enabled(el_id: str) -> bool:
        return driver.find_element(By.ID, el_id).is_enabled()

    assert text("contact").startswith("heard") and enabled("btn-arm")
    live.service.send_signal(signal.SIGSTOP)
    try:
        until(lambda: text("contact").startswith("NO CONTACT"), 10, "NO CONTACT on the page")
        # the silence the page had measured when it turned: over its 1.5 s threshold,
        # under 2 s (it checks every 0.1 s)
        silence = driver.execute_script("return rotaGs.silenceAtFlip")
        assert 1.5 < silence < 2.0, silence
        assert "stale" in cls("state") and "stale" in cls("link") and "bad" in cls("contact")
        assert "stale" in driver.find_element(By.TAG_NAME, "body").get_attribute("class")
        assert driver.find_element(By.ID, "stale-banner").is_displayed()
        assert text("state") == "airborne"  # as it was last heard, greyed
        until(lambda: "s old)" in text("speed-now"), 5, "the speed marked old")
        assert not any(enabled(b) for b in ("btn-arm", "btn-takeoff", "btn-start", "btn-disarm"))
        assert all(enabled(b) for b in ("btn-hold", "btn-land", "btn-abort"))
    finally:
        live.service.send_signal(signal.SIGCONT)
    until(lambda: text("contact").startswith("heard"), 20, "contact again on the page")
    assert "stale" not in cls("state") and enabled("btn-arm")
    assert not driver.find_element(By.ID, "stale-banner").is_displayed()
    assert "contact again" in text("log")


async def _hover(gs: GroundStation) -> None:
    from sitl.demo import hovering

    await hovering(gs)


def test_the_flight_record_replays(live):
    live.service.send_signal(signal.SIGTERM)
    assert live.service.wait(30) == 0
    files = sorted(live.record_dir.glob("sim-*.mcap"))
    assert files
    out = live.tmp / "replay.png"
    r = live.rota_gs("replay", *map(str, files), "--plot", str(out), "--json")
    assert r.returncode == 0, r.stderr
    figures = json.loads(r.stdout.rsplit("\nplot:", 1)[0])
    assert figures["plans_flown"] == ["plan-0"] and figures["setpoints"] > 300
    assert 1.0 < figures["max_speed_m_s"] < 3.0 and figures["max_tracking_error_m"] < 1.5
    # what was commanded stays inside the file's envelope (v_max 2, a_max per axis
    # [2, 2, 1.5]), within the re-timer's 1 % between check points
    assert figures["max_commanded_speed_m_s"] <= 2.0 * 1.01
    assert all(a <= lim * 1.01 for a, lim in
               zip(figures["max_acceleration_per_axis_m_s2"], (2.0, 2.0, 1.5), strict=True))
    assert out.stat().st_size > 50_000
    shutil.rmtree(live.record_dir)
