"""In-flight estimation of ROTA's speed-to-deviation model ``s = m v + b`` (paper Eq. 15)
and its memory time ``T`` (``docs/safety-model.md``), per vehicle, persisted.

What matters for a collision is how far the vehicle's **true** position is off the commanded
path (a vehicle behind schedule but on the path is as safe as that point of the path; in a
turn, lag cuts the corner, which is off the path). The companion sees part of it
(``docs/estimator.md``):

* the **tracking error** as the service measures it: PX4's position estimate minus the
  nearest setpoint sent in the last ``[safety] tracking_lag_s`` (PX4's lag along the path
  forgiven);
* **PX4's own position standard deviation** (the ODOMETRY covariance): the part of the
  deviation PX4 knows it cannot see (its estimate minus the truth). It is added as a
  variance, ``d^2 = e_track^2 + s_px4^2`` per axis.

What neither shows is the estimation error's real size where the EKF under-reports it, and
how it correlates with the tracking error; docs/estimator.md measures that on PX4 SIH.

The model: per horizontal axis the deviation is ``N(0, s^2)`` with ``s = max(m v_T + b,
floor)``, where ``v_T`` is the largest speed of the last ``T`` seconds (``T = 0``: the speed
now, the paper's model). This is exactly what ROTA enforces with error memory (the vehicle is
at a braking point's limit for the last ``T`` seconds), so the learned ``T`` is the one ROTA
needs. It is fitted by maximum likelihood, for every ``T`` on a grid at once, from sufficient
statistics: per ``T`` and speed bin, the weighted count of axis samples, the sum of their
squared deviations and of their speeds. The fit per ``T`` is a weighted least squares of the
bins' RMS deviation on their mean speed, iterated (the weights are the Fisher information
``2 n / s^2``; bins where the model is at its floor are left out), with the prior ``(m, b)``
as a Gaussian penalty; ``T`` is then chosen by the likelihood. All of it is a few small
numpy operations, cheap enough for the service's event loop.

Robustness:

* a sample whose deviation exceeds ``max_deviation_m`` (a replan jump, a glitch) or, once the
  estimate is trusted, ``gate`` times the model's std, is an outlier: rejected and counted;
* 5 Hz samples are correlated over about a second: each counts ``sample_weight``;
* statistics fade with ``forget_s`` seconds of flight, so a changed vehicle is followed;
* the estimate is clamped to configured bounds; ``T`` to ``[0, memory_max_s]``; a learned
  ``T`` replaces the configured one only when it is longer and the likelihood favours it by
  ``memory_evidence`` (nats, in weighted samples): the estimation error's own memory is
  invisible to the companion, so the evidence can lengthen ``T``, never shorten it;
* until ``min_samples`` samples were accepted, ROTA gets the estimate only if it is at least
  as cautious as the configured model (never a faster ``m``, ``b`` or a shorter ``T``);
* it can be frozen, set and reset; it is saved per vehicle and restored.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections import deque
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from filterpy.kalman import KalmanFilter

from companion.uncertainty.settings import EstimatorSettings
from rota.chance import UncertaintyModel

#: Memory times the likelihood is evaluated on (s).
MEMORY_GRID = tuple(np.round(np.arange(0.0, 3.01, 0.25), 2))
#: Speed bins of the statistics (m/s): 0.1 m/s wide up to 8 m/s (faster samples: last bin).
BIN_WIDTH, N_BINS = 0.1, 80
_FLOOR = 0.01  # s never goes below this in the likelihood (m)
SCHEMA = "rota/deviation-estimate"
#: The outlier gate's model is refitted every this many samples.
GATE_REFIT = 25
#: The fit follows the evidence every this many accepted samples (1 s at 5 Hz).
REFIT_EVERY = 5


@dataclass(frozen=True)
class Fit:
    """The fitted model for one memory time."""

    memory_s: float
    m: float
    b: float
    m_std: float
    b_std: float
    nll: float


def _fit_all(count: np.ndarray, sq: np.ndarray, vsum: np.ndarray, m0: float, b0: float,
             s_m: float, s_b: float, bounds: tuple[float, float, float, float]
             ) -> list[tuple[float, ...]]:
    """Per memory time (rows): ``(m, b, m_std, b_std, nll)``, fitted from the bins' weighted
    counts ``count``, sums of squared deviations ``sq`` and sums of speeds ``vsum`` (rows x
    bins; a bin's speed is its mean).

    Per memory time, a filterpy :class:`~filterpy.kalman.KalmanFilter` over ``(m, b)`` (all
    memory times in one filter, as independent blocks of its state) starts at the prior
    ``N((m0, b0), diag(s_m^2, s_b^2))`` and takes the bins' RMS
    deviations as measurements (``H`` rows ``(v, 1)``, noise ``s^2 / (2 n)``, the inverse
    Fisher information of a bin of ``n`` axis samples; passed in their sufficient 2 x 2
    form); the noise is re-judged at
    the updated line and the update repeated from the prior (iteratively re-weighted: the
    filter's posterior is then the penalised maximum-likelihood fit). Bins where the model
    sits at its floor say nothing about the line and are left out."""
    has = count > 1e-9
    v = np.where(has, vsum / np.where(has, count, 1.0), (np.arange(N_BINS) + 0.5) * BIN_WIDTH)
    rms = np.sqrt(np.where(has, sq / np.where(has, count, 1.0), 0.0))
    rows = len(count)
    m = np.full(rows, m0)
    b = np.full(rows, b0)
    prior_x = np.tile([m0, b0], rows)[:, None]
    prior_p = np.kron(np.eye(rows), np.diag([s_m**2, s_b**2]))
    # One filterpy filter whose state holds every memory time's (m, b) (independent blocks):
    # one update per re-weighting for all of them.
    kf = KalmanFilter(dim_x=2 * rows, dim_z=2 * rows)
    for _ in range(4):
        line = m[:, None] * v + b[:, None]
        s = np.maximum(line, _FLOOR)
        w = np.where(has & (line > _FLOOR), 2.0 * count / s**2, 0.0)
        # the bins' measurements in their sufficient form: per memory time the weighted
        # least-squares line and its covariance (the same posterior as one update per bin;
        # a direction no bin informs gets a variance of 1e12)
        info = np.empty((rows, 2, 2))
        info[:, 0, 0] = (w * v * v).sum(1) + 1e-12
        info[:, 0, 1] = info[:, 1, 0] = (w * v).sum(1)
        info[:, 1, 1] = w.sum(1) + 1e-12
        rhs = np.stack([(w * v * rms).sum(1), (w * rms).sum(1)], axis=1)
        cov = np.linalg.inv(info)
        z = np.einsum("kij,kj->ki", cov, rhs).reshape(-1, 1)
        r = np.zeros((2 * rows, 2 * rows))
        for k in range(rows):
            r[2 * k:2 * k + 2, 2 * k:2 * k + 2] = cov[k]
        kf.x = prior_x.copy()
        kf.P = prior_p.copy()
        kf.update(z, R=r, H=np.eye(2 * rows))
        m = np.clip(kf.x[0::2, 0], bounds[0], bounds[1])
        b = np.clip(kf.x[1::2, 0], bounds[2], bounds[3])
    s = np.maximum(m[:, None] * v + b[:, None], _FLOOR)
    nll = (sq / (2.0 * s**2) + count * np.log(s)).sum(1)
    var = np.diag(kf.P)
    return [(float(m[k]), float(b[k]), math.sqrt(max(float(var[2 * k]), 0.0)),
             math.sqrt(max(float(var[2 * k + 1]), 0.0)), float(nll[k])) for k in range(rows)]


class UncertaintyEstimator:
    """Learns ``m``, ``b`` and ``T`` of the deviation model; also the service's uncertainty
    source (``model()`` at every re-time, ``describe()`` for the status)."""

    def __init__(self, prior: UncertaintyModel, settings: EstimatorSettings,
                 path: Path | None = None, v_check: float = 2.0) -> None:
        self.prior = prior
        self.settings = settings
        self.path = path
        self.v_check = v_check  # speed at which "more cautious" is judged (the speed limit)
        self.grid = np.array([t for t in MEMORY_GRID if t <= settings.memory_max_s + 1e-9])
        self.reset()
        if path is not None and path.exists():
            self.load()

    # ------------------------------------------------------------ evidence
    def reset(self) -> None:
        self._count = np.zeros((len(self.grid), N_BINS))
        self._sq = np.zeros((len(self.grid), N_BINS))
        self._vsum = np.zeros((len(self.grid), N_BINS))
        self._speeds: deque[tuple[float, float]] = deque()
        self.samples = self.outliers = self.skipped = 0
        self.session_samples = 0  # accepted since this estimator started (the restart floor)
        self._weight = 0.0  # seconds of evidence (faded with forget_s)
        self._last_t: float | None = None
        self._fits: list[Fit] | None = None
        self._gate: tuple[UncertaintyModel, UncertaintyModel] | None = None
        self._anchor = (self.prior.m, self.prior.b)
        self._trusted = False
        self._set_memory: float | None = None  # set() by the operator

    @property
    def configured_memory_s(self) -> float:
        """The memory time in force without evidence: set() by the operator, else the
        configuration's."""
        return self.prior.memory_s if self._set_memory is None else self._set_memory

    def observe(self, speed: float, deviation: np.ndarray, reported_std: np.ndarray | None = None,
                t: float | None = None) -> str:
        """One sample: the vehicle's ``speed`` (m/s), its tracking error per horizontal axis
        ``deviation`` (reported position minus the nearest recent setpoint, m) and PX4's
        position std per axis (None: not reported). Returns ``"accepted"``, ``"outlier"``,
        ``"frozen"`` or ``"invalid"``."""
        s = self.settings
        if s.frozen or not s.enabled:
            return "frozen"
        dev = np.asarray(deviation, dtype=float)
        rep = np.zeros_like(dev) if reported_std is None else np.asarray(reported_std, float)
        if (not math.isfinite(speed) or speed < 0 or dev.ndim != 1 or rep.shape != dev.shape
                or not (np.all(np.isfinite(dev)) and np.all(np.isfinite(rep)))):
            self.skipped += 1
            return "invalid"
        now = time.monotonic() if t is None else float(t)
        dt = 0.0 if self._last_t is None else max(now - self._last_t, 0.0)
        self._last_t = now
        self._speeds.append((now, float(speed)))
        while self._speeds and self._speeds[0][0] < now - self.grid[-1] - 1e-9:
            self._speeds.popleft()
        v_t = self._window_speeds(now)
        sq = float(np.sum(dev**2 + rep**2))
        if np.sqrt(sq / len(dev)) > s.max_deviation_m:
            self.outliers += 1
            return "outlier"
        if self.samples >= s.min_samples:
            # (the gate's model is refitted every GATE_REFIT samples: a refit is a few ms)
            # (judged at the larger of the model in use and the evidence's own fit: the
            # evidence rule holding the estimate near the prior must not reject the evidence)
            if self._gate is None or self.samples % GATE_REFIT == 0:
                fit = self.best()[0]
                self._gate = (self.model(), UncertaintyModel(m=fit.m, b=fit.b,
                                                             memory_s=fit.memory_s))
            model_s = max(max(u.m * float(np.interp(u.memory_s, self.grid, v_t)) + u.b
                              for u in self._gate), _FLOOR)
            if math.sqrt(sq / len(dev)) > s.gate * model_s:
                self.outliers += 1
                return "outlier"
        if dt > 0.0 and s.forget_s > 0.0:
            fade = math.exp(-dt / s.forget_s)
            self._count *= fade
            self._sq *= fade
            self._vsum *= fade
            self._weight *= fade
        rows = np.arange(len(self.grid))
        bins = np.minimum((v_t / BIN_WIDTH).astype(int), N_BINS - 1)
        self._count[rows, bins] += s.sample_weight * len(dev)
        self._sq[rows, bins] += s.sample_weight * sq
        self._vsum[rows, bins] += s.sample_weight * len(dev) * v_t
        self._weight += s.sample_weight
        self.samples += 1
        self.session_samples += 1
        if self.samples % REFIT_EVERY == 0:  # a refit costs a few ms: once a second at 5 Hz
            self._fits = None
        return "accepted"

    def _window_speeds(self, now: float) -> np.ndarray:
        """Largest speed over the last T seconds, for every T of the grid."""
        t = np.array([x[0] for x in self._speeds])
        v = np.array([x[1] for x in self._speeds])
        age = now - t
        return np.array([v[age <= T + 1e-9].max() for T in self.grid])

    # ------------------------------------------------------------- the fit
    def fits(self) -> list[Fit]:
        """The fitted model for every memory time of the grid."""
        if self._fits is None:
            s = self.settings
            rows = _fit_all(self._count, self._sq, self._vsum, *self._anchor, s.prior_std_m,
                            s.prior_std_b,
                            (s.m_min, s.m_max, s.b_min, s.b_max))
            self._fits = [Fit(float(T), *r) for T, r in zip(self.grid, rows, strict=True)]
        return self._fits

    def best(self) -> tuple[Fit, bool]:
        """The learned model and whether its memory time was learned: the most likely memory
        time when it is *longer* than the configured one (its nearest grid value) by at
        least ``memory_evidence`` of log-likelihood, else the configured one.

        Never shorter: the evidence shows the memory of the tracking error only. The
        estimation error's own memory is invisible (PX4 reports a std, not the error), so
        finding no memory in what the companion sees is no evidence that there is none."""
        conf, top, gain = self._memory_evidence()
        if self.settings.learn_memory and gain >= self.settings.memory_evidence:
            return top, True
        return conf, False

    def _memory_evidence(self) -> tuple[Fit, Fit, float]:
        """The fit at the configured memory time, the most likely longer one, and the
        log-likelihood gain of lengthening it (0 if no longer one is more likely)."""
        fits = self.fits()
        conf = min(fits, key=lambda f: abs(f.memory_s - self.configured_memory_s))
        top = min(fits, key=lambda f: f.nll)
        if top.memory_s <= conf.memory_s:
            return conf, conf, 0.0
        return conf, top, conf.nll - top.nll

    @property
    def memory_gain(self) -> float:
        """The evidence for a longer memory time than the configured one: the
        log-likelihood gain of the most likely one (lengthened at
        ``memory_evidence``)."""
        return self._memory_evidence()[2]

    @property
    def m(self) -> float:
        return self._anchor[0] + self.shrink * (self.best()[0].m - self._anchor[0])

    @property
    def b(self) -> float:
        return self._anchor[1] + self.shrink * (self.best()[0].b - self._anchor[1])

    @property
    def evidence_s(self) -> float:
        """Seconds of flight evidence (faded with ``forget_s``) the estimate rests on."""
        return self._weight

    @property
    def shrink(self) -> float:
        """The evidence rule: the share of the way from the configured (or set) model to the
        fit that the estimate has gone, ``t / (t + prior_weight_s)`` after ``t`` seconds of
        evidence (``prior_weight_s = 0``: all the way)."""
        w = self.settings.prior_weight_s
        return 1.0 if w <= 0 else self._weight / (self._weight + w)

    @property
    def memory_s(self) -> float:
        """The learned memory time, or the configured one."""
        fit, learned = self.best()
        return fit.memory_s if learned else self.configured_memory_s

    @property
    def std(self) -> tuple[float, float]:
        """Standard deviations of ``m`` and ``b`` (from the fit's information)."""
        fit, _ = self.best()
        return fit.m_std, fit.b_std

    # ---------------------------------------------- the uncertainty source
    def estimate(self) -> UncertaintyModel:
        """The current estimate as a model (whatever the evidence)."""
        return UncertaintyModel(m=self.m, b=self.b, floor=self.prior.floor,
                                per_axis=self.prior.per_axis, memory_s=self.memory_s)

    def in_use(self) -> str:
        """``"estimate"`` or ``"prior"``: which one ROTA gets now."""
        if not self.settings.enabled:
            return "prior"
        if self.session_samples >= self.settings.min_samples or self._trusted:
            return "estimate"
        # Before enough evidence since this start: the estimate only if it is at least as
        # cautious as the prior (the config file) at low speed and at the speed limit, and
        # remembers at least as long. So the file is the floor after every restart.
        est, pri = self.estimate(), self.prior
        if est.memory_s < pri.memory_s:
            return "prior"
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
                "memory_s": used.memory_s,
                "estimate": {"m": round(self.m, 5), "b": round(self.b, 5),
                             "memory_s": self.memory_s, "m_std": round(sm, 5),
                             "b_std": round(sb, 5), "memory_gain": round(self.memory_gain, 3)},
                "prior": {"m": self.prior.m, "b": self.prior.b,
                          "memory_s": self.prior.memory_s},
                "samples": self.samples, "session_samples": self.session_samples,
                "evidence_s": round(self._weight, 1), "shrink": round(self.shrink, 3),
                "outliers": self.outliers, "frozen": self.settings.frozen,
                "per_axis": self.prior.per_axis}

    # ------------------------------------------------------------- control
    def set(self, m: float, b: float, memory_s: float | None = None) -> None:
        """Trust ``m``, ``b`` (and ``T``) as if ``min_samples`` had been seen (until the next
        restart: then the config file is the floor again): they become the prior mean the
        data is fitted around, and the configured memory time."""
        s = self.settings
        if not (s.m_min <= m <= s.m_max and s.b_min <= b <= s.b_max):
            raise ValueError(f"m={m}, b={b} outside the bounds m in [{s.m_min}, {s.m_max}], "
                             f"b in [{s.b_min}, {s.b_max}]")
        if memory_s is not None:
            if not 0.0 <= memory_s <= s.memory_max_s:
                raise ValueError(f"memory_s={memory_s} outside [0, {s.memory_max_s}]")
            self._set_memory = float(memory_s)
        self._anchor = (float(m), float(b))
        self._trusted = True
        self._fits = None

    def freeze(self, frozen: bool) -> None:
        self.settings = replace(self.settings, frozen=bool(frozen))

    # ---------------------------------------------------------- persistence
    def to_dict(self) -> dict[str, Any]:
        return {"schema": SCHEMA, "version": 1, "stamp": time.time(), "grid": self.grid.tolist(),
                "bin_width": BIN_WIDTH, "count": self._count.tolist(), "sq": self._sq.tolist(),
                "vsum": self._vsum.tolist(),
                "anchor": list(self._anchor), "trusted": self._trusted,
                "set_memory_s": self._set_memory,
                "samples": self.samples, "outliers": self.outliers, "evidence_s": self._weight,
                "frozen": self.settings.frozen, "prior": asdict(self.prior)}

    def save(self) -> None:
        if self.path is None:
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_suffix(".tmp")
        tmp.write_text(json.dumps(self.to_dict()))
        os.replace(tmp, self.path)  # atomic: a crash never leaves half a file

    def load(self) -> None:
        assert self.path is not None
        try:
            d = json.loads(self.path.read_text())
            if d.get("schema") != SCHEMA:
                raise ValueError("not a deviation estimate (an older version learned PX4's "
                                 "covariance only)")
            count = np.asarray(d["count"], dtype=float)
            sq = np.asarray(d["sq"], dtype=float)
            vsum = np.asarray(d["vsum"], dtype=float)
            anchor = tuple(float(x) for x in d["anchor"])
            if (count.shape != self._count.shape or sq.shape != count.shape
                    or vsum.shape != count.shape or not np.all(np.isfinite(vsum))
                    or d["grid"] != self.grid.tolist() or d["bin_width"] != BIN_WIDTH
                    or len(anchor) != 2 or not np.all(np.isfinite(count))
                    or not np.all(np.isfinite(sq)) or not all(map(math.isfinite, anchor))):
                raise ValueError("non-finite or misshapen statistics")
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"{self.path}: cannot restore the uncertainty estimate ({exc})") \
                from None
        self._count, self._sq, self._vsum = count, sq, vsum
        # The config file is the floor after every restart: a saved set that is less
        # cautious than the file (in m, b or the memory time) is dropped, and nothing saved is
        # trusted until min_samples new samples arrive (in_use); the evidence itself stays.
        pri = self.prior
        self._anchor = (max(anchor[0], pri.m), max(anchor[1], pri.b))  # type: ignore[index]
        self._trusted = False
        memory = d.get("set_memory_s")
        self._set_memory = (None if memory is None or float(memory) < pri.memory_s
                            else float(memory))
        weight = d.get("evidence_s")
        self._weight = (float(count[0].sum()) / 2.0 if not isinstance(weight, int | float)
                        or not math.isfinite(weight) or weight < 0 else float(weight))
        self.samples = int(d.get("samples", 0))
        self.outliers = int(d.get("outliers", 0))
        self.session_samples = 0
        self._fits = None
        if d.get("frozen"):
            self.freeze(True)
