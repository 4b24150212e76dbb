"""The reduced benchmark that CI runs: two small rows of Table II with
every peer. It asserts correctness against the high-accuracy reference solve,
never speed (the CI machine is shared)."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("cvxpy")
pytest.importorskip("toppra")
pytest.importorskip("copp_py")

from sitl import bench  # noqa: E402


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    rep = bench.run_bench(out, quick=True, repeats=1, log=lambda *_: None)
    return rep, out


def test_quick_rows_run_and_write_outputs(report):
    rep, out = report
    assert [(r["trajectory"], r["dtau"]) for r in rep["rows"]] == list(bench.QUICK_ROWS)
    assert json.loads((out / "bench.json").read_text())["rows"]
    md = (out / "bench.md").read_text()
    assert "| 7m | 0.1 |" in md and "Machine:" in md


def test_rota_matches_the_reference_solve(report):
    rep, _ = report
    for row in rep["rows"]:
        for key in ("full", "topp_rota"):
            check = row["checks"][key]
            assert check["ok"], (row["trajectory"], row["dtau"], key, check["why"])
            assert abs(check["obj_rel_err"]) <= 1e-3
            assert check["same_problem_rel_err"] <= bench.SAME_TOL
    assert bench.rota_ok(rep)


def test_cvxpy_peer_and_copp_socp_agree_with_their_references(report):
    rep, _ = report
    for row in rep["rows"]:
        assert abs(row["checks"]["cvxpy"]["obj_rel_err"]) <= 0.05  # fewer check points
        assert abs(row["checks"]["copp_socp"]["obj_rel_err"]) <= 1e-3
        assert abs(row["checks"]["nodes_exact"]["obj_rel_err"]) <= 1e-6
        for key in ("toppra", "copp_ra", "nodes_reach"):  # reachability: a little slower
            assert -1e-3 <= row["checks"][key]["obj_rel_err"] <= 0.02


def test_timings_and_memory_are_reported(report):
    rep, _ = report
    for row in rep["rows"]:
        med = row["median_s"]
        for key in ("full", "solver", "full_clarabel", "topp_rota", "nodes_reach",
                    "nodes_exact", "toppra", "copp_ra", "copp_socp", "cvxpy"):
            assert np.isfinite(med[key]) and med[key] > 0, key
        # (no comparison of two timings here: "solver <= full" is true of the work, but two
        # medians measured apart invert on a busy machine; seen 4.5 ms against 1.0 ms. The
        # benchmark prints them; speed is measured there, not asserted in a test.)
        assert row["mem_tracemalloc_MiB"] > 0
        assert row["paper_s"] == bench.PAPER[row["trajectory"]][row["dtau"]]


def test_wrong_answer_is_caught():
    """A fast wrong answer does not count: a solution 1 % too slow fails the
    objective check, one that speeds through the limits fails the FD check."""
    trajs, _ = bench.load_data()
    traj = trajs["7m"]
    from rota import Limits, RetimeInput, retime

    res = retime(RetimeInput(trajectory=traj, limits=Limits(bench.V_MAX, bench.A_MAX),
                             smoothness=0.0, dtau=0.1))
    assert res.ok
    vmax = np.full(len(res.timemap.tau), bench.V_MAX)
    assert bench.fd_check(traj, res.timemap, vmax) is None
    obj = bench.objective(res.timemap.tau, res.timemap.beta, 0.0)
    assert not bench.verdict(obj * 1.01, obj, None)["ok"]
    from rota.timemap import TimeMap

    fast = TimeMap(res.timemap.tau, res.timemap.beta * 1.2)
    assert bench.fd_check(traj, fast, vmax) is not None
