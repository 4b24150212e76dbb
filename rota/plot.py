"""Plots of a re-time: speed and acceleration profiles before and after, with the
braking zones shaded (paper Fig. 5), the time mapping (Fig. 4), and a top view
of the path with braking points and obstacles (Fig. 2)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from rota.problem import Limits  # noqa: E402
from rota.result import REJECTED, RetimeResult  # noqa: E402

REJECTED_COLOUR = "C3"


def plot_result(result: RetimeResult, limits: Limits, path: str | Path,
                obstacles: NDArray[np.float64] | None = None, title: str = "") -> Path:
    """Write a 2x2 figure for ``result`` to ``path`` (PNG, SVG or PDF by suffix)."""
    fig = figure(result, limits, obstacles, title)
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def figure(result: RetimeResult, limits: Limits, obstacles: NDArray[np.float64] | None = None,
           title: str = "") -> plt.Figure:
    """The figure of :func:`plot_result`. A rejected result (the path is unsafe) is
    drawn as rejected: its path in red with the reason, the planned profile only,
    no re-timed profile (the result's time mapping is a stand-in, never flown)."""
    if result.status == REJECTED:
        return _rejected(result, limits, obstacles, title)
    traj = result.trajectory
    t0, t1 = traj.domain
    tau_o = np.linspace(t0, t1, 1000)
    _, v_o, a_o = traj.evaluate(tau_o)
    t_o = tau_o - t0
    t_r = np.linspace(0.0, result.duration, 1000)
    sp = result.sample(t_r)
    zones = [(float(result.timemap.real_time(a)[0]), float(result.timemap.real_time(b)[0]))
             for a, b in result.diagnostics.intervals]

    fig, ax = plt.subplots(2, 2, figsize=(12, 8))
    a_speed, a_acc, a_map, a_top = ax[0, 0], ax[0, 1], ax[1, 0], ax[1, 1]
    a_speed.plot(t_o, np.linalg.norm(v_o, axis=1), "--", color="grey", label="original")
    a_speed.plot(t_r, np.linalg.norm(sp.velocity, axis=1), color="C0", label="re-timed")
    lim_t = result.t
    a_speed.step(lim_t, np.minimum(result.speed_limits, limits.v_max), where="mid", color="C3",
                 lw=0.8, label="speed limit")
    a_speed.set(xlabel="time (s)", ylabel="speed (m/s)", title="Speed")
    for k, name in enumerate("xyz"):
        a_acc.plot(t_o, a_o[:, k], "--", color=f"C{k}", alpha=0.5, lw=0.8)
        a_acc.plot(t_r, sp.acceleration[:, k], color=f"C{k}", label=f"a_{name} re-timed")
    a_max = max(limits.a_max)
    a_acc.axhline(a_max, color="C3", lw=0.8)
    a_acc.axhline(-a_max, color="C3", lw=0.8)
    a_acc.set(xlabel="time (s)", ylabel="acceleration (m/s²)",
              title="Acceleration (dashed: original)")
    for a in (a_speed, a_acc):
        for z0, z1 in zones:
            a.axvspan(z0, z1, color="C3", alpha=0.12, lw=0)
        a.legend(loc="upper right", fontsize=8)
        a.grid(alpha=0.3)

    a_map.plot(result.t, result.tau - t0, color="C0", label="tau = h(t) (re-timed)")
    end = max(result.duration, t1 - t0)
    a_map.plot([0, t1 - t0], [0, t1 - t0], "--", color="grey", label="original (tau = t)")
    a_map.set(xlabel="real time t (s)", ylabel="trajectory time tau (s)", xlim=(0, end),
              title=f"Time mapping: {t1 - t0:.2f} s -> {result.duration:.2f} s ({result.status})")
    a_map.legend(fontsize=8)
    a_map.grid(alpha=0.3)

    p = traj.position(tau_o)
    _obstacles(a_top, obstacles, p)
    a_top.plot(p[:, 0], p[:, 1], color="C0", label="path")
    mask = result.diagnostics.braking_mask
    if mask is not None and np.any(mask):
        bp = traj.position(result.tau[mask])
        a_top.scatter(bp[:, 0], bp[:, 1], s=8, color="C3", zorder=3, label="braking points")
    _top_view(a_top, fig, title)
    return fig


def _obstacles(ax: plt.Axes, obstacles: NDArray[np.float64] | None,
               p: NDArray[np.float64]) -> None:
    if obstacles is not None and len(obstacles):
        near = np.all((obstacles[:, :2] > p[:, :2].min(0) - 2)
                      & (obstacles[:, :2] < p[:, :2].max(0) + 2), axis=1)
        ax.scatter(obstacles[near, 0], obstacles[near, 1], s=2, color="k", alpha=0.4,
                   label="occupied voxels")


def _top_view(ax: plt.Axes, fig: plt.Figure, title: str) -> None:
    ax.set(xlabel="x (m)", ylabel="y (m)", title="Top view")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    fig.tight_layout()


def _rejected(result: RetimeResult, limits: Limits, obstacles: NDArray[np.float64] | None,
              title: str) -> plt.Figure:
    """A rejected path: the planned speed and acceleration, the reason, the path in red."""
    import textwrap

    traj = result.trajectory
    t0, t1 = traj.domain
    tau = np.linspace(t0, t1, 1000)
    p, v, a = traj.evaluate(tau)
    fig, ax = plt.subplots(2, 2, figsize=(12, 8))
    a_speed, a_acc, a_note, a_top = ax[0, 0], ax[0, 1], ax[1, 0], ax[1, 1]
    a_speed.plot(tau - t0, np.linalg.norm(v, axis=1), "--", color="grey", label="as planned")
    a_speed.axhline(limits.v_max, color="C3", lw=0.8, label="speed limit")
    a_speed.set(xlabel="planned time (s)", ylabel="speed (m/s)", title="Speed (not flown)")
    for k, name in enumerate("xyz"):
        a_acc.plot(tau - t0, a[:, k], "--", color=f"C{k}", lw=0.8, label=f"a_{name} planned")
    a_acc.set(xlabel="planned time (s)", ylabel="acceleration (m/s²)",
              title="Acceleration (not flown)")
    for one in (a_speed, a_acc):
        one.legend(loc="upper right", fontsize=8)
        one.grid(alpha=0.3)
    a_note.axis("off")
    reason = textwrap.fill(result.message or "rejected", 60)
    a_note.text(0.02, 0.95, f"REJECTED: not flown\n\n{reason}", va="top", ha="left",
                fontsize=10, color=REJECTED_COLOUR, transform=a_note.transAxes, wrap=True)
    _obstacles(a_top, obstacles, p)
    a_top.plot(p[:, 0], p[:, 1], "--", color=REJECTED_COLOUR, label="rejected path")
    _top_view(a_top, fig, title)
    return fig
