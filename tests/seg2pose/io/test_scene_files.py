"""scene.json and the ground points: exact round trips and bad input naming the field or line."""

import json

import numpy as np
import pytest
from io_fixtures import make_scene, write

from seg2pose.core.errors import InputError
from seg2pose.io.scene import load_scene, read_ground_points


def test_scene_round_trip(tmp_path):
    s = make_scene(tmp_path)
    r = load_scene(tmp_path)
    assert r.to_dict() == json.loads(json.dumps(s.to_dict()))
    assert r.fingerprint() == s.fingerprint()
    assert np.allclose(r.cameras["c1"].P / r.cameras["c1"].P[2, 3], s.cameras["c1"].P / s.cameras["c1"].P[2, 3])
    assert np.array_equal(r.ground_points, s.ground_points)
    assert r.split_range("train") == (0, 9) and r.split_range(None) is None


@pytest.mark.parametrize("text,match", [
    ("x,y,z\n0,0,0\n1,0,0\n", r"g.csv: need at least 3 ground points"),
    ("x,y,z\n0,0,0\n1,0,0\n0,1,0\n1,0,0\n", r"g.csv:3: duplicate ground point"),
    ("0,0,0\n1,0,nan\n0,1,0\n", r"g.csv:2: NaN or inf"),
    ("0,0,0\n1,0\n", r"g.csv:2: expected 3 fields"),
    ("0,0,0\n1,a,0\n", r"g.csv:2: expected numbers"),
])
def test_ground_bad_input(tmp_path, text, match):
    with pytest.raises(InputError, match=match):
        read_ground_points(write(tmp_path, "g.csv", text))


def scene_json_with(tmp_path, mutate):
    make_scene(tmp_path)
    d = json.loads((tmp_path / "scene.json").read_text())
    mutate(d)
    (tmp_path / "scene.json").write_text(json.dumps(d))


@pytest.mark.parametrize("mutate,match", [
    (lambda d: d["cameras"][1].update(P=[[1, 0, 0, 0], [0, 1, 0, 0]]),
     r"field 'cameras\[c1\].P': expected shape \(3, 4\)"),
    (lambda d: d["cameras"][1].update(P=[[1, 0, 0, 0], [0, 1, 0, 0], [1, 1, 0, 0]]),
     r"field 'cameras\[c1\].P': P has rank < 3"),
    (lambda d: d["cameras"][0].update(width=0),
     r"field 'cameras\[c0\].width': expected an integer in \[1, 1048576\], got 0"),
    (lambda d: d["cameras"][0]["K"][0].__setitem__(0, float("nan")),
     r"scene.json: field 'cameras\[c0\].K': NaN or inf"),
    (lambda d: d.update(version=2), r"field 'version': unsupported version 2"),
    (lambda d: d.update(fps=-1), r"field 'fps'"),
    (lambda d: d.update(classes={"a": 1}), r"field 'classes'"),
    (lambda d: d["classes"][0].update(default_height="x"),
     r"field 'classes\[0\].default_height': expected a number in \[0, 20\]"),
    (lambda d: d.update(configs={"m": ["nope"]}), r"field 'configs.m': configuration 'm' names unknown cameras"),
    (lambda d: d.update(splits={"train": [5, 1]}), r"field 'splits.train'"),
    (lambda d: d["cameras"][0].update(distortion={"k1": "x"}), r"field 'cameras\[c0\].distortion.k1'"),
    (lambda d: d["cameras"][0].pop("R"), r"field 'cameras\[c0\].R': missing"),
])
def test_scene_bad_input(tmp_path, mutate, match):
    scene_json_with(tmp_path, mutate)
    with pytest.raises(InputError, match=match):
        load_scene(tmp_path)
