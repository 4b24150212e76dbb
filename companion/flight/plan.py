"""What the vehicle is commanded to do at any instant: follow a re-timed plan or
hold a point. Everything here is ENU and uses the service's monotonic clock.

A new plan never makes the commanded position jump: when it takes over, the gap
between the old command and the new plan's start (at most the stitch
tolerance) is carried as an offset that fades out over ``blend_s`` along a
quintic smootherstep, so the added velocity and acceleration start and end at
zero; :func:`blend_time` picks ``blend_s`` so the added acceleration stays under
a budget.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from companion.flight.reaction import Timing
from companion.frames import yaw_enu_to_ned_deg
from rota.result import RetimeResult
from rota.schema import Heading
from rota.trajectory import smootherstep_fade

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Command:
    """A commanded state (ENU): position, velocity, acceleration."""

    position: FloatArray
    velocity: FloatArray = field(default_factory=lambda: np.zeros(3))
    acceleration: FloatArray = field(default_factory=lambda: np.zeros(3))


@dataclass(frozen=True)
class Hold:
    """Hold a point (ENU)."""

    position: FloatArray
    reason: str = ""

    def command(self, now: float) -> Command:  # noqa: ARG002 - same interface as Plan
        return Command(np.asarray(self.position, dtype=float).copy())

    def finished(self, now: float) -> bool:  # noqa: ARG002
        return True


@dataclass(frozen=True)
class Plan:
    """Follow ``result`` with its time 0 at clock time ``t0``.

    Attributes:
        id: the trajectory's id.
        result: the re-timed trajectory (ENU).
        t0: clock time (s) at which the plan's time 0 happens.
        offset: position gap (ENU) at takeover, faded out over ``blend_s``.
        blend_t0: clock time the fade starts (the takeover; None: ``t0``). A
            takeover on a tick later than ``t0`` then still starts from the full
            gap, so its first setpoint is exactly the last one commanded.
    """

    id: str
    result: RetimeResult
    t0: float
    offset: FloatArray = field(default_factory=lambda: np.zeros(3))
    blend_s: float = 1.0
    blend_t0: float | None = None
    timing: Timing | None = None  #: its trajectory's way here (the reaction time)
    heading: Heading | None = None  #: the planner's heading (ENU degrees), if it sent one

    @property
    def _blend_start(self) -> float:
        return self.t0 if self.blend_t0 is None else self.blend_t0

    @property
    def end_time(self) -> float:
        return self.t0 + self.result.duration

    def finished(self, now: float) -> bool:
        return now >= self.end_time and now >= self._blend_start + self.blend_s

    def progress(self, now: float) -> float:
        """Share of the plan's duration flown, 0..1."""
        d = self.result.duration
        return float(np.clip((now - self.t0) / d, 0.0, 1.0)) if d > 0 else 1.0

    def yaw_ned_deg(self, now: float) -> float | None:
        """The planner's heading where the plan is at ``now`` (NED degrees; None if the
        planner sent none): its trajectory time from the re-timed time map."""
        if self.heading is None:
            return None
        tau = float(self.result.timemap.evaluate(max(now - self.t0, 0.0))[0][0])
        return yaw_enu_to_ned_deg(math.radians(self.heading.at(tau)))

    def command(self, now: float) -> Command:
        sp = self.result.sample(max(now - self.t0, 0.0))
        p, v, a = sp.position[0], sp.velocity[0], sp.acceleration[0]
        x = (now - self._blend_start) / self.blend_s
        if np.any(self.offset) and x < 1.0:
            w, dw, ddw = smootherstep_fade(x, self.blend_s)
            p, v, a = p + w * self.offset, v + dw * self.offset, a + ddw * self.offset
        return Command(p, v, a)


#: Peak |d^2 w / dx^2| of the smootherstep (at x = 1/2 -/+ 1/(2 sqrt 3)).
_PEAK_DDW = 10 / np.sqrt(3)


#: Peak |d w / dx| of the smootherstep (at x = 1/2).
_PEAK_DW = 30 / 16


def blend_time(gap: float, accel_budget: float = 0.5, minimum: float = 0.5) -> float:
    """Blend duration (s) that fades a ``gap`` (m) with at most ``accel_budget`` m/s^2."""
    return max(minimum, float(np.sqrt(_PEAK_DDW * gap / accel_budget)))


def blend_speed(gap: float) -> float:
    """The largest velocity (m/s) a takeover blend of ``gap`` (m) adds to the plan's."""
    return _PEAK_DW * gap / blend_time(gap)


@dataclass(frozen=True)
class Brake:
    """Stop smoothly along the path being flown: constant deceleration ``decel``
    along the arc length from speed ``v0``, then hold where it stops.

    ``path`` is the remaining path as dense points (ENU); ``shift`` a constant
    offset added to it (a takeover blend still in progress when braking began).
    """

    path: FloatArray  # (n, 3)
    v0: float
    t0: float
    decel: float
    shift: FloatArray = field(default_factory=lambda: np.zeros(3))
    reason: str = ""

    def __post_init__(self) -> None:
        seg = np.linalg.norm(np.diff(self.path, axis=0), axis=1)
        object.__setattr__(self, "_s", np.concatenate([[0.0], np.cumsum(seg)]))

    @property
    def stop_time(self) -> float:
        return self.t0 + self.v0 / self.decel

    def finished(self, now: float) -> bool:
        return now >= self.stop_time

    def _at(self, s: float) -> tuple[FloatArray, FloatArray]:
        arc = self._s  # type: ignore[attr-defined]
        s = float(np.clip(s, 0.0, arc[-1]))
        i = int(np.clip(np.searchsorted(arc, s, side="right") - 1, 0, len(arc) - 2))
        seg = arc[i + 1] - arc[i]
        f = (s - arc[i]) / seg if seg > 0 else 0.0
        p = self.path[i] + f * (self.path[i + 1] - self.path[i])
        d = self.path[i + 1] - self.path[i]
        tangent = d / seg if seg > 0 else np.zeros(3)
        return p + self.shift, tangent

    def command(self, now: float) -> Command:
        t = float(np.clip(now - self.t0, 0.0, self.v0 / self.decel))
        speed = self.v0 - self.decel * t
        s = self.v0 * t - 0.5 * self.decel * t * t
        p, tangent = self._at(s)
        if now >= self.stop_time or s >= self._s[-1]:  # type: ignore[attr-defined]
            return Command(p)
        return Command(p, speed * tangent, -self.decel * tangent)


def brake_along(plan: Plan, now: float, decel: float, reason: str = "") -> Brake:
    """A :class:`Brake` that leaves ``plan`` at ``now`` along its own path."""
    cmd = plan.command(now)
    tm = plan.result.timemap
    tau_now = float(tm.evaluate(max(now - plan.t0, 0.0))[0][0])
    v0 = float(np.linalg.norm(cmd.velocity))
    reach = v0 * v0 / (2 * decel) + 0.5
    t0_, t1_ = plan.result.trajectory.domain
    tau = np.linspace(tau_now, t1_, 400)
    pts = plan.result.trajectory.position(tau)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    keep = arc <= reach + (arc[1] if len(arc) > 1 else 0.0)
    pts = pts[keep] if keep.sum() >= 2 else pts[:2]
    shift = cmd.position - pts[0]
    return Brake(pts, v0, now, decel, shift, reason)
