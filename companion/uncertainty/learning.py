"""The in-flight estimator's link to the service: feeding it while flying in
offboard, saving it, and answering the ``estimator`` query
(``docs/estimator.md``)."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable
from typing import Any

import numpy as np

from companion.flight.autopilot import Autopilot
from companion.settings.config import Config
from companion.settings.reconfigure import parse_estimator_request
from companion.status import Reporter, after_setpoint
from companion.uncertainty.estimator import UncertaintyEstimator


class Learning:
    def __init__(self, estimator: UncertaintyEstimator | None, autopilot: Autopilot,
                 flying: Callable[[], bool], track_errors: Callable[[], np.ndarray],
                 link_timeout_s: Callable[[], float], report: Reporter,
                 beat: asyncio.Event | None = None) -> None:
        self.estimator = estimator
        self._beat = beat or asyncio.Event()  # the stream's (set after every setpoint)
        self.autopilot = autopilot
        self._flying = flying
        self._track_errors = track_errors
        self._link_timeout_s = link_timeout_s
        self.report = report

    async def run(self) -> None:
        """5 Hz: feed the estimator while flying in offboard; save every 10 s."""
        k = 0
        while self.estimator is not None:
            await asyncio.sleep(0.18)
            await after_setpoint(self._beat, 0.05)  # in the stream's idle time
            k += 1
            est, tel = self.estimator, self.autopilot.telemetry
            if k % 50 == 0 and est.samples:
                with contextlib.suppress(OSError):
                    est.save()
            if not (self._flying() and tel.velocity is not None
                    and self.autopilot.link_ok(self._link_timeout_s())):
                continue
            errors = self._track_errors()
            if len(errors):  # the newest tracking error, horizontal axes
                std = tel.position_std
                est.observe(float(np.linalg.norm(tel.velocity)), np.asarray(errors[-1])[:2],
                            None if std is None else np.asarray(std)[:2])

    def answer(self, request: Any, peer: str = "unknown",
               file_cfg: Config | None = None) -> tuple[bool, str, dict[str, Any] | None]:
        """The ``estimator`` query: read (None), or ``{"reset": true}``,
        ``{"freeze": bool}``, ``{"set": {"m": .., "b": .., "memory_s": ..}}`` (memory_s
        optional). A set may only be at least as cautious as ``file_cfg``'s model (the
        envelope; learning may go below it, on evidence). Every change is audited and saved with the
        estimate. Returns (ok, message, description)."""
        ok, message = True, ""
        est = self.estimator
        try:
            if est is None:
                raise ValueError("the in-flight estimator is disabled ([estimator] enabled)")
            if request is not None:
                # checked whole first (companion.settings.reconfigure): a refused part
                # applies nothing
                req = parse_estimator_request(request, file_cfg)
                if req.reset:
                    est.reset()
                    message = "estimate reset to the configured model"
                if req.freeze is not None:
                    est.freeze(req.freeze)
                    message = f"estimator {'frozen' if req.freeze else 'learning'}"
                if req.set is not None:
                    m, b, memory = req.set
                    est.set(m, b, memory)
                    message = f"estimate set to m={m}, b={b}" + (
                        "" if memory is None else f", memory_s={memory}")
                est.save()
                self.report.audit(f"estimator: {message} (saved: it outlives a restart)", peer)
        except (ValueError, KeyError, TypeError, OSError) as exc:
            ok, message = False, str(exc)
            self.report.error("estimator", message)
        return ok, message, est.describe() if est is not None else None

    def save(self) -> None:
        if self.estimator is not None:
            with contextlib.suppress(OSError):
                self.estimator.save()

