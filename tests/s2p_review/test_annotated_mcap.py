"""The annotated MCAP set: annotated tracks with their sources, the journal as attachments, and
``s2p import-mcap`` restoring a working annotation project."""

from __future__ import annotations

import numpy as np
import pytest
from review_fixtures import make_scene
from scene_fixtures import s2p

from annotate import Project
from s2p_review.annotated_mcap import export_annotated_mcap, restore_annotation_files
from s2p_review.mcap_import import read_mcap_records
from seg2pose.core.errors import InputError


def test_export_import_restores_the_annotation_project(monkeypatch, capsys, tmp_path):
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
    from mcap.reader import make_reader

    scene = make_scene(tmp_path / "scene", n_frames=12, video=True)
    with Project.open(scene) as p:
        p.create_track("car")
        p.set_keyframe(1, 0, -8.0, -1.5, heading=0.0)
        p.set_keyframe(1, 10, -2.0, -1.5, heading=0.0)
        p.mark(1, 3, 4, "occluded")
        p.create_track("pedestrian")
        p.set_keyframe(2, 2, 1.0, 2.0, heading=1.0)
        p.set_keyframe(2, 8, 1.0, 4.0)
        p.undo()  # the history travels: redo works after the import
        before = {t: tr.to_dict() for t, tr in p.tracks.items()}
        poses = p.poses()
    code, out, err = s2p(monkeypatch, capsys, "annotate", "export", scene.root, "--force",
                         "--no-tanalyst", "-o", tmp_path / "exp")
    assert code == 0, err
    mcap = tmp_path / "exp" / "annotations.mcap"
    rec = read_mcap_records(mcap)
    assert any(n.startswith("annotations/journal-") for n in rec.attachments)
    rows = [r for m in rec.poses for r in m["rows"]]
    assert [r["source"] for r in rows if r["track_id"] == 1][:5] == [
        "keyframe", "interpolated", "interpolated", "occluded", "occluded"]
    labels = set()
    with open(mcap, "rb") as f:
        for _s, _ch, m in make_reader(f).iter_messages(topics=["/road_users/scene"]):
            su = SceneUpdate.FromString(m.data)
            labels |= {t.text for e in su.entities for t in e.texts}
    assert "c1 keyframe" in labels and "c1 occluded" in labels

    code, out, err = s2p(monkeypatch, capsys, "import-mcap", mcap, "-o", tmp_path / "restored")
    assert code == 0, err
    with Project.open(tmp_path / "restored") as q:
        assert {t: tr.to_dict() for t, tr in q.tracks.items()} == before
        back = q.poses()
        assert np.array_equal(back.xyz, poses.xyz) and list(back.source) == list(poses.source)
        q.redo()
        assert q.track(2).frames == [2, 8]
    from seg2pose.io.poses import read_poses

    run = read_poses(tmp_path / "restored" / "out" / "annotations" / "poses.csv")
    assert list(run.source) == list(poses.source)
    # the set restores a scene with pictures: every frame's video (H.264, the Foxglove schema)
    # and the masks files byte for byte
    from s2p_review.imagery import video_frames
    from seg2pose.io.scene import load_scene

    with open(mcap, "rb") as f:
        video = [(ch.topic, sch.name) for sch, ch, _ in make_reader(f).iter_messages()
                 if ch.topic.endswith("/video")]
    assert sorted(set(video)) == [("/cameras/c0/video", "foxglove.CompressedVideo"),
                                  ("/cameras/c1/video", "foxglove.CompressedVideo")]
    assert len(video) == 2 * 12
    restored = load_scene(tmp_path / "restored")
    for cam in scene.cameras:
        assert (restored.masks_path(cam).read_bytes() == scene.masks_path(cam).read_bytes())
        want = dict(video_frames(scene, cam, 0, 11))
        got = dict(video_frames(restored, cam, 0, 11))
        assert sorted(got) == list(range(12))
        for f, img in got.items():  # lossy H.264: the picture, not the bytes
            assert np.abs(img.astype(float).mean((0, 1)) - want[f].mean((0, 1))).max() < 4.0


def test_attachment_names_cannot_leave_the_folder(tmp_path):
    with pytest.raises(InputError, match="cannot be used in a file name") as e:
        restore_annotation_files({"annotations/../scene.json": b"{}"}, tmp_path, "x.mcap")
    assert e.value.file == "x.mcap"
    with pytest.raises(InputError, match="cannot be used in a file name"):
        restore_annotation_files({"annotations/sub/journal.jsonl": b""}, tmp_path, "x.mcap")
    assert restore_annotation_files({"other.txt": b"", "annotations/journal-000000.jsonl": b"a"},
                                    tmp_path) == [tmp_path / "annotations" / "journal-000000.jsonl"]
    with pytest.raises(ValueError, match="must be named annotations/"):
        export_annotated_mcap(None, tmp_path, tmp_path / "x.mcap", {"journal.jsonl": b""})
