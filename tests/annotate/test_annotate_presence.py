"""Presence first: pre-annotation follows a run's track only where a camera has its road user's
mask; rows name their provenance; unchecked estimates refuse the export unless asked for."""

import numpy as np
import pytest
from review_fixtures import EST_OFFSET, make_run, make_scene

from annotate import EditError, Project
from annotate.export import UnreviewedError, export_gt, gt_table
from annotate.presence import annotated_run_tracks, plan, presence, runs
from annotate.table import source_counts
from seg2pose.io.mots import MaskTable, read_mots, write_mots
from seg2pose.io.poses import SOURCES, PoseTable, read_poses, write_poses

N = 40


def _drop_masks(scene, track: int, frames) -> None:
    """Remove ``track``'s masks in ``frames`` from every camera: the road user is unseen there."""
    for cam in scene.cameras:
        t = read_mots(scene.masks_path(cam))
        keep = ~((t.track_id == track) & np.isin(t.frame, list(frames)))
        write_mots(scene.masks_path(cam), t.take(np.flatnonzero(keep)))


@pytest.fixture
def scene(tmp_path):
    s = make_scene(tmp_path / "scene", n_frames=N)
    _drop_masks(s, 12, range(15, 27))     # the car leaves every view for 12 frames
    _drop_masks(s, 12, [6, 7])            # and is missed twice: a short gap
    return s


def test_runs_and_plan_by_hand():
    assert runs(np.array([0, 1, 2, 5, 6, 11])) == [(0, 6), (11, 11)]      # gap of 2 bridged
    assert runs(np.array([0, 1, 2, 5, 6, 11]), max_gap=1) == [(0, 2), (5, 6), (11, 11)]
    assert runs(np.array([], int)) == []
    f = np.arange(0, 30)
    est = PoseTable(f, np.full(30, 5), np.full(30, "car", object),
                    np.column_stack([f * 1.0, f * 0.0, f * 0.0]), np.zeros(30))
    seen = np.r_[0:8, 10:12, 20:30]      # 8, 9 missing (short); 12..19 missing (long)
    p = plan(est, seen, every=5)
    # keyframes every 5 frames from each run's start, plus each run's last frame
    assert [k[0] for k in p.keyframes] == [0, 5, 10, 11, 20, 25, 29]
    assert p.spans == [(8, 9, "occluded"), (12, 19, "outside")]
    assert p.keyframes[1][1:] == (5.0, 0.0, 0.0)
    assert plan(est, np.array([], int), 5).keyframes == []


def test_presence_from_masks():
    t0 = MaskTable([0, 1, 1, 3], [4, 4, -1, 9], [1, 1, 1, 1], 10, 10, [b""] * 4)
    t1 = MaskTable([2, 1], [4, 9], [1, 1], 10, 10, [b""] * 2)
    got = presence([t0, t1])
    assert sorted(got) == [4, 9]
    assert got[4].tolist() == [0, 1, 2] and got[9].tolist() == [1, 3]


def test_preannotation_never_spans_frames_without_the_road_user(scene, tmp_path):
    run = make_run(scene, tmp_path / "run")
    with Project.open(scene, run=run) as p:
        ch = p.preannotate(every=10)
        car = next(p.track(t) for t in ch.created if p.track(t).meta["run_track"] == 12)
        assert car.spans == [(6, 7, "occluded"), (15, 26, "outside")]
        assert car.frames == [0, 10, 14, 27, 37, 39]
        rows = p.track_poses(car.id)
        assert not np.isin(rows.frame, np.arange(15, 27)).any()
        assert set(rows.frame.tolist()) == set(range(0, 15)) | set(range(27, N))
        # every row sits on the run's estimate of its road user (a straight line: exact)
        truth = read_poses(scene.gt_path)
        t12 = truth.take(truth.track_id == 12)
        d = np.linalg.norm(rows.xyz[:, :2] - (t12.xyz[rows.frame, :2] + EST_OFFSET[:2]), axis=1)
        assert d.max() < 1e-6
        # accepting estimates every N on a track follows the same presence
        p.create_track("car", meta={"run_track": 12})
        new = p.tracks[max(p.tracks)]
        p.accept_estimate(new.id, every=10)
        assert (15, 26, "outside") in p.track(new.id).spans
        assert not np.isin(p.track_poses(new.id).frame, np.arange(15, 27)).any()


def test_road_users_annotated_by_position_are_skipped(scene, tmp_path):
    run = make_run(scene, tmp_path / "run")
    with Project.open(scene, run=run) as p:
        # the car keyframed by hand 0.9 m beside the run's estimate, linked to nothing
        p.create_track("car")
        p.set_keyframe(1, 0, -8.0 + 0.3 + 0.9, -1.5 - 0.4, heading=0.0)
        p.set_keyframe(1, 14, -8.0 + 0.6 * 14 + 0.3 + 0.9, -1.5 - 0.4, heading=0.0)
        assert annotated_run_tracks(p.run.table, p.poses()) == {12}
        ch = p.preannotate(every=10, skip_annotated=True)
        assert sorted(p.track(t).meta["run_track"] for t in ch.created) == [4, 7]
        with pytest.raises(EditError, match="not annotated already"):
            p.preannotate(every=10, skip_annotated=True)


def test_provenance_of_every_row_and_the_export_gate(scene, tmp_path):
    run = make_run(scene, tmp_path / "run")
    with Project.open(scene, run=run) as p:
        ch = p.preannotate(every=10, run_tracks=[4])
        ped = ch.track
        assert set(p.track_poses(ped).source) == {"estimate-unchecked"}
        with pytest.raises(UnreviewedError, match=f"{N} rows of 1 tracks are unchecked") as e:
            gt_table(p)
        assert e.value.counts == {ped: N}
        assert len(gt_table(p, allow_unreviewed=True)) == N
        # frames 0..12 played back and passed: keyframes 0, 10 accepted, the rest reviewed
        p.mark_reviewed(ped, 0, 12)
        src = p.track_poses(ped).source
        assert src[0] == src[10] == "estimate-accepted"
        assert set(src[[1, 9, 11, 12]]) == {"reviewed"}
        # 13..19 lie between keyframe 10 (accepted) and 20 (unchecked): still unchecked
        assert set(src[13:20]) == {"estimate-unchecked"}
        p.accept_estimate(ped, 20)                        # looked at and accepted (y)
        assert p.track_poses(ped).source[20] == "estimate-accepted"
        assert set(p.track_poses(ped).source[13:20]) == {"interpolated"}
        p.nudge(ped, 30, 0.1, 0.0)                        # corrected by hand
        assert p.track_poses(ped).source[30] == "keyframe"
        p.mark(ped, 33, 34, "occluded")
        counts = source_counts(p.track_poses(ped))[ped]
        assert counts == {"estimate-accepted": 3, "reviewed": 11, "interpolated": 16,
                          "keyframe": 1, "estimate-unchecked": 7, "occluded": 2}
        p.mark_reviewed(ped, 5, 8, reviewed=False)
        assert p.track(ped).reviewed == [(0, 4), (9, 12)]
        p.undo()
        assert p.track(ped).reviewed == [(0, 12)]
        p.mark_reviewed(ped, 0, N - 1)
        path = export_gt(p, tmp_path / "gt.csv")
    # the reader takes every provenance back; a reopened journal gives the same review state
    back = read_poses(path)
    assert set(back.source) <= set(SOURCES) and "estimate-unchecked" not in set(back.source)
    with Project.open(scene, read_only=True) as q:
        assert q.track(ped).reviewed == [(0, N - 1)]


def test_every_source_round_trips_through_the_gt_file(tmp_path):
    n = len(SOURCES)
    t = PoseTable(np.arange(n), np.ones(n), np.full(n, "car", object), np.zeros((n, 3)),
                  np.zeros(n), np.ones((n, 3)), np.array(SOURCES, object))
    write_poses(tmp_path / "p.csv", t)
    assert read_poses(tmp_path / "p.csv").source.tolist() == list(SOURCES)


def test_status_and_export_count_provenance_per_track(scene, tmp_path, monkeypatch, capsys):
    from scene_fixtures import s2p

    run = make_run(scene, tmp_path / "run")
    with Project.open(scene, run=run) as p:
        ped = p.preannotate(every=10, run_tracks=[4]).track
    code, out, err = s2p(monkeypatch, capsys, "annotate", "status", scene.root)
    assert code == 0, err
    assert f"rows by provenance: {N} estimate-unchecked" in out
    assert f"  pedestrian {ped}: {N} estimate-unchecked" in out
    args = ("annotate", "export", scene.root, "--no-mcap", "--no-tanalyst", "--force")
    code, out, err = s2p(monkeypatch, capsys, *args)
    assert code != 0 and f"{N} rows of 1 tracks are unchecked estimates" in err
    assert "--allow-unreviewed" in err
    code, out, err = s2p(monkeypatch, capsys, *args, "--allow-unreviewed")
    assert code == 0, err
    assert f"{N} rows ({N} estimate-unchecked)" in out and f"  pedestrian {ped}: {N} estimate-unchecked" in out
    assert set(read_poses(scene.gt_path).source) == {"estimate-unchecked"}
