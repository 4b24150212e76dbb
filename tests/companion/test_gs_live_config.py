"""The live Foxglove view (``rota-gs foxglove``) learns the service's configuration even
when its first query goes unanswered (a service still starting, a busy machine: seen in
tests/e2e/test_foxglove_e2e.py, every plot without ``v_max``), and follows the speed limit
in force that every status carries (a run-time tightening)."""

from __future__ import annotations

import time

import companion.gs.foxglove as live
from companion.gs.client import GroundStationError


class _Session:
    def declare_subscriber(self, key, handler):  # noqa: ANN001, ANN201, ARG002
        return self

    def undeclare(self) -> None:
        pass


class _Station:
    """What the view uses of a GroundStation; its config query fails ``fail`` times."""

    vehicle = "sim"

    def __init__(self, fail: int) -> None:
        self.fail, self.asked, self.status = fail, 0, {}
        self.session = _Session()
        self.on_message = None

    def key(self, name: str) -> str:
        return f"rota/sim/{name}"

    def config(self) -> dict:
        self.asked += 1
        if self.asked <= self.fail:
            raise GroundStationError("no reply to 'config' within 5 s")
        return {"ok": True, "config": {"limits": {"v_max": 2.0},
                                       "safety": {"max_tracking_error_m": 1.5}}}


def _until(predicate, timeout_s: float = 5.0) -> None:  # noqa: ANN001
    end = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.01)


def test_a_config_not_given_at_start_is_asked_again_on_a_status(monkeypatch):
    monkeypatch.setattr(live, "CONFIG_RETRY_S", 0.0)
    gs = _Station(fail=1)
    view = live.LiveView(gs, port=0)
    try:
        assert view.config is None and gs.asked == 1
        view._on_message("status", {"limits": {"v_max": 2.0}})
        _until(lambda: view.config is not None)
        assert gs.asked == 2
        _until(lambda: view.scene.v_max == 2.0 and view.scene.brake_at == 1.5)
    finally:
        view.close()


def test_the_speed_limit_follows_the_status():
    v_max = 1.5
    gs = _Station(fail=0)
    view = live.LiveView(gs, port=0)
    try:
        _until(lambda: view.scene.v_max == 2.0)
        view._on_message("status", {"limits": {"v_max": v_max}})  # tightened at run time
        _until(lambda: view.scene.v_max == v_max)
        assert view.scene.brake_at == 1.5 and gs.asked == 1  # the rest kept, no new query
    finally:
        view.close()
