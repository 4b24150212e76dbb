"""How fast the service reacts to a planner: for each replan flown, the time from
the trajectory message's arrival at the service to the first setpoint of its
re-timed plan leaving for PX4, and its parts:

========== ===================================================================
decode     arrival (Zenoh's callback) to decoded and validated (worker process)
queue      decoded to the start of its re-time (a re-time already running, or
           the newest-only rule holding it)
retime     the re-time in the worker: join, ROTA, and the hand-back
stitch     re-timed to offered to the stream as a plan
takeover   offered to its takeover: the plan starts at a takeover time chosen
           ahead (the solve latency estimate, so the join is where the command
           will be) and at the setpoint tick on or after it
========== ===================================================================

All on the service's monotonic clock. :class:`Reactions` keeps the last
:data:`KEPT` and summarises them on status (``reaction_ms``); ``rota-companion
soak`` prints them.
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

#: Replans kept for the summary.
KEPT = 600
PARTS = ("decode", "queue", "retime", "stitch", "takeover")


@dataclass(frozen=True)
class Timing:
    """Clock times (monotonic, s) of one trajectory on its way to the vehicle."""

    arrived: float
    decoded: float
    started: float = 0.0  #: its re-time began
    retimed: float = 0.0  #: its re-time came back
    offered: float = 0.0  #: offered to the stream as a plan


class Reactions:
    """The last :data:`KEPT` reactions (thread-safe: the stream's thread adds them)."""

    def __init__(self) -> None:
        self._rows: deque[tuple[float, ...]] = deque(maxlen=KEPT)
        self._lock = threading.Lock()
        self._added = 0
        self._summary: tuple[int, dict[str, Any] | None] = (0, None)

    def flown(self, timing: Timing | None, first_setpoint: float) -> None:
        """A plan whose trajectory went through ``timing`` took over at ``first_setpoint``."""
        if timing is None or not timing.offered:
            return
        t = timing
        row = (first_setpoint - t.arrived, t.decoded - t.arrived, t.started - t.decoded,
               t.retimed - t.started, t.offered - t.retimed, first_setpoint - t.offered)
        with self._lock:
            self._rows.append(row)
            self._added += 1

    def summary(self) -> dict[str, Any] | None:
        """p50, p99 and max of the whole and p50 and p99 of each part, in ms (None:
        none yet); made again only when a reaction was added since (status asks twice
        a second)."""
        with self._lock:
            if self._summary[0] == self._added:
                return self._summary[1]
            added, rows = self._added, np.array(self._rows) * 1000.0
        p50, p99 = np.percentile(rows, [50.0, 99.0], axis=0).round(1).tolist()
        out = {"count": len(rows), "p50": p50[0], "p99": p99[0],
               "max": round(float(rows[:, 0].max()), 1),
               "parts_p50": dict(zip(PARTS, p50[1:], strict=True)),
               "parts_p99": dict(zip(PARTS, p99[1:], strict=True))}
        self._summary = (added, out)
        return out
