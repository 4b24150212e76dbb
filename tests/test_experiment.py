"""The collision-rate experiment (issue #8): statistics, a reduced run of the full grid (CI),
determinism, the command line."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.optimize import brentq

from sitl.experiment import (
    ExperimentConfig,
    cell_stats,
    mcnemar_one_sided,
    run_experiment,
    wilson,
    write_outputs,
)
from sitl.experiment_cli import main

Z95 = 1.959963984540054


def _wilson_by_root(k: int, n: int) -> tuple[float, float]:
    """Independent Wilson interval: the p with |k - n p| = z sqrt(n p (1 - p))."""
    def f(p: float) -> float:
        return (k - n * p) ** 2 - Z95**2 * n * p * (1 - p)
    p_hat = k / n
    lo = 0.0 if k == 0 else brentq(f, 1e-12, min(p_hat, 1 - 1e-12))
    hi = 1.0 if k == n else brentq(f, max(p_hat, 1e-12), 1 - 1e-12)
    return lo, hi


@pytest.mark.parametrize("k,n", [(0, 50), (1, 50), (5, 50), (25, 50), (50, 50), (3, 500),
                                 (120, 500)])
def test_wilson_matches_its_definition(k, n):
    assert wilson(k, n) == pytest.approx(_wilson_by_root(k, n), abs=1e-9)


def test_wilson_known_value():
    lo, hi = wilson(0, 50)  # textbook: z^2 / (n + z^2)
    assert lo == 0.0 and hi == pytest.approx(Z95**2 / (50 + Z95**2), rel=1e-12)


def test_mcnemar_one_sided():
    planned = np.array([True] * 6 + [False] * 10)
    rota = np.zeros(16, dtype=bool)
    assert mcnemar_one_sided(planned, rota) == pytest.approx(0.5**6)
    # Concordant pairs do not count; the reverse direction gives p = 1.
    both = np.array([True] * 3 + [False] * 3)
    assert mcnemar_one_sided(both, both) == 1.0
    assert mcnemar_one_sided(rota[:6], np.array([True] * 6)) == 1.0
    # b = 7, c = 2: P(X >= 7 | Bin(9, 1/2)) = (36 + 9 + 1) / 512.
    p = np.array([True] * 7 + [False] * 2 + [True])
    r = np.array([False] * 7 + [True] * 2 + [True])
    assert mcnemar_one_sided(p, r) == pytest.approx(46 / 512)


def test_cell_stats_from_synthetic_data():
    cfg = ExperimentConfig(trials=6, densities=(0.043,), speeds=(2.0,), accel_ratio=1.5)
    data = {
        "planned": [True, True, True, True, True, False],
        "status": ["optimal"] * 4 + ["fallback", "no-plan"],
        "collided": {"planned": [True, True, False, False, True, False],
                     "rota": [False, True, False, False, False, False]},
        "closest": {"planned": [-0.01, -0.02, 0.3, 0.2, -0.001, math.nan],
                    "rota": [0.1, -0.02, 0.3, 0.25, 0.05, math.nan]},
        "ground_contact": {"planned": [False] * 6, "rota": [False] * 6},
        "duration_planned": [10.0, 11.0, 12.0, 13.0, 14.0, math.nan],
        "duration_rota": [11.0, 12.0, 13.0, 14.0, 15.0, math.nan],
        "path_clearance": [0.2, 0.15, 0.3, 0.2, 0.25, math.nan],
        "braking_fraction": [0.1, 0.2, 0.3, 0.4, 0.5, math.nan],
    }
    c = cell_stats(cfg, 0, 0, data)
    assert c.n == 5 and c.plan_failures == 1 and c.a_max == 3.0
    assert c.collisions == {"planned": 3, "rota": 1}
    assert c.rate["planned"] == pytest.approx(0.6)
    assert c.ci95["rota"] == pytest.approx(wilson(1, 5))
    assert c.discordant == (2, 0) and c.p_mcnemar == pytest.approx(0.25)
    assert c.mean_duration == {"planned": 12.0, "rota": 13.0}
    assert c.closest_median["planned"] == pytest.approx(-0.001)
    assert c.retime_status == {"optimal": 4, "fallback": 1}
    assert c.path_clearance_min == pytest.approx(0.15)
    assert c.rota_not_higher and c.needs_significance and not c.significant and not c.done


def test_rejected_paths_policy():
    """Paths ROTA rejects are left out of both arms (default) or flown with the fallback."""
    data = {
        "planned": [True, True, True], "status": ["optimal", "rejected", "optimal"],
        "collided": {"planned": [False, True, False], "rota": [False, False, False]},
        "closest": {"planned": [0.1, -0.1, 0.2], "rota": [0.1, 0.3, 0.2]},
        "ground_contact": {"planned": [False] * 3, "rota": [False] * 3},
        "duration_planned": [10.0, 10.0, 10.0], "duration_rota": [11.0, 30.0, 11.0],
        "path_clearance": [0.2, 0.1, 0.2], "braking_fraction": [0.1, 0.1, 0.1],
    }
    ex = cell_stats(ExperimentConfig(trials=3), 0, 0, data)
    assert ex.n == 2 and ex.collisions["planned"] == 0 and ex.rejected_planned_collisions == 1
    assert ex.mean_duration["rota"] == 11.0 and ex.retime_status["rejected"] == 1
    fb = cell_stats(ExperimentConfig(trials=3, rejected="fallback"), 0, 0, data)
    assert fb.n == 3 and fb.collisions == {"planned": 1, "rota": 0}


def test_reduced_grid_runs_and_writes_table_and_plot(tmp_path):
    """The CI run: the full 3 x 3 grid with 3 trials per cell."""
    cfg = ExperimentConfig(trials=3, workers=2, chunk=2)
    result = run_experiment(cfg)
    assert len(result.cells) == 9
    for c in result.cells:
        assert c.n + c.plan_failures + c.retime_status.get("rejected", 0) == 3
        assert 0.0 <= c.rate["planned"] <= 1.0 and 0.0 <= c.rate["rota"] <= 1.0
        assert c.ci95["planned"][0] <= c.rate["planned"] <= c.ci95["planned"][1]
        assert c.mean_duration["planned"] > 0 and c.mean_duration["rota"] > 0
        # The planner flies at the limit: faster limits -> shorter flights.
        assert c.a_max == pytest.approx(cfg.accel_ratio * c.v_max)
    for d in cfg.densities:
        t = [result.cell(d, v).mean_duration["planned"] for v in cfg.speeds]
        assert t[0] > t[1] > t[2]
    # Per-trial data are consistent with the statistics.
    data = result.trials[(2, 2)]
    flown = np.array(data["planned"])
    col = np.array(data["collided"]["planned"])[flown]
    closest = np.array(data["closest"]["planned"])[flown]
    assert np.array_equal(col, closest < 0.0)
    paths = write_outputs(result, str(tmp_path), "rota-sitl experiment collision-rate")
    md = open(paths["md"]).read()
    assert "| Mid (0.043/m^2) |" in md and "v = 3 m/s" in md and "Seed 0" in md
    assert md.count("\n| 0.0") == 9  # one detail row per cell
    assert open(paths["png"], "rb").read(8) == b"\x89PNG\r\n\x1a\n"
    js = json.load(open(paths["json"]))
    assert js["config"]["trials"] == 3 and len(js["cells"]) == 9


def test_results_do_not_depend_on_chunking_or_workers():
    base = dict(densities=(0.063,), speeds=(3.0,), trials=4)
    a = run_experiment(ExperimentConfig(workers=1, chunk=4, **base))
    b = run_experiment(ExperimentConfig(workers=2, chunk=1, **base))
    da, db = a.trials[(0, 0)], b.trials[(0, 0)]
    for key in ("noise_seed", "world_seed", "duration_rota"):
        assert da[key] == db[key]
    assert da["closest"] == db["closest"] and da["collided"] == db["collided"]


def test_cli(tmp_path, capsys):
    out = tmp_path / "t1"
    assert main(["experiment", "collision-rate", "--trials", "1", "--densities", "0.025",
                 "--speeds", "1", "--workers", "1", "--out", str(out), "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "Command: `rota-sitl experiment collision-rate --trials 1" in text
    assert (out / "table1.md").exists() and (out / "table1.png").exists()
