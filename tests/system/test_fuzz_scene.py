"""Fuzzing of the scene readers and the scene importers that share them (hypothesis): scene.json
and ground points (near-valid inputs, random bytes, exact round trips of valid files) and UTOCS
recordings; every input ends in the project's one-line error or in a scene ``load_scene``
reads."""

from __future__ import annotations

import json
import math

import numpy as np
from fuzz_fixtures import (
    FUZZ,
    FUZZ_FILES,
    finite,
    folder,
    fuzz_file,
    json_values,
    mutate_json,
    mutate_text,
    only_s2p_errors,
    text_like,
)
from hostile_fixtures import write_scene, write_utocs
from hypothesis import given
from hypothesis import strategies as st
from io_fixtures import make_scene

from seg2pose.core.errors import S2PError
from seg2pose.io.scene import load_scene, read_ground_points, write_ground_points


@FUZZ
@given(st.data())
def test_scene_json_near_valid(data):
    with folder() as d:
        write_scene(d, frames=1, users=1)
        obj = json.loads((d / "scene.json").read_text())
        (d / "scene.json").write_text(mutate_json(data, obj))
        s = only_s2p_errors(lambda: load_scene(d))
        if s is not None:  # what is accepted is sane
            assert FPS_OK(s.fps)
            for c in s.cameras.values():
                assert type(c.width) is int and 0 < c.width <= 2 ** 20
                assert np.isfinite(c.K).all() and np.allclose(c.K[2], [0, 0, 1])
            assert all(type(c.id) is int for c in s.classes)


def FPS_OK(fps: float) -> bool:
    return math.isfinite(fps) and 1e-3 <= fps <= 1e6


@FUZZ
@given(st.binary(max_size=400))
def test_scene_json_random_bytes(blob):
    with folder() as d:
        write_scene(d, frames=1, users=1)
        (d / "scene.json").write_bytes(blob)
        only_s2p_errors(lambda: load_scene(d))


@FUZZ
@given(st.lists(st.tuples(finite, finite, finite), min_size=3, max_size=30, unique=True))
def test_ground_points_round_trip(pts):
    with folder() as d:
        write_ground_points(d / "g.csv", np.array(pts))
        assert np.array_equal(read_ground_points(d / "g.csv"), np.array(pts))


@FUZZ
@given(st.data())
def test_ground_points_near_valid(data):
    with folder() as d:
        write_ground_points(d / "g.csv", np.array([[0.0, 0, 0], [1, 0, 0.5], [0, 2, 1], [3, 3, -1]]))
        (d / "g.csv").write_text(mutate_text(data, (d / "g.csv").read_text(), ","))
        pts = only_s2p_errors(lambda: read_ground_points(d / "g.csv"))
        if pts is not None:
            assert pts.shape[1] == 3 and len(pts) >= 3 and np.isfinite(pts).all()
            assert np.abs(pts).max() <= 1e6


@FUZZ
@given(st.data())
def test_utocs_near_valid(data):
    from seg2pose.io.utocs import import_utocs

    with folder() as d:
        src = write_utocs(d / "u", frames=2)
        which = data.draw(st.sampled_from(["cameras.json", "positions/000001.json", "ground_points.txt"]))
        p = src / which
        if which.endswith(".json"):
            p.write_text(mutate_json(data, json.loads(p.read_text())))
        else:
            p.write_text(mutate_text(data, p.read_text(), ","))
        out = d / "out"
        s = only_s2p_errors(lambda: import_utocs(src, out, log=lambda *a: None))
        if s is None:
            assert not (out / "scene.json").exists()
        else:  # an accepted recording gives a scene s2p can load, and nothing outside out/
            load_scene(out)
            assert sorted(x.name for x in d.iterdir()) == ["out", "u"]


@FUZZ
@given(st.binary(max_size=300), st.sampled_from(["cameras.json", "positions/000000.json"]))
def test_utocs_random_bytes(blob, which):
    from seg2pose.io.utocs import import_utocs

    with folder() as d:
        src = write_utocs(d / "u", frames=1)
        (src / which).write_bytes(blob)
        only_s2p_errors(lambda: import_utocs(src, d / "out", log=lambda *a: None))


def write_ground(path, pts):
    from seg2pose.io.scene import write_ground_points

    write_ground_points(path, pts)


@FUZZ_FILES
@given(text_like())
def test_fuzz_ground(tmp_path, data):
    fuzz_file(tmp_path, "g.csv", data, read_ground_points, write_ground, np.testing.assert_array_equal)


@FUZZ_FILES
@given(st.lists(st.tuples(*[st.floats(-1e5, 1e5, allow_nan=False)] * 3), min_size=3, max_size=12,
                unique_by=lambda p: (p[0], p[1])), st.booleans())
def test_valid_ground_points_parse_exactly(tmp_path, pts, header):
    text = ("x,y,z\n" if header else "") + "".join(f"{x!r},{y!r},{z!r}\n" for x, y, z in pts)
    (tmp_path / "g.csv").write_text(text)
    np.testing.assert_array_equal(read_ground_points(tmp_path / "g.csv"), np.array(pts, float))


@FUZZ_FILES
@given(json_values, st.sampled_from(["version", "fps", "cameras", "classes", "configs", "splits",
                                     "ground_points", "extra", "c0", "c0.K", "c0.distortion",
                                     "c1.P", "c0.width"]))
def test_fuzz_scene_json(tmp_path, value, key):
    if not (tmp_path / "scene.json").exists():
        make_scene(tmp_path)
    d = json.loads((tmp_path / "scene.json").read_text())
    if key.startswith("c0.") or key.startswith("c1."):
        d["cameras"][int(key[1])][key[3:]] = value
    elif key == "c0":
        d["cameras"][0] = value
    else:
        d[key] = value
    (tmp_path / "s2").mkdir(exist_ok=True)
    (tmp_path / "s2" / "ground_points.csv").write_bytes((tmp_path / "ground_points.csv").read_bytes())
    try:
        (tmp_path / "s2" / "scene.json").write_text(json.dumps(d))
    except ValueError:
        return
    try:
        load_scene(tmp_path / "s2")
    except S2PError:
        pass


@FUZZ_FILES
@given(st.binary(max_size=200))
def test_fuzz_scene_bytes(tmp_path, data):
    (tmp_path / "scene.json").write_bytes(data)
    try:
        load_scene(tmp_path)
    except S2PError:
        pass
