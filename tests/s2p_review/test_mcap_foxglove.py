"""What a Foxglove user sees in an MCAP export: display images with class colours over the
video, outlines on every frame a mask is shown, no false headings, real timestamps with the
frame recoverable, a file in log-time order front to back, and a layout that names topics the
file has. Also: run folders hold no absolute paths."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from review_fixtures import make_run, make_scene, video_rgb

from s2p_review import columns as C
from s2p_review import layout as L
from s2p_review.foxglove_layout import layout_topics
from s2p_review.mcap_export import ExportOptions, export_mcap
from seg2pose.io.mots import read_mots
from seg2pose.io.poses import read_poses, write_poses
from seg2pose.io.scene import load_scene

N_FRAMES = 12
START = "2021-06-14T08:00:00Z"
START_NS = 1623657600 * 10**9


@pytest.fixture(scope="module", autouse=True)
def _opencv_one_thread():
    """OpenCV on one thread in this module (its worker pool hangs processes forked later)."""
    from video_fixtures import single_threaded_opencv

    yield from single_threaded_opencv()



def _messages(path, topics=None) -> list:
    """(topic, log_time, data) of every message, in the file's order (a front-to-back read)."""
    from mcap.records import Channel, Message
    from mcap.stream_reader import StreamReader

    chans, out = {}, []
    with open(path, "rb") as f:
        for r in StreamReader(f).records:
            if isinstance(r, Channel):
                chans[r.id] = r.topic
            elif isinstance(r, Message) and (topics is None or chans[r.channel_id] in topics):
                out.append((chans[r.channel_id], r.log_time, r.data))
    return out


def _parse(cls, data):
    m = cls()
    m.ParseFromString(data)
    return m


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    root = tmp_path_factory.mktemp("fox")
    scene = make_scene(root / "scene", n_frames=N_FRAMES, video=True)
    d = json.loads((scene.root / "scene.json").read_text())
    d["start_time"] = START
    (scene.root / "scene.json").write_text(json.dumps(d))
    scene = load_scene(scene.root)
    run = make_run(scene, root / "scene" / "out" / "run-s2pn", method="seg2posenet", residual=0.2)
    t = read_poses(run / "poses.csv")
    t.heading[t.track_id == 4] = np.nan  # the pedestrian: heading unknown
    write_poses(run / "poses.csv", t)
    res = export_mcap(scene, run, root / "x.mcap", ExportOptions(mask_every=3, image_scale=0.5))
    return scene, run, res, root


def test_display_images_show_class_colours_over_video(exported):
    import cv2
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage

    scene, _, res, _ = exported
    msgs = _messages(res.path, {"/cameras/c0/display"})
    assert len(msgs) == 4  # frames 0, 3, 6, 9
    _, ns, data = msgs[2]
    f = (ns - START_NS) * scene.fps / 1e9
    assert abs(f - 6) < 1e-6
    img = cv2.imdecode(np.frombuffer(_parse(CompressedImage, data).data, np.uint8), 1)[..., ::-1]
    assert img.shape == (60, 80, 3)  # image_scale 0.5
    mt = read_mots(scene.masks_path("c0"), frame_range=(6, 6))
    cls = C.paint_masks(mt.rles, mt.class_id, np.zeros(len(mt), np.int64), 120, 160, 1)[0]
    small = cv2.resize(cls, (80, 60), interpolation=cv2.INTER_NEAREST)
    by_id = {c.id: np.array(L.class_color(c.name, c.id)) for c in scene.classes}
    video = np.array(video_rgb(6))
    # each pixel's nearest candidate: the video, or the video blended with a class colour
    cand = {0: video, **{k: 0.45 * video + 0.55 * c for k, c in by_id.items()}}
    keys = np.array(list(cand))
    near = keys[np.argmin(np.linalg.norm(img[:, :, None, :] - np.array(list(cand.values())),
                                         axis=3), axis=2)]
    present = np.unique(cls[cls > 0])
    assert len(present) == 3
    for cid in present:
        inner = cv2.erode((small == cid).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        assert inner.sum() >= 2
        assert np.mean(near[inner] == cid) > 0.7, (cid, np.mean(near[inner] == cid))
    far = cv2.dilate((small > 0).astype(np.uint8), np.ones((5, 5), np.uint8)) == 0
    assert np.abs(img[far].mean(axis=0) - video).max() < 12


def test_display_without_video_is_exact_rgb8(tmp_path):
    from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

    scene = make_scene(tmp_path / "s", n_frames=4, video=False)
    run = make_run(scene, tmp_path / "s" / "out" / "r")
    res = export_mcap(scene, run, tmp_path / "n.mcap", ExportOptions(cameras=["c1"]))
    msgs = _messages(res.path, {"/cameras/c1/display", "/cameras/c1/masks"})
    disp = [_parse(RawImage, d) for t, _, d in msgs if t.endswith("display")]
    ids = [_parse(RawImage, d) for t, _, d in msgs if t.endswith("masks")]
    assert len(disp) == len(ids) == 4 and disp[2].encoding == "rgb8" and ids[2].encoding == "mono16"
    img = np.frombuffer(disp[2].data, np.uint8).reshape(120, 160, 3)
    mt = read_mots(scene.masks_path("c1"), frame_range=(2, 2))
    cls = C.paint_masks(mt.rles, mt.class_id, np.zeros(len(mt), np.int64), 120, 160, 1)[0]
    lut = np.zeros((8, 3), np.uint8)
    for c in scene.classes:
        lut[c.id] = L.class_color(c.name, c.id)
    np.testing.assert_array_equal(img, lut[cls])
    # the lossless ids: track id + 1
    a = np.frombuffer(ids[2].data, "<u2").reshape(120, 160)
    assert set(np.unique(a)) == {0, *(mt.track_id + 1).tolist()}


def test_outlines_on_every_frame_a_mask_is_shown(exported):
    from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
    from foxglove_schemas_protobuf.PointsAnnotation_pb2 import PointsAnnotation

    scene, _, res, _ = exported
    ann = _messages(res.path, {"/cameras/c1/annotations"})
    assert len(ann) == N_FRAMES
    for f, (_, _, data) in enumerate(ann):
        shown = f - f % 3  # the mask frame a viewer shows at frame f
        loops = [p for p in _parse(ImageAnnotations, data).points
                 if p.type == PointsAnnotation.LINE_LOOP]
        mt = read_mots(scene.masks_path("c1"), frame_range=(shown, shown))
        assert len(loops) == len(mt), f"frame {f}: {len(loops)} outlines, {len(mt)} masks shown"
        for p in loops:  # in the half-size image
            xy = np.array([[q.x, q.y] for q in p.points])
            assert xy.max(axis=0)[0] <= 80.5 and xy.max(axis=0)[1] <= 60.5


def test_unknown_headings_have_no_orientation(exported):
    from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    _, run, res, _ = exported
    t = read_poses(run / "poses.csv")
    frame = 0
    for topic, data in [(t_, d) for t_, _, d in _messages(res.path, {"/road_users/poses",
                                                                      "/road_users/scene"})]:
        if topic == "/road_users/poses":
            # the car and the bicyclist, each with its own heading; not the pedestrian
            ft = t.take((t.frame == frame) & np.isfinite(t.heading))
            poses = _parse(PosesInFrame, data).poses
            got = np.array([[p.position.x, p.position.y, 2 * np.arctan2(p.orientation.z, p.orientation.w)]
                            for p in poses])
            np.testing.assert_allclose(got, np.c_[ft.xyz[:, :2], ft.heading], atol=1e-9)
            assert len(poses) == 2
            frame += 1
            continue
        ents = {e.id: e for e in _parse(SceneUpdate, data).entities}
        ped = ents["4"]
        meta = {kv.key: kv.value for kv in ped.metadata}
        assert meta == {"track_id": "4", "class": "pedestrian", "heading": "unknown"}
        assert len(ped.cubes) == 0 and len(ped.cylinders) == 1
        car = ents["12"]
        assert len(car.cubes) == 1 and {kv.key: kv.value for kv in car.metadata}["heading"] == "0.0"
    assert frame == N_FRAMES


def test_log_times_monotonic_over_the_whole_file_and_real(exported):
    scene, _, res, _ = exported
    msgs = _messages(res.path)
    times = np.array([ns for _, ns, _ in msgs])
    assert np.all(np.diff(times) >= 0)
    assert times[0] == START_NS and times[-1] == START_NS + round((N_FRAMES - 1) * 1e9 / scene.fps)
    from mcap.reader import make_reader

    with open(res.path, "rb") as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}["s2p"]
    assert int(meta["start_ns"]) == START_NS and meta["start_time"] == START
    # the frame number of every JSON message follows from its log time
    fps = float(meta["fps"])
    for topic, ns, data in msgs:
        if topic.startswith("/s2p/"):
            assert json.loads(data)["frame"] == round((ns - START_NS) * fps / 1e9)


def test_layout_names_topics_in_the_file(exported):
    scene, _, res, _ = exported
    assert res.layout.name == "x.layout.json"
    doc = json.loads(res.layout.read_text())
    have = {t for t, _, _ in _messages(res.path)}
    named = layout_topics(doc)
    assert named <= have, named - have
    images = [c["imageMode"] for c in doc["configById"].values() if "imageMode" in c]
    assert sorted(i["imageTopic"] for i in images) == ["/cameras/c0/display", "/cameras/c1/display"]
    assert all(list(i["annotations"]) == [i["imageTopic"].replace("display", "annotations")]
               for i in images)
    plots = [c for c in doc["configById"].values() if "paths" in c]
    assert [p["value"] for p in plots[0]["paths"]] == [
        "/s2p/errors.mean", "/s2p/errors.pedestrian", "/s2p/errors.bicyclist", "/s2p/errors.car"]
    errs = [json.loads(d) for t, _, d in _messages(res.path, {"/s2p/errors"})]
    assert len(errs) == N_FRAMES and abs(errs[0]["car"] - np.hypot(0.3, 0.4)) < 1e-9


def _strings(obj):
    if isinstance(obj, dict):
        for v in obj.values():
            yield from _strings(v)
    elif isinstance(obj, list):
        for v in obj:
            yield from _strings(v)
    elif isinstance(obj, str):
        yield obj


def test_run_json_has_no_absolute_paths(tmp_path):
    """``s2p run`` writes paths relative to the run folder; the export carries that file."""
    from seg2pose.method.pipeline import RunOptions, run_scene

    scene = make_scene(tmp_path / "scene", n_frames=4)
    run = run_scene(scene, tmp_path / "scene" / "out" / "base", RunOptions(config="stereo", baseline=True,
                    progress=False))
    meta = json.loads((run / "run.json").read_text())
    assert not [s for s in _strings(meta) if os.path.isabs(s) or str(tmp_path) in s]
    assert (run / meta["scene"]).resolve() == scene.root.resolve()
    res = export_mcap(scene, run, tmp_path / "r.mcap")
    from s2p_review.mcap_import import read_mcap_records

    att = json.loads(read_mcap_records(res.path).attachments["run.json"])
    assert not [s for s in _strings(att) if os.path.isabs(s)]
