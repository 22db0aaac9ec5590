"""MCAP export / import: exact round trip, Foxglove schemas, Rerun's own MCAP reader."""

from __future__ import annotations

import json
from collections import defaultdict

import numpy as np
import pytest
from review_fixtures import make_run, make_scene
from typer.testing import CliRunner

from s2p_review.mcap_export import ExportOptions, export_mcap
from s2p_review.mcap_import import import_mcap, read_mcap_records
from seg2pose.core.errors import InputError, S2PError
from seg2pose.io.poses import PoseTable, read_poses, write_poses

N_FRAMES = 12


@pytest.fixture(scope="module", autouse=True)
def _opencv_one_thread():
    """OpenCV on one thread in this module (its worker pool hangs processes forked later)."""
    from video_fixtures import single_threaded_opencv

    yield from single_threaded_opencv()



@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    root = tmp_path_factory.mktemp("mcap")
    scene = make_scene(root / "scene", n_frames=N_FRAMES, video=True)
    run = make_run(scene, root / "scene" / "out" / "run-s2pn", method="seg2posenet", residual=0.25)
    # exercise NaN headings and sizes in the lossless channel
    t = read_poses(run / "poses.csv")
    t.heading[:3] = np.nan
    t.size[4] = [np.nan, 1.0, 2.0]
    write_poses(run / "poses.csv", t)
    out = export_mcap(scene, run, root / "x.mcap").path
    return scene, run, out, root


def test_round_trip_is_exact(exported):
    scene, run, out, root = exported
    run_dir = import_mcap(out, root / "restored")
    assert run_dir == root / "restored" / "out" / "run-s2pn"
    assert (root / "restored" / "scene.json").read_bytes() == (scene.root / "scene.json").read_bytes()
    assert (root / "restored" / "ground_points.csv").read_bytes() == \
        (scene.root / "ground_points.csv").read_bytes()
    assert (run_dir / "poses.csv").read_bytes() == (run / "poses.csv").read_bytes()
    a, b = read_poses(run / "poses.csv"), read_poses(run_dir / "poses.csv")
    for col in ("frame", "track_id", "cls", "xyz", "heading", "size"):
        np.testing.assert_array_equal(getattr(a, col), getattr(b, col))
    assert json.loads((run_dir / "run.json").read_text())["method"] == "seg2posenet"
    # the views come back value for value
    from seg2pose.io.run import read_views

    va, vb = read_views(run / "views.csv"), read_views(run_dir / "views.csv")
    for col in ("frame", "track_id", "camera", "cls", "uv", "normal", "residual"):
        np.testing.assert_array_equal(getattr(va, col), getattr(vb, col))
    # the restored folder is a scene folder again
    from seg2pose.io.scene import load_scene

    s2 = load_scene(root / "restored")
    assert s2.fingerprint() == scene.fingerprint()


def test_foxglove_channels(exported):
    from mcap.reader import make_reader

    scene, run, out, _ = exported
    schemas, counts = {}, defaultdict(int)
    with open(out, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        for ch in summary.channels.values():
            schemas[ch.topic] = summary.schemas[ch.schema_id].name
        for _s, ch, _m in reader.iter_messages():
            counts[ch.topic] += 1
    want = {"/cameras/c0/calibration": "foxglove.CameraCalibration",
            "/cameras/c0/transform": "foxglove.FrameTransform",
            "/cameras/c0/masks": "foxglove.RawImage",
            "/cameras/c0/image": "foxglove.CompressedImage",
            "/cameras/c0/annotations": "foxglove.ImageAnnotations",
            "/road_users/poses": "foxglove.PosesInFrame",
            "/road_users/scene": "foxglove.SceneUpdate",
            "/gt/scene": "foxglove.SceneUpdate",
            "/s2p/poses": "s2p.PoseFrame", "/s2p/views": "s2p.ViewFrame"}
    for topic, name in want.items():
        assert schemas.get(topic) == name, topic
    assert counts["/road_users/poses"] == N_FRAMES and counts["/s2p/poses"] == N_FRAMES
    assert counts["/cameras/c1/masks"] == N_FRAMES and counts["/cameras/c1/image"] == N_FRAMES


def test_mask_image_holds_track_ids(exported):
    from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
    from mcap.reader import make_reader

    from seg2pose.io.mots import read_mots
    from seg2pose.structures.masks import decode

    scene, _, out, _ = exported
    with open(out, "rb") as f:
        msgs = [m for _s, _c, m in make_reader(f).iter_messages(topics=["/cameras/c0/masks"])]
    img = RawImage()
    img.ParseFromString(msgs[3].data)
    assert img.encoding == "mono16"
    a = np.frombuffer(img.data, "<u2").reshape(img.height, img.width)
    mt = read_mots(scene.masks_path("c0"), frame_range=(3, 3))
    want = np.zeros_like(a)
    for r, t in zip(mt.rles, mt.track_id):
        want[decode(r, mt.height, mt.width) > 0] = t + 1
    np.testing.assert_array_equal(a, want)


def test_rerun_mcap_reader_decodes(exported):
    import rerun.chunk as rc

    _, _, out, _ = exported
    comps = defaultdict(set)
    rows = defaultdict(int)
    for ch in rc.McapReader(out).stream():
        if ch.is_static:
            continue
        rows[ch.entity_path] += ch.num_rows
        for n in ch.to_record_batch().schema.names:
            comps[ch.entity_path].add(n.split(":")[0])
    for cam in ("c0", "c1"):
        assert "Pinhole" in comps[f"/cameras/{cam}/calibration"]
        assert "Transform3D" in comps[f"/cameras/{cam}/transform"]
        assert "Image" in comps[f"/cameras/{cam}/masks"]
        assert "EncodedImage" in comps[f"/cameras/{cam}/image"]
        assert rows[f"/cameras/{cam}/masks"] == N_FRAMES
    assert "InstancePoses3D" in comps["/road_users/poses"]
    assert rows["/road_users/poses"] == N_FRAMES


def test_transform_and_calibration_values(exported):
    """The world->camera transform maps the camera centre and axes (optical frame) correctly."""
    from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
    from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
    from mcap.reader import make_reader
    from scipy.spatial.transform import Rotation

    scene, _, out, _ = exported
    with open(out, "rb") as f:
        it = make_reader(f).iter_messages(topics=["/cameras/c1/transform", "/cameras/c1/calibration"])
        got = {c.topic: m.data for _s, c, m in it}
    tf = FrameTransform()
    tf.ParseFromString(got["/cameras/c1/transform"])
    cal = CameraCalibration()
    cal.ParseFromString(got["/cameras/c1/calibration"])
    cam = scene.cameras["c1"]
    np.testing.assert_allclose([tf.translation.x, tf.translation.y, tf.translation.z], cam.center)
    q = [tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w]
    np.testing.assert_allclose(Rotation.from_quat(q).as_matrix(), cam.R.T, atol=1e-9)
    np.testing.assert_allclose(np.reshape(cal.K, (3, 3)), cam.K)
    assert (cal.width, cal.height) == (cam.width, cam.height)


def test_existing_outputs_refused(exported):
    scene, run, out, root = exported
    with pytest.raises(S2PError, match="--force"):
        export_mcap(scene, run, out)
    d = root / "occupied"
    d.mkdir()
    (d / "mine.txt").write_text("x")
    with pytest.raises(S2PError, match="--force"):
        import_mcap(out, d)
    import_mcap(out, d, force=True)
    assert (d / "mine.txt").read_text() == "x" and (d / "scene.json").exists()


def test_bad_mcap_files(tmp_path):
    p = tmp_path / "bad.mcap"
    p.write_bytes(b"nonsense")
    with pytest.raises(InputError, match="bad.mcap.*not a readable MCAP"):
        import_mcap(p, tmp_path / "o")
    assert not (tmp_path / "o").exists()
    with pytest.raises(InputError, match="not found"):
        read_mcap_records(tmp_path / "missing.mcap")


def test_mcap_without_scene_attachment(tmp_path):
    from mcap.writer import Writer

    p = tmp_path / "other.mcap"
    with open(p, "wb") as f:
        w = Writer(f)
        w.start()
        w.finish()
    with pytest.raises(InputError, match="scene.json"):
        import_mcap(p, tmp_path / "o")


def test_export_rejects_mismatched_run(exported):
    scene, _, _, root = exported
    bad = make_run(scene, root / "badrun", frame_shift=50)
    with pytest.raises(InputError, match="frame"):
        export_mcap(scene, bad, root / "bad.mcap")
    assert not (root / "bad.mcap").exists()


def test_cli_export_import(exported):
    from seg2pose.cli import app

    scene, run, _, root = exported
    runner = CliRunner()
    out = root / "cli.mcap"
    r = runner.invoke(app, ["export", str(scene.root), "--run", str(run), "-o", str(out),
                            "--frames", "2:5", "--mask-every", "2"])
    assert r.exit_code == 0, r.output
    r = runner.invoke(app, ["import-mcap", str(out), "-o", str(root / "cli-restored")])
    assert r.exit_code == 0, r.output
    t = read_poses(root / "cli-restored" / "out" / "run-s2pn" / "poses.csv")
    assert set(t.frame.tolist()) == {2, 3, 4, 5}
    full = read_poses(run / "poses.csv").in_frames((2, 5))
    np.testing.assert_array_equal(t.xyz, full.xyz)


def test_empty_pose_table_round_trip(exported, tmp_path):
    """A run that found nobody (header-only poses.csv, no views) exports and imports back to
    the same files, and the frames asked for are still there for the viewers."""
    import shutil

    scene, run, _, _ = exported
    empty = tmp_path / "run-empty"
    shutil.copytree(run, empty)
    (empty / "views.csv").unlink()
    write_poses(empty / "poses.csv", PoseTable.empty(with_size=True))
    res = export_mcap(scene, empty, tmp_path / "e.mcap", ExportOptions(frames=(2, 4)))
    rec = read_mcap_records(res.path)
    assert rec.poses == [] and rec.views == [] and rec.metadata["s2p"]["has_views"] == "false"
    back = import_mcap(res.path, tmp_path / "restored")
    assert (back / "poses.csv").read_bytes() == (empty / "poses.csv").read_bytes()
    assert not (back / "views.csv").exists()
    t = read_poses(back / "poses.csv")
    assert len(t) == 0 and t.size is not None
    from mcap.reader import make_reader

    with open(res.path, "rb") as f:
        topics = [c.topic for _s, c, _m in make_reader(f).iter_messages(topics=["/cameras/c0/masks"])]
    assert len(topics) == 3  # frames 2, 3, 4


def test_image_annotations_outline_masks(exported):
    from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
    from foxglove_schemas_protobuf.PointsAnnotation_pb2 import PointsAnnotation
    from mcap.reader import make_reader

    from seg2pose.io.mots import read_mots
    from seg2pose.structures.masks import rle_stats

    scene, _, out, _ = exported
    with open(out, "rb") as f:
        msgs = [m for _s, _c, m in make_reader(f).iter_messages(topics=["/cameras/c1/annotations"])]
    ann = ImageAnnotations()
    ann.ParseFromString(msgs[6].data)
    loops = [p for p in ann.points if p.type == PointsAnnotation.LINE_LOOP]
    lists = [p for p in ann.points if p.type == PointsAnnotation.LINE_LIST]
    mt = read_mots(scene.masks_path("c1"), frame_range=(6, 6))
    assert len(loops) == len(mt) and len(lists) == 3
    assert all(len(p.points) == 24 for p in lists)  # 12 edges
    from seg2pose.io.run import read_views

    v = read_views(exported[1] / "views.csv")
    sel = (v.frame == 6) & (v.camera == "c1")
    pts = [p for p in ann.points if p.type == PointsAnnotation.POINTS]
    got = sorted((p.points[0].x, p.points[0].y) for p in pts)
    np.testing.assert_allclose(got, sorted(map(tuple, v.uv[sel])))
    boxes = rle_stats(mt.rles, mt.height, mt.width)[2]
    for p, b in zip(loops, boxes):
        xy = np.array([[q.x, q.y] for q in p.points])
        assert len(xy) >= 3
        assert (xy[:, 0] >= b[0]).all() and (xy[:, 0] <= b[2]).all()
        assert (xy[:, 1] >= b[1]).all() and (xy[:, 1] <= b[3]).all()
