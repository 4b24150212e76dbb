"""Inputs and caps hold: --max-points caps setpoints after the solve, unknown
fields are refused by name, ``-o -`` is standard output, messages show plain
numbers (issue 29)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rota.errors import InputError, plain
from rota.schema import RESULT_FIELDS, result_from_dict, trajectory_from_dict
from tests.helpers.cli import one_line_error, run

SPLINE = {"schema": "rota/trajectory", "version": 1, "type": "bspline", "knot_span": 1.0,
          "control_points": [[0, 0, 1], [1, 0, 1], [2, 0, 1], [3, 0, 1], [4, 0, 1]]}


def test_max_points_caps_setpoints_after_the_solve(example, tmp_path):  # noqa: F811
    """Planned at about 16 s, the re-time at 1 mm/s lasts hours: 650k setpoints at
    50 Hz, over the default cap, refused after the solve, nothing written."""
    out = tmp_path / "r.json"
    r = run("rota", "retime", str(example), "-o", str(out), "--v-max", "0.001", "--rate", "50")
    one_line_error(r, 2, "--rate", "setpoints", "--max-points", "nothing written")
    assert not out.exists()
    r = run("rota", "retime", str(example), "-o", str(out), "--v-max", "0.001", "--rate", "5",
            "--max-points", "200000")
    assert r.returncode == 0, r.stderr
    sp = json.loads(out.read_text())["setpoints"]
    assert 50_000 < len(sp["t"]) <= 200_000


@pytest.mark.parametrize(("kind", "typo", "extra"), [
    ("bspline", "degre", {"degre": 5}),
    ("bspline", "t", {"t": [0, 1]}),  # a field of another type
    ("samples", "degree", {"degree": 3}),
    ("samples", "velocity", {"velocity": [[0, 0, 0], [0, 0, 0]]}),
    ("polynomial", "knot_span", {"knot_span": 1.0}),
])
def test_unknown_trajectory_fields_are_refused_by_name(kind, typo, extra):
    msg = {"bspline": SPLINE,
           "samples": {"schema": "rota/trajectory", "version": 1, "type": "samples",
                       "t": [0, 1], "p": [[0, 0, 1], [1, 0, 1]]},
           "polynomial": {"schema": "rota/trajectory", "version": 1, "type": "polynomial",
                          "durations": [1.0],
                          "coefficients": [[[0, 1, 0], [0, 0, 0], [1, 0, 0]]]}}[kind]
    trajectory_from_dict(msg)  # valid without the extra field
    with pytest.raises(InputError) as err:
        trajectory_from_dict(msg | extra)
    assert err.value.field == typo and "unknown field" in str(err.value)


def test_rota_retime_names_the_unknown_field(tmp_path):
    path = tmp_path / "t.json"
    path.write_text(json.dumps(SPLINE | {"degre": 5}))
    one_line_error(run("rota", "retime", str(path), "-o", str(tmp_path / "r.json")), 2,
                   "degre", "unknown field")


def test_unknown_result_fields_are_refused(example, tmp_path):  # noqa: F811
    out = tmp_path / "r.json"
    assert run("rota", "retime", str(example), "-o", str(out), "--rate", "10").returncode == 0
    d = json.loads(out.read_text())
    assert set(d) <= set(RESULT_FIELDS)
    result_from_dict(d)
    with pytest.raises(InputError) as err:
        result_from_dict(d | {"durration": 1.0})
    assert err.value.field == "durration"


def test_dash_output_is_standard_output(example, tmp_path):  # noqa: F811
    r = run("rota", "retime", str(example), "-o", "-", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["schema"] == "rota/result"  # nothing else on stdout
    assert "optimal" in r.stderr
    assert not (tmp_path / "-").exists()


def test_messages_show_plain_numbers(example, tmp_path):  # noqa: F811
    import rota
    from rota.trajectory import Window

    assert plain((np.float64(1.5), np.int64(2))) == "(1.5, 2)"
    assert plain(np.array([[0.0, 1.0]])) == "[[0.0, 1.0]]"
    texts = []
    for make in (lambda: rota.Limits(1.0, (0.0, 1.0, 1.0)).a_max_vec,
                 lambda: Window(base=trajectory_from_dict(SPLINE).trajectory, start=99.0),
                 lambda: rota.BSplineTrajectory(control_points=np.zeros((5, 3)),
                                                knot_span=np.float64(0.0))):
        with pytest.raises(InputError) as err:
            make()
        texts.append(str(err.value))
    r = run("rota", "retime", str(example), "-o", str(tmp_path / "r.json"), "--a-max", "0,3,3")
    one_line_error(r, 2, "a_max")
    texts.append(r.stderr)
    from rota.voxelmap import VoxelMap

    vmap = tmp_path / "map.json"
    vmap.write_text(json.dumps(VoxelMap(0.1, np.array([[2.05, 1.25, 1.55]])).to_dict()))
    r = run("rota", "retime", str(example), "-o", str(tmp_path / "r.json"), "--map", str(vmap))
    assert r.returncode in (0, 4) and "braking zones" in r.stdout, (r.stdout, r.stderr)
    assert "none" not in r.stdout  # the obstacle is near the path
    texts.append(r.stdout)
    for text in texts:
        assert "np." not in text and "float64" not in text, text
    assert "got 0.0" in texts[0]
