"""Detector COCO input, new scenes from video + calibration, and video -> masks for a scene."""

import json

import numpy as np
import pytest
from video_fixtures import H, W, calibration, det, rle, single_threaded_opencv, write_folder

from seg2pose.core.errors import InputError, S2PError
from seg2pose.io.mots import read_mots
from seg2pose.io.scene import load_scene
from seg2pose.structures.masks import decode
from seg2pose.video.detections import DetectionConfig, import_detections
from seg2pose.video.video_scene import new_scene, read_calibration, scene_import_detections, scene_masks_from_video

opencv_one_thread = pytest.fixture(autouse=True)(single_threaded_opencv)

CLASSES = {"pedestrian": 1, "bicyclist": 2, "car": 3}


def test_coco_detections_threshold_nms_bicyclists(tmp_path):
    recs = [det(0, 1, rle(10, 10, 10, 30)), det(0, 2, rle(8, 25, 16, 20)),      # rider on a bicycle
            det(0, 3, rle(60, 60, 40, 20), 0.95), det(0, 3, rle(61, 60, 40, 20), 0.8),  # duplicate car
            det(0, 1, rle(120, 10, 8, 20), 0.3),                                   # below threshold
            det(1, 2, rle(100, 80, 16, 16)),                                       # a lone bicycle
            det(1, 8, [[10, 10, 30, 10, 30, 40, 10, 40]], 0.9)]                    # truck polygon -> car
    (tmp_path / "d.json").write_text(json.dumps({
        "images": [{"id": 0, "frame": 0, "height": H, "width": W},
                   {"id": 1, "frame": 1, "height": H, "width": W}],
        "categories": [{"id": 1, "name": "person"}, {"id": 2, "name": "bicycle"},
                       {"id": 3, "name": "car"}, {"id": 8, "name": "truck"}],
        "annotations": recs}))
    t = import_detections(tmp_path / "d.json", CLASSES, size=(H, W), log=lambda s: None)
    assert t.frame.tolist() == [0, 0, 1] and t.class_id.tolist() == [2, 3, 3]
    rider = decode(t.rles[0], H, W)
    assert rider.sum() == 10 * 30 + 16 * 20 - 10 * 15         # union of person and bicycle
    assert t.score[1] == pytest.approx(0.95)                   # the better duplicate stays
    assert decode(t.rles[2], H, W).sum() == 20 * 30            # polygon corners -> 20 x 30 pixels
    kept = import_detections(tmp_path / "d.json", CLASSES, size=(H, W),
                             cfg=DetectionConfig(lone_bicycles=True), log=lambda s: None)
    assert kept.class_id.tolist() == [2, 3, 2, 3]


def test_coco_bad_frames_and_sizes(tmp_path):
    (tmp_path / "d.json").write_text(json.dumps({"images": [{"id": 5, "frame": 0}],
                                                 "annotations": [det(6, 1, rle(1, 1, 5, 5))]}))
    with pytest.raises(InputError, match=r"d.json: field '\[0\].image_id': image_id 6 matches no entry"):
        import_detections(tmp_path / "d.json", CLASSES, log=lambda s: None)
    (tmp_path / "r.json").write_text(json.dumps([det(12, 1, rle(1, 1, 5, 5))]))
    with pytest.raises(InputError, match=r"frame 12 matches no video frame \(the video has 10"):
        import_detections(tmp_path / "r.json", CLASSES, n_frames=10, log=lambda s: None)
    with pytest.raises(InputError, match=r"masks are 160x120 pixels but the camera calibration is 320x240"):
        import_detections(tmp_path / "r.json", CLASSES, size=(240, 320), log=lambda s: None)
    (tmp_path / "p.json").write_text(json.dumps([det(0, 1, [[1, 1, 5, 1]])]))
    with pytest.raises(InputError, match=r"polygon masks need the image size"):
        import_detections(tmp_path / "p.json", CLASSES, log=lambda s: None)


def test_new_scene_then_masks_from_video(tmp_path):
    cam = calibration(tmp_path)
    boxes = [dict(id=1, x=10, y=60, w=10, h=24, vx=2, vy=0), dict(id=2, x=140, y=100, w=18, h=12, vx=-3)]
    frames = write_folder(tmp_path / "frames", 30, boxes)
    scene = new_scene(tmp_path / "sc", {"c0": frames}, tmp_path / "calib.json",
                      tmp_path / "ground.csv", fps=10, log=lambda s: None)
    assert scene.cameras["c0"].width == W and np.allclose(scene.cameras["c0"].P, cam.P)
    s = load_scene(tmp_path / "sc")
    assert s.video_path("c0") == tmp_path / "sc" / "video" / "c0" and s.fps == 10
    with pytest.raises(S2PError, match="--force"):
        new_scene(tmp_path / "sc", {"c0": frames}, tmp_path / "calib.json", tmp_path / "ground.csv")
    logs = []
    scene_masks_from_video(tmp_path / "sc", bg={"min_area": 40, "init_samples": 10},
                           tracker={"min_length": 5}, log=logs.append)
    t = read_mots(tmp_path / "sc" / "masks" / "c0.txt")
    assert sorted(set(t.track_id.tolist())) == [1, 2] and (t.class_id > 0).all()
    assert len(t) == 60 and any("c0: 30 frames -> 60 masks -> 2 tracks" in m for m in logs)
    with pytest.raises(S2PError, match="--force"):
        scene_masks_from_video(tmp_path / "sc", log=lambda s: None)
    # a detector's file for the same scene: tracked because it has no ids
    recs = [det(f, 3, rle(10 + 2 * f, 60, 10, 24)) for f in range(30)]
    (tmp_path / "d.json").write_text(json.dumps(recs))
    n = scene_import_detections(tmp_path / "sc", "c0", tmp_path / "d.json", force=True,
                                log=lambda s: None)
    t = read_mots(tmp_path / "sc" / "masks" / "c0.txt")
    assert n == 30 and set(t.track_id.tolist()) == {1} and set(t.class_id.tolist()) == {3}


def test_calibration_files(tmp_path):
    cam = calibration(tmp_path, with_size=True)
    frames = write_folder(tmp_path / "frames", 3, [])
    with pytest.raises(InputError, match=r"frames: frames are 160x120 pixels but the camera calibration is 170x120"):
        new_scene(tmp_path / "sc", {"c0": frames}, tmp_path / "calib.json", tmp_path / "ground.csv")
    (tmp_path / "P.txt").write_text("\n".join(" ".join(f"{v:.12g}" for v in row) for row in cam.P))
    got = read_calibration(tmp_path / "P.txt", {"cam": (W, H)})["cam"]
    assert np.allclose(got.K, cam.K) and np.allclose(got.R, cam.R) and np.allclose(got.t, cam.t)
    (tmp_path / "bad.txt").write_text("1 2 3")
    with pytest.raises(InputError, match=r"bad.txt: expected 12 finite numbers"):
        read_calibration(tmp_path / "bad.txt", {"cam": (W, H)})


def test_utocs_single_camera_finds_any_video(tmp_path):
    from video_fixtures import write_video

    from seg2pose.io.utocs import import_utocs

    src = tmp_path / "rec"
    (src / "positions").mkdir(parents=True)
    (src / "cameras.json").write_text(json.dumps({
        "instrinsics": {"f": 100.0, "Cx": W / 2, "Cy": H / 2},
        "cams": [{"id": 3, "x": -12.0, "y": 3.0, "z": 6.0, "pitch": -25.0, "roll": 0.0, "yaw": 20.0}]}))
    (src / "ground_points.txt").write_text(
        "\n".join(f"{x},{y},0" for x in range(-10, 11, 5) for y in range(-10, 11, 5)) + "\n")
    for frame in (40, 42, 44):
        (src / "positions" / f"{frame:06d}.json").write_text(json.dumps([
            {"type": "car", "id": 1, "x": 0.5 * frame, "y": 0.0, "z": 0.0, "l": 4.5, "w": 1.8,
             "h": 1.5, "forward_x": 1.0, "forward_y": 0.0}]))
    write_video(src / "vid.avi", 3, [])
    import_utocs(src, tmp_path / "sc", log=lambda *a: None)
    s = load_scene(tmp_path / "sc")
    assert s.video_path("cam3") == tmp_path / "sc" / "video" / "cam3.avi"
    assert s.extra["video_frames"] == {"cam3": {"first": 40, "step": 2}}
    from seg2pose.video.video_scene import camera_reader
    assert [f for f, _ in camera_reader(s, "cam3").frames()] == [40, 42, 44]
    write_video(src / "other.mp4", 2, [], fourcc="mp4v")
    with pytest.raises(InputError, match=r"several videos \(other.mp4, vid.avi\) and one camera"):
        import_utocs(src, tmp_path / "sc2", log=lambda *a: None)
