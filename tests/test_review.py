"""Review recordings without a viewer: column builders with known answers, run checks, the
.rrd read back with rerun.chunk (entities and row counts), bad input, the CLI."""

from __future__ import annotations

import io
import json
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from seg2pose.errors import InputError, S2PError
from seg2pose.io.mots import read_mots
from seg2pose.masks import decode, encode
from s2p_review import columns as C
from s2p_review import layout as L
from seg2pose.cli.common import parse_frames
from seg2pose.io.run import read_views
from s2p_review.recording import LogStyle
from s2p_review.runs import load_run, scene_last_frame
from s2p_review.session import RecordOptions, Targets, record

from review_fixtures import CLASS_ID, EST_OFFSET, TRACKS, make_run, make_scene

N_FRAMES = 20
NO_IMAGES = RecordOptions(style=LogStyle(masks=False, video=False))


@pytest.fixture(scope="module", autouse=True)
def _opencv_one_thread():
    """OpenCV on one thread in this module (its worker pool hangs processes forked later)."""
    from video_fixtures import single_threaded_opencv

    yield from single_threaded_opencv()



@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    root = tmp_path_factory.mktemp("review")
    scene = make_scene(root / "scene", n_frames=N_FRAMES, video=True)
    base = make_run(scene, root / "scene" / "out" / "run-base")
    s2pn = make_run(scene, root / "scene" / "out" / "run-s2pn", method="seg2posenet", residual=0.2)
    return scene, base, s2pn, root


# --- column builders ------------------------------------------------------------------------------
@settings(max_examples=25, deadline=None)
@given(st.integers(1, 4), st.integers(0, 2**31 - 1))
def test_paint_masks_matches_pycocotools(n, seed):
    rng = np.random.default_rng(seed)
    h, w = 13, 17
    masks = rng.random((n, h, w)) < 0.3
    rles = [encode(m) for m in masks]
    vals = np.arange(1, n + 1)
    img = C.paint_masks(rles, vals, np.zeros(n, np.int64), h, w, 1)[0]
    want = np.zeros((h, w), np.uint8)
    for m, v in zip(masks, vals):  # later masks over earlier ones
        want[m] = v
    np.testing.assert_array_equal(img, want)


def test_paint_masks_slots_and_uint16():
    m = np.zeros((4, 5), np.uint8)
    m[1:3, 2:4] = 1
    rle = encode(m)
    out = C.paint_masks([rle, rle], np.array([300, 7]), np.array([2, 0]), 4, 5, 3, dtype=np.uint16)
    assert out.shape == (3, 4, 5) and out.dtype == np.uint16
    np.testing.assert_array_equal(out[2], m.astype(np.uint16) * 300)
    np.testing.assert_array_equal(out[0], m * 7)
    assert not out[1].any()


def test_box_columns_known_answer():
    f = C.box_columns(np.array([[1.0, 2.0, 0.5]]), np.array([np.pi / 2]), np.array([[4.0, 2.0, 1.5]]))
    np.testing.assert_allclose(f["centers"], [[1.0, 2.0, 1.25]])
    np.testing.assert_allclose(f["half_sizes"], [[2.0, 1.0, 0.75]])
    np.testing.assert_allclose(f["quaternions"], [[0, 0, np.sqrt(0.5), np.sqrt(0.5)]], atol=1e-12)


def test_box_corners_heading_turns_length_axis():
    c = C.box_corners(np.zeros((1, 3)), np.array([np.pi / 2]), np.array([[4.0, 2.0, 1.0]]))[0]
    # heading 90 degrees: the 4 m length lies along y, the 2 m width along x
    np.testing.assert_allclose(np.ptp(c[:, 0]), 2.0, atol=1e-12)
    np.testing.assert_allclose(np.ptp(c[:, 1]), 4.0, atol=1e-12)
    np.testing.assert_allclose(sorted(set(np.round(c[:, 2], 9))), [0.0, 1.0])


def test_frame_lengths_and_trails():
    frame = np.array([0, 0, 1, 3, 3, 3])
    np.testing.assert_array_equal(C.frame_lengths(frame, 0, 4), [2, 1, 0, 3, 0])
    tid = np.array([1, 2, 1, 1, 2, 5])
    xyz = np.arange(18, dtype=float).reshape(6, 3)
    strips = C.trail_strips(tid, frame, xyz, length=2)
    assert [len(s) for s in strips] == [1, 1, 2, 2, 2, 1]
    np.testing.assert_array_equal(strips[3], xyz[[2, 3]])  # track 1: frames 1, 3
    np.testing.assert_array_equal(strips[4], xyz[[1, 4]])  # track 2: frames 0, 3


def test_projected_edges_hit_mask(tiny):
    """The projected box of a road user lies on its mask: the edge segments' bounding box
    matches the mask's bounding box within a pixel or two."""
    scene = tiny[0]
    from seg2pose.io.poses import read_poses

    gt = read_poses(scene.gt_path)
    cam = scene.cameras["c0"]
    sel = np.flatnonzero((gt.frame == 5) & (gt.track_id == 12))
    segs, idx = C.projected_edges(cam, gt.xyz[sel], gt.heading[sel], gt.size[sel])
    assert segs.shape == (12, 2, 2) and list(idx) == [0]
    mt = read_mots(scene.masks_path("c0"))
    k = np.flatnonzero((mt.frame == 5) & (mt.track_id == 12))[0]
    ys, xs = np.nonzero(decode(mt.rles[k], mt.height, mt.width))
    pts = segs.reshape(-1, 2)
    np.testing.assert_allclose([pts[:, 0].min(), pts[:, 1].min()], [xs.min(), ys.min()], atol=2)
    np.testing.assert_allclose([pts[:, 0].max(), pts[:, 1].max()], [xs.max() + 1, ys.max() + 1], atol=2)


def test_layout_labels_and_colours(tiny):
    scene = tiny[0]
    assert L.labels(np.array(["car", "pedestrian"]), np.array([12, 4])) == ["c12", "p4"]
    cols = L.class_colors(np.array(["car", "bicyclist"]), scene.classes)
    assert cols.dtype == np.uint8 and tuple(cols[0]) == L.CLASS_COLORS["car"]
    assert L.safe_name("run a/b") == "run_a_b"


def test_parse_frames():
    assert parse_frames("3:9") == (3, 9)
    assert parse_frames(None) is None
    for bad in ("3", "9:3", "a:b", "-1:2"):
        with pytest.raises(InputError, match="--frames"):
            parse_frames(bad)


# --- runs ------------------------------------------------------------------------------------------
def test_load_run_reads_views(tiny):
    scene, base, s2pn, _ = tiny
    run = load_run(s2pn, scene, scene_last_frame(scene))
    assert run.name == "run-s2pn" and run.cameras == ["c0", "c1"]
    assert run.frame_range == (0, N_FRAMES - 1)
    v = run.views
    assert len(v) == sum(len(read_mots(scene.masks_path(c))) for c in ("c0", "c1"))
    np.testing.assert_allclose(v.residual[0], [0.2, -0.2])
    np.testing.assert_allclose(run.poses.xyz[0] - EST_OFFSET,
                               np.r_[TRACKS[4][1], run.poses.xyz[0, 2]], atol=1e-12)


def test_scene_last_frame(tiny):
    assert scene_last_frame(tiny[0]) == N_FRAMES - 1


def test_run_with_unknown_camera_is_rejected(tiny):
    scene, _, _, root = tiny
    bad = make_run(scene, root / "bad-cam", cameras=["c0", "c9"])
    with pytest.raises(InputError, match=r"c9.*lacks|lacks.*c9"):
        load_run(bad, scene, scene_last_frame(scene))


def test_run_beyond_scene_frames_is_rejected(tiny):
    scene, _, _, root = tiny
    bad = make_run(scene, root / "bad-frames", frame_shift=100)
    with pytest.raises(InputError, match="frame"):
        load_run(bad, scene, scene_last_frame(scene))


def test_views_csv_errors_name_line(tmp_path):
    p = tmp_path / "views.csv"
    p.write_text("frame,track_id,camera,class,u,v,xn,yn,zn,dx,dy\n0,1,c0,car,1,2,3,4,5,6,7\n"
                 "1,1,c0,car,1,2,x,4,5,6,7\n")
    with pytest.raises(InputError, match=r"views.csv:3"):
        read_views(p)
    p.write_text("frame,track,camera\n")
    with pytest.raises(InputError, match=r"views.csv:1.*expected header"):
        read_views(p)


# --- the recording, read back ------------------------------------------------------------------------
def _rrd_rows(path: Path) -> tuple[Counter, Counter, list]:
    import rerun.chunk as rc

    reader = rc.RrdReader(path)
    rows, comps = Counter(), Counter()
    for ch in reader.stream():
        if ch.is_static:
            for n in ch.to_record_batch().schema.names:
                comps[(ch.entity_path, n)] += 1
            continue
        rows[ch.entity_path] += ch.num_rows
        for n in ch.to_record_batch().schema.names:
            comps[(ch.entity_path, n)] += 1
    return rows, comps, reader.blueprints()


def test_rrd_holds_expected_entities_and_rows(tiny):
    scene, base, s2pn, root = tiny
    out = record(scene, [base, s2pn], root / "rec.rrd").rrd
    assert out == root / "rec.rrd" and out.stat().st_size > 0
    rows, comps, bps = _rrd_rows(out)
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
        assert rows[f"/world/road_users/{r}"] == n
        assert rows[f"/world/road_users/{r}/trails"] == n
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
        if ch.entity_path == "/world/road_users/run-base" and not ch.is_static:
            boxes = ch.to_record_batch()
        if ch.entity_path == "/metrics/error/run-base/mean" and not ch.is_static:
            errors = ch.to_record_batch()
        if ch.entity_path.endswith("/masks"):
            masks.append(ch)
    assert not masks
    frames = boxes.column("frame").to_pylist()
    i = frames.index(5)
    labels = boxes.column("Boxes3D:labels").to_pylist()[i]
    centers = np.array(boxes.column("Boxes3D:centers").to_pylist()[i])
    k = labels.index("c12")
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


# --- bad input and outputs ---------------------------------------------------------------------------
def test_existing_output_refused_and_kept(tiny):
    scene, base, _, root = tiny
    p = root / "exists.rrd"
    p.write_bytes(b"keep me")
    with pytest.raises(S2PError, match="--force"):
        record(scene, [base], p)
    assert p.read_bytes() == b"keep me"
    record(scene, [base], Targets(rrd=p, force=True), NO_IMAGES)
    assert p.read_bytes() != b"keep me"


def test_failed_recording_leaves_nothing(tiny):
    scene, _, _, root = tiny
    bad = make_run(scene, root / "bad2", cameras=["nope"])
    out = root / "never.rrd"
    with pytest.raises(InputError):
        record(scene, [bad], out)
    assert not out.exists()
    assert not [p for p in root.iterdir() if p.name.startswith(".never.rrd")]


def test_unreachable_viewer_url(tiny):
    from s2p_review.viewer import free_port

    scene, base, _, root = tiny
    url = f"rerun+http://127.0.0.1:{free_port()}/proxy"
    with pytest.raises(S2PError, match="no viewer answers"):
        record(scene, [base], Targets(connect=url))
    with pytest.raises(S2PError, match="bad viewer URL"):
        record(scene, [base], Targets(connect="http://nowhere"))


def test_unreadable_video(tiny, tmp_path):
    import shutil

    scene, base, _, _ = tiny
    from seg2pose.io.scene import load_scene

    copy = tmp_path / "scene"
    shutil.copytree(scene.root, copy, ignore=shutil.ignore_patterns("out"))
    (copy / "video" / "c0.mp4").write_bytes(b"not a video")
    s2 = load_scene(copy)
    with pytest.raises(InputError, match=r"c0.mp4.*cannot open video"):
        record(s2, [base], tmp_path / "v.rrd")
    assert not (tmp_path / "v.rrd").exists()


def test_nothing_to_do(tiny):
    scene, base, _, _ = tiny
    with pytest.raises(S2PError, match="nothing to do"):
        record(scene, [base], Targets())


# --- CLI -------------------------------------------------------------------------------------------
def test_cli_review_and_errors(tiny):
    from seg2pose.cli import app

    scene, base, s2pn, root = tiny
    runner = CliRunner()
    out = root / "cli.rrd"
    r = runner.invoke(app, ["review", str(scene.root), "--run", str(base), "--run", str(s2pn),
                            "-o", str(out), "--frames", "2:7", "--no-video"])
    assert r.exit_code == 0, r.output
    assert "rerun " + str(out) in r.output
    rows, _, _ = _rrd_rows(out)
    assert rows["/world/road_users/run-s2pn"] == 6
    r = runner.invoke(app, ["review", str(scene.root), "--run", str(base), "-o", str(out)])
    assert r.exit_code != 0 and "--force" in str(r.exception)


def test_cli_main_prints_one_line_error(tiny, monkeypatch, capsys):
    import sys

    from seg2pose import cli

    scene, _, _, root = tiny
    bad = make_run(scene, root / "bad3", cameras=["zz"])
    monkeypatch.setattr(sys, "argv", ["s2p", "review", str(scene.root), "--run", str(bad),
                                      "-o", str(root / "x.rrd")])
    with pytest.raises(SystemExit) as e:
        cli.main()
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "run.json" in err and "zz" in err and len(err.strip().splitlines()) == 1


def test_run_json_meta_roundtrip(tiny, tmp_path):
    """run.json as read for review equals the file, and comes back equal through an MCAP export
    and import; a run.json without cameras takes them from views.csv."""
    import shutil

    from s2p_review.mcap_export import ExportOptions, export_mcap
    from s2p_review.mcap_import import import_mcap

    scene, base, _, _ = tiny
    on_disk = json.loads((base / "run.json").read_text())
    run = load_run(base, scene, scene_last_frame(scene))
    assert run.meta == on_disk and run.cameras == ["c0", "c1"]
    out = export_mcap(scene, base, tmp_path / "m.mcap", ExportOptions(frames=(0, 1))).path
    back = import_mcap(out, tmp_path / "restored")
    assert json.loads((back / "run.json").read_text()) == on_disk
    shutil.copytree(base, tmp_path / "nocams")
    meta = dict(on_disk, cameras=[])
    (tmp_path / "nocams" / "run.json").write_text(json.dumps(meta))
    v = read_views(base / "views.csv")
    (tmp_path / "nocams" / "views.csv").write_text(
        "\n".join([l for l in (base / "views.csv").read_text().splitlines() if ",c0," not in l]) + "\n")
    assert "c0" in set(v.camera.tolist())
    assert load_run(tmp_path / "nocams", scene).cameras == ["c1"]


def test_trail_points_match_trail_strips():
    rng = np.random.default_rng(3)
    frame = np.sort(rng.integers(0, 30, 200))
    tid = rng.integers(0, 6, 200)
    xyz = rng.normal(size=(200, 3))
    pts, offs = C.trail_points(tid, frame, xyz, length=7)
    strips = C.trail_strips(tid, frame, xyz, length=7)
    assert len(offs) == 201
    for i, s in enumerate(strips):
        np.testing.assert_array_equal(pts[offs[i]:offs[i + 1]], s)


def test_strips_arrow_is_rerun_type():
    import rerun as rr

    segs = np.arange(24, dtype=float).reshape(3, 2, 4)[:, :, :2].copy()
    arr = C.segments_arrow(segs, rr.components.LineStrip2DBatch)
    assert arr.type == rr.components.LineStrip2DBatch._ARROW_DATATYPE
    assert arr.to_pylist()[1] == [list(map(float, p)) for p in segs[1]]


def test_bad_rle_in_masks_named(tiny, tmp_path):
    import shutil

    from seg2pose.io.scene import load_scene

    scene, base, _, _ = tiny
    copy = tmp_path / "scene"
    shutil.copytree(scene.root, copy, ignore=shutil.ignore_patterns("out", "video"))
    lines = (copy / "masks" / "c0.txt").read_text().splitlines()
    parts = lines[7].split()
    lines[7] = " ".join(parts[:5] + ["0" + parts[5]])  # a leading zero-length run: too few pixels
    (copy / "masks" / "c0.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"c0.txt: frame 2, track 7: RLE covers"):
        record(load_scene(copy), [base], tmp_path / "bad.rrd")
    assert not (tmp_path / "bad.rrd").exists()


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


def test_spawn_without_display_is_a_clear_error(tiny, monkeypatch):
    import sys

    if not sys.platform.startswith("linux"):
        pytest.skip("display variables are a Linux matter")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    scene, base, _, root = tiny
    with pytest.raises(S2PError, match="no display"):
        record(scene, [base], Targets(spawn=True))


def test_run_of_another_scene_is_rejected(tiny):
    scene, _, _, root = tiny
    bad = make_run(scene, root / "other-scene")
    meta = json.loads((bad / "run.json").read_text())
    meta["scene_fingerprint"] = "0123456789abcdef"
    (bad / "run.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match="another scene"):
        load_run(bad, scene, scene_last_frame(scene))


def test_projected_edges_skip_boxes_far_outside(tiny):
    scene = tiny[0]
    cam = scene.cameras["c0"]
    # one box at the scene centre (in view), one right beside the camera (corners far outside)
    c = cam.center
    xyz = np.array([[0.0, 0.0, 0.0], [c[0] + 1.0, c[1] + 1.0, c[2] - 1.0]])
    segs, idx = C.projected_edges(cam, xyz, np.zeros(2), np.array([[4.0, 2.0, 1.5]] * 2))
    assert list(idx) == [0] and segs.shape == (12, 2, 2)


def test_box_path_covers_all_edges():
    pairs = {tuple(sorted(p)) for p in zip(C.PATH[:-1], C.PATH[1:])}
    assert pairs == {tuple(sorted(e)) for e in C.EDGES.tolist()}
    assert len(C.PATH) == 16


def test_runs_tell_apart_and_labels_are_not_drawn(tiny):
    """The baseline's boxes are hollow and pale, Seg2PoseNet's solid in the class colours; box
    labels are data (hover, selection), never drawn over each other."""
    import rerun.chunk as rc

    scene, base, s2pn, root = tiny
    out = record(scene, [base, s2pn], root / "looks.rrd", NO_IMAGES).rrd
    static, cols = {}, {}
    for ch in rc.RrdReader(out).stream():
        b = ch.to_record_batch()
        for run in ("run-base", "run-s2pn"):
            if ch.entity_path != f"/world/road_users/{run}":
                continue
            if ch.is_static:
                static[run] = {n: b.column(n).to_pylist()[0] for n in b.schema.names
                               if n.startswith("Boxes3D:")}
            else:
                cols[run] = np.array([c for row in b.column("Boxes3D:colors").to_pylist() for c in row])
    assert static["run-base"]["Boxes3D:show_labels"] == [False]
    assert static["run-s2pn"]["Boxes3D:show_labels"] == [False]
    fills = {r: static[r]["Boxes3D:fill_mode"][0] for r in static}
    assert fills["run-s2pn"] != fills["run-base"]
    rgba = lambda c: np.array([(c >> 24) & 255, (c >> 16) & 255, (c >> 8) & 255, c & 255]).T  # noqa: E731
    car = np.array(L.class_color("car"))
    b, s = rgba(cols["run-base"]), rgba(cols["run-s2pn"])
    assert any((s[:, :3] == car).all(axis=1)) and not any((b[:, :3] == car).all(axis=1))
    # the baseline is 40 % of the way to grey: less saturated than Seg2PoseNet's colours
    sat = lambda c: (c[:, :3].max(axis=1) - c[:, :3].min(axis=1)).mean()  # noqa: E731
    assert abs(sat(b) - 0.6 * sat(s)) < 1.0  # saturation scales by 1 - 0.4


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
