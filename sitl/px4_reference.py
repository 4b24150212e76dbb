"""Reference flights of real PX4 (SIH quadrotor) that the ``sitl`` vehicle is calibrated against.

The recordings (PX4 main, airframe 10040, default parameters, no RC; MAVSDK sending offboard
setpoints at 50 Hz, a passive observer on the GCS link; one host clock) are described in
docs/sitl.md ("Calibration"). :func:`extract` reads their CSV files and keeps what the
calibration needs in one compressed file, ``sitl/data/px4_sih_reference.npz`` (shipped with
the package); :func:`load` reads it back as a dict of arrays:

* ``<run>/sp_t``, ``<run>/sp_pva``, ``<run>/sp_mask``: setpoints on the wire, one row per
  message (time s; position, velocity, acceleration NED; type mask): every 50 Hz copy, so a
  replay sends what PX4 got;
* ``<run>/t``, ``<run>/pos``, ``<run>/mode``: PX4's response at ~50 Hz: its position estimate
  (what it controls and reports) and mode; ``tracking/truth`` and ``hover/truth`` SIH's ground
  truth, ``hover/vel`` the estimated velocity (positions kept to the millimetre);
* ``<run>/phase_names``, ``<run>/phase_t``: the segments (``line_v2_out``, ...) and start times;

for the runs ``tracking`` (lines and circles at 1-3 m/s), ``steps`` (position steps),
``hover`` (30 s at a fixed setpoint) and ``loss`` (three offboard losses at 2 m/s, resumed 3 s
later); ``takeoff/...`` (time from the takeoff command, z, mode, landed state) and
``arm/hb_latency`` (arm command to the first armed HEARTBEAT, 12 trials).
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import numpy as np

DATA = Path(__file__).resolve().parent / "data" / "px4_sih_reference.npz"
#: PX4 mode names; the file stores their index (``<run>/mode`` is decoded by :func:`load`)
MODES = ("", "AUTO_LOITER", "AUTO_TAKEOFF", "AUTO_RTL", "AUTO_LAND", "OFFBOARD", "POSCTL")
LANDED = ("", "ON_GROUND", "TAKEOFF", "IN_AIR", "LANDING")
_RUNS = {"tracking": "04_tracking", "steps": "03_step_responses", "hover": "06_hover_noise",
         "loss": "05_offboard_loss"}
_XYZ = ("x", "y", "z")


def _read(path: Path) -> dict[str, list[str]]:
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    return {name: [r[j] for r in rows[1:]] for j, name in enumerate(rows[0])}


def _floats(col: list[str]) -> np.ndarray:
    return np.array([float(c) if c else np.nan for c in col], dtype=np.float32)


def _mm(values: np.ndarray) -> np.ndarray:
    """Metres (or m/s) as int16 millimetres (NaN: -32768), which compress far better."""
    out = np.round(np.nan_to_num(values, nan=-32.768) * 1000.0)
    return np.clip(out, -32768, 32767).astype(np.int16)


def _codes(col: list[str], names: tuple[str, ...]) -> np.ndarray:
    return np.array([names.index(c) for c in col], dtype=np.int8)


def _columns(table: dict[str, list[str]], names: tuple[str, ...], prefix: str = "") -> np.ndarray:
    return np.column_stack([_floats(table[prefix + n]) for n in names])


def _setpoints(table: dict[str, list[str]]) -> dict[str, np.ndarray]:
    """Merged wire rows (``t_s`` .. ``t_last_s``, ``n_copies``) expanded to every copy."""
    t0, t1 = _floats(table["t_s"]), _floats(table["t_last_s"])
    n = _floats(table["n_copies"]).astype(int)
    t = np.concatenate([np.linspace(a, b, k) if k > 1 else [a]
                        for a, b, k in zip(t0, t1, n, strict=True)]).astype(np.float32)
    rows = np.repeat(np.arange(len(n)), n)
    pva = np.column_stack([_columns(table, _XYZ), _columns(table, ("vx", "vy", "vz")),
                           _columns(table, ("afx", "afy", "afz"))])[rows]
    return {"t": t, "pva": np.round(pva * 1e4).astype(np.int32),  # the CSV's 0.1 mm
            "mask": _floats(table["type_mask"]).astype(np.int32)[rows]}


def _phases(events: dict[str, list[str]]) -> tuple[np.ndarray, np.ndarray]:
    names, starts = [], []
    for t, ev, detail in zip(events["t_s"], events["event"], events["detail"], strict=True):
        if ev == "phase":
            names.append(json.loads(detail)["phase"])
            starts.append(float(t))
    return np.array(names), np.array(starts)


def extract(csv_dir: str | Path, out: str | Path = DATA) -> Path:
    """Read the recordings in ``csv_dir`` (the ``px4-sih`` directory) into ``out``."""
    src = Path(csv_dir)
    arrays: dict[str, np.ndarray] = {}
    for run, stem in _RUNS.items():
        table = _read(src / f"{stem}.csv")
        for key, value in _setpoints(_read(src / f"{stem}_setpoints.csv")).items():
            arrays[f"{run}/sp_{key}"] = value
        arrays[f"{run}/t"] = _floats(table["t_s"])
        arrays[f"{run}/pos"] = _mm(_columns(table, _XYZ))
        if run in ("tracking", "hover"):
            arrays[f"{run}/truth"] = _mm(_columns(table, _XYZ, "gt_"))
        if run == "hover":
            arrays[f"{run}/vel"] = _mm(_columns(table, ("vx", "vy", "vz")))
        arrays[f"{run}/mode"] = _codes(table["mode"], MODES)
        names, starts = _phases(_read(src / f"{stem}_events.csv"))
        arrays[f"{run}/phase_names"] = names
        arrays[f"{run}/phase_t"] = starts.astype(np.float32)
    take = _read(src / "02_takeoff.csv")
    events = _read(src / "02_takeoff_events.csv")
    t_cmd = next(float(t) for t, ev, d in zip(events["t_s"], events["event"], events["detail"],
                                                strict=True)
                 if ev == "COMMAND_LONG" and d.startswith("cmd=22"))
    arrays["takeoff/t"] = _floats(take["t_s"]) - t_cmd
    arrays["takeoff/z"] = _floats(take["z"]).astype(np.float32)
    arrays["takeoff/mode"] = _codes(take["mode"], MODES)
    arrays["takeoff/landed"] = _codes(take["landed_state"], LANDED)
    trials = _read(src / "01_arm_latency_trials.csv")
    arrays["arm/hb_latency"] = _floats(trials["hb_armed_onboard_link_latency_s"])
    arrays["arm/ack_latency"] = _floats(trials["ack_latency_s"])
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(out, **arrays)
    return out


def load(path: str | Path = DATA) -> dict[str, Any]:
    """The reference data (see module docstring)."""
    with np.load(path) as npz:
        out = {key: npz[key] for key in npz.files}
    for key in out:
        if key.endswith("/sp_pva"):
            out[key] = out[key] / 1e4
        elif out[key].dtype == np.int16:
            out[key] = np.where(out[key] == -32768, np.nan, out[key] / 1000.0)
        elif key.endswith("/mode"):
            out[key] = np.array(MODES)[out[key]]
        elif key.endswith("/landed"):
            out[key] = np.array(LANDED)[out[key]]
    return out


def phase_span(ref: dict[str, Any], run: str, phase: str) -> tuple[float, float]:
    """Start and end (the next phase's start) of ``phase`` in ``run``."""
    names, starts = ref[f"{run}/phase_names"], ref[f"{run}/phase_t"]
    k = int(np.flatnonzero(names == phase)[0])
    end = float(starts[k + 1]) if k + 1 < len(starts) else float(ref[f"{run}/t"][-1])
    return float(starts[k]), end


if __name__ == "__main__":  # pragma: no cover - maintenance: python -m sitl.px4_reference DIR
    import sys

    print(extract(sys.argv[1]))
