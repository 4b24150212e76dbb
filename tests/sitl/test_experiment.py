"""The collision-rate experiment: statistics, the arms (planner, ROTA, ROTA with memory,
equal-time uniform slow-downs), a reduced run of the full grid, determinism, the memory rule,
the command line."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.optimize import brentq

from rota.trajectory import BSplineTrajectory
from sitl.experiment import ExperimentConfig, planned_sampler, run_experiment
from sitl.experiment_cli import main
from sitl.experiment_report import memory_rule, write_outputs
from sitl.experiment_stats import cell_stats, mcnemar, wilson
from sitl.planner import plan
from sitl.world import forest

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


def test_mcnemar_two_sided():
    first = np.array([True] * 6 + [False] * 10)
    none = np.zeros(16, dtype=bool)
    assert mcnemar(first, none) == (6, 0, pytest.approx(2 * 0.5**6))
    assert mcnemar(none, first) == (0, 6, pytest.approx(2 * 0.5**6))  # symmetric
    both = np.array([True] * 3 + [False] * 3)
    assert mcnemar(both, both) == (0, 0, 1.0)  # concordant pairs do not count
    # b = 7, c = 2: 2 * P(X >= 7 | Bin(9, 1/2)) = 2 * 46 / 512.
    a = np.array([True] * 7 + [False] * 2 + [True])
    b = np.array([False] * 7 + [True] * 2 + [True])
    assert mcnemar(a, b) == (7, 2, pytest.approx(92 / 512))


def _synthetic(outcomes: dict[str, list[bool]], status: list[str], duration: dict) -> dict:
    n = len(status)
    return {
        "planned": [s != "no-plan" for s in status],
        "status": {"0": status, "1": status},
        "duration": duration,
        "flights": {"correlated": {a: {"collided": c, "ground": [False] * n,
                                       "closest": [0.1] * n, "end_time": [1.0] * n}
                                   for a, c in outcomes.items()}},
    }


def test_cell_stats_arms_pairs_and_claim():
    cfg = ExperimentConfig(trials=12, densities=(0.043,), speeds=(2.0,), accel_ratio=1.5,
                           memories=(0.0, 1.0))
    n = 12
    crash = {"planned": [True] * 8 + [False] * 4, "rota:0": [True] * 6 + [False] * 6,
             "rota:1": [False] * 12, "uniform:0": [True] * 7 + [False] * 5,
             "uniform:1": [True] * 10 + [False] * 2}
    dur = {a: [10.0 + i for i in range(n)] for a in crash}
    data = _synthetic(crash, ["optimal"] * 10 + ["rejected", "no-plan"], dur)
    data["flights"]["correlated"]["rota:0"]["ground"] = [False] * 6 + [True] + [False] * 5
    c = cell_stats(cfg, "correlated", 0, 0, data)
    assert c.n == 10 and c.plan_failures == 1 and c.a_max == 3.0
    assert c.crashes == {"planned": 8, "rota:0": 7, "rota:1": 0, "uniform:0": 7,
                         "uniform:1": 10}
    assert c.collisions["rota:0"] == 6 and c.ground["rota:0"] == 1
    assert c.rate["uniform:1"] == 1.0 and c.ci95["rota:1"] == pytest.approx(wilson(0, 10))
    assert c.mean_duration["planned"] == pytest.approx(np.mean(np.arange(10) + 10.0))
    test = c.pair("uniform:1", "rota:1")
    assert (test.only_first, test.only_second) == (10, 0)
    assert test.p == pytest.approx(2 * 0.5**10)
    assert c.claim == "holds"  # planner 80 % > 5 %, 10 vs 0 discordant, p = 0.002
    assert c.retime_status == {"optimal": 10, "rejected": 1}
    assert {(p.first, p.second) for p in c.pairs} == {
        ("planned", "rota:0"), ("planned", "rota:1"), ("uniform:0", "rota:0"),
        ("uniform:1", "rota:1"), ("rota:0", "rota:1")}
    # The same data with fewer trials: no longer significant at 0.01.
    few = cell_stats(cfg, "correlated", 0, 0, _synthetic(
        {a: v[:6] for a, v in crash.items()}, ["optimal"] * 6, {a: v[:6] for a, v in
                                                                dur.items()}))
    assert few.claim == "fails"


def test_rejected_paths_policy():
    """Paths ROTA rejects are left out of every arm (default) or flown with the fallback."""
    cfg = ExperimentConfig(trials=3, memories=(0.0,), uniform=False)
    crash = {"planned": [False, True, False], "rota:0": [False, False, False]}
    data = _synthetic(crash, ["optimal", "rejected", "optimal"],
                      {"planned": [10.0] * 3, "rota:0": [11.0, 30.0, 11.0]})
    data["status"] = {"0": ["optimal", "rejected", "optimal"]}
    ex = cell_stats(cfg, "correlated", 0, 0, data)
    assert ex.n == 2 and ex.crashes["planned"] == 0 and ex.rejected_planned_crashes == 1
    assert ex.mean_duration["rota:0"] == 11.0 and ex.claim == "n/a"
    fb = cell_stats(ExperimentConfig(trials=3, memories=(0.0,), uniform=False,
                                     rejected="fallback"), "correlated", 0, 0, data)
    assert fb.n == 3 and fb.crashes == {"planned": 1, "rota:0": 0}


def test_uniform_slow_down_is_the_planned_path_slower():
    traj = plan(forest(0.043, 3), 2.0, 2.0)
    assert isinstance(traj, BSplineTrajectory)
    scale = 0.8
    t = np.linspace(0.0, traj.duration / scale, 400)
    p, v, a = planned_sampler(traj, scale)(t)
    p0, v0, a0 = traj.evaluate(scale * t)
    assert np.allclose(p, p0) and np.allclose(v, scale * v0) and np.allclose(a, scale**2 * a0)
    assert np.allclose(p[-1], traj.position(np.array([traj.duration]))[0])


def test_reduced_grid_runs_and_writes_table_and_plot(tmp_path):
    """The CI run: the full 3 x 3 grid, 2 trials per cell, every arm, both error models."""
    cfg = ExperimentConfig(trials=2, workers=2, chunk=2)
    result = run_experiment(cfg)
    assert set(result.cells) == {"correlated", "drift"}
    for kind, cells in result.cells.items():
        assert len(cells) == 9
        for c in cells:
            assert c.n + c.plan_failures + c.retime_status.get("rejected", 0) == 2
            assert c.arms == ("planned", "rota:0", "rota:1", "uniform:0", "uniform:1")
            for a in c.arms:
                assert c.crashes[a] == c.collisions[a] + c.ground[a] <= c.n
            if c.n:
                # equal-time controls, and memory never makes ROTA faster
                assert c.mean_duration["uniform:0"] == pytest.approx(c.mean_duration["rota:0"])
                assert c.mean_duration["uniform:1"] == pytest.approx(c.mean_duration["rota:1"])
                assert c.mean_duration["rota:1"] >= c.mean_duration["rota:0"] - 1e-9
        for d in cfg.densities:
            t = [result.cell(kind, d, v).mean_duration["planned"] for v in cfg.speeds]
            assert t[0] > t[1] > t[2]
    # Per-trial data are consistent with the statistics: a tree collision is a negative
    # closest approach.
    data = result.trials[(2, 2)]
    ok = np.array(data["planned"])
    for arm in ("planned", "rota:1"):
        f = data["flights"]["drift"][arm]
        assert np.array_equal(np.array(f["collided"])[ok], np.array(f["closest"])[ok] < 0.0)
    paths = write_outputs(result, str(tmp_path), "rota-sitl experiment collision-rate")
    md = open(paths["md"]).read()
    assert "| Mid (0.043/m^2) |" in md and "v = 3 m/s" in md and "Seed 0" in md
    assert md.count("\n| 0.0") == 4 * 9  # two detail tables per error model
    assert "### drift error" in md and "Claim (ROTA + memory 1 s" in md
    assert open(paths["png"], "rb").read(8) == b"\x89PNG\r\n\x1a\n"
    js = json.load(open(paths["json"]))
    assert js["config"]["trials"] == 2 and len(js["cells"]["drift"]) == 9


def test_results_do_not_depend_on_chunking_or_workers():
    base = dict(densities=(0.063,), speeds=(3.0,), trials=2)
    a = run_experiment(ExperimentConfig(workers=1, chunk=2, **base))
    b = run_experiment(ExperimentConfig(workers=2, chunk=1, **base))
    da, db = a.trials[(0, 0)], b.trials[(0, 0)]
    for key in ("noise_seed", "world_seed", "duration"):
        assert da[key] == db[key]
    assert da["flights"] == db["flights"]


def test_memory_rule():
    """The smallest T whose next step on the grid no longer lowers the crash rate
    significantly (two-sided exact McNemar, p >= 0.05)."""
    n = 40
    crash = {"planned": [True] * 30 + [False] * 10,
             "rota:0": [True] * 24 + [False] * 16,   # -> 0.5: 24 vs 4 fewer: significant
             "rota:0.5": [True] * 4 + [False] * 36,  # then 2 vs 0: not significant
             "rota:1": [True] * 2 + [False] * 38,
             "rota:1.5": [False] * 40}
    cfg = ExperimentConfig(trials=n, densities=(0.063,), speeds=(3.0,), uniform=False,
                           memories=(0.0, 0.5, 1.0, 1.5))
    data = _synthetic(crash, ["optimal"] * n, {a: [1.0] * n for a in crash})
    data["status"] = {k: ["optimal"] * n for k in ("0", "0.5", "1", "1.5")}

    class Result:
        config = cfg
        trials = {(0, 0): data}
        cells = {"correlated": [cell_stats(cfg, "correlated", 0, 0, data)]}

    assert memory_rule(Result, "correlated") == 0.5  # type: ignore[arg-type]
    # 24 -> 10 -> 2 -> 0: 14 vs 0, 8 vs 0 (p = 0.008), then 2 vs 0 (p = 0.5)
    data["flights"]["correlated"]["rota:0.5"]["collided"] = [True] * 10 + [False] * 30
    assert memory_rule(Result, "correlated") == 1.0  # type: ignore[arg-type]


def test_cli(tmp_path, capsys):
    out = tmp_path / "t1"
    assert main(["experiment", "collision-rate", "--trials", "1", "--densities", "0.025",
                 "--speeds", "1", "--workers", "1", "--error-models", "drift", "--memory",
                 "1.5", "--out", str(out), "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "Command: `rota-sitl experiment collision-rate --trials 1" in text
    assert "ROTA + memory 1.5 s" in text and "### drift error" in text
    assert "### correlated" not in text
    assert (out / "table1.md").exists() and (out / "table1.png").exists()
    dose = tmp_path / "dose"
    assert main(["experiment", "memory-dose", "--trials", "1", "--memories", "0,1",
                 "--speed", "1", "--density", "0.025", "--workers", "1", "--out", str(dose),
                 "--quiet"]) == 0
    assert "Rule (the larger pick" in capsys.readouterr().out
    assert (dose / "dose.png").exists()


def test_cli_rejects_bad_arguments(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["experiment", "collision-rate", "--error-models", "white"])
    assert exc.value.code == 2
    assert main(["experiment", "collision-rate", "--trials", "0", "--quiet"]) == 2
    assert "--trials: must be at least 1" in capsys.readouterr().err
