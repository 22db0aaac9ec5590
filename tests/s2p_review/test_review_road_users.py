"""One entity per road user in review recordings, read back from the .rrd with rerun.chunk
(not from the logging code's own structures): the same road user at two frames is one entity,
an entity only ever holds one road user (so hiding it hides that road user at every frame and
no other), names that differ stay apart, trails come from a visible time range."""

from __future__ import annotations

import json
from collections import defaultdict

import numpy as np
import pytest
from review_fixtures import CLASS_ID, EST_OFFSET, FPS, N_FRAMES, NO_IMAGES, TRACKS, review_scene

from s2p_review import layout as L
from s2p_review import road_users as RU
from s2p_review.session import record
from seg2pose.io.atomic import atomic_write_text
from seg2pose.io.scene import load_scene

tiny = pytest.fixture(scope="module")(review_scene)


def _chunks(path):
    """entity path -> list of record batches of its temporal chunks."""
    import rerun.chunk as rc

    out = defaultdict(list)
    for ch in rc.RrdReader(path).stream():
        if not ch.is_static:
            out[ch.entity_path].append(ch.to_record_batch())
    return out


def _statics(path):
    """entity path -> names of its static components."""
    import rerun.chunk as rc

    out = defaultdict(set)
    for ch in rc.RrdReader(path).stream():
        if ch.is_static:
            out[ch.entity_path] |= set(ch.to_record_batch().schema.names)
    return out


def _rows(batches, column):
    """(frame, value list) pairs of ``column`` over an entity's chunks."""
    return [(f, v) for b in batches if column in b.schema.names
            for f, v in zip(b.column("frame").to_pylist(), b.column(column).to_pylist())]


def _info(batches, field):
    """(frame, [value]) pairs of one field of the road user's AnyValues struct ``road_user``."""
    return [(f, [d[field] for d in v]) for f, v in _rows(batches, "road_user")]


def _road_user_paths(chunks, run_part):
    """The road users' entities of a run: world/road_users/<run>/<track id>."""
    prefix = f"/world/road_users/{run_part}/"
    return {p for p in chunks if p.startswith(prefix) and p[len(prefix):].isdigit()}


@pytest.fixture(scope="module")
def two_names(tiny, tmp_path_factory):
    """A recording of two runs named "tri T" and "tri_T" (lossy escaping made them one)."""
    from review_fixtures import make_run

    scene, _, _, _ = tiny
    root = tmp_path_factory.mktemp("names")
    a = make_run(scene, root / "tri T")
    b = make_run(scene, root / "tri_T", method="seg2posenet", residual=0.2)
    return record(scene, [a, b], root / "names.rrd", NO_IMAGES).rrd


def test_one_road_user_is_one_entity_at_every_frame(tiny):
    scene, base, _, root = tiny
    path = record(scene, [base], root / "users.rrd", NO_IMAGES).rrd
    chunks, statics = _chunks(path), _statics(path)
    paths = _road_user_paths(chunks, "run-base")
    assert paths == {f"/world/road_users/run-base/{tid}" for tid in TRACKS}
    for tid, (cls, p0, v) in TRACKS.items():
        ent = f"/world/road_users/run-base/{tid}"
        assert not statics[ent]  # everything it shows is in its rows, one send per entity
        row = {col: dict(_rows(chunks[ent], col)) for col in ("Boxes3D:centers", "Boxes3D:class_ids")}
        row |= {k: dict(_info(chunks[ent], k)) for k in ("track_id", "class", "speed_mps")}
        for f in (3, 9):  # the same road user, selected at two frames: one entity path
            assert row["track_id"][f] == [tid] and row["class"][f] == [cls]
            assert row["Boxes3D:class_ids"][f] == [CLASS_ID[cls]]  # through the AnnotationContext
            x = p0[0] + f * v[0] + EST_OFFSET[0]
            np.testing.assert_allclose(np.array(row["Boxes3D:centers"][f])[0, 0], x, atol=1e-5)
            np.testing.assert_allclose(row["speed_mps"][f], [np.hypot(*v) * FPS], rtol=1e-6)
    # colours and class names of the run's look: an annotation context over its road users
    assert "AnnotationContext:context" in statics["/world/road_users/run-base"]


def test_an_entity_never_holds_another_road_user(tiny, two_names):
    """Hiding a road user's entity hides that road user at every frame and nothing else: over
    the whole recording each road-user entity carries one track id, in one row per frame."""
    chunks = _chunks(two_names)
    for run_part in ("tri\\ T", "tri_T"):
        for path in _road_user_paths(chunks, run_part):
            tid = int(path.rsplit("/", 1)[1])
            rows = _info(chunks[path], "track_id")
            assert sorted(f for f, _ in rows) == list(range(N_FRAMES))
            assert all(v == [tid] for _, v in rows), path
            assert all(len(c) == 1 for _, c in _rows(chunks[path], "Boxes3D:centers"))


def test_run_names_that_differ_stay_two_entities(two_names):
    chunks = _chunks(two_names)
    spaced, underscored = _road_user_paths(chunks, "tri\\ T"), _road_user_paths(chunks, "tri_T")
    assert len(spaced) == len(underscored) == len(TRACKS)
    assert not spaced & underscored
    # each run's road users are its own: their source is their run's method
    src = {p.split("/")[3]: dict(_info(chunks[p], "source"))[0] for p in spaced | underscored}
    assert src == {"tri\\ T": ["baseline"], "tri_T": ["seg2posenet"]}


def test_camera_names_that_differ_stay_two_entities(tiny, tmp_path):
    """Cameras "c 0" and "c_0" (both valid names) are two camera entities with their own poses."""
    import shutil

    from review_fixtures import make_run

    scene = tiny[0]
    root = tmp_path / "scene"
    shutil.copytree(scene.root, root, ignore=shutil.ignore_patterns("out", "video"))
    meta = json.loads((root / "scene.json").read_text())
    rename = {"c0": "c 0", "c1": "c_0"}
    for cam in meta["cameras"]:
        cam["name"] = rename[cam["name"]]
    meta["configs"] = {"stereo": ["c 0", "c_0"]}
    atomic_write_text(root / "scene.json", json.dumps(meta))
    for old, new in rename.items():
        (root / "masks" / f"{old}.txt").rename(root / "masks" / f"{new}.txt")
    renamed = load_scene(root)
    run = make_run(renamed, root / "out" / "r")
    chunks = _chunks(record(renamed, [run], tmp_path / "cams.rrd", NO_IMAGES).rrd)
    assert L.cam_path("c 0") != L.cam_path("c_0")
    for cam in ("c\\ 0", "c_0"):
        assert len(_rows(chunks[f"/world/cameras/{cam}/poses/r"], "LineStrips2D:strips")) == N_FRAMES


def test_series_per_road_user_have_hand_derived_values(tiny):
    """Speed from 10 fps straight-line tracks (|v| per frame x 10), the error is the run's
    offset from the truth."""
    scene, base, _, root = tiny
    chunks = _chunks(record(scene, [base], root / "series.rrd", NO_IMAGES).rrd)
    for tid, (_, _, v) in TRACKS.items():
        speed = np.array([s[0] for _, s in _rows(chunks[f"/world/road_users/run-base/{tid}"],
                                                 "Scalars:scalars")])
        np.testing.assert_allclose(speed, np.hypot(*v) * FPS, rtol=1e-9)
        err = np.array([s[0] for _, s in _rows(chunks[f"/metrics/road_users/run-base/error/{tid}"],
                                               "Scalars:scalars")])
        np.testing.assert_allclose(err, np.hypot(*EST_OFFSET[:2]), atol=1e-9)
        assert len(speed) == len(err) == N_FRAMES


def test_trails_are_children_of_their_road_users_with_a_visible_time_range(tiny):
    """Each road user's trail is a child entity of it (hiding the road user hides the trail)
    holding one segment per frame, its own step (no point repeated over frames), and the
    blueprint's 3D view shows exactly those trails over the last TRAIL_FRAMES frames."""
    import rerun.chunk as rc

    scene, base, _, root = tiny
    path = record(scene, [base], root / "trail.rrd", NO_IMAGES).rrd
    chunks = _chunks(path)
    for tid, (_, _, v) in TRACKS.items():
        strips = dict(_rows(chunks[f"/world/road_users/run-base/{tid}/trail"], "LineStrips3D:strips"))
        assert sorted(strips) == list(range(1, N_FRAMES)) and all(len(s) == 1 for s in strips.values())
        steps = {tuple(np.round(np.diff(np.array(s[0])[:, :2], axis=0)[0], 5)) for s in strips.values()}
        assert steps == {tuple(np.round(v, 5))}  # this road user's step, at every frame
    reader = rc.RrdReader(path)
    overrides = defaultdict(list)
    for ch in reader.stream(store=reader.blueprints()[0]):
        if "/ViewContents/overrides/" in ch.entity_path:
            b = ch.to_record_batch()
            for n in b.schema.names:
                if "VisibleTimeRanges" in n:
                    overrides[ch.entity_path.split("/ViewContents/overrides/")[1]] += b.column(n).to_pylist()
    assert set(overrides) == {f"world/road_users/run-base/{tid}/trail/visualizers" for tid in TRACKS}
    for ranges in overrides.values():
        by_timeline = {r["timeline"]: r["range"] for batch in ranges for r in batch}
        # cursor-relative bounds (the union's tag is not in to_pylist): the last 30 frames, 3 s
        assert by_timeline["frame"] == {"start": -L.TRAIL_FRAMES, "end": 0}
        assert by_timeline["time"] == {"start": -L.TRAIL_FRAMES * 10**9 // int(FPS), "end": 0}


def test_error_disc_and_r90_series_are_the_road_users_own(tiny):
    """A run with error bars: each road user's disc (a ring of radius r90 around its ground
    point, coloured by size) is on its own entity, hidden with it, and its r90 is a series."""
    from review_fixtures import make_run

    from s2p_review.error_discs import r90_colors
    from seg2pose.io.poses import read_poses, write_poses

    scene, _, _, root = tiny
    run = make_run(scene, root / "with-r90")
    poses = read_poses(run / "poses.csv")
    poses.r90 = 0.5 + 0.01 * poses.track_id + 0.1 * poses.frame  # metres, known per row
    write_poses(run / "poses.csv", poses)
    chunks = _chunks(record(scene, [run], root / "r90.rrd", NO_IMAGES).rrd)
    for tid in TRACKS:
        ent = chunks[f"/world/road_users/with-r90/{tid}"]
        rings, centers = dict(_rows(ent, "LineStrips3D:strips")), dict(_rows(ent, "Boxes3D:centers"))
        colors = dict(_rows(ent, "LineStrips3D:colors"))
        for f in (2, 7):
            r90 = 0.5 + 0.01 * tid + 0.1 * f
            ring = np.array(rings[f][0])
            np.testing.assert_allclose(np.linalg.norm(ring[:, :2] - np.array(centers[f])[0, :2], axis=1), r90,
                                       rtol=1e-5)
            c = colors[f][0]
            rgba = [(c >> 24) & 255, (c >> 16) & 255, (c >> 8) & 255, c & 255]
            assert rgba == r90_colors(np.array([r90]))[0].tolist()
        series = dict(_rows(chunks[f"/metrics/road_users/with-r90/r90/{tid}"], "Scalars:scalars"))
        np.testing.assert_allclose([series[f][0] for f in range(N_FRAMES)],
                                   [0.5 + 0.01 * tid + 0.1 * f for f in range(N_FRAMES)], rtol=1e-9)
    assert not [p for p in chunks if p.startswith("/world/road_users/with-r90/") and p.endswith("r90")]


def test_the_annotation_app_ranges_the_trails_of_its_runs_road_users(tiny):
    """The app's blueprint names every trail of the run it shows (run_tracks: the poses' track
    ids with a position), as s2p review's does."""
    from s2p_review.annotation_log import run_tracks

    _, base, _, _ = tiny
    assert run_tracks(base) == sorted(TRACKS)
    overrides = L.trail_overrides({"run-base": run_tracks(base)}, L.TRAIL_FRAMES, FPS)
    assert set(overrides) == {f"world/road_users/run-base/{tid}/trail" for tid in TRACKS}
    assert L.trail_path("tri T", 7) == "world/road_users/tri\\ T/7/trail"


def test_shown_frames_empty_the_road_user_after_each_stretch():
    frames, lengths = RU.shown_frames(np.array([2, 3, 4, 7, 8]), last=9)
    assert frames.tolist() == [2, 3, 4, 5, 7, 8, 9] and lengths.tolist() == [1, 1, 1, 0, 1, 1, 0]
    frames, lengths = RU.shown_frames(np.array([2, 3]), last=3)  # the range ends with it
    assert frames.tolist() == [2, 3] and lengths.tolist() == [1, 1]


def test_speeds_are_slopes_within_tracks_and_none_for_a_single_row():
    tid = np.array([1, 1, 1, 2, 5, 5])
    frame = np.array([0, 1, 3, 0, 4, 6])
    xy = np.array([[0, 0], [1, 0], [3, 0], [9, 9], [0, 0], [0, 4]], float)
    s = RU.speeds(tid, frame, xy, fps=10.0, half=1)
    # track 1 moves 1 m per frame (x = frame): 10 m/s from every window; track 2 has one row;
    # track 5: 4 m over 2 frames = 20 m/s at both ends
    np.testing.assert_allclose(s[[0, 1, 2, 4, 5]], [10.0, 10.0, 10.0, 20.0, 20.0])
    assert np.isnan(s[3])
    # a window of three rows (-1, 0, +1 frames) over x = 0, 0, 3: slope (3 - 0) / 0.2 s = 15 m/s,
    # the first row's window (0, +1) slope 0; far-away frame numbers change nothing
    s = RU.speeds(np.array([3, 3, 3]), np.array([0, 1, 2]) + 10**7, np.array([[0, 0], [0, 0], [3, 0]], float),
                  fps=10.0, half=1)
    np.testing.assert_allclose(s, [0.0, 15.0, 30.0], atol=1e-6)
