"""Time the host took from this machine: the per-CPU ``steal`` counters of
``/proc/stat``, sampled while a test flies.

On a virtual machine the hypervisor may deschedule a virtual CPU. Nothing on
it runs meanwhile, however high its priority, and its clock runs on: measured
on the 2-core VM this project is tested on, with two busy loops beside it, a
process at nice -5 that only sleeps 5 ms at a time overslept by 100-105 ms
several times a minute, each time while ``steal`` on its CPU grew by as much.
A setpoint stream on that CPU shows the same gap, although the service did
nothing wrong; on the companion computer (no hypervisor) it cannot happen.

:class:`StealMonitor` records the counters, and :meth:`HostSteal.excuse` charges
each time the host took a CPU to the one gap it fell in, so that the stream
checks (:mod:`sitl.stream_checks`) can measure gaps net of it and say so.
"""

from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass, field

import numpy as np

#: The kernel's clock ticks per second, the unit of ``/proc/stat``.
CLOCK_TICKS = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
#: Steal is accounted on the CPU it hit when that CPU runs again, at its next
#: timer tick: a sample this long after an interval still belongs to it (s).
ACCOUNTING_DELAY_S = 0.02
#: A gap may be this much shorter than the time the host took and still hold it:
#: the counters round down to whole ticks, and a task asleep on the CPU taken may
#: be woken on the other one a little before the first runs again (s).
OVERLAP_SLACK_S = 2.0 / CLOCK_TICKS
#: Only the host's longer takings are charged (it takes about 100 ms at a time when
#: the machine is busy): a tick or two of steal cannot be told from the stream's
#: own lateness, and the stream's p99 budget must hold with it.
MIN_EVENT_S = 0.05


def read_steal() -> np.ndarray:
    """Seconds stolen from each CPU since boot (empty where unknown)."""
    try:
        with open("/proc/stat") as f:
            lines = [ln.split() for ln in f if ln.startswith("cpu") and ln[3:4].isdigit()]
    except OSError:
        return np.zeros(0)
    # cpuN user nice system idle iowait irq softirq steal ...
    return np.array([int(ln[8]) if len(ln) > 8 else 0 for ln in lines], float) / CLOCK_TICKS


@dataclass(frozen=True)
class HostSteal:
    """Samples of the per-CPU steal counters: ``t`` (host monotonic s) and
    ``steal`` (seconds, one column per CPU)."""

    t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    steal: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))

    def events(self) -> list[tuple[float, float, float]]:
        """Each time the host took a CPU away: ``(from, to, seconds)``, where the
        interval is wide enough to hold it wherever within the sampling it fell
        (consecutive samples that both grew are one event)."""
        out = []
        if len(self.t) < 2 or not self.steal.size:
            return out
        grew = np.diff(self.steal, axis=0)
        for cpu in range(grew.shape[1]):
            k = np.flatnonzero(grew[:, cpu] > 0)
            for run in np.split(k, np.flatnonzero(np.diff(k) > 1) + 1):
                if len(run):
                    amount = float(grew[run, cpu].sum())
                    out.append((float(self.t[run[0]]) - amount - ACCOUNTING_DELAY_S,
                                float(self.t[run[-1] + 1]), amount))
        return out

    def excuse(self, gaps: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """How much of each gap the host took. Every event of at least
        :data:`MIN_EVENT_S`, the largest first, is charged to the largest gap not yet
        charged whose interval ``a[k]`` to ``b[k]`` (host monotonic s) meets it, and
        only if that gap is about as long as the event (:data:`OVERLAP_SLACK_S`): a
        stream whose CPU was taken away for so long has such a gap; if none has,
        the host took another CPU. One event per gap (the stream runs on one CPU at
        a time), and never more than the gap's excess over the stream's usual
        spacing (its median gap)."""
        charged = np.zeros(len(gaps))
        if not len(gaps):
            return charged
        usual = float(np.median(gaps))
        for t0, t1, amount in sorted(self.events(), key=lambda e: -e[2]):
            if amount < MIN_EVENT_S:
                break
            k = np.flatnonzero((b >= t0) & (a <= t1) & (charged == 0)
                               & (gaps >= amount - OVERLAP_SLACK_S))
            if len(k):
                j = k[np.argmax(gaps[k])]
                charged[j] = min(amount, max(gaps[j] - usual, 0.0))
        return charged

    def total(self) -> float:
        """The most time any one CPU lost over all the samples (s)."""
        if len(self.t) < 2 or not self.steal.size:
            return 0.0
        return float(np.max(self.steal[-1] - self.steal[0]))


class StealMonitor:
    """Samples the steal counters every ``period_s`` in a thread, from
    :meth:`start` to :meth:`stop`; :meth:`samples` gives what it has."""

    def __init__(self, period_s: float = 0.01) -> None:
        self.period_s = period_s
        self._t: list[float] = []
        self._steal: list[tuple[float, ...]] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> StealMonitor:
        if read_steal().size and self._thread is None:
            self._thread = threading.Thread(target=self._run, name="steal-monitor",
                                            daemon=True)
            self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            steal = read_steal()
            with self._lock:
                self._t.append(time.monotonic())
                self._steal.append(tuple(steal))

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(1.0)

    def samples(self) -> HostSteal:
        with self._lock:
            if not self._t:
                return HostSteal()
            return HostSteal(np.asarray(self._t), np.asarray(self._steal, float))
