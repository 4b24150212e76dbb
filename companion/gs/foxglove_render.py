"""A picture of what Foxglove shows of a flight record, drawn with matplotlib from
the record's Foxglove channels alone (decoded by their schemas): the 3D panel (the
map's cubes, the planner's path, the re-timed path in its speed colours, braking
zones, the setpoints, the vehicle's track and body) and the plot panels of the
layout (speed against ``v_max`` and the chance-constrained limit; tracking error).
For documentation and for machines where Foxglove's app cannot run.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from companion.gs.foxglove import decoded


def _xyz(v: Any) -> list[float]:
    return [v.x, v.y, v.z]


def _rgba(c: Any) -> tuple[float, float, float, float]:
    return (c.r, c.g, c.b, c.a)


def _box_faces(c: np.ndarray, s: np.ndarray) -> list[np.ndarray]:
    """The four sides and the top of a box (the bottom is never seen from above)."""
    lo, hi = c - s / 2, c + s / 2
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    return [np.array(f) for f in (
        [(x0, y0, z0), (x1, y0, z0), (x1, y0, z1), (x0, y0, z1)],
        [(x1, y0, z0), (x1, y1, z0), (x1, y1, z1), (x1, y0, z1)],
        [(x1, y1, z0), (x0, y1, z0), (x0, y1, z1), (x1, y1, z1)],
        [(x0, y1, z0), (x0, y0, z0), (x0, y0, z1), (x0, y1, z1)],
        [(x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)])]


def render(paths: Iterable[str | Path], out: str | Path, title: str = "",
           margin_m: float = 3.0) -> Path:
    """Draw the record's Foxglove scene and plots to ``out`` (PNG, SVG or PDF).
    Obstacles more than ``margin_m`` beside the flight are left out (for clarity)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

    d = decoded(list(paths))
    if "/foxglove/plan" not in d and "/tf" not in d:
        raise ValueError("no Foxglove channels in the record (recorded with [record] "
                         "foxglove = false, or before they existed?)")
    track = np.array([_xyz(m.translation) for _, m in d.get("/tf", [])]).reshape(-1, 3)
    setp = np.array([_xyz(m.pose.position) for _, m in d.get("/foxglove/setpoint", [])]
                    ).reshape(-1, 3)
    fig = plt.figure(figsize=(16, 8.5))
    grid = fig.add_gridspec(2, 2, width_ratios=(1.35, 1), height_ratios=(1.4, 1))
    ax = fig.add_subplot(grid[:, 0], projection="3d")
    spd = fig.add_subplot(grid[0, 1])
    trk = fig.add_subplot(grid[1, 1], sharex=spd)
    flown = np.vstack([a for a in (track, setp) if len(a)])
    lo, hi = flown.min(axis=0) - margin_m, flown.max(axis=0) + margin_m

    # ---------------------------------------------------------------- 3D panel
    if "/foxglove/map" in d:
        (_, update) = d["/foxglove/map"][-1]
        faces, colours = [], []
        for entity in update.entities:
            for cube in entity.cubes:
                c, s = np.array(_xyz(cube.pose.position)), np.array(_xyz(cube.size))
                if np.all(c[:2] >= lo[:2]) and np.all(c[:2] <= hi[:2]):
                    faces += _box_faces(c, s)
                    colours += [_rgba(cube.color)] * 5
        if faces:
            ax.add_collection3d(Poly3DCollection(faces, facecolors=colours, edgecolors="none",
                                                 alpha=0.55))
            ax.plot([], [], "s", color="0.45", label="obstacles (/foxglove/map)")
    plans = d.get("/foxglove/plan", [])
    for k, (_, update) in enumerate(plans):
        latest = k == len(plans) - 1
        for entity in update.entities:
            planned, retimed, *zones = entity.lines
            p = np.array([_xyz(q) for q in planned.points])
            ax.plot(*p.T, ":", color="0.4", lw=1.2 if latest else 0.8,
                    label="planner's path" if latest else None)
            r = np.array([_xyz(q) for q in retimed.points])
            seg = np.stack([r[:-1], r[1:]], axis=1)
            cols = [_rgba(c) for c in retimed.colors][:-1]
            ax.add_collection3d(Line3DCollection(seg, colors=cols, linewidths=3.5 if latest
                                                 else 1.5, alpha=1.0 if latest else 0.35))
            for z in zones:
                q = np.array([_xyz(x) for x in z.points])
                ax.plot(*q.T, color=_rgba(z.color)[:3], lw=9, alpha=0.5,
                        solid_capstyle="round",
                        label="braking zone" if latest and z is zones[0] else None)
    if len(setp):
        ax.plot(*setp.T, color="tab:blue", lw=0.8, label="setpoints (/foxglove/setpoint)")
    if len(track):
        ax.plot(*track.T, color="k", lw=1.0, label="vehicle (/tf map -> base_link)")
        ax.scatter(*track[-1], color="k", s=60, marker="s")
    ax.plot([], [], color="tab:red", lw=3.5, label="re-timed path (colour: speed)")
    ax.set(xlim=(lo[0], hi[0]), ylim=(lo[1], hi[1]), zlim=(0, max(hi[2], 3.0)),
           xlabel="x east (m)", ylabel="y north (m)", zlabel="z up (m)")
    ax.set_box_aspect((hi[0] - lo[0], hi[1] - lo[1], max(hi[2], 3.0)))
    ax.view_init(elev=38, azim=-110)
    ax.set_title("3D: /foxglove/map, /foxglove/plan, /foxglove/setpoint, /tf")
    ax.legend(fontsize=8, loc="upper left")

    # ---------------------------------------------------------------- plots
    t0 = min(s for topic in ("/plot/command", "/plot/vehicle") for s, _ in d.get(topic, [])
             [:1]) if ("/plot/command" in d or "/plot/vehicle" in d) else 0.0
    cmd = d.get("/plot/command", [])
    veh = d.get("/plot/vehicle", [])

    def column(rows: list[tuple[float, dict[str, Any]]], key: str) -> tuple[np.ndarray, ...]:
        t = np.array([s - t0 for s, _ in rows])
        v = np.array([np.nan if m.get(key) is None else m[key] for _, m in rows], float)
        return t, v

    for rows, key, label, style in ((cmd, "speed", "commanded", dict(color="tab:blue")),
                                    (veh, "speed", "reported (PX4)", dict(color="k", lw=1)),
                                    (cmd, "v_max", "v_max", dict(color="tab:red")),
                                    (cmd, "chance_limit", "chance-constrained limit",
                                     dict(color="darkviolet", ls="--"))):
        if rows:
            spd.plot(*column(rows, key), label=label, **style)
    if cmd:
        t, z = column(cmd, "braking_zone")
        spd.fill_between(t, 0, 1, where=z > 0, color="tab:orange", alpha=0.3,
                         transform=spd.get_xaxis_transform(), label="braking zone")
    spd.set(ylabel="speed (m/s)", title="/plot/command, /plot/vehicle: speed")
    spd.set_ylim(0, 1.4 * spd.get_ylim()[1])  # room for the legend
    spd.legend(fontsize=8, loc="upper right", ncol=2)
    spd.grid(alpha=0.3)
    if veh:
        trk.plot(*column(veh, "tracking_error"), color="k", lw=1, label="tracking error")
        trk.plot(*column(veh, "brake_threshold"), color="tab:red", ls="--",
                 label="brake threshold")
    trk.set(xlabel="time (s)", ylabel="error (m)", title="/plot/vehicle: tracking error")
    trk.set_ylim(bottom=0)
    trk.legend(fontsize=8, loc="upper right")
    trk.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    out = Path(out)
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return out
