"""In-flight estimation of ROTA's velocity-to-uncertainty model ``s = m v + b``
(paper Eq. 15) with a Kalman filter (filterpy), per vehicle, persisted.

Evidence (see ``docs/estimator.md``): at the current speed ``v`` one
measurement ``z`` of the position standard deviation, from

* ``s_px4``: PX4's own position standard deviation (the ODOMETRY pose
  covariance, averaged over the three axes) - the state estimator's statement of
  its uncertainty, the quantity Eq. 15 models;
* ``s_track``: the standard deviation of the tracking error (reported minus
  commanded position) over the last second, its mean removed: the random part
  of how far the vehicle strays from the commanded path. The mean (a lag at
  speed) is a controller property, not uncertainty.

``z = s_px4`` when PX4 reports a covariance, else ``z = s_track``. With
``include_tracking`` the two add as independent contributions,
``z = sqrt(s_px4^2 + s_track^2)``: more cautious (control error also moves the
vehicle off its nominal position), but no longer the estimator's own model.

The filter's state is ``[m, b]`` with a slow random walk; a measurement is
linear, ``z = [v, 1] x``, where the model is above its floor. Robustness:

* the hover regime (``v < min_speed``) is skipped: it says nothing about ``m``;
* an innovation beyond ``gate`` standard deviations is an outlier: rejected and
  counted;
* the estimate is clamped to configured bounds;
* until ``min_samples`` measurements were accepted, the model handed to ROTA
  is never less cautious than the configured prior;
* it can be frozen, set and reset; it is saved per vehicle and restored.
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from filterpy.kalman import KalmanFilter

from rota.chance import UncertaintyModel


@dataclass(frozen=True)
class EstimatorSettings:
    enabled: bool = True  # learn in flight (false: the configured model only)
    min_samples: int = 150  # accepted measurements before the estimate may be less cautious
    min_speed: float = 0.5  # m/s; slower measurements carry no information on m
    m_min: float = 0.0
    m_max: float = 1.0
    b_min: float = -0.5
    b_max: float = 0.5
    prior_std_m: float = 0.15  # prior standard deviation of m (s)
    prior_std_b: float = 0.15  # prior standard deviation of b (m)
    measurement_std: float = 0.03  # m, noise of one measurement
    process_std: float = 0.001  # random walk of m and b per sqrt(s)
    gate: float = 4.0  # innovations beyond this many standard deviations are outliers
    include_tracking: bool = False  # add the tracking-error spread to PX4's std
    frozen: bool = False


class UncertaintyEstimator:
    """A Kalman filter on ``[m, b]``; also the service's uncertainty source."""

    def __init__(self, prior: UncertaintyModel, settings: EstimatorSettings,
                 path: Path | None = None, v_check: float = 2.0) -> None:
        self.prior = prior
        self.settings = settings
        self.path = path
        self.v_check = v_check  # speed at which "more cautious" is judged (the speed limit)
        self.samples = 0
        self.outliers = 0
        self.skipped = 0
        self._last_t: float | None = None
        self._kf = self._new_filter()
        if path is not None and path.exists():
            self.load()

    # ------------------------------------------------------------ the filter
    def _new_filter(self) -> KalmanFilter:
        s = self.settings
        kf = KalmanFilter(dim_x=2, dim_z=1)
        kf.x = np.array([[self.prior.m], [self.prior.b]])
        kf.P = np.diag([s.prior_std_m**2, s.prior_std_b**2])
        kf.F = np.eye(2)
        kf.R = np.array([[s.measurement_std**2]])
        kf.Q = np.zeros((2, 2))
        return kf

    @property
    def m(self) -> float:
        return float(self._kf.x[0, 0])

    @property
    def b(self) -> float:
        return float(self._kf.x[1, 0])

    @property
    def std(self) -> tuple[float, float]:
        """Standard deviations of ``m`` and ``b`` (the filter's own uncertainty)."""
        return float(math.sqrt(self._kf.P[0, 0])), float(math.sqrt(self._kf.P[1, 1]))

    def observe(self, speed: float, z: float, t: float | None = None) -> str:
        """One measurement: position std ``z`` (m) at ``speed`` (m/s).

        Returns what happened: ``"accepted"``, ``"outlier"``, ``"hover"`` (no
        information on m), ``"floor"`` (at the model's floor: not linear),
        ``"frozen"``, ``"invalid"``.
        """
        s = self.settings
        if s.frozen or not s.enabled:
            return "frozen"
        if not (math.isfinite(speed) and math.isfinite(z)) or speed < 0 or z < 0:
            self.skipped += 1
            return "invalid"
        if speed < s.min_speed:
            self.skipped += 1
            return "hover"
        if z <= self.prior.floor + 1e-6:
            self.skipped += 1
            return "floor"
        now = time.monotonic() if t is None else t
        dt = 0.0 if self._last_t is None else max(now - self._last_t, 0.0)
        self._last_t = now
        self._kf.Q = np.eye(2) * (s.process_std**2) * dt
        self._kf.predict()
        H = np.array([[speed, 1.0]])
        y = z - float((H @ self._kf.x)[0, 0])
        S = float((H @ self._kf.P @ H.T)[0, 0]) + s.measurement_std**2
        if y * y > s.gate**2 * S:
            self.outliers += 1
            return "outlier"
        self._kf.update(np.array([[z]]), H=H)
        self._kf.x[0, 0] = float(np.clip(self.m, s.m_min, s.m_max))
        self._kf.x[1, 0] = float(np.clip(self.b, s.b_min, s.b_max))
        self.samples += 1
        return "accepted"

    # ---------------------------------------------- the uncertainty source
    def estimate(self) -> UncertaintyModel:
        """The current estimate as a model (whatever the evidence)."""
        return UncertaintyModel(m=self.m, b=self.b, floor=self.prior.floor,
                                per_axis=self.prior.per_axis)

    def in_use(self) -> str:
        """``"estimate"`` or ``"prior"``: which one ROTA gets now."""
        if not self.settings.enabled:
            return "prior"
        if self.samples >= self.settings.min_samples:
            return "estimate"
        # Before enough evidence: the estimate only if it is at least as cautious
        # as the prior at low speed and at the speed limit.
        est, pri = self.estimate(), self.prior
        for v in (self.settings.min_speed, max(self.v_check, self.settings.min_speed)):
            if est.m * v + est.b < pri.m * v + pri.b:
                return "prior"
        return "estimate"

    def model(self) -> UncertaintyModel:
        return self.estimate() if self.in_use() == "estimate" else self.prior

    def describe(self) -> dict[str, Any]:
        sm, sb = self.std
        used = self.model()
        return {"source": "estimator" if self.settings.enabled else "config",
                "in_use": self.in_use(), "m": round(used.m, 5), "b": round(used.b, 5),
                "estimate": {"m": round(self.m, 5), "b": round(self.b, 5),
                             "m_std": round(sm, 5), "b_std": round(sb, 5)},
                "prior": {"m": self.prior.m, "b": self.prior.b},
                "samples": self.samples, "outliers": self.outliers,
                "frozen": self.settings.frozen, "per_axis": self.prior.per_axis}

    # ------------------------------------------------------------- control
    def reset(self) -> None:
        self._kf = self._new_filter()
        self.samples = self.outliers = self.skipped = 0
        self._last_t = None

    def set(self, m: float, b: float, std_m: float | None = None,
            std_b: float | None = None) -> None:
        s = self.settings
        if not (s.m_min <= m <= s.m_max and s.b_min <= b <= s.b_max):
            raise ValueError(f"m={m}, b={b} outside the bounds m in [{s.m_min}, {s.m_max}], "
                             f"b in [{s.b_min}, {s.b_max}]")
        self._kf.x = np.array([[float(m)], [float(b)]])
        if std_m is not None and std_b is not None:
            self._kf.P = np.diag([std_m**2, std_b**2])
        self.samples = max(self.samples, s.min_samples)  # an explicit setting is trusted

    def freeze(self, frozen: bool) -> None:
        from dataclasses import replace

        self.settings = replace(self.settings, frozen=bool(frozen))

    # ---------------------------------------------------------- persistence
    def to_dict(self) -> dict[str, Any]:
        return {"schema": "rota/uncertainty-estimate", "version": 1, "stamp": time.time(),
                "m": self.m, "b": self.b, "P": self._kf.P.tolist(), "samples": self.samples,
                "outliers": self.outliers, "frozen": self.settings.frozen,
                "prior": asdict(self.prior)}

    def save(self) -> None:
        if self.path is None:
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_suffix(".tmp")
        tmp.write_text(json.dumps(self.to_dict(), indent=1))
        os.replace(tmp, self.path)  # atomic: a crash never leaves half a file

    def load(self) -> None:
        assert self.path is not None
        try:
            d = json.loads(self.path.read_text())
            m, b = float(d["m"]), float(d["b"])
            P = np.asarray(d["P"], dtype=float)
            if P.shape != (2, 2) or not np.all(np.isfinite(P)) or not (
                    math.isfinite(m) and math.isfinite(b)):
                raise ValueError("non-finite or misshapen estimate")
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"{self.path}: cannot restore the uncertainty estimate ({exc})") \
                from None
        s = self.settings
        self._kf.x = np.array([[float(np.clip(m, s.m_min, s.m_max))],
                               [float(np.clip(b, s.b_min, s.b_max))]])
        self._kf.P = P
        self.samples = int(d.get("samples", 0))
        self.outliers = int(d.get("outliers", 0))
        if d.get("frozen"):
            self.freeze(True)


def evidence(s_px4: float, s_track: float, include_tracking: bool) -> float:
    """The measurement ``z`` from PX4's std and the tracking spread (NaN: none)."""
    if math.isfinite(s_px4):
        if include_tracking and math.isfinite(s_track):
            return math.hypot(s_px4, s_track)
        return s_px4
    return s_track


def tracking_std(errors: np.ndarray) -> float:
    """Standard deviation (per axis, averaged) of tracking errors ``(n, 3)`` with
    their mean removed; NaN with fewer than 5 samples."""
    if len(errors) < 5:
        return float("nan")
    return float(np.sqrt(np.mean(np.var(errors, axis=0))))
