"""The review workflow: the queue of frames that need a look (worst first), playback that stops
where the track leaves its road user, reviewed spans, and the CVAT-like edits of the large
picture (drag the base, turn by the handle, l/w/h keys and field, hide the other tracks)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from review_fixtures import EST_OFFSET, make_run, make_scene

from annotate import Project
from annotate.app.controller import Controller
from annotate.review_queue import play_stop, review_queue
from seg2pose.io.poses import read_poses

N = 30


@pytest.fixture
def scene(tmp_path):
    return make_scene(tmp_path / "scene", n_frames=N)


def _est(scene, track, frame):
    t = read_poses(scene.gt_path)
    i = np.flatnonzero((t.track_id == track) & (t.frame == frame))[0]
    return t.xyz[i, :2] + EST_OFFSET[:2]


def test_playback_stops_where_the_interpolation_leaves_the_road_user(scene, tmp_path):
    run = make_run(scene, tmp_path / "run")
    with Project.open(scene, run=run) as p:
        p.create_track("car", interp="linear", meta={"run_track": 12})
        x0, y0 = _est(scene, 12, 0)
        x1, y1 = _est(scene, 12, 20)
        p.set_keyframe(1, 0, x0, y0, heading=0.0)
        p.set_keyframe(1, 20, x1, y1 + 3.0, heading=0.0)   # 3 m off at frame 20
        # linear: the track is 3 f / 20 m off the estimate at frame f: > 1 m from frame 7 on
        assert play_stop(p, 1, 0) == (7, "the track is 1.05 m from its road user's estimate")
        assert play_stop(p, 1, 7)[0] == 8
        p.set_keyframe(1, 20, x1, y1, heading=0.0)
        assert play_stop(p, 1, 0) == (20, "the end of the track")
        # nothing unchecked yet: the queue is empty; pre-annotated road users fill it
        assert review_queue(p) == []
        p.preannotate(every=10, run_tracks=[4, 7])
        q = review_queue(p)
        assert {lk.track for lk in q} == {2, 3} and all(lk.first == 0 and lk.last == N - 1 for lk in q)
        p.mark_reviewed(2, 0, N - 1)
        assert [lk.track for lk in review_queue(p)] == [3]


def test_review_mode_in_the_controller(scene, tmp_path):
    run = make_run(scene, tmp_path / "run")
    ctl = Controller.open(scene.root, run=run)
    try:
        assert "pre-annotated 3 road users" in ctl.do("preannotate")
        assert len(ctl.panel()["review"]) == 3
        msg = ctl.do("next_look")
        tid = ctl.selected
        assert tid is not None and "expected error" in msg
        ctl.do(f"goto:{0}")
        assert "playing track" in ctl.do("play")
        steps = 0
        while ctl.play_step():
            steps += 1
        assert ctl.frame == N - 1 and steps == N - 1 and "the end of the track" in ctl.message
        ctl.review_from = 0
        assert ctl.do("mark_reviewed") == f"track {tid}: frames 0..{N - 1} reviewed"
        assert ctl.project.track(tid).reviewed == [(0, N - 1)]
        assert len(ctl.panel()["review"]) == 2
        info = ctl.panel()["info"]
        assert info["sources"] == {"estimate-accepted": 3, "reviewed": N - 3}  # keyframes 0, 25, 29
        # any action stops a playback
        ctl.do("goto:0")
        ctl.do("play")
        ctl.do("next_frame")
        assert ctl.play_to is None
        # size: keys by 10 cm, the field sets all three
        l0, w0, h0 = ctl.project.track(tid).size
        ctl.do("size:l:0.1")
        ctl.do("size:h:-0.1")
        assert ctl.project.track(tid).size == pytest.approx((l0 + 0.1, w0, h0 - 0.1))
        ctl.do("set_size:4.0, 1.9, 1.4")
        assert ctl.project.track(tid).size == (4.0, 1.9, 1.4)
        assert "expected l,w,h" in ctl.do("set_size:4;2")
        ctl.do("only_selected")
        assert ctl.only_selected and ctl.panel()["only_selected"]
    finally:
        ctl.close()


def test_drag_the_base_and_turn_by_the_handle(scene):
    ctl = Controller.open(scene.root)
    try:
        ctl.do("class:car")
        ctl.do("new_track")
        tid = ctl.selected
        ctl.project.set_keyframe(tid, 0, 0.0, 0.0, heading=0.0)
        box = ctl.box_handles("c0")
        assert len(box["base"]) == 4 and len(box["handle"]) == 2
        cam, g = scene.cameras["c0"], scene.ground

        def pix(x, y):
            uv, _, _ = cam.project_points(np.array([[x, y, float(g.height(np.array([[x, y]]))[0])]]))
            return uv[0]

        # dragging a point of the ground 1.5 m along +x moves the box 1.5 m along +x
        ctl.drag("c0", pix(0.5, 0.2), pix(2.0, 0.2))
        x, y, h = ctl.project.pose_at(tid, 0)
        assert (x, y) == pytest.approx((1.5, 0.0), abs=1e-6)
        # the handle dragged to a point north of the box: it faces north
        ctl.rotate_to("c0", pix(1.5, 3.0))
        assert ctl.project.pose_at(tid, 0)[2] == pytest.approx(math.pi / 2, abs=1e-6)
        assert ctl.drag("c0", pix(1.5, 0.0), pix(1.5, 1.0)).startswith(f"track {tid}: moved by (+0.00, +1.00)")
        ctl.do("deselect")
        assert ctl.box_handles("c0") is None
    finally:
        ctl.close()
