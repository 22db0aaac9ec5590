"""Review recordings' column builders with known answers: mask images, boxes and their edges,
trails, the layout's labels and colours."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from review_fixtures import review_scene
from video_fixtures import single_threaded_opencv

from s2p_review import columns as C
from s2p_review import layout as L
from seg2pose.io.mots import read_mots
from seg2pose.structures.masks import decode, encode

_opencv_one_thread = pytest.fixture(scope="module", autouse=True)(single_threaded_opencv)
tiny = pytest.fixture(scope="module")(review_scene)



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
    assert L.entity_part("run a/b") == "run\\ a\\/b"  # Rerun's escaping: lossless


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
