"""Why a tick of the setpoint stream came late, from the kernel's own accounting.

A tick late by tens of milliseconds has one of three causes, and each calls for a
different remedy on the companion computer:

* the thread **waited for a CPU** (it was runnable, other work ran): the kernel's
  run-queue wait of the thread grew (``/proc/thread-self/schedstat``, field 2):
  give the service more priority or a CPU of its own;
* the **host took the CPU** (a virtual machine's hypervisor ran something else:
  nothing on that CPU runs, at any priority): the ``steal`` counter of a CPU grew
  (``/proc/stat``); it cannot happen on bare metal;
* the thread was **blocked** (Python's GIL, a lock): neither grew, and the thread
  was woken many times (field 3, time slices) while it waited.

:class:`TickClock` keeps the counters of the last tick (one read of two small
files per tick, about 30 us; the parsing happens only for a late tick) and
:meth:`TickClock.explain` says, in words, what the kernel saw since then. Where
the files do not exist it says nothing.
"""

from __future__ import annotations

import os

#: The unit of /proc/stat (clock ticks per second).
CLOCK_TICKS = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def _read(path: str) -> bytes | None:
    try:
        with open(path, "rb") as f:
            return f.read(65536)
    except OSError:
        return None


def _sched(raw: bytes | None) -> tuple[int, int] | None:
    """(run-queue wait ns, time slices) from a schedstat line."""
    if not raw:
        return None
    fields = raw.split()
    return (int(fields[1]), int(fields[2])) if len(fields) >= 3 else None


def _steal(raw: bytes | None) -> list[int]:
    """Steal ticks per CPU from /proc/stat."""
    if not raw:
        return []
    out = []
    for line in raw.split(b"\n"):
        if line.startswith(b"cpu") and line[3:4].isdigit():
            fields = line.split()
            out.append(int(fields[8]) if len(fields) > 8 else 0)
    return out


class TickClock:
    """The kernel's counters for the calling thread at its last tick (call
    :meth:`tick` from the thread itself, once per tick)."""

    def __init__(self) -> None:
        self._prev: tuple[bytes | None, bytes | None] = (None, None)
        self._now: tuple[bytes | None, bytes | None] = (None, None)

    def tick(self) -> None:
        self._prev = self._now
        self._now = (_read("/proc/thread-self/schedstat"), _read("/proc/stat"))

    def explain(self) -> str:
        """What the kernel saw between the last two ticks, in words ("" if unknown)."""
        a, b = _sched(self._prev[0]), _sched(self._now[0])
        parts = []
        s0, s1 = _steal(self._prev[1]), _steal(self._now[1])
        if s0 and len(s0) == len(s1):
            took = max(y - x for x, y in zip(s0, s1, strict=True)) / CLOCK_TICKS
            if took > 0:
                parts.append(f"the host took a CPU for {1e3 * took:.0f} ms")
        if a is not None and b is not None:
            parts.append(f"the stream waited {(b[0] - a[0]) / 1e6:.0f} ms for a CPU")
            if b[1] - a[1] > 3:
                parts.append(f"was woken {b[1] - a[1]} times (blocked: the GIL or a lock)")
        return "; ".join(parts)
