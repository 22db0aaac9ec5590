"""The annotation Project: edits, placement, pre-annotation, undo/redo, replay."""

import math
import random

import numpy as np
import pytest
from annotate_fixtures import random_edit, state
from review_fixtures import EST_OFFSET, make_run, make_scene

from annotate import EditError, Project
from seg2pose.io.poses import read_poses


@pytest.fixture
def scene(tmp_path):
    return make_scene(tmp_path / "scene", n_frames=30)


@pytest.fixture
def project(scene):
    p = Project.open(scene)
    yield p
    p.close()


def test_keyframes_to_poses_with_ground_z_and_sources(project, scene):
    ch = project.create_track("car")
    assert ch.created == {1} and ch.track == 1 and project.track(1).size == (4.5, 1.8, 1.5)
    project.set_keyframe(1, 0, -8.0, -1.5, heading=0.0)
    project.set_keyframe(1, 10, -2.0, -1.5)
    project.mark(1, 4, 6, "occluded")
    t = project.poses()
    assert t.frame.tolist() == list(range(11))
    np.testing.assert_allclose(t.xyz[:, 0], -8.0 + 0.6 * np.arange(11), atol=1e-12)
    np.testing.assert_allclose(t.xyz[:, 2], scene.ground.height(t.xyz[:, :2]))
    assert t.source[[0, 1, 5, 10]].tolist() == ["keyframe", "interpolated", "occluded", "keyframe"]
    assert project.interpolation(1) == "hermite"
    project.set_interpolation(1, "linear")
    assert project.interpolation(1) == "linear"


def test_outside_span_stops_interpolation_and_removes_keyframes(project):
    project.create_track("pedestrian")
    for f, x in ((0, 0.0), (5, 1.0), (10, 2.0), (20, 4.0)):
        project.set_keyframe(1, f, x, 0.0, 0.0)
    project.mark(1, 8, 12, "outside")
    assert project.track(1).frames == [0, 5, 20]
    # the segments are 0..5 and 20..20: frames 6..19 have no pose (a gap, not a guess)
    assert project.poses().frame.tolist() == [0, 1, 2, 3, 4, 5, 20]
    with pytest.raises(EditError, match="outside span"):
        project.set_keyframe(1, 9, 1.0, 0.0)
    project.undo()
    assert project.track(1).frames == [0, 5, 10, 20]


def test_bad_input_is_refused_with_names(project, scene):
    with pytest.raises(EditError, match="unknown class 'lorry'; the scene knows pedestrian"):
        project.create_track("lorry")
    project.create_track("car")
    with pytest.raises(EditError, match=r"frame 30 is outside the scene's frames 0..29"):
        project.set_keyframe(1, 30, 0.0, 0.0)
    with pytest.raises(EditError, match="frame must be an integer >= 0"):
        project.set_keyframe(1, -1, 0.0, 0.0)
    with pytest.raises(EditError, match="no track 7"):
        project.nudge(7, 0, 0.02, 0)
    with pytest.raises(EditError, match="finite"):
        project.set_keyframe(1, 0, float("nan"), 0.0)
    with pytest.raises(EditError, match="size must be three numbers"):
        project.set_size(1, (4.0, -1.0, 1.5))
    with pytest.raises(EditError, match="refused"):
        project.set_keyframe(1, 0, 500.0, 0.0)
    # off the support but within reach: kept, flagged and noted
    project.set_keyframe(1, 0, 40.0, 0.0)
    assert project.track(1).keyframes[0].flags == ("auto_heading", "off_support")
    assert "off_support" in project.notes[-1]
    assert project.seq == 2  # the refused edits wrote nothing


def test_nudge_rotate_and_relative_nudge(project):
    project.create_track("car")
    project.set_keyframe(1, 0, 0.0, 0.0, heading=math.pi / 2)
    project.set_keyframe(1, 10, 0.0, 5.0, heading=math.pi / 2)
    project.nudge(1, 0, 0.10, 0.0)
    assert project.track(1).keyframes[0][:2] == (0.10, 0.0)
    project.nudge(1, 0, 0.50, 0.0, relative=True)  # forwards = +y for heading 90 deg
    k = project.track(1).keyframes[0]
    assert k.x == pytest.approx(0.10) and k.y == pytest.approx(0.50)
    project.rotate(1, 0, 15)
    assert project.track(1).keyframes[0].heading == pytest.approx(math.pi / 2 + math.radians(15))
    # nudging an interpolated frame makes it a keyframe
    project.nudge(1, 5, 0.02, 0.0)
    assert 5 in project.track(1).keyframes
    assert [n for _, n in project.history()][-4:] == ["nudge", "nudge", "rotate", "nudge"]


def test_place_from_pixel_recovers_the_ground_point(project, scene):
    cam = scene.cameras["c0"]
    X = np.array([[2.0, 1.0, float(scene.ground.height(np.array([[2.0, 1.0]]))[0])]])
    uv = cam.project_points(X)[0][0]
    project.create_track("pedestrian")
    project.place_from_pixel(1, 3, "c0", uv)
    k = project.track(1).keyframes[3]
    assert abs(k.x - 2.0) < 1e-6 and abs(k.y - 1.0) < 1e-6
    # a click on the body's centre 0.9 m above the ground
    X2 = X + [0, 0, 0.9]
    project.place_from_pixel(1, 4, "c0", cam.project_points(X2)[0][0], height=0.9)
    k = project.track(1).keyframes[4]
    assert abs(k.x - 2.0) < 1e-6 and abs(k.y - 1.0) < 1e-6
    with pytest.raises(EditError, match="outside camera c0's 160x120 image"):
        project.place_from_pixel(1, 5, "c0", (500, 10))
    with pytest.raises(EditError, match="unknown camera 'c9'"):
        project.place_from_pixel(1, 5, "c9", (5, 10))


def test_place_from_mask_normal_position_or_run_estimate(scene, tmp_path):
    gt = read_poses(scene.gt_path)
    run = make_run(scene, tmp_path / "run")
    with Project.open(scene, run=run) as p:
        p.create_track("car")
        p.place_from_mask(1, 5, "c0", 12)
        k = p.track(1).keyframes[5]
        truth = gt.xyz[(gt.frame == 5) & (gt.track_id == 12)][0]
        np.testing.assert_allclose([k.x, k.y], truth[:2] + EST_OFFSET[:2], atol=1e-9)
        assert k.flags == ("estimate",)
        p.place_from_mask(1, 6, "c0", 12, use_run=False)
        k = p.track(1).keyframes[6]
        assert k.flags == ("auto_heading", "normal")
        truth = gt.xyz[(gt.frame == 6) & (gt.track_id == 12)][0]
        assert np.hypot(k.x - truth[0], k.y - truth[1]) < 3.0  # a normal position: near, not exact
        # a manual move marks it checked
        p.nudge(1, 6, 0.02, 0.0)
        assert p.track(1).keyframes[6].flags == ("auto_heading",)  # heading still auto
        with pytest.raises(EditError, match="no mask of track 99"):
            p.place_from_mask(1, 6, "c0", 99, use_run=False)


def test_preannotate_and_accept_estimates(scene, tmp_path):
    run = make_run(scene, tmp_path / "run")
    with Project.open(scene, run=run) as p:
        ch = p.preannotate(every=10)
        assert len(ch.created) == 3
        by_run = {p.track(t).meta["run_track"]: p.track(t) for t in ch.created}
        assert by_run[12].frames == [0, 10, 20, 29] and by_run[12].cls == "car"
        assert all(k.flags == ("estimate",) for k in by_run[12].keyframes.values())
        p.undo()
        assert not p.tracks
        p.create_track("car", meta={"run_track": 12})
        p.accept_estimate(1, 7)
        assert p.track(1).frames == [7]
        p.accept_estimate(1, every=5, frames=(10, 20))
        assert p.track(1).frames == [7, 10, 15, 20]
        with pytest.raises(EditError, match="no estimate of road user 55"):
            p.accept_estimate(1, 7, run_track=55)
        # a track linked to no road user never pulls in the run track that shares its number
        p.create_track("car")
        with pytest.raises(EditError, match="track 2 is linked to no road user"):
            p.accept_estimate(2, 7)
        # pre-annotating a project with tracks: the road users annotated already are skipped
        ch = p.preannotate(every=10, skip_annotated=True)
        assert sorted(p.track(t).meta["run_track"] for t in ch.created) == \
            sorted(set(by_run) - {12})


def test_split_and_merge(project):
    project.create_track("car")
    for f in (0, 10, 20, 30 - 1):
        project.set_keyframe(1, f, float(f), 0.0, 0.0)
    project.mark(1, 12, 25, "occluded")
    ch = project.split_track(1, 15)
    new = ch.track
    assert ch.created == {new} and project.track(1).frames == [0, 10]
    assert project.track(new).frames == [20, 29]
    assert project.track(1).spans == [(12, 14, "occluded")]
    assert project.track(new).spans == [(15, 25, "occluded")]
    project.merge_tracks(1, new)
    assert project.track(1).frames == [0, 10, 20, 29] and new not in project.tracks
    assert project.track(1).spans == [(12, 25, "occluded")]
    project.create_track("car")
    project.set_keyframe(new, 10, 0.0, 0.0)
    with pytest.raises(EditError, match=r"both have keyframes at frames \[10\]"):
        project.merge_tracks(1, new)


@pytest.mark.parametrize("seed", range(2))
def test_undo_redo_are_inverse_and_replay_equals_live(scene, seed):
    rng = random.Random(seed)
    with Project.open(scene) as p:
        states = [state(p)]
        for _ in range(60):
            random_edit(p, rng, allow_undo=False)
            states.append(state(p))
        # undo everything, checking each intermediate state, then redo it all
        for k in range(len(p.history())):
            p.undo()
            assert state(p) == states[-2 - k]
        for k in range(len(states) - 1):
            p.redo()
            assert state(p) == states[1 + k]
        # some undos, then new edits (the redo branch is dropped)
        for _ in range(7):
            p.undo()
        before_last = state(p)
        random_edit(p, rng, allow_undo=False)
        assert not p.can_redo
        live, hist, poses = state(p), p.history(), p.poses()
    with Project.open(scene) as q:
        assert state(q) == live and q.history() == hist
        np.testing.assert_array_equal(q.poses().xyz, poses.xyz)
        q.undo()  # the undo history survives the reopen
        assert state(q) == before_last


def test_change_notification_names_the_changed_track(project):
    seen = []
    unsubscribe = project.subscribe(seen.append)
    project.create_track("car")
    project.create_track("pedestrian")
    project.set_keyframe(2, 3, 1.0, 1.0)
    project.undo()
    assert [(c.kind, set(c.tracks)) for c in seen] == [("edit", {1}), ("edit", {2}),
                                                       ("edit", {2}), ("undo", {2})]
    unsubscribe()
    project.redo()
    assert len(seen) == 4


def test_import_poses_from_truth_every_n_frames(scene, tmp_path):
    gt = read_poses(scene.gt_path)
    with Project.open(scene) as p:
        ch = p.import_poses(gt, every=10)
        assert ch.created == {4, 7, 12}
        assert p.track(12).frames == [0, 10, 20, 29] and p.track(12).size == (4.5, 1.8, 1.5)
        assert p.track(12).keyframes[10].flags == ("imported",)
        # straight constant-speed truth: every interpolant reproduces it between keyframes
        est = p.poses()
        np.testing.assert_allclose(est.xyz, gt.xyz, atol=1e-9)
        assert p.import_poses(gt, every=15, keep_ids=False).created == {13, 14, 15}
        with pytest.raises(EditError, match=r"track ids \[4, 7, 12\] are taken"):
            p.import_poses(gt)
        files = p.journal_files()
        assert [f.name for f in files] == ["journal-000000.jsonl"]
    # T-Analyst tracks have no heading: it follows the motion
    nan = gt.take(gt.track_id == 4)
    nan.heading[:] = np.nan
    with Project.open(scene) as p:
        p.delete_track(4)
        p.import_poses(nan, every=10)
        assert p.track(4).keyframes[10].heading == pytest.approx(-math.pi / 2)
