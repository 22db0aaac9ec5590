"""The association in review (s2p_review/association.py): masks by id in every camera and each
view's estimate joined to its fused pose."""

from __future__ import annotations

import numpy as np
import pytest
from review_fixtures import make_run, make_scene

from s2p_review.association import association_strips, id_color
from s2p_review.runs import load_run
from s2p_review.session import record

N = 12


@pytest.fixture(scope="module", autouse=True)
def _opencv_one_thread():
    from video_fixtures import single_threaded_opencv

    yield from single_threaded_opencv()


def test_strips_join_views_to_their_fused_pose(tmp_path):
    scene = make_scene(tmp_path / "scene", n_frames=N)
    run_dir = make_run(scene, tmp_path / "scene" / "out" / "run")
    run = load_run(run_dir, scene)
    frames, strips, ids = association_strips(run, ["c0", "c1"], 0, N - 1)
    v = run.views
    assert len(frames) == int(np.sum(v.track_id >= 0)) and (np.diff(frames) >= 0).all()
    # each segment ends at the fused pose of its (frame, id) and starts at the view's estimate
    p = run.poses
    for k in range(0, len(frames), 7):
        row = np.flatnonzero((p.frame == frames[k]) & (p.track_id == ids[k]))[0]
        assert np.allclose(strips[k, 1], p.xyz[row])
    assert np.allclose(association_strips(run, ["c0"], 0, N - 1)[1][:, 0, :2],
                       (v.normal[:, :2] + v.residual)[v.camera == "c0"][np.argsort(
                           v.frame[v.camera == "c0"], kind="stable")])
    assert id_color([1])[0].tolist() == id_color([1 + 255])[0].tolist() != id_color([2])[0].tolist()


def test_recording_holds_the_association(tmp_path):
    import rerun.chunk as rc

    scene = make_scene(tmp_path / "scene", n_frames=N)
    run_dir = make_run(scene, tmp_path / "scene" / "out" / "run")
    out = record(scene, [run_dir], tmp_path / "rec.rrd").rrd
    rows = {}
    for ch in rc.RrdReader(out).stream():
        if not ch.is_static:
            rows[ch.entity_path] = rows.get(ch.entity_path, 0) + ch.num_rows
    assert rows["/world/association/run"] == N
    assert rows["/world/cameras/c0/masks_by_id"] == N and rows["/world/cameras/c1/masks_by_id"] == N


def test_two_runs_log_each_cameras_masks_by_id_once(tmp_path):
    """The masks by id are the scene's, not a run's: a recording of two runs holds them once
    per camera and frame (they were logged once per run, doubling the demo's sample file), and
    both runs' association lines."""
    import shutil

    import rerun.chunk as rc

    scene = make_scene(tmp_path / "scene", n_frames=N)
    a = make_run(scene, tmp_path / "scene" / "out" / "run")
    b = tmp_path / "scene" / "out" / "run2"
    shutil.copytree(a, b)
    out = record(scene, [a, b], tmp_path / "rec.rrd").rrd
    rows = {}
    for ch in rc.RrdReader(out).stream():
        if not ch.is_static:
            rows[ch.entity_path] = rows.get(ch.entity_path, 0) + ch.num_rows
    assert rows["/world/association/run"] == rows["/world/association/run2"] == N
    assert rows["/world/cameras/c0/masks_by_id"] == N and rows["/world/cameras/c1/masks_by_id"] == N
