"""What the vehicle received, checked: the offboard setpoints a
:class:`~sitl.process.SimProcess` recorded (:attr:`SimReport.setpoints`),
measured for rate, gaps, jumps, limits and the geofence.

Gaps are measured twice: between the send stamps the setpoints carry
(``time_boot_ms``, the sender's clock: what the service achieved, and a setpoint
lost on the way shows as a gap too) and between their arrival times at the
vehicle (which add the simulator's own scheduling delays). Jumps use the send
stamps, so two setpoints that arrive together are not mistaken for a jump, and
a gap never excuses a leap: the step after a gap may be at most what the
allowed speed covers in the stall budget (a stream that stalled longer and
resumed where the wall clock says the plan now is would jump).

On a virtual machine the host may take a CPU away for about 100 ms
(:mod:`sitl.host_steal`); given the host's steal counters, a gap is measured net
of the time the host took within it, and the figures say how much that was.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from sitl.host_steal import HostSteal

#: Stamps carry whole milliseconds.
STAMP_RESOLUTION_S = 1e-3
#: The longest spacing that may excuse a step between two setpoints (s): the
#: service's default stall budget (``[stream] stall_budget_s``). After a shorter
#: stall the service goes on with its plan where the clock says (the vehicle,
#: following the last setpoint's velocity, is there too); after a longer one it
#: must brake from the last setpoint it sent, and a step past this is a jump.
MAX_STEP_DT = 0.25


@dataclass(frozen=True)
class StreamFigures:
    """Figures of a setpoint stream as the vehicle received it."""

    count: int
    duration_s: float
    max_gap_s: float  # between send stamps
    p99_gap_s: float
    max_arrival_gap_s: float  # between arrivals at the vehicle
    p99_arrival_gap_s: float
    max_speed: float  # largest step between consecutive setpoints over their spacing, m/s
    jumps: int  # steps over ``allowed_speed`` x spacing
    largest_jump_m: float
    outside_fence: int
    non_finite: int
    host_steal_gaps: int = 0  # send gaps within which the host took a CPU away
    host_steal_s: float = 0.0  # how much it took within them (s), left out of them
    max_gap_with_steal_s: float = 0.0  # the largest send gap, the host's time in it
    max_commanded_speed: float = 0.0  # largest |velocity| commanded, m/s

    def problems(self, max_gap_s: float = 0.1, p99_gap_s: float = 0.025) -> list[str]:
        """What breaks the stream's promises (empty: none)."""
        out = []
        if self.count < 2:
            out.append(f"only {self.count} setpoints")
        eps = STAMP_RESOLUTION_S / 2  # stamps are whole milliseconds
        if self.max_gap_s > max_gap_s + eps:
            out.append(f"gap of {self.max_gap_s * 1e3:.0f} ms > {max_gap_s * 1e3:.0f} ms")
        if self.p99_gap_s > p99_gap_s + eps:
            out.append(f"p99 gap {self.p99_gap_s * 1e3:.1f} ms > {p99_gap_s * 1e3:.0f} ms")
        if self.jumps:
            out.append(f"{self.jumps} jumps (largest {self.largest_jump_m:.2f} m)")
        if self.outside_fence:
            out.append(f"{self.outside_fence} setpoints outside the geofence")
        if self.non_finite:
            out.append(f"{self.non_finite} non-finite setpoints")
        return out

    def summary(self) -> str:
        return (f"{self.count} setpoints in {self.duration_s:.1f} s; gap max "
                f"{self.max_gap_s * 1e3:.1f} ms, p99 {self.p99_gap_s * 1e3:.1f} ms (arrival: max "
                f"{self.max_arrival_gap_s * 1e3:.1f}, p99 {self.p99_arrival_gap_s * 1e3:.1f} ms); "
                f"fastest step {self.max_speed:.2f} m/s, fastest velocity commanded "
                f"{self.max_commanded_speed:.3f} m/s, {self.jumps} jumps, "
                f"{self.outside_fence} outside the fence, {self.non_finite} non-finite"
                + (f"; gaps net of {self.host_steal_s * 1e3:.0f} ms the host took a CPU "
                   f"away within {self.host_steal_gaps} of them (largest gap with it: "
                   f"{self.max_gap_with_steal_s * 1e3:.1f} ms)" if self.host_steal_gaps
                   else ""))


def _gaps(t: np.ndarray, pauses: Sequence[tuple[float, float]], wall: np.ndarray,
          host_steal: HostSteal, on_host: np.ndarray | None = None,
          ) -> tuple[np.ndarray, np.ndarray]:
    """Gaps of ``t`` net of what the host took within them, leaving out those that
    span a pause (wall-clock intervals in which the sender was stopped on purpose),
    by arrival or by send time (a setpoint sent just before the service was stopped
    may sit in its frozen MAVSDK's socket and arrive after the pause: the gap after
    it, by send stamps, is still the pause's); and what the host took. ``on_host``:
    the times ``t`` on the host's monotonic clock, where the host's takings are
    looked for (default ``wall``)."""
    dt = np.diff(t)
    on_host = wall if on_host is None else on_host
    stolen = host_steal.excuse(dt, on_host[:-1], on_host[1:])
    keep = np.ones(len(dt), dtype=bool)
    for a, b in pauses:
        keep &= ~((wall[:-1] <= b) & (wall[1:] >= a))
        keep &= ~((on_host[:-1] <= b) & (on_host[1:] >= a))
    return (dt - stolen)[keep], stolen[keep]


def check_stream(setpoints: dict[str, np.ndarray], allowed_speed: float,
                 fence: tuple[Sequence[float], Sequence[float]] | None = None,
                 origin: Sequence[float] = (0.0, 0.0, 0.0),
                 window: tuple[float, float] | None = None,
                 pauses: Sequence[tuple[float, float]] = (),
                 host_steal: HostSteal | None = None,
                 max_step_dt: float = MAX_STEP_DT) -> StreamFigures:
    """Check the setpoints received within ``window`` (host monotonic seconds).

    Args:
        setpoints: as :attr:`sitl.process.SimReport.setpoints` (world ENU).
        allowed_speed: no setpoint may move faster than this from the one before (m/s).
        fence: ``(min, max)`` ENU corners relative to ``origin`` (the vehicle's home).
        pauses: wall-clock intervals to leave out of the gaps (the sender was stopped).
        host_steal: the host's steal counters over the flight: gaps are measured
            net of the time the host took a CPU away within them.
        max_step_dt: the service's stall budget (s): the longest spacing that
            excuses a step.
    """
    wall = np.asarray(setpoints["wall_time"], dtype=float)
    keep = np.ones(len(wall), dtype=bool)
    if window is not None:
        keep = (wall >= window[0]) & (wall <= window[1])
    wall = wall[keep]
    sent = np.asarray(setpoints["sent_s"], dtype=float)[keep]
    p = np.asarray(setpoints["position"], dtype=float)[keep] - np.asarray(origin)
    v = np.asarray(setpoints["velocity"], dtype=float)[keep]
    a = np.asarray(setpoints["acceleration"], dtype=float)[keep]
    finite = np.all(np.isfinite(p), axis=1) & np.all(np.isfinite(v), axis=1) & \
        np.all(np.isfinite(a), axis=1)
    n = len(wall)
    if n < 2:
        return StreamFigures(n, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0, 0.0, 0, int(n - finite.sum()))
    # The send gaps are looked up on the sender's clock, put on the host's (the
    # arrival times would not do: a receiver held up by the host as well takes in
    # the setpoint before the gap late, and the gap then seems to start after it).
    sent_on_host = sent + float(np.median(wall - sent))
    gaps, stolen = _gaps(sent, pauses, wall, host_steal or HostSteal(), sent_on_host)
    arrivals, _ = _gaps(wall, pauses, wall, host_steal or HostSteal())
    dt = np.clip(np.diff(sent), 0.0, max_step_dt) + STAMP_RESOLUTION_S
    step = np.linalg.norm(np.diff(p, axis=0), axis=1)
    speed = np.where(np.isfinite(step), step / dt, np.inf)
    over = step > allowed_speed * dt + 0.01
    outside = 0
    if fence is not None:
        lo, hi = np.asarray(fence[0]), np.asarray(fence[1])
        outside = int(np.count_nonzero(finite & np.any((p < lo - 1e-6) | (p > hi + 1e-6),
                                                       axis=1)))

    def pct(x: np.ndarray) -> float:
        return float(np.percentile(x, 99)) if len(x) else 0.0

    return StreamFigures(
        count=n, duration_s=float(wall[-1] - wall[0]),
        max_gap_s=float(gaps.max()) if len(gaps) else 0.0, p99_gap_s=pct(gaps),
        max_arrival_gap_s=float(arrivals.max()) if len(arrivals) else 0.0,
        p99_arrival_gap_s=pct(arrivals),
        max_speed=float(np.nanmax(speed)), jumps=int(np.count_nonzero(over)),
        largest_jump_m=float(np.nanmax(np.where(over, step, 0.0))),
        outside_fence=outside, non_finite=int(n - finite.sum()),
        host_steal_gaps=int(np.count_nonzero(stolen)), host_steal_s=float(stolen.sum()),
        max_gap_with_steal_s=float((gaps + stolen).max()) if len(gaps) else 0.0,
        max_commanded_speed=float(np.max(np.linalg.norm(v[finite], axis=1), initial=0.0)))


def fastest_yaw_rate(setpoints: dict[str, np.ndarray], period: float,
                     window: tuple[float, float] | None = None) -> float:
    """The fastest the yaw the vehicle received turned (deg/s): each change between
    consecutive setpoints over their spacing by send stamps, and at least ``period``
    (the stream's tick: a setpoint sent late carries its tick's yaw, so the next, on
    time, may follow it closely)."""
    wall = np.asarray(setpoints["wall_time"], dtype=float)
    keep = np.ones(len(wall), dtype=bool) if window is None else \
        (wall >= window[0]) & (wall <= window[1])
    yaw = np.asarray(setpoints["yaw_ned_deg"], dtype=float)[keep]
    sent = np.asarray(setpoints["sent_s"], dtype=float)[keep]
    ok = np.isfinite(yaw)
    yaw, sent = yaw[ok], sent[ok]
    if len(yaw) < 2:
        return 0.0
    step = np.abs((np.diff(yaw) + 180.0) % 360.0 - 180.0)
    return float(np.max(step / np.maximum(np.diff(sent), period)))
