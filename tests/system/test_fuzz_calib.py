"""Fuzzing of the calibration files (hypothesis): calib.json (written by ``s2p calibrate-camera``,
read by ``s2p new-scene --calibration``), clicked point pairs, surveyed points and aerial
images' world files. A damaged file is refused in one line naming it, or read; what is read,
its writer writes back and the reader reads again to the same values (one schema for both)."""

from __future__ import annotations

import json

import numpy as np
from fuzz_fixtures import FUZZ, folder, mutate_json, mutate_text, only_s2p_errors
from hypothesis import given
from hypothesis import strategies as st

from seg2pose.core.validate import MAX_COORD, MAX_PIXEL_COORD
from seg2pose.geometry.camera import Camera
from seg2pose.io.calib_files import (
    calib_json,
    read_calib_json,
    read_pairs,
    read_survey,
    read_world_file,
    write_world_file,
)

W, H = 64, 48
GROUND = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])


def _calib() -> dict:
    a = Camera.look_at("c0", np.array([0.0, -10.0, 8.0]), np.array([0.0, 10.0, 0.0]), 50.0, W, H)
    b = Camera.look_at("c1", np.array([3.0, -10.0, 8.0]), np.array([0.0, 10.0, 0.0]), 60.0, W, H)
    return {"cameras": [a.to_dict(), b.to_dict()], "report": {"rms_px": 0.5, "pairs": [1, 2]}}


@FUZZ
@given(st.data())
def test_calib_json_near_valid_round_trip(data):
    """calib.json with one field mutated: refused in one line naming it, or its cameras are
    written back by calibrate-camera's writer and read again unchanged."""
    with folder() as d:
        p = d / "calib.json"
        p.write_text(mutate_json(data, _calib()))
        got = only_s2p_errors(lambda: read_calib_json(p))
        if got is None:
            return
        cams, _ = got
        assert all(c.width <= 2**20 and np.isfinite(c.K).all() for c in cams.values())
        text = calib_json([c.to_dict() for c in cams.values()], {}, file=d / "again.json")
        (d / "again.json").write_text(text)
        back, unsized = read_calib_json(d / "again.json")
        assert list(back) == list(cams) and unsized == []
        for name, c in cams.items():
            np.testing.assert_array_equal(back[name].K, c.K)
            np.testing.assert_array_equal(back[name].R, c.R)
            np.testing.assert_array_equal(back[name].t, c.t)


@FUZZ
@given(st.binary(max_size=300))
def test_calib_json_random_bytes(blob):
    with folder() as d:
        (d / "calib.json").write_bytes(blob)
        only_s2p_errors(lambda: read_calib_json(d / "calib.json"))


PAIRS = "camera,u,v,x,y,z,name\nc0,10.5,20,1.0,2.0,0.0,a\nc0,30,40.25,-3,4,,b\nc1,5,6,7,8,0.5,c\n"
SURVEY = "name,x,y,z\np1,1.0,2.0,0.5\np2,-3,4,\np3,5,6,7\n"


@FUZZ
@given(st.data(), st.sampled_from(["pairs", "survey"]))
def test_pairs_and_survey_near_valid(data, which):
    """Clicked pairs and surveyed points: refused in one line naming the file, or read into
    finite pixels and metres within the readers' ranges (z may be unknown: NaN)."""
    with folder() as d:
        p = d / f"{which}.csv"
        p.write_text(mutate_text(data, PAIRS if which == "pairs" else SURVEY, ","))
        got = only_s2p_errors(lambda: read_pairs(p) if which == "pairs" else read_survey(p))
        if got is None:
            return
        if which == "pairs":
            for v in got.values():
                assert np.isfinite(v["uv"]).all() and (np.abs(v["uv"]) <= MAX_PIXEL_COORD).all()
                assert np.isfinite(v["X"][:, :2]).all() and not (np.abs(v["X"]) > MAX_COORD).any()
                assert len(v["names"]) == len(v["uv"]) == len(v["X"])
        else:
            names, pts = got
            assert len(set(names)) == len(names) == len(pts)
            assert np.isfinite(pts[:, :2]).all() and not (np.abs(pts) > MAX_COORD).any()


WORLD = "0.25\n0.0\n0.0\n-0.25\n100.125\n200.125\n"


@FUZZ
@given(st.data())
def test_world_file_near_valid_round_trip(data):
    """An aerial image's world file: refused in one line, or its map written back and read
    again to the same map."""
    with folder() as d:
        p = d / "a.pgw"
        p.write_text(mutate_text(data, WORLD, None))
        A = only_s2p_errors(lambda: read_world_file(p))
        if A is None:
            return
        write_world_file(d / "b.pgw", A)
        np.testing.assert_allclose(read_world_file(d / "b.pgw"), A, rtol=1e-12, atol=1e-9)


@FUZZ
@given(st.binary(max_size=200), st.sampled_from(["pairs", "survey", "world"]))
def test_calibration_inputs_random_bytes(blob, which):
    with folder() as d:
        p = d / "f"
        p.write_bytes(blob)
        reader = {"pairs": read_pairs, "survey": read_survey, "world": read_world_file}[which]
        only_s2p_errors(lambda: reader(p))


def test_calib_json_written_is_read_by_new_scene(tmp_path):
    """The writer's output is what new-scene reads: two cameras, exactly."""
    from seg2pose.io.calib_files import write_calibration

    cal = _calib()
    write_calibration(tmp_path / "calib.json", cal["cameras"], cal["report"], "", GROUND, {})
    cams, unsized = read_calib_json(tmp_path / "calib.json", {"c0": (W, H)})
    assert list(cams) == ["c0", "c1"] and unsized == []
    assert json.loads((tmp_path / "calib.json").read_text())["report"] == cal["report"]
