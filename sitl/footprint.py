"""What a process tree costs the machine it runs on, read from ``/proc``: CPU time
(user + system, the share of one core over a window), resident memory (RSS) and
proportional memory (PSS: shared pages split among the processes that map them,
so the tree's PSS adds up to what it really takes), per process and in total.

``rota-sitl soak`` samples the service's tree with it (``docs/service.md``,
"Footprint").
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

_TICK = os.sysconf("SC_CLK_TCK")


@dataclass(frozen=True)
class Process:
    pid: int
    name: str  #: the command line, shortened
    cpu_s: float  #: user + system CPU time so far
    rss_mb: float
    pss_mb: float


def children(pid: int) -> list[int]:
    """Every descendant of ``pid`` (children first, then theirs)."""
    out: list[int] = []
    todo = [pid]
    while todo:
        parent = todo.pop()
        for task in Path(f"/proc/{parent}/task").glob("*"):
            try:
                kids = [int(k) for k in (task / "children").read_text().split()]
            except OSError:
                continue
            out.extend(kids)
            todo.extend(kids)
    return out


def _name(pid: int) -> str:
    raw = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    words = [w.decode(errors="replace") for w in raw if w]
    for i, word in enumerate(words):  # python -m module ...: the module is the name
        if word == "-m" and i + 1 < len(words):
            return " ".join(words[i + 1:i + 3])
        if "multiprocessing.forkserver" in word:  # the fork server and what it forked
            return "worker (forked)" if "forkserver" in _parent_cmdline(pid) else "fork server"
        if "multiprocessing" in word or "spawn_main" in word:
            return "worker (spawned)"
    return " ".join(Path(w).name if j == 0 else w for j, w in enumerate(words[:2]))


def _parent_cmdline(pid: int) -> str:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        ppid = stat[stat.rindex(")") + 2:].split()[1]
        return Path(f"/proc/{ppid}/cmdline").read_bytes().decode(errors="replace")
    except (OSError, IndexError, ValueError):
        return ""


def process(pid: int) -> Process | None:
    """One process now (None: it is gone)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        fields = stat[stat.rindex(")") + 2:].split()
        cpu = (int(fields[11]) + int(fields[12])) / _TICK  # utime, stime
        rss = pss = 0.0
        for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
            key, _, value = line.partition(":")
            if key == "Rss":
                rss = int(value.split()[0]) / 1024
            elif key == "Pss":
                pss = int(value.split()[0]) / 1024
        return Process(pid, _name(pid), cpu, rss, pss)
    except (OSError, ValueError, IndexError):
        return None


def tree(pid: int) -> dict[int, Process]:
    """``pid`` and its descendants now."""
    out = {}
    for p in [pid, *children(pid)]:
        got = process(p)
        if got is not None:
            out[p] = got
    return out


@dataclass(frozen=True)
class Usage:
    """A process tree over a window: CPU share of one core and memory at its end."""

    window_s: float
    processes: tuple[tuple[str, float, float, float], ...]  #: (name, cpu share, RSS, PSS)

    @property
    def cpu(self) -> float:
        return sum(p[1] for p in self.processes)

    @property
    def rss_mb(self) -> float:
        return sum(p[2] for p in self.processes)

    @property
    def pss_mb(self) -> float:
        return sum(p[3] for p in self.processes)

    def table(self) -> str:
        rows = [f"{'process':<34} {'CPU':>7} {'RSS MB':>8} {'PSS MB':>8}"]
        rows += [f"{name[:34]:<34} {100 * cpu:6.1f}% {rss:8.1f} {pss:8.1f}"
                 for name, cpu, rss, pss in self.processes]
        rows.append(f"{'total':<34} {100 * self.cpu:6.1f}% {self.rss_mb:8.1f} "
                    f"{self.pss_mb:8.1f}")
        return "\n".join(rows) + f"\n(over {self.window_s:.0f} s; CPU as a share of one core)"


class Meter:
    """CPU and memory of a process tree between :meth:`start` and :meth:`stop`."""

    def __init__(self, pid: int) -> None:
        self.pid = pid
        self._t0 = 0.0
        self._before: dict[int, Process] = {}

    def start(self) -> None:
        self._t0, self._before = time.monotonic(), tree(self.pid)

    def stop(self) -> Usage:
        now, after = time.monotonic(), tree(self.pid)
        window = now - self._t0
        rows = []
        for pid, p in after.items():
            # a process born in the window: all its CPU time is in the window
            spent = p.cpu_s - (self._before[pid].cpu_s if pid in self._before else 0.0)
            rows.append((p.name, spent / window, p.rss_mb, p.pss_mb))
        return Usage(window, tuple(rows))
