"""Bad inputs get clear errors naming the field; JSON round trips."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rota import (
    BSplineTrajectory,
    InputError,
    Limits,
    PolynomialTrajectory,
    RetimeInput,
    SampledTrajectory,
    retime,
)
from rota.cli import main
from rota.schema import (
    TrajectoryMessage,
    result_from_dict,
    result_to_dict,
    trajectory_from_dict,
    trajectory_to_dict,
)
from tests.helpers.strategies import bspline, polynomial, sampled

CPS = np.array([[0, 0, 0], [1, 0, 0], [2, 1, 0], [3, 1, 1], [4, 2, 1]], dtype=float)


@pytest.mark.parametrize(("make", "field", "words"), [
    (lambda: BSplineTrajectory(control_points=np.where(CPS == 2, np.nan, CPS), knot_span=0.5),
     "control_points[2][0]", "finite"),
    (lambda: BSplineTrajectory(control_points=np.zeros((0, 3)), knot_span=0.5),
     "control_points", "empty"),
    (lambda: BSplineTrajectory(control_points=CPS[:, :2], knot_span=0.5),
     "control_points", "3 columns"),
    (lambda: BSplineTrajectory(control_points=CPS[:3], knot_span=0.5),
     "control_points", "at least"),
    (lambda: BSplineTrajectory(control_points=CPS, knot_span=-1.0), "knot_span", "positive"),
    (lambda: BSplineTrajectory(control_points=CPS, knot_span="fast"), "knot_span", "positive"),
    (lambda: BSplineTrajectory(control_points=CPS), "knot_span", "exactly one"),
    (lambda: BSplineTrajectory(control_points=CPS, knots=np.arange(5.0)), "knots", "entries"),
    (lambda: BSplineTrajectory(control_points=CPS, knot_span=0.5, degree=2), "degree", "3 to 7"),
    (lambda: SampledTrajectory(t=[0, 1, 1, 2], p=np.zeros((4, 3))), "t[2]", "increasing"),
    (lambda: SampledTrajectory(t=[0, 2, 1], p=np.zeros((3, 3))), "t[2]", "increasing"),
    (lambda: SampledTrajectory(t=[0, 1, 2], p=np.zeros((4, 3))), "p", "one row"),
    (lambda: SampledTrajectory(t=[0], p=np.zeros((1, 3))), "t", "at least 2"),
    (lambda: SampledTrajectory(t=[0, 1], p=[[0, 0, 0], [1, np.inf, 0]]), "p[1][1]", "finite"),
    (lambda: SampledTrajectory(t=[0, 1], p=np.zeros((2, 3)), a=np.zeros((2, 3))), "a",
     "velocities"),
    (lambda: PolynomialTrajectory(durations=[1.0, -1.0], coefficients=np.zeros((2, 3, 4))),
     "durations[1]", "positive"),
    (lambda: PolynomialTrajectory(durations=[1.0], coefficients=np.zeros((2, 3, 4))),
     "coefficients", "shape"),
    (lambda: PolynomialTrajectory(durations=[1.0, 1.0], coefficients=np.stack(
        [np.zeros((3, 4)), np.ones((3, 4))])), "coefficients[1]", "does not continue"),
    (lambda: Limits(-1.0, 2.0), "limits.v_max", "positive"),
    (lambda: Limits(1.0, (1.0, 0.0, 1.0)), "limits.a_max[1]", "positive"),
    (lambda: Limits(1.0, (1.0, 1.0)), "limits.a_max", "3"),
    (lambda: Limits(float("nan"), 1.0), "limits.v_max", "finite"),
    (lambda: RetimeInput(trajectory=bspline(1, 5, 1.0), limits=Limits(1, 1), dtau=0.0),
     "dtau", "positive"),
    (lambda: RetimeInput(trajectory=bspline(1, 5, 1.0), limits=Limits(1, 1), smoothness=-1),
     "smoothness", ">= 0"),
    (lambda: RetimeInput(trajectory=bspline(1, 5, 1.0), limits=Limits(1, 1),
                         start_velocity=[1.0, np.nan, 0]), "start_velocity[1]", "finite"),
    (lambda: RetimeInput(trajectory=bspline(1, 5, 1.0), limits=Limits(1, 1),
                         speed_limits=np.ones(3)), "speed_limits", "grid node"),
    (lambda: RetimeInput(trajectory=CPS, limits=Limits(1, 1)), "trajectory", "Trajectory"),
])
def test_bad_input_names_the_field(make, field, words):
    with pytest.raises(InputError) as err:
        make()
    assert err.value.field == field
    assert words in err.value.message


@pytest.mark.parametrize("traj", [bspline(2, 6, 0.7), polynomial(2, 6, 0.7),
                                  sampled(2, 6, 0.7, False), sampled(2, 6, 0.7, True)])
def test_trajectory_json_round_trip(traj):
    msg = TrajectoryMessage(traj, id="abc", frame="ENU", stamp=12.5)
    d = json.loads(json.dumps(trajectory_to_dict(msg)))
    back = trajectory_from_dict(d)
    assert back.id == "abc" and back.frame == "ENU" and back.stamp == 12.5
    tau = np.linspace(*traj.domain, 50)
    for x, y in zip(traj.evaluate(tau), back.trajectory.evaluate(tau), strict=True):
        assert np.allclose(x, y)


def test_result_json_round_trip_rebuilds_the_sampler():
    traj = bspline(4, 6, 1.0)
    msg = TrajectoryMessage(traj, id="r1")
    result = retime(RetimeInput(trajectory=traj, limits=Limits(1.5, 2.0)))
    d = json.loads(json.dumps(result_to_dict(result, msg, rate_hz=10.0)))
    assert len(d["setpoints"]["t"]) == len(d["setpoints"]["p"]) >= 10 * result.duration
    back, _ = result_from_dict(d)
    t = np.linspace(0, result.duration, 77)
    assert np.allclose(back.sample(t).position, result.sample(t).position)
    assert back.status == result.status and back.duration == pytest.approx(result.duration)


@pytest.mark.parametrize(("patch", "field"), [
    ({"schema": "rota/other"}, "schema"),
    ({"version": 99}, "version"),
    ({"frame": "NWU"}, "frame"),
    ({"type": "nurbs"}, "type"),
    ({"stamp": "yesterday"}, "stamp"),
    ({"degree": 3.5}, "degree"),
    ({"control_points": [[0, 0, 0], [1, 1, 1], [2, 2, "x"], [3, 3, 3]]}, "control_points"),
])
def test_bad_messages_name_the_field(patch, field):
    d = trajectory_to_dict(TrajectoryMessage(bspline(2, 6, 0.7)))
    d.update(patch)
    with pytest.raises(InputError) as err:
        trajectory_from_dict(d)
    assert err.value.field == field


def test_missing_field_is_named():
    d = trajectory_to_dict(TrajectoryMessage(bspline(2, 6, 0.7)))
    del d["control_points"]
    with pytest.raises(InputError, match="control_points: is required"):
        trajectory_from_dict(d)


def test_cli_retime_writes_result_and_plot(tmp_path, capsys):
    src = tmp_path / "in.json"
    assert main(["example", "-o", str(src)]) == 0
    out, png = tmp_path / "out.json", tmp_path / "plot.png"
    code = main(["retime", str(src), "-o", str(out), "--v-max", "1", "--a-max", "3",
                 "--plot", str(png), "--rate", "50"])
    assert code == 0
    d = json.loads(out.read_text())
    assert d["schema"] == "rota/result" and d["status"] == "optimal"
    assert d["duration"] < d["input_duration"]
    assert png.stat().st_size > 10_000


def test_cli_bad_input_exit_code_and_message(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text('{"schema": "rota/trajectory", "version": 1, "type": "bspline",'
                   ' "knot_span": 0.1, "control_points": [[0, 0, 0]]}')
    assert main(["retime", str(bad), "-o", str(tmp_path / "o.json")]) == 2
    assert "control_points" in capsys.readouterr().err
    (tmp_path / "nojson.json").write_text("{")
    assert main(["retime", str(tmp_path / "nojson.json"), "-o", str(tmp_path / "o.json")]) == 2


def test_cli_fallback_exit_code(tmp_path):
    src = tmp_path / "in.json"
    main(["example", "-o", str(src)])
    code = main(["retime", str(src), "-o", str(tmp_path / "o.json"),
                 "--start-velocity", "0,3,0"])
    assert code == 3
    assert json.loads((tmp_path / "o.json").read_text())["status"] == "fallback"
