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

    def flown(self, timing: Timing | None, first_setpoint: float) -> None:
        """A plan whose trajectory went through ``timing`` took over at ``first_setpoint``."""
        if timing is None or not timing.offered:
            return
        t = timing
        row = (first_setpoint - t.arrived, t.decoded - t.arrived, t.started - t.decoded,
               t.retimed - t.started, t.offered - t.retimed, first_setpoint - t.offered)
        with self._lock:
            self._rows.append(row)

    def summary(self) -> dict[str, Any] | None:
        """p50, p99 and max of the whole and p50 of each part, in ms (None: none yet)."""
        with self._lock:
            if not self._rows:
                return None
            rows = np.array(self._rows) * 1000.0
        total = rows[:, 0]
        return {"count": len(rows),
                "p50": round(float(np.percentile(total, 50)), 1),
                "p99": round(float(np.percentile(total, 99)), 1),
                "max": round(float(total.max()), 1),
                "parts_p50": {name: round(float(np.percentile(rows[:, i + 1], 50)), 1)
                              for i, name in enumerate(PARTS)},
                "parts_p99": {name: round(float(np.percentile(rows[:, i + 1], 99)), 1)
                              for i, name in enumerate(PARTS)}}
