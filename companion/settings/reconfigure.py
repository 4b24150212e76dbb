"""Run-time requests over Zenoh: the ``config`` query, and the parsing of the
``estimator`` query's requests.

Configuration changes stay inside the config file's envelope
(:mod:`companion.settings.envelope`), each is audited (logged at WARNING with the
requesting peer, an ``audit`` event on status), and none survives a restart: the
config file is the vehicle's configuration, and the service starts from it every
time (``docs/security.md``).

Every request is checked whole before anything of it applies: a request with one
refused part changes nothing. Booleans are ``true`` or ``false`` (never a truthy
string or number), numbers finite and within a float's range, and an error names
the field.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from companion.settings.config import (
    SECTIONS,
    Config,
    ConfigError,
    flag,
    from_dict,
    number,
    short,
    unknown_section,
)
from companion.settings.envelope import check_change
from companion.status import Reporter

#: Settings that can change at run time through the config queryable.
RUNTIME_SECTIONS = ("limits", "safety", "uncertainty", "stream")  # [estimator]: its query
CONFIG_FORM = '{"set": {section: {name: value}}}'


class Reconfigure:
    """Applies ``{"set": {section: {name: value}}}`` requests to the live config."""

    def __init__(self, file_cfg: Config, current: Callable[[], Config],
                 use: Callable[[Config], None], report: Reporter) -> None:
        self.file_cfg = file_cfg  # the envelope
        self._current = current
        self._use = use
        self.report = report

    def apply(self, request: Any, peer: str) -> str:
        changes = parse_config_request(request)
        new = from_dict(changes, base=self._current())
        check_change(self.file_cfg, new, changes)
        self._use(new)
        self.report.audit(f"configuration changed: {json.dumps(changes)} (until the next "
                          "restart)", peer)
        return "configuration updated (until the next restart: the config file rules)"


def parse_config_request(request: Any) -> dict[str, dict[str, Any]]:
    """The changes of a config request, its sections checked: unknown sections are
    named as unknown (with the sections that can change), known ones that cannot
    change at run time as such. (The settings are checked by
    :func:`companion.settings.config.from_dict` and
    :func:`companion.settings.envelope.check_change`.)"""
    if not isinstance(request, dict) or set(request) != {"set"} \
            or not isinstance(request["set"], dict):
        raise ConfigError(f"config request must be {CONFIG_FORM}")
    changes = request["set"]
    if not changes:
        raise ConfigError(f"config request: nothing to set ({CONFIG_FORM})")
    for section, values in changes.items():
        if section not in SECTIONS:
            raise unknown_section(section, RUNTIME_SECTIONS, "sections that change at run time")
        if section not in RUNTIME_SECTIONS:
            raise ConfigError(f"[{section}]: cannot change at run time (only "
                              f"{', '.join(RUNTIME_SECTIONS)} can; restart with a new config "
                              "file to change it)")
        if not isinstance(values, dict) or not values:
            raise ConfigError(f"[{section}]: must be a table of settings, got "
                              f"{short(json.dumps(values))}")
    return changes


# ------------------------------------------------------------------ estimator
ESTIMATOR_FORM = ('{"reset": true}, {"freeze": true|false} or {"set": {"m": number, '
                  '"b": number[, "memory_s": number]}} (or several of them in one object)')


@dataclass(frozen=True)
class EstimatorRequest:
    """An ``estimator`` query's request, checked whole: what to do, in this order."""

    reset: bool = False
    freeze: bool | None = None  # None: leave as it is
    set: tuple[float, float, float | None] | None = None  # (m, b, memory_s or None)


def parse_estimator_request(request: Any, file_cfg: Config | None) -> EstimatorRequest:
    """Check an ``estimator`` request before any of it applies. A ``set`` may only be
    as cautious as ``file_cfg``'s model or more (``m``, ``b``, ``memory_s`` at least the
    file's) and within the estimator's bounds. Raises ConfigError (a ValueError)."""
    if not isinstance(request, dict) or not request \
            or not set(request) <= {"reset", "freeze", "set"}:
        raise ConfigError(f"request must be {ESTIMATOR_FORM}")
    reset = flag(request.get("reset", False), "reset")
    freeze = flag(request["freeze"], "freeze") if "freeze" in request else None
    model = None
    if "set" in request:
        model = _model(request["set"])
        if file_cfg is not None:
            _inside(file_cfg, *model)
    return EstimatorRequest(reset=reset, freeze=freeze, set=model)


def _model(values: Any) -> tuple[float, float, float | None]:
    """(m, b, memory_s or None) of a set request, finite numbers."""
    if not isinstance(values, dict) or not {"m", "b"} <= set(values) <= {"m", "b", "memory_s"}:
        raise ConfigError('set: must be {"m": number, "b": number[, "memory_s": number]}')
    m = number(values["m"], "set: m")
    b = number(values["b"], "set: b")
    memory = values.get("memory_s")
    return m, b, None if memory is None else number(memory, "set: memory_s")


def _inside(file_cfg: Config, m: float, b: float, memory: float | None) -> None:
    u, e = file_cfg.uncertainty, file_cfg.estimator
    if m < u.m or b < u.b or (memory is not None and memory < u.memory_s):
        raise ConfigError(f"m={m}, b={b}, memory_s={memory} refused: a set may only be as "
                          f"cautious as the config file's m={u.m}, b={u.b}, "
                          f"memory_s={u.memory_s} or more")
    if not (e.m_min <= m <= e.m_max and e.b_min <= b <= e.b_max):
        raise ConfigError(f"m={m}, b={b} outside the bounds m in [{e.m_min}, {e.m_max}], "
                          f"b in [{e.b_min}, {e.b_max}]")
    if memory is not None and not 0.0 <= memory <= e.memory_max_s:
        raise ConfigError(f"memory_s={memory} outside [0, {e.memory_max_s}]")
