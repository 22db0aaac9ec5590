"""Matching masks to ground truth (paper 4.1) and the RLE point lookup it uses."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from seg2pose.geometry.camera import Camera
from seg2pose.io.mots import MaskTable
from seg2pose.io.poses import PoseTable
from seg2pose.method.matching import candidate_pairs, match_masks_to_truth, truth_points
from seg2pose.structures.masks import encode, rle_contains

H, W = 120, 160
CAM = Camera.look_at("c", center=[0, -20, 10], target=[0, 0, 0], f=150.0, width=W, height=H)
NAMES = {1: "pedestrian", 2: "bicyclist", 3: "car"}


def box_mask(x0, y0, x1, y1):
    m = np.zeros((H, W), np.uint8)
    m[y0:y1, x0:x1] = 1
    return encode(m)


def around(uv, r):
    u, v = int(uv[0]), int(uv[1])
    return box_mask(max(u - r, 0), max(v - r, 0), min(u + r + 1, W), min(v + r + 1, H))


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_rle_contains_equals_decoded_lookup(seed):
    rng = np.random.default_rng(seed)
    n = 5
    masks = [(rng.random((H, W)) < rng.uniform(0.05, 0.9)).astype(np.uint8) for _ in range(n)]
    rles = [encode(m) for m in masks]
    k = 200
    idx = rng.integers(0, n, k)
    pts = rng.uniform([-5, -5], [W + 5, H + 5], (k, 2))
    got = rle_contains(rles, H, W, idx, pts)
    want = np.zeros(k, bool)
    for j in range(k):
        x, y = pts[j]
        if 0 <= x < W and 0 <= y < H:
            want[j] = masks[idx[j]][int(y), int(x)] == 1
    assert np.array_equal(got, want)


def test_rle_contains_pixel_edges():
    r = box_mask(10, 20, 11, 21)  # exactly pixel (row 20, col 10)
    pts = np.array([[10.0, 20.0], [10.999, 20.999], [11.0, 20.5], [10.5, 19.999]])
    assert rle_contains([r], H, W, np.zeros(4, int), pts).tolist() == [True, True, False, False]


def test_candidate_pairs():
    mi, gi = candidate_pairs(np.array([5, 1, 5, 7]), np.array([5, 2, 7, 5]))
    assert sorted(zip(mi.tolist(), gi.tolist())) == [(0, 0), (0, 3), (2, 0), (2, 3), (3, 2)]


def test_truth_points_box_centre_or_default_height():
    gt = PoseTable([0, 0], [1, 2], np.array(["car", "pedestrian"], object),
                   [[1, 2, 0.5], [3, 4, 0.0]], [0, 0], size=[[4, 2, 1.5], [0.5, 0.5, np.nan]])
    p = truth_points(gt, {"pedestrian": 0.8})
    assert np.allclose(p, [[1, 2, 1.25], [3, 4, 0.8]])


def make_gt(rows):
    """rows: (frame, track, cls, x, y)"""
    f, t, c, x, y = zip(*rows)
    xyz = np.stack([x, y, np.zeros(len(x))], axis=1).astype(float)
    size = np.tile([1.0, 1.0, 2.0], (len(x), 1))
    return PoseTable(f, t, np.array(c, object), xyz, np.zeros(len(x)), size)


def test_match_one_to_one_smallest_and_frames():
    gt = make_gt([(0, 10, "car", 0, 0), (0, 11, "pedestrian", 3, 0), (1, 10, "car", 1, 0),
                  (1, 12, "car", 60, 0)])  # row 3 is outside the image
    uv, _, _ = CAM.project_points(truth_points(gt))
    assert CAM.in_image(uv).tolist() == [True, True, True, False]
    rles = [
        around(uv[0], 30),  # 0: big car mask covering the car and the pedestrian (frame 0)
        around(uv[1], 3),   # 1: small pedestrian mask (frame 0)
        around(uv[0], 5),   # 2: small car mask at the car (frame 0): wins over mask 0
        around(uv[2], 4),   # 3: car in frame 1
        around(uv[1], 4),   # 4: frame 1, nobody there
        around(uv[2], 4),   # 5: frame 1, a pedestrian-class mask over the car: wrong class
    ]
    masks = MaskTable([0, 0, 0, 1, 1, 1], [-1] * 6, [3, 1, 3, 3, 3, 1], H, W, rles)
    res = match_masks_to_truth(CAM, masks, gt, NAMES)
    assert res.tolist() == [-1, 1, 0, 2, -1, -1]


def test_match_mask_covering_two_users_takes_nearest():
    # two cars on the camera's line of sight: the nearer one occludes the farther one
    near, far = np.array([0.0, -5.0, 0.0]), np.array([0.0, 5.0, 0.0])
    gt = make_gt([(3, 1, "car", *far[:2]), (3, 2, "car", *near[:2])])
    uv, depth, _ = CAM.project_points(truth_points(gt))
    assert depth[1] < depth[0]
    lo, hi = np.minimum(uv[0], uv[1]), np.maximum(uv[0], uv[1])
    big = box_mask(int(lo[0]) - 3, int(lo[1]) - 3, int(hi[0]) + 4, int(hi[1]) + 4)
    masks = MaskTable([3], [7], [3], H, W, [big])
    assert match_masks_to_truth(CAM, masks, gt, NAMES).tolist() == [1]
    # with a second, smaller mask only around the far one, both are matched
    masks2 = MaskTable([3, 3], [7, 8], [3, 3], H, W, [big, around(uv[0], 2)])
    assert match_masks_to_truth(CAM, masks2, gt, NAMES).tolist() == [1, 0]


def test_match_empty_inputs():
    gt = make_gt([(0, 1, "car", 0, 0)])
    assert match_masks_to_truth(CAM, MaskTable.empty(H, W), gt, NAMES).tolist() == []
    masks = MaskTable([0], [1], [0], H, W, [box_mask(0, 0, W, H)])  # class 0: unknown
    assert match_masks_to_truth(CAM, masks, gt, NAMES).tolist() == [-1]
