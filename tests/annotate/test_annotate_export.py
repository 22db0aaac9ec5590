"""Exports of an annotation project: gt/poses.csv with the source column (never silently over
truth from elsewhere), the journal files restoring a working project, a run-like folder."""

import json

import numpy as np
import pytest
from review_fixtures import make_scene

from annotate import Project
from annotate.export import annotated_poses, export_gt, journal_files, write_annotation_run
from seg2pose.core.errors import S2PError
from seg2pose.io.poses import read_poses


@pytest.fixture
def scene(tmp_path):
    return make_scene(tmp_path / "scene", n_frames=30)


def annotate(p):
    p.create_track("car")
    p.set_keyframe(1, 0, -8.0, -1.5, heading=0.0)
    p.set_keyframe(1, 10, -2.0, -1.5, heading=0.0)
    p.set_keyframe(1, 20, 4.0, -1.5, heading=0.0)
    p.mark(1, 4, 6, "occluded")
    p.create_track("pedestrian")
    p.set_keyframe(2, 2, 1.0, 2.0, heading=1.0)
    p.set_keyframe(2, 12, 1.0, 4.0)
    p.mark(2, 5, 8, "outside")


def test_export_gt_writes_every_frame_with_sources(scene):
    with Project.open(scene) as p:
        annotate(p)
        with pytest.raises(S2PError, match="not an annotation export .*--force"):
            export_gt(p)  # the fixture's gt/poses.csv is truth from elsewhere
        path = export_gt(p, force=True)
        t = read_poses(path)
        car = t.take(t.track_id == 1)
        assert car.frame.tolist() == list(range(21))
        np.testing.assert_allclose(car.xyz[:, 0], -8 + 0.6 * np.arange(21), atol=1e-9)
        assert car.source[[0, 1, 4, 6, 7, 10]].tolist() == [
            "keyframe", "interpolated", "occluded", "occluded", "interpolated", "keyframe"]
        # the outside span 5..8 cuts the pedestrian's only interval: no poses between 2 and 12
        assert t.take(t.track_id == 2).frame.tolist() == [2, 12]
        assert np.array_equal(t.size[t.track_id == 1][0], p.track(1).size)
        p.set_keyframe(1, 25, 7.0, -1.5)
        export_gt(p)  # a previous export is replaced without --force
        assert read_poses(path).frame[read_poses(path).track_id == 1].max() == 25
        assert np.array_equal(read_poses(path).xyz, annotated_poses(p).xyz)


def test_journal_files_restore_a_working_project(scene, tmp_path):
    with Project.open(scene) as p:
        annotate(p)
        p.undo()  # the history travels too: redo works after restoring
        files = journal_files(p)
        before = {t: tr.to_dict() for t, tr in p.tracks.items()}
    assert all(n.startswith("annotations/") and "lock" not in n for n in files)
    copy = make_scene(tmp_path / "copy", n_frames=30)  # same calibration and ground: same fingerprint
    for name, data in files.items():
        (copy.root / name).parent.mkdir(exist_ok=True)
        (copy.root / name).write_bytes(data)
    with Project.open(copy.root) as q:
        assert {t: tr.to_dict() for t, tr in q.tracks.items()} == before
        q.redo()
        assert q.track(2).spans == [(5, 8, "outside")]


def test_annotation_run_folder(scene, tmp_path):
    with Project.open(scene) as p:
        annotate(p)
        run = write_annotation_run(p, tmp_path / "run")
        meta = json.loads((run / "run.json").read_text())
        assert meta["kind"] == "annotations" and meta["journal_records"] == p.seq
        assert read_poses(run / "poses.csv").source is not None
    with Project.open(scene) as p:
        p.delete_track(1)
        p.delete_track(2)
        with pytest.raises(S2PError, match="no annotated poses"):
            export_gt(p, force=True)
