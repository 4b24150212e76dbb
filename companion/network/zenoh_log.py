"""Zenoh's own log in the service's: access-control denials as warnings.

Zenoh drops a message its access control denies before the service sees it, and
says so only in its own (Rust) log, at TRACE, on standard output: one line per
denied message, beside one line per *allowed* message at the same level. Nothing
of that reached any log before. :func:`forward` runs Zenoh's log into a pipe read
by a thread here, which passes on

* each denial as a WARNING of the service's log (so the journal and the flight
  record's ``log`` channel name the peer, its link and the key), the same denial
  repeated within :data:`REPEAT_S` counted, not repeated;
* Zenoh's own warnings and errors, as they are;

and drops the rest. Whatever else writes to standard output (the service's own
log goes straight to it, not through the pipe) passes through unchanged. The
pipe's writing end never blocks: were this thread ever starved, Zenoh's log
lines are lost, never Zenoh's threads held up.

Process-wide (it takes over file descriptor 1), so only the service's command
line (``rota-companion run``) calls it, before its logging is set up, and only
when the access control is on.
"""

from __future__ import annotations

import fcntl
import logging
import os
import re
import select
import sys
import threading
import time

log = logging.getLogger("rota.companion")

#: Zenoh's log filter: warnings, and the access control's per-message verdicts.
FILTER = "warn,zenoh::net::routing::interceptor::access_control=trace"
#: Denial lines of one peer, flow and key this close together are one warning, s.
GROUP_S = 0.1
#: The same warning again within this many seconds is counted, not logged again.
REPEAT_S = 1.0
#: Denials remembered for counting (a flood of distinct keys stays bounded).
MAX_REMEMBERED = 256

_ANSI = re.compile(r"\x1b\[[0-9;]*m")
#: ``<stamp> <LEVEL> [thread] ThreadId(n) <target>: <message>``
_LINE = re.compile(r"^\S+\s+(TRACE|DEBUG|INFO|WARN|ERROR)\s+.*?(zenoh[\w:]*): (.*)$")
#: ``<zid> on <interface+transport+cert...> is unauthorized to <Put> (<ingress>) on <key>``
_DENIED = re.compile(r"^(\S+) on (\S+) is unauthorized to (.+?) \((\w+)\) on (.*)$")


class Denials:
    """Groups Zenoh's denial lines: those of one peer, flow and key that come
    within :data:`GROUP_S` (Zenoh's verdicts for every message kind when it first
    sees a key, or a burst of messages) are said in one warning; the same group
    again within :data:`REPEAT_S` is counted, and the count said with the next."""

    def __init__(self) -> None:
        self._open: dict[tuple[str, str, str], tuple[float, str, list[str]]] = {}
        self._said: dict[tuple[str, str, str], tuple[float, int]] = {}

    def add(self, zid: str, subject: str, action: str, flow: str, key: str,
            now: float) -> None:
        group = (zid, flow, key)
        first, _, actions = self._open.setdefault(group, (now, subject, []))
        if action not in actions:
            actions.append(action)

    def flush(self, now: float, everything: bool = False) -> None:
        """Say the groups older than GROUP_S (all of them with ``everything``)."""
        for group, (first, subject, actions) in list(self._open.items()):
            if not everything and now - first < GROUP_S:
                continue
            del self._open[group]
            said = self._said.get(group)
            if said is not None and now - said[0] < REPEAT_S:
                self._said[group] = (said[0], said[1] + 1)
                continue
            if said is None and len(self._said) >= MAX_REMEMBERED:
                self._said.pop(next(iter(self._said)))
            self._said[group] = (now, 0)
            zid, flow, key = group
            held = said[1] if said else 0
            more = f" (and {held} more times since it was last said)" if held else ""
            log.warning("Zenoh access control denied %s (%s) on %s to peer %s, link %s%s",
                        ", ".join(actions), flow, key, zid, subject, more)


def handle(line: str, denials: Denials, now: float) -> bool:
    """One line of Zenoh's output: taken (True) if it is Zenoh's (a denial goes to
    ``denials``, a warning or error is logged, the rest dropped), else False (the
    caller passes a line that is not Zenoh's through)."""
    match = _LINE.match(_ANSI.sub("", line).strip())
    if match is None:
        return False
    level, _target, message = match.groups()
    denied = _DENIED.match(message)
    if denied:
        zid, subject, action, flow, key = denied.groups()
        denials.add(zid, subject, action, flow, key, now)
    elif level in ("WARN", "ERROR"):
        log.log(logging.ERROR if level == "ERROR" else logging.WARNING, "zenoh: %s", message)
    return True


def forward(zenoh_module) -> None:  # noqa: ANN001 - the zenoh module, imported by the caller
    """Take over standard output for Zenoh's log (see the module's docstring); call
    before logging is set up and before the first Zenoh session opens. ``RUST_LOG``
    set by the user wins."""
    sys.stdout.flush()
    original = os.dup(1)
    read_end, write_end = os.pipe()
    flags = fcntl.fcntl(write_end, fcntl.F_GETFL)
    fcntl.fcntl(write_end, fcntl.F_SETFL, flags | os.O_NONBLOCK)
    os.dup2(write_end, 1)
    os.close(write_end)
    # Python's own standard output (the service's log) goes straight to where fd 1
    # went before; what else writes to fd 1 is passed on by the pump
    sys.stdout = os.fdopen(original, "w", buffering=1, encoding="utf-8",
                           errors="backslashreplace", closefd=False)

    def pump() -> None:
        denials = Denials()
        pending = b""
        while True:
            ready, _, _ = select.select([read_end], [], [], GROUP_S)
            chunk = os.read(read_end, 65536) if ready else b""
            if ready and not chunk:
                break  # (the write end closed: the process is ending)
            pending += chunk
            *lines, pending = pending.split(b"\n")
            now = time.monotonic()
            for raw in lines:
                try:
                    if not handle(raw.decode("utf-8", "replace"), denials, now):
                        os.write(original, raw + b"\n")
                except Exception:  # noqa: BLE001, S110 - the pump must not die on a line
                    pass
            denials.flush(now)

    threading.Thread(target=pump, name="zenoh-log", daemon=True).start()
    zenoh_module.init_log_from_env_or(FILTER)
