"""Mask-geometry features (seg2pose/method/features.py): known answers on a flat ground."""

import numpy as np

from seg2pose.geometry.camera import Camera
from seg2pose.geometry.ground import GroundSurface
from seg2pose.geometry.normal import normal_positions
from seg2pose.method.features import GEO_NAMES, N_GEO, mask_geometry
from seg2pose.structures.masks import encode, mask_centers

W, H = 1280, 720
FLAT = GroundSurface(np.array([(x, y, 0.0) for x in range(-40, 41, 10) for y in range(-10, 71, 10)], float))
CAM = Camera.look_at("c", center=[0, 0, 10], target=[0, 30, 0], f=900, width=W, height=H)
G = {n: i for i, n in enumerate(GEO_NAMES)}


def column_mask(foot_xy, height_m, half_w_px=6):
    """A rectangle mask: the image of a vertical segment from the ground point ``foot_xy`` up
    ``height_m`` metres, ``half_w_px`` pixels either side of it. Returns the mask and its box."""
    (u0, v0), (u1, v1) = CAM.project_points(np.array([[*foot_xy, 0.0], [*foot_xy, height_m]]))[0]
    u = int(round((u0 + u1) / 2))
    top, bottom = int(round(v1)), int(round(v0))
    m = np.zeros((H, W), np.uint8)
    m[top:bottom, u - half_w_px:u + half_w_px] = 1
    return m, (u - half_w_px, top, u + half_w_px, bottom)


def features_of(masks, dh, ch):
    rles = [encode(m) for m in masks]
    cen = mask_centers(rles, H, W, "bbox")
    nrm, _ = normal_positions(CAM, FLAT, cen, np.asarray(dh, float))
    return mask_geometry(CAM, FLAT, rles, H, W, cen, nrm[:, :2], dh, ch), nrm


def test_box_fill_and_border_features_are_exact():
    m, (x0, y0, x1, y1) = column_mask((2.0, 30.0), 1.8)
    f, _ = features_of([m], [0.9], [1.8])
    assert f.shape == (1, N_GEO) and f.dtype == np.float32
    assert np.isclose(f[0, G["box_w"]], (x1 - x0) / 100) and np.isclose(f[0, G["box_h"]], (y1 - y0) / 100)
    assert np.isclose(f[0, G["fill"]], 1.0)
    assert np.allclose(f[0, [G["centroid_dx"], G["centroid_dy"]]], 0.0, atol=1e-6)
    assert not f[0, G["cut_left"]:].any()
    cut = np.zeros((H, W), np.uint8)
    cut[300:400, :20] = 1          # touches the left border only
    cut[300:310, :5] = 1
    g, _ = features_of([cut], [0.9], [1.8])
    assert g[0, G["cut_left"]] == 1 and g[0, G["cut_top"]:].sum() == 0
    # centroid of the L shape lies left of and above the box centre: (2.5 - 10) * 50/1050 etc.
    area = 100 * 20 + 0  # the second block lies inside the first
    assert np.isclose(g[0, G["fill"]], area / (20 * 100))


def test_foot_top_and_height_ratio_locate_a_standing_road_user():
    """The foot feature points at the true foot (within a pixel's worth), the top feature at the
    true top when the class height is right, and h_ratio is the relative height error."""
    for y, true_h in ((20.0, 1.8), (35.0, 1.6), (50.0, 1.9)):
        m, _ = column_mask((1.0, y), true_h)
        f, nrm = features_of([m], [0.9], [1.8])
        foot = nrm[0, :2] + 2 * f[0, [G["foot_dx"], G["foot_dy"]]]
        top = nrm[0, :2] + 2 * f[0, [G["top_dx"], G["top_dy"]]]
        px = np.linalg.norm(CAM.center - [1.0, y, 0]) / 900 * 10 / 3  # metres per pixel along the ground, roughly
        assert np.linalg.norm(foot - [1.0, y]) < 1.5 * px
        if true_h == 1.8:
            assert np.linalg.norm(top - [1.0, y]) < 1.5 * px
        assert abs(f[0, G["h_ratio"]] - (true_h / 1.8 - 1)) < 0.04


def test_occluded_legs_give_a_negative_height_ratio_and_a_far_normal_position():
    full, _ = column_mask((0.0, 30.0), 1.8)
    upper = full.copy()
    rows = np.flatnonzero(full.any(axis=1))
    upper[rows[len(rows) // 2]:] = 0   # legs hidden behind a car
    f, nrm = features_of([full, upper], [0.9, 0.9], [1.8, 1.8])
    assert f[1, G["h_ratio"]] < -0.4 < f[0, G["h_ratio"]]
    assert nrm[1, 1] > nrm[0, 1] + 1.0        # the baseline puts the occluded one too far ...
    # the full body's foot cue agrees with its normal position (0.9 m is half of 1.8 m); the
    # occluded one's "foot" (its waist) meets the ground well beyond: the cues tell them apart
    assert abs(f[0, G["foot_dy"]]) < 0.05 and f[1, G["foot_dy"]] > 0.5


def test_empty_input_and_missing_rays_give_zeros():
    assert mask_geometry(CAM, FLAT, [], H, W, np.zeros((0, 2)), np.zeros((0, 2)), [], []).shape == (0, N_GEO)
    sky = np.zeros((H, W), np.uint8)
    sky[0:30, 600:620] = 1             # above the horizon: the rays miss the ground
    f, nrm = features_of([sky], [0.9], [1.8])
    assert np.isfinite(f).all() and np.abs(f).max() <= 5
