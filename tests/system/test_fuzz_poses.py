"""Fuzzing of the run folder's files (hypothesis): poses.csv, views.csv and run.json. Near-valid
and random inputs end in the project's one-line error or parse; what a reader accepts, the
writer writes back exactly (one schema, io/schemas.py); valid files parse to the values
written."""

from __future__ import annotations

import math

import numpy as np
from fuzz_fixtures import FUZZ, FUZZ_FILES, finite, finite_m, folder, fuzz_file, mutate_text, only_s2p_errors, text_like
from hostile_fixtures import write_scene
from hypothesis import given
from hypothesis import strategies as st

from seg2pose.io.poses import PoseTable, read_poses, write_poses


@st.composite
def pose_tables(draw):
    n = draw(st.integers(0, 12))
    frames = sorted(draw(st.lists(st.integers(0, 10 ** 9), min_size=n, max_size=n)))
    tids = draw(st.lists(st.integers(-1, 10 ** 12), min_size=n, max_size=n, unique=True))
    xyz = draw(st.lists(st.tuples(finite, finite, finite), min_size=n, max_size=n))
    heading = draw(st.lists(st.one_of(st.floats(-4, 4), st.just(math.nan)), min_size=n, max_size=n))
    size = draw(st.lists(st.tuples(*[st.one_of(st.floats(0.01, 100), st.just(math.nan))] * 3),
                         min_size=n, max_size=n))
    cls = draw(st.lists(st.sampled_from(["car", "pedestrian", "bicyclist"]), min_size=n, max_size=n))
    return PoseTable(frames, tids, np.array(cls, object), np.array(xyz).reshape(-1, 3), heading,
                     np.array(size).reshape(-1, 3))


@FUZZ
@given(pose_tables())
def test_poses_round_trip(t):
    with folder() as d:
        write_poses(d / "p.csv", t)
        r = read_poses(d / "p.csv")
        assert np.array_equal(r.frame, t.frame) and np.array_equal(r.track_id, t.track_id)
        assert list(r.cls) == list(t.cls) and np.array_equal(r.xyz, t.xyz)
        assert np.array_equal(r.heading, t.heading, equal_nan=True)
        assert np.array_equal(r.size, t.size, equal_nan=True)


@FUZZ
@given(st.data())
def test_poses_near_valid(data):
    with folder() as d:
        s = write_scene(d, frames=3, users=2)
        p = s.gt_path
        p.write_text(mutate_text(data, p.read_text(), ","))
        r = only_s2p_errors(lambda: read_poses(p, known_classes=["car", "pedestrian", "bicyclist"]))
        if r is not None and len(r):
            assert np.isfinite(r.xyz).all() and not np.isinf(r.heading).any()
            assert r.size is None or ((r.size > 0) | np.isnan(r.size)).all()


def same_poses(a: PoseTable, b: PoseTable):
    for col in ("frame", "track_id", "cls", "xyz", "heading", "size"):
        np.testing.assert_array_equal(getattr(a, col), getattr(b, col))


@FUZZ_FILES
@given(text_like())
def test_fuzz_poses(tmp_path, data):
    fuzz_file(tmp_path, "p.csv", b"frame,track_id,class,x,y,z,heading\n" + data, read_poses, write_poses,
          same_poses)
    fuzz_file(tmp_path, "p.csv", data, read_poses, write_poses, same_poses)


@FUZZ_FILES
@given(st.lists(st.tuples(st.integers(0, 10**6), st.integers(-1, 10**6),
                          st.sampled_from(["car", "pedestrian", "bicyclist"]), finite_m, finite_m, finite_m,
                          st.floats(allow_infinity=False)), max_size=12,
                unique_by=lambda r: (r[0], r[1])),  # one row per road user and frame
       st.booleans(), st.sampled_from([",", ", "]))
def test_valid_poses_parse_exactly(tmp_path, rows, with_size, sep):
    rows = sorted(rows, key=lambda r: r[0])
    head = "frame,track_id,class,x,y,z,heading" + (",l,w,h" if with_size else "")
    lines = [head] + [sep.join([str(f), str(t), c] + [repr(v) for v in (x, y, z, h)]
                               + (["4.5", "1.8", "1.5"] if with_size else []))
                      for f, t, c, x, y, z, h in rows]
    (tmp_path / "p.csv").write_text("\n".join(lines) + "\n")
    got = read_poses(tmp_path / "p.csv")
    assert got.frame.tolist() == [r[0] for r in rows] and got.track_id.tolist() == [r[1] for r in rows]
    assert got.cls.tolist() == [r[2] for r in rows]
    np.testing.assert_array_equal(got.xyz, np.array([r[3:6] for r in rows], float).reshape(-1, 3))
    np.testing.assert_array_equal(got.heading, np.array([r[6] for r in rows], float))
    if with_size:
        np.testing.assert_array_equal(got.size, np.tile([4.5, 1.8, 1.5], (len(rows), 1)))
    else:
        assert got.size is None


# --- views.csv and run.json: the run writer's schema is its reader's -----------------------------

def _views_text() -> str:
    from seg2pose.io.run import ViewTable, format_views

    v = ViewTable([0, 0, 1], [1, 2, 1], ["c0", "c1", "c0"], ["car", "pedestrian", "car"],
                  [[10.5, 20.25], [3, 4], [11, 21]], [[1, 2, 0], [np.nan] * 3, [1.5, 2, 0]],
                  [[0.1, -0.2], [0, 0], [0, 0]], [[1, 0, 0.3], [0, 1, 0], [0, 0, 0]],
                  [1.25, np.nan, 0.5], [[0, 0, 4, 8], [np.nan] * 4, [1, 1, 5, 9]])
    return format_views(v)


def _same_views(a, b) -> None:
    for col in ("frame", "track_id", "camera", "cls", "uv", "normal", "residual", "cues", "r90", "box"):
        np.testing.assert_array_equal(getattr(a, col), getattr(b, col))


@FUZZ_FILES
@given(st.data())
def test_views_near_valid_round_trip(tmp_path, data):
    """A damaged views.csv is refused in one line, or read and written back exactly by the run
    folder's writer (which refuses what the reader refuses: one schema)."""
    from seg2pose.io.run import read_views, write_run_folder

    p = tmp_path / "views.csv"
    p.write_text(mutate_text(data, _views_text(), ","))
    v = only_s2p_errors(lambda: read_views(p))
    if v is not None:
        run = tmp_path / "run"
        write_run_folder(run, PoseTable.empty(), v, {}, force=True)
        _same_views(read_views(run / "views.csv"), v)


@FUZZ_FILES
@given(text_like())
def test_fuzz_views(tmp_path, data):
    from seg2pose.io.run import read_views

    head = b"frame,track_id,camera,class,u,v,xn,yn,zn,dx,dy\n"
    for blob in (data, head + data):
        fuzz_file(tmp_path, "views.csv", blob, read_views)


RUN_META = {"scene": "../..", "scene_fingerprint": "abc", "config": "mono-1", "cameras": ["c0"],
            "method": "baseline", "smooth_frames": 3, "models": {}, "split": "test",
            "frame_range": [0, 9], "created": "2026-01-01T00:00:00Z", "n_frames": 10,
            "n_views": 4, "n_poses": 2}


@FUZZ_FILES
@given(st.data())
def test_run_json_near_valid_round_trip(tmp_path, data):
    """run.json with one field mutated: refused in one line, or read and written back equal."""
    from fuzz_fixtures import mutate_json

    from seg2pose.io.run import read_run_meta, write_run_folder

    (tmp_path / "r").mkdir(exist_ok=True)
    (tmp_path / "r" / "run.json").write_text(mutate_json(data, RUN_META))
    meta = only_s2p_errors(lambda: read_run_meta(tmp_path / "r"))
    if meta is not None:
        write_run_folder(tmp_path / "w", PoseTable.empty(), None, meta, force=True)
        assert read_run_meta(tmp_path / "w") == meta
