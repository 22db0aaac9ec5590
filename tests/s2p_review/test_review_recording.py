"""Review recordings without a viewer: the .rrd read back with rerun.chunk (entities, row
counts, values), mask cadence, video frames, runs told apart."""

from __future__ import annotations

import io
from collections import Counter

import numpy as np
import pytest
from review_fixtures import CLASS_ID, EST_OFFSET, N_FRAMES, NO_IMAGES, TRACKS, review_scene, rrd_rows
from video_fixtures import single_threaded_opencv

from s2p_review import layout as L
from s2p_review.recording import LogStyle
from s2p_review.session import RecordOptions, record
from seg2pose.io.mots import read_mots
from seg2pose.structures.masks import decode

_opencv_one_thread = pytest.fixture(scope="module", autouse=True)(single_threaded_opencv)
tiny = pytest.fixture(scope="module")(review_scene)



# --- the recording, read back ------------------------------------------------------------------------

def test_rrd_holds_expected_entities_and_rows(tiny):
    scene, base, s2pn, root = tiny
    out = record(scene, [base, s2pn], root / "rec.rrd").rrd
    assert out == root / "rec.rrd" and out.stat().st_size > 0
    rows, comps, bps = rrd_rows(out)
    assert len(bps) == 1  # the blueprint travels with the recording
    n = N_FRAMES
    for cam in ("c0", "c1"):
        p = f"/world/cameras/{cam}"
        for sub in ("masks", "image", "gt", "poses/run-base", "poses/run-s2pn",
                    "normal/run-base", "normal/run-s2pn"):
            assert rows[f"{p}/{sub}"] == n, sub
        assert (p, "Pinhole:image_from_camera") in comps and (p, "Transform3D:translation") in comps
        assert rows[f"/world/estimates/run-s2pn/{cam}"] == n
        assert rows[f"/world/estimates/run-s2pn/{cam}/residuals"] == n
        assert f"/world/estimates/run-base/{cam}/residuals" not in rows  # baseline: no residuals
    for r in ("run-base", "run-s2pn"):
        for tid in TRACKS:  # one entity per road user, on every frame it is seen
            assert rows[f"/world/road_users/{r}/{tid}"] == n
            assert rows[f"/world/road_users/{r}/{tid}/trail"] == n - 1  # a step per frame after its first
            assert rows[f"/metrics/road_users/{r}/error/{tid}"] == n
        for k in ("mean", "car", "pedestrian", "bicyclist"):
            assert rows[f"/metrics/error/{r}/{k}"] == n
    assert rows["/world/gt"] == n
    assert ("/world/ground/mesh", "Mesh3D:vertex_positions") in comps
    assert ("/", "AnnotationContext:context") in comps


def test_rrd_values(tiny):
    """Spot values: the car's box at frame 5 and the error series (all equal to the offset)."""
    import rerun.chunk as rc

    scene, base, _, root = tiny
    out = record(scene, [base], root / "values.rrd", NO_IMAGES).rrd
    boxes, errors, masks = None, None, []
    for ch in rc.RrdReader(out).stream():
        if ch.entity_path == "/world/road_users/run-base/12" and not ch.is_static:
            boxes = ch.to_record_batch()
        if ch.entity_path == "/metrics/error/run-base/mean" and not ch.is_static:
            errors = ch.to_record_batch()
        if ch.entity_path.endswith("/masks"):
            masks.append(ch)
    assert not masks
    frames = boxes.column("frame").to_pylist()
    i = frames.index(5)
    centers = np.array(boxes.column("Boxes3D:centers").to_pylist()[i])
    assert boxes.column("Boxes3D:class_ids").to_pylist()[i] == [CLASS_ID["car"]]
    k = 0
    x = TRACKS[12][1][0] + 5 * TRACKS[12][2][0] + EST_OFFSET[0]
    np.testing.assert_allclose(centers[k, 0], x, atol=1e-5)
    err = np.array([v[0] for v in errors.column("Scalars:scalars").to_pylist()])
    np.testing.assert_allclose(err, np.hypot(*EST_OFFSET[:2]), atol=1e-9)


def test_rrd_masks_hold_class_ids(tiny):
    import rerun.chunk as rc

    scene, base, _, root = tiny
    out = record(scene, [base], root / "masks.rrd",
                 RecordOptions(frames=(3, 6), cameras=["c1"], style=LogStyle(video=False))).rrd
    buf = None
    for ch in rc.RrdReader(out).stream():
        if ch.entity_path == "/world/cameras/c1/masks" and not ch.is_static:
            buf = ch.to_record_batch()
    assert buf.column("frame").to_pylist() == [3, 4, 5, 6]
    img = np.array(buf.column("SegmentationImage:buffer").to_pylist()[1][0], np.uint8)
    cam = scene.cameras["c1"]
    img = img.reshape(cam.height, cam.width)
    mt = read_mots(scene.masks_path("c1"), frame_range=(4, 4))
    want = np.zeros_like(img)
    for r, c in zip(mt.rles, mt.class_id):
        want[decode(r, mt.height, mt.width) > 0] = c
    np.testing.assert_array_equal(img, want)
    assert set(np.unique(img)) <= {0, *CLASS_ID.values()}


def test_mask_cadence(tiny):
    """Filled masks on the cadence and blank between (never a stale mask); outlines and (as a
    video asset) the video on every frame; JPEG video on its own cadence."""
    import rerun.chunk as rc

    scene, base, _, root = tiny
    for fmt, image_rows in (("jpeg", 2), ("asset", N_FRAMES)):
        out = record(scene, [base], root / f"cad-{fmt}.rrd", RecordOptions(
            mask_every=5, video_every=10, style=LogStyle(video_format=fmt))).rrd
        rows, fills, cleared = Counter(), [], []
        for ch in rc.RrdReader(out).stream():
            if ch.is_static:
                continue
            b = ch.to_record_batch()
            rows[ch.entity_path] += ch.num_rows
            if ch.entity_path == "/world/cameras/c0/masks":
                names = b.schema.names
                (fills if "SegmentationImage:buffer" in names else cleared).extend(
                    b.column("frame").to_pylist())
        assert sorted(fills) == [0, 5, 10, 15]
        assert sorted(cleared) == [f for f in range(N_FRAMES) if f % 5]
        assert rows["/world/cameras/c0/masks/outlines"] == N_FRAMES
        assert rows["/world/cameras/c0/image"] == image_rows, fmt


def test_video_asset_shows_every_frame_as_that_frame(tiny, tmp_path):
    """The viewer's video asset: each scene frame refers to a video frame that shows that
    frame's number (a video whose frames carry a visible frame code)."""
    import shutil

    import av
    import rerun.chunk as rc

    from s2p_review.frame_code import read_code, write_code_video
    from seg2pose.io.scene import load_scene

    scene, base, _, _ = tiny
    copy = tmp_path / "scene"
    shutil.copytree(scene.root, copy, ignore=shutil.ignore_patterns("out"))
    cam = scene.cameras["c0"]
    write_code_video(copy / "video" / "c0.mp4", cam.width, cam.height, N_FRAMES)
    out = record(load_scene(copy), [base], tmp_path / "asset.rrd",
                 RecordOptions(cameras=["c0"], style=LogStyle(masks=False))).rrd
    blob = refs = None
    for ch in rc.RrdReader(out).stream():
        if ch.entity_path != "/world/cameras/c0/image":
            continue
        b = ch.to_record_batch()
        if ch.is_static and "AssetVideo:blob" in b.schema.names:
            blob = bytes(b.column("AssetVideo:blob").to_pylist()[0][0])
        elif not ch.is_static:
            refs = dict(zip(b.column("frame").to_pylist(),
                            [v[0] for v in b.column("VideoFrameReference:timestamp").to_pylist()]))
    assert blob is not None and sorted(refs) == list(range(N_FRAMES))
    with av.open(io.BytesIO(blob)) as c:
        st = c.streams.video[0]
        decoded = {int(round(fr.pts * st.time_base * 1e9)): fr.to_ndarray(format="gray")
                   for fr in c.decode(st)}
    for f in range(N_FRAMES):
        img = decoded[refs[f]]
        assert read_code(lambda u, v: img[int(v * img.shape[0]), int(u * img.shape[1])]) == f


def test_mask_outlines_known_square(tmp_path):
    from pycocotools import mask as cm

    from s2p_review import imagery
    from seg2pose.io.mots import MaskTable

    m = np.zeros((40, 60), np.uint8, order="F")
    m[10:20, 5:25] = 1
    rle = cm.encode(m)["counts"]
    t = MaskTable(np.array([0]), np.array([3]), np.array([1]), 40, 60, [rle])
    polys, owner = imagery.outlines(t, tmp_path / "m.txt")
    assert owner.tolist() == [0] and len(polys) == 1
    p = polys[0]
    assert (p[0] == p[-1]).all()  # closed
    assert p[:, 0].min() == 5.5 and p[:, 0].max() == 24.5
    assert p[:, 1].min() == 10.5 and p[:, 1].max() == 19.5


def test_auto_cadence(tiny):
    from s2p_review.selection import auto_every, resolve_cadence

    scene = tiny[0]
    px = 160 * 120 * 2
    assert auto_every(1000, ["c0", "c1"], scene, budget_px=px * 100) == 10
    assert auto_every(1000, ["c0", "c1"], scene, budget_px=px * 1000) == 1
    assert auto_every(1001, ["c0"], scene, budget_px=px / 2 * 100) == 11
    cad = resolve_cadence(scene, 0, 19, ["c0", "c1"])
    assert (cad.masks, cad.video, cad.notes()) == (1, 1, [])
    # 20 frames of 2 x 160x120 px = 768000 px; a budget of 100000 px gives one frame in 8
    cad = resolve_cadence(scene, 0, 19, ["c0", "c1"], video_every=3, budget_px=1e5)
    assert (cad.masks, cad.video, cad.reduced) == (8, 3, ("masks",))


def test_short_video_is_noted(tiny, tmp_path):
    import shutil

    import cv2

    from seg2pose.io.scene import load_scene

    scene, base, _, _ = tiny
    copy = tmp_path / "scene"
    shutil.copytree(scene.root, copy, ignore=shutil.ignore_patterns("out"))
    vw = cv2.VideoWriter(str(copy / "video" / "c1.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 10, (160, 120))
    for _ in range(5):
        vw.write(np.zeros((120, 160, 3), np.uint8))
    vw.release()
    res = record(load_scene(copy), [base], tmp_path / "v.rrd", RecordOptions(mask_every=1, video_every=1))
    assert any("c1" in n and "only 5 of the 20" in n for n in res.notes), res.notes


def test_views_without_normal_position_are_left_out_in_3d(tiny, tmp_path):
    import shutil

    import rerun.chunk as rc

    scene, _, s2pn, _ = tiny
    run = tmp_path / "run-nan"
    shutil.copytree(s2pn, run)
    lines = (run / "views.csv").read_text().splitlines()
    parts = lines[1].split(",")  # frame 0, camera c0
    parts[6:9] = ["nan", "nan", "nan"]
    lines[1] = ",".join(parts)
    (run / "views.csv").write_text("\n".join(lines) + "\n")
    out = record(scene, [run], tmp_path / "n.rrd",
                 RecordOptions(frames=(0, 1), style=LogStyle(masks=False, video=False))).rrd
    pts = arrows = None
    for ch in rc.RrdReader(out).stream():
        if ch.entity_path == "/world/estimates/run-nan/c0" and not ch.is_static:
            pts = ch.to_record_batch().column("Points3D:positions").to_pylist()
        if ch.entity_path == "/world/estimates/run-nan/c0/residuals" and not ch.is_static:
            arrows = ch.to_record_batch().column("Arrows3D:origins").to_pylist()
    assert [len(p) for p in pts] == [2, 3] and [len(a) for a in arrows] == [2, 3]
    assert np.isfinite(np.array(pts[0])).all()


def test_runs_tell_apart_and_labels_are_not_drawn(tiny):
    """The baseline's boxes are hollow and pale, Seg2PoseNet's solid in the class colours (each
    run's look is its annotation context, over its road users' class ids); box labels are data
    (hover, selection), never drawn over each other (the 3D view's default)."""
    import rerun as rr
    import rerun.chunk as rc

    scene, base, s2pn, root = tiny
    out = record(scene, [base, s2pn], root / "looks.rrd", NO_IMAGES).rrd
    context, fills = {}, {}
    reader = rc.RrdReader(out)
    for ch in reader.stream():
        b = ch.to_record_batch()
        for run in ("run-base", "run-s2pn"):
            if ch.entity_path == f"/world/road_users/{run}" and ch.is_static:
                infos = b.column("AnnotationContext:context").to_pylist()[0][0]
                context[run] = {d["class_description"]["info"]["label"]: d["class_description"]["info"]["color"]
                                for d in infos}
            if ch.entity_path == f"/world/road_users/{run}/12" and not ch.is_static:  # the car
                fills[run] = b.column("Boxes3D:fill_mode").to_pylist() if "Boxes3D:fill_mode" in b.schema.names \
                    else None
    defaults = {}
    for ch in reader.stream(store=reader.blueprints()[0]):
        if ch.entity_path.endswith("/defaults"):
            b = ch.to_record_batch()
            defaults |= {n: b.column(n).to_pylist()[0] for n in b.schema.names if ":" in n}
    # neither boxes nor trails draw their class names over the scene
    assert defaults["Boxes3D:show_labels"] == defaults["LineStrips3D:show_labels"] == [False]
    solid, wire = rr.components.FillMode.Solid.value, rr.components.FillMode.MajorWireframe.value
    assert defaults["Boxes3D:fill_mode"] == [solid] and fills["run-s2pn"] is None  # the default
    assert {tuple(v) for v in fills["run-base"]} == {(wire,)}  # the baseline's, in its rows
    rgba = lambda c: np.array([(c >> 24) & 255, (c >> 16) & 255, (c >> 8) & 255, c & 255])  # noqa: E731
    car = np.array(L.class_color("car"))
    b, s = rgba(context["run-base"]["car"]), rgba(context["run-s2pn"]["car"])
    assert (s[:3] == car).all() and s[3] == L.RUN_LOOKS["model"]["alpha"] and not (b[:3] == car).all()
    # the baseline is 40 % of the way to grey: less saturated than Seg2PoseNet's colours
    sat = lambda c: c[:3].max() - c[:3].min()  # noqa: E731
    assert abs(sat(b) - 0.6 * sat(s)) <= 1.0  # saturation scales by 1 - 0.4


def test_video_stored_small_is_shown_at_camera_size(tiny):
    """--image-scale 0.5: JPEGs of half the camera's size, scaled back by the image entity's
    transform so that they cover the camera's whole image."""
    import cv2
    import rerun.chunk as rc

    scene, base, _, root = tiny
    out = record(scene, [base], root / "small.rrd",
                 RecordOptions(cameras=["c0"], style=LogStyle(masks=False, image_scale=0.5,
                                                              video_format="jpeg"))).rrd
    scale = blob = None
    for ch in rc.RrdReader(out).stream():
        if ch.entity_path != "/world/cameras/c0/image":
            continue
        b = ch.to_record_batch()
        if ch.is_static:
            scale = b.column("Transform3D:scale").to_pylist()[0][0]
        else:
            blob = bytes(b.column("EncodedImage:blob").to_pylist()[0][0])
    img = cv2.imdecode(np.frombuffer(blob, np.uint8), 1)
    assert img.shape[:2] == (60, 80)
    assert scale == [2.0, 2.0, 1.0]
