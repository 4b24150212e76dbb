"""Run-time configuration over Zenoh: the ``config`` query. Changes stay inside
the config file's envelope (:mod:`companion.envelope`), each is audited (logged
at WARNING with the requesting peer, an ``audit`` event on status), and none
survives a restart: the config file is the vehicle's configuration, and the
service starts from it every time (``docs/security.md``)."""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

from companion.config import Config, ConfigError, from_dict
from companion.envelope import check_change
from companion.status import Reporter

#: Settings that can change at run time through the config queryable.
RUNTIME_SECTIONS = ("limits", "uncertainty", "safety")  # [estimator]: the estimator query


class Reconfigure:
    """Applies ``{"set": {section: {name: value}}}`` requests to the live config."""

    def __init__(self, file_cfg: Config, current: Callable[[], Config],
                 use: Callable[[Config], None], report: Reporter) -> None:
        self.file_cfg = file_cfg  # the envelope
        self._current = current
        self._use = use
        self.report = report

    def apply(self, request: Any, peer: str) -> str:
        if not isinstance(request, dict) or set(request) != {"set"} \
                or not isinstance(request["set"], dict):
            raise ConfigError('config request must be {"set": {section: {name: value}}}')
        changes = request["set"]
        for section, values in changes.items():
            if section not in RUNTIME_SECTIONS:
                raise ConfigError(f"[{section}]: cannot change at run time "
                                  f"(only {', '.join(RUNTIME_SECTIONS)}); restart")
            if not isinstance(values, dict):
                raise ConfigError(f"[{section}]: must be a table")
        new = from_dict(changes, base=self._current())
        check_change(self.file_cfg, new, changes)
        self._use(new)
        self.report.audit(f"configuration changed: {json.dumps(changes)} (until the next "
                          "restart)", peer)
        return "configuration updated (until the next restart: the config file rules)"
