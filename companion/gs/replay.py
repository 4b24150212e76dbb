"""Replay a flight record (:mod:`companion.recording.record`): its figures and the plot an
engineer reads after a flight.

The plot has the path over the map (top view: the planner's paths, what was
commanded, what the vehicle reported, braking zones, where each replan took
over, takeoff and landing), the speed against time (reported and commanded, the
speed limit ``v_max``, the chance-constrained limits of each plan, braking zones
shaded, replans, takeoff and landing marked) and the tracking error against its
brake threshold.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from companion.recording.record import read
from rota.errors import InputError

#: Plan colours: no red or orange (the speed limit and braking zones use them).
PLAN_COLOURS = ("tab:blue", "tab:green", "tab:purple", "tab:brown", "tab:pink", "tab:olive",
                "tab:cyan", "tab:gray")
ZONE_COLOUR = "tab:orange"
LIMIT_COLOUR = "tab:red"
CHANCE_COLOUR = "darkviolet"


@dataclass(frozen=True)
class Flight:
    """What a flight record holds, as arrays; times are UNIX seconds."""

    config: dict[str, Any]
    tel_t: np.ndarray
    position: np.ndarray  # (N, 3) ENU, PX4's estimate
    velocity: np.ndarray
    tracking_error: np.ndarray  # NaN where not streaming
    sp_t: np.ndarray
    sp_p: np.ndarray
    sp_v: np.ndarray
    sp_a: np.ndarray
    sp_source: list[str]
    retimed: list[tuple[float, dict[str, Any]]]
    map: dict[str, Any] | None
    commands: list[tuple[float, dict[str, Any]]]
    statuses: list[tuple[float, dict[str, Any]]]
    logs: list[tuple[float, dict[str, Any]]] = field(default_factory=list)

    @property
    def t0(self) -> float:
        stamps = [a[0] for a in (self.tel_t, self.sp_t) if len(a)]
        return min(stamps) if stamps else 0.0

    def plans(self) -> list[tuple[str, float, dict[str, Any]]]:
        """(id, takeover time, the re-timed result flown) of each plan, in flight order."""
        out = []
        seen: set[str] = set()
        for t, src in zip(self.sp_t, self.sp_source, strict=True):
            if src in seen or src in ("hold", "brake"):
                continue
            seen.add(src)
            results = [r for s, r in self.retimed if r.get("id") == src and s <= t + 1e-3]
            results = results or [r for _, r in self.retimed if r.get("id") == src]
            if results:
                out.append((src, float(t), results[-1]))
        return out

    def rejected(self) -> list[tuple[str, float, dict[str, Any]]]:
        """(id, time, result) of each re-timed plan the service rejected (the path
        is unsafe: through an obstacle of the map); never flown."""
        return [(str(r.get("id") or ""), float(s), r) for s, r in self.retimed
                if r.get("status") == "rejected"]

    def phase(self, command: str, until: tuple[str, ...]) -> tuple[float, float] | None:
        """From the (accepted) ``command`` to the first status in a state of ``until``."""
        starts = [s for s, r in self.commands if r.get("command") == command and r.get("ok")]
        if not starts:
            return None
        begin = starts[0]
        ends = [s for s, st in self.statuses if s > begin and st.get("state") in until]
        last = self.tel_t[-1] if len(self.tel_t) else begin
        return begin, ends[0] if ends else float(last)


#: The first bytes of every MCAP file.
MCAP_MAGIC = b"\x89MCAP0\r\n"
#: The channels of a flight record (companion.recording.record).
CHANNELS = ("telemetry", "setpoint", "retimed", "map", "command", "status", "log", "config",
            "trajectory")


def check_files(paths: Iterable[str | Path]) -> list[Path]:
    """The record files, each an MCAP file; InputError naming the first that is not."""
    out = []
    for p in map(Path, paths):
        if not p.is_file():
            raise InputError(str(p), "no such file")
        with open(p, "rb") as fh:
            head = fh.read(len(MCAP_MAGIC))
        if not head:
            raise InputError(str(p), "is empty (0 bytes): not a flight record (a service "
                             "that failed to start writes none)")
        if head != MCAP_MAGIC:
            raise InputError(str(p), "is not an MCAP file (flight records are .mcap files "
                             "in [record] dir)")
        out.append(p)
    return out


def load(paths: Iterable[str | Path]) -> Flight:
    """Read one flight's record files (the parts of one run, in order). InputError
    (one line) for a file that is not a flight record, or a record without a
    vehicle in it (no telemetry, no setpoints)."""
    files = sorted(check_files(paths))
    tel, sps, retimed, commands, statuses, logs = [], [], [], [], [], []
    config: dict[str, Any] = {}
    vmap = None
    seen = 0
    for channel, stamp, m in read(files):
        seen += channel in CHANNELS and isinstance(m, dict)
        if not isinstance(m, dict):
            continue
        if channel == "telemetry":
            tel.append((stamp, m))
        elif channel == "setpoint":
            sps.append((stamp, m))
        elif channel == "retimed":
            retimed.append((stamp, m))
        elif channel == "map":
            vmap = m
        elif channel == "command":
            commands.append((stamp, m))
        elif channel == "status":
            statuses.append((stamp, m))
        elif channel == "log":
            logs.append((stamp, m))
        elif channel == "config" and not config:
            config = m
    names = ", ".join(str(f) for f in files)
    if not seen:
        raise InputError(names, "holds no flight-record channels (an MCAP file from "
                         "another program?)")
    tel = [(s, m) for s, m in tel if m.get("position") is not None]
    if not tel and not sps:
        raise InputError(names, "a record without a vehicle: no telemetry and no setpoints "
                         "(the service did not connect to PX4, or stopped at once)")
    nan3 = [np.nan] * 3

    def arr(rows: list, key: str, default: Any = nan3) -> np.ndarray:
        width = len(default) if isinstance(default, list) else 1
        return np.array([default if m.get(key) is None else m[key] for _, m in rows],
                        dtype=float).reshape(len(rows), width)

    return Flight(
        config=config, tel_t=np.array([s for s, _ in tel]), position=arr(tel, "position"),
        velocity=arr(tel, "velocity"),
        tracking_error=arr(tel, "tracking_error", np.nan).ravel(),
        sp_t=np.array([s for s, _ in sps]), sp_p=arr(sps, "p"), sp_v=arr(sps, "v"),
        sp_a=arr(sps, "a"), sp_source=[m.get("source") or "" for _, m in sps],
        retimed=retimed, map=vmap, commands=commands, statuses=statuses, logs=logs)


def stats(f: Flight) -> dict[str, Any]:
    """Figures of a flight: maxima of the reported speed, the commanded speed,
    the commanded acceleration (its norm, and per axis, which is what the limits
    ``a_max`` bound) and the tracking error; plans and braking zones flown."""

    def top(x: np.ndarray) -> float | None:
        x = x[np.isfinite(x)]
        return round(float(x.max()), 3) if len(x) else None

    plans = f.plans()
    return {
        "max_speed_m_s": top(np.linalg.norm(f.velocity, axis=1)) if len(f.velocity) else None,
        "max_commanded_speed_m_s": top(np.linalg.norm(f.sp_v, axis=1)) if len(f.sp_v) else None,
        "max_acceleration_m_s2": top(np.linalg.norm(f.sp_a, axis=1)) if len(f.sp_a) else None,
        "max_acceleration_per_axis_m_s2": ([top(np.abs(f.sp_a[:, k])) for k in range(3)]
                                           if len(f.sp_a) else None),
        "max_tracking_error_m": top(f.tracking_error),
        "plans_flown": [p[0] for p in plans],
        "plans_rejected": [{"id": ident, "reason": r.get("message", "")}
                           for ident, _, r in f.rejected()],
        "braking_zones_flown": sum(len(r.get("braking_zones", [])) for _, _, r in plans),
        "setpoints": len(f.sp_t),
    }


def _path(result: dict[str, Any], n: int = 300) -> tuple[np.ndarray, np.ndarray]:
    """Positions along a result's trajectory at trajectory times, and those times."""
    from rota.schema import result_from_dict

    res, _ = result_from_dict(result)
    tau = np.linspace(*res.trajectory.domain, n)
    return tau, res.trajectory.position(tau)


def _zone_times(result: dict[str, Any], start: float) -> list[tuple[float, float]]:
    tau, t = np.asarray(result["tau"]), np.asarray(result["t"])
    return [(start + float(np.interp(a, tau, t)), start + float(np.interp(b, tau, t)))
            for a, b in result.get("braking_zones", [])]


def _draw_map(ax: Any, vmap: dict[str, Any], z_band: tuple[float, float]) -> None:
    occ = np.asarray(vmap.get("occupied") or [], dtype=float).reshape(-1, 3)
    occ = occ[(occ[:, 2] >= z_band[0]) & (occ[:, 2] <= z_band[1])]
    if not len(occ):
        return
    res = float(vmap["resolution"])
    lo = occ[:, :2].min(axis=0) - res / 2
    ij = np.floor((occ[:, :2] - lo) / res).astype(int)
    img = np.zeros(ij.max(axis=0)[::-1] + 1)
    img[ij[:, 1], ij[:, 0]] = 1.0
    hi = lo + np.array(img.shape[::-1]) * res
    ax.imshow(np.ma.masked_equal(img, 0), origin="lower", extent=(lo[0], hi[0], lo[1], hi[1]),
              cmap="Greys", vmin=0, vmax=1.4, interpolation="nearest", zorder=0)
    ax.plot([], [], "s", color="0.45", label="obstacles (map)")


def plot(f: Flight, path: str | Path, title: str = "") -> Path:
    """Draw the flight (see the module doc) to ``path`` (PNG, SVG or PDF)."""
    import matplotlib.pyplot as plt

    fig = figure(f, title)
    out = Path(path)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out


def figure(f: Flight, title: str = "") -> Any:
    """The figure :func:`plot` writes. Rejected plans are drawn apart: their paths
    dashed in the limit's red with an x where they begin, marked "rejected" where
    the service rejected them on the time axis, and their reasons listed below."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(16, 8.5))
    grid = fig.add_gridspec(3, 2, width_ratios=(1.05, 1), height_ratios=(1, 1, 0.7))
    top = fig.add_subplot(grid[:, 0])
    spd = fig.add_subplot(grid[0:2, 1])
    trk = fig.add_subplot(grid[2, 1], sharex=spd)
    t0 = f.t0
    limits = f.config.get("limits", {})
    safety = f.config.get("safety", {})
    plans = f.plans()
    air = f.position[:, 2] > 0.3 if len(f.position) else np.zeros(0, bool)

    # ---------------------------------------------------------------- top view
    if f.map is not None:
        z = f.position[air, 2] if air.any() else np.array([1.0])
        _draw_map(top, f.map, (float(z.min()) - 0.5, float(z.max()) + 0.5))
    zone_label = "braking zone"
    for k, (ident, _, r) in enumerate(plans):
        c = PLAN_COLOURS[k % len(PLAN_COLOURS)]
        tau, p = _path(r)
        top.plot(p[:, 0], p[:, 1], ":", color=c, lw=1.2, label=f"{ident}: planner's path")
        mine = np.array([s == ident for s in f.sp_source])
        top.plot(f.sp_p[mine, 0], f.sp_p[mine, 1], "-", color=c, lw=2.2,
                 label=f"{ident}: commanded")
        for a, b in r.get("braking_zones", []):
            sel = (tau >= a) & (tau <= b)
            q = p[sel] if sel.sum() >= 2 else p[[np.argmin(abs(tau - (a + b) / 2))]]
            top.plot(q[:, 0], q[:, 1], color=ZONE_COLOUR, lw=9, alpha=0.45, solid_capstyle="round",
                     zorder=3)
            mid = p[np.argmin(abs(tau - (a + b) / 2))]
            top.plot(*mid[:2], "D", color=ZONE_COLOUR, mec="k", ms=7, zorder=4, label=zone_label)
            zone_label = None
        start = f.sp_p[mine][0]
        top.plot(*start[:2], ">", color=c, mec="k", ms=11, zorder=5)
        top.annotate(f"{ident} takes over" if k else f"{ident} starts", start[:2],
                     textcoords="offset points", xytext=(6, 8), fontsize=8, color=c)
    rejected = f.rejected()
    for k, (ident, _, r) in enumerate(rejected):
        _, p = _path(r)
        top.plot(p[:, 0], p[:, 1], "--", color=LIMIT_COLOUR, lw=1.2, alpha=0.8,
                 label="rejected plan (not flown)" if k == 0 else None)
        top.plot(*p[0, :2], "x", color=LIMIT_COLOUR, ms=9, mew=2)
        top.annotate(f"{ident} rejected", p[0, :2], textcoords="offset points",
                     xytext=(6, -12), fontsize=8, color=LIMIT_COLOUR)
    if air.any():
        top.plot(f.position[air, 0], f.position[air, 1], color="k", lw=1,
                 label="flown (PX4's estimate)")
    for name, marker, until in (("takeoff", "^", ("airborne",)),
                                ("land", "v", ("ready", "not_ready"))):
        ph = f.phase(name, until)
        if ph is not None and len(f.tel_t):
            i = int(np.clip(np.searchsorted(f.tel_t, ph[0]), 0, len(f.tel_t) - 1))
            top.plot(*f.position[i, :2], marker, color="k", mfc="w", ms=12, mew=2,
                     label=name + (" (command)" if name == "land" else ""), zorder=6)
    top.set(aspect="equal", xlabel="x east (m)", ylabel="y north (m)",
            title="Top view (PX4 local frame, ENU)")
    top.legend(fontsize=8, loc="best")
    top.grid(alpha=0.2)

    # ---------------------------------------------------------------- speed
    for name, until, label in (("takeoff", ("airborne",), "takeoff"),
                               ("land", ("ready", "not_ready"), "landing")):
        ph = f.phase(name, until)
        if ph is not None:
            for ax in (spd, trk):
                ax.axvspan(ph[0] - t0, ph[1] - t0, color="0.85", zorder=0)
            spd.text((ph[0] + ph[1]) / 2 - t0, 0.02, label, ha="center", va="bottom",
                     fontsize=8, color="0.3", transform=spd.get_xaxis_transform())
    zone_label, chance_label = "braking zone", "chance-constrained limit"
    for k, (ident, t_take, r) in enumerate(plans):
        c = PLAN_COLOURS[k % len(PLAN_COLOURS)]
        for a, b in _zone_times(r, t_take):
            mid, half = (a + b) / 2, max((b - a) / 2, 0.1)  # short zones stay visible
            spd.axvspan(mid - half - t0, mid + half - t0, color=ZONE_COLOUR, alpha=0.3,
                        label=zone_label, zorder=1)
            zone_label = None
        lim = np.array([np.nan if x is None else x for x in r.get("speed_limits", [])], float)
        if np.isfinite(lim).any():
            t_nodes = t_take + np.asarray(r["t"]) - t0
            spd.plot(t_nodes, lim, color=CHANCE_COLOUR, lw=1.4, ls="--", label=chance_label)
            chance_label = None
        for ax in (spd, trk):
            ax.axvline(t_take - t0, color=c, lw=1, ls="-.")
        spd.text(t_take - t0, 0.98, f" {ident}", color=c, fontsize=8, va="top",
                 transform=spd.get_xaxis_transform())
    for ident, stamp, _ in rejected:
        spd.axvline(stamp - t0, color=LIMIT_COLOUR, lw=1, ls=":")
        spd.text(stamp - t0, 0.9, f" {ident} rejected", color=LIMIT_COLOUR, fontsize=8,
                 va="top", transform=spd.get_xaxis_transform())
    if len(f.sp_t):
        spd.plot(f.sp_t - t0, np.linalg.norm(f.sp_v, axis=1), color="tab:blue", lw=1.2,
                 label="commanded speed")
    if len(f.tel_t):
        spd.plot(f.tel_t - t0, np.linalg.norm(f.velocity, axis=1), color="k", lw=1,
                 label="reported speed (PX4)")
    if "v_max" in limits:
        spd.axhline(limits["v_max"], color=LIMIT_COLOUR, lw=1.5,
                    label=f"v_max {limits['v_max']:g} m/s")
    spd.set(ylabel="speed (m/s)", title="Speed")
    spd.set_ylim(0, 1.35 * max(spd.get_ylim()[1], limits.get("v_max", 0.0)))  # legend room
    spd.legend(fontsize=8, loc="upper right", ncol=2)
    spd.grid(alpha=0.3)

    # ---------------------------------------------------------------- tracking
    if len(f.tel_t):
        trk.plot(f.tel_t - t0, f.tracking_error, color="k", lw=1, label="tracking error")
    if "max_tracking_error_m" in safety:
        trk.axhline(safety["max_tracking_error_m"], color=LIMIT_COLOUR, lw=1.2,
                    label=f"brake at {safety['max_tracking_error_m']:g} m")
    trk.set(xlabel=f"time (s) since {_clock(t0)} UTC", ylabel="error (m)",
            title="Tracking error (reported position - command)")
    trk.set_ylim(bottom=0)
    trk.legend(fontsize=8, loc="upper right")
    trk.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    if rejected:
        import textwrap

        lines = [textwrap.shorten(f"{ident} rejected at {_clock(stamp)} UTC: "
                                  f"{r.get('message', '')}", 170)
                 for ident, stamp, r in rejected[:4]]
        more = len(rejected) - 4
        lines += [f"... and {more} more rejected"] if more > 0 else []
        fig.text(0.01, 0.005, "\n".join(lines), fontsize=8, color=LIMIT_COLOUR, va="bottom")
        fig.tight_layout(rect=(0, 0.025 * len(lines), 1, 1))
    else:
        fig.tight_layout()
    return fig


def _clock(t: float) -> str:
    import time

    return time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime(t))
