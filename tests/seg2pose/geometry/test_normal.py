"""Normal positions (3.2), default heights by bisection, late fusion (3.3), headings (eq. 2)."""

import math

import cv2
import numpy as np
import pytest
from scipy.optimize import brentq

from seg2pose.geometry.camera import Camera
from seg2pose.geometry.ground import GroundSurface
from seg2pose.geometry.normal import (
    CENTER_METHODS,
    DEFAULT_CENTER_METHOD,
    closer_share,
    default_height_bisection,
    fuse_views,
    headings_from_tracks,
    normal_positions,
)
from seg2pose.structures.masks import encode, mask_centers

W, H = 1280, 720


def bumpy_ground() -> GroundSurface:
    """A road with a 15 cm kerb and a gentle slope (ground points as a surveyor would take)."""
    pts = []
    for x in np.arange(-30, 31, 3.0):
        for y in np.arange(-5, 40, 3.0):
            z = 0.01 * y + (0.15 if x > 6 else 0.0)
            pts.append((x, y, z))
    return GroundSurface(np.array(pts))


CAM = Camera.look_at("c", center=[-4, -12, 7], target=[0, 12, 0], f=900, width=W, height=H)


def box_corners(xy, ground: GroundSurface, l, w, h, heading) -> np.ndarray:
    """(8, 3) corners of a box standing on the ground at xy (bottom centre)."""
    z0 = ground.height(np.array([xy]))[0]
    c, s = math.cos(heading), math.sin(heading)
    out = []
    for dl in (-l / 2, l / 2):
        for dw in (-w / 2, w / 2):
            for dz in (0, h):
                out.append((xy[0] + c * dl - s * dw, xy[1] + s * dl + c * dw, z0 + dz))
    return np.array(out)


def render_box(corners: np.ndarray) -> np.ndarray:
    """Exact synthetic mask: the convex hull of the projected corners, filled."""
    uv, _, front = CAM.project_points(corners)
    assert front.all()
    m = np.zeros((H, W), np.uint8)
    # fillConvexPoly takes integer vertices: use 8 fractional bits for sub-pixel accuracy
    hull = cv2.convexHull(np.round((uv - 0.5) * 256).astype(np.int32))
    cv2.fillConvexPoly(m, hull, 1, lineType=cv2.LINE_8, shift=8)
    return m


def paper_normal_position(center_uv, ground: GroundSurface, h: float) -> np.ndarray:
    """The paper's definition, computed independently: the first point along the ray through
    the mask centre at height h above the surface (brentq on a scanned bracket), then down to
    the ground."""
    d = CAM.unproject(np.asarray(center_uv)[None])[0]
    o = CAM.center

    def f(s):
        p = o + s * d
        return p[2] - ground.height(p[None, :2])[0] - h

    grid = np.linspace(0, 200, 4001)
    pts = o + grid[:, None] * d
    vals = pts[:, 2] - ground.height(pts[:, :2]) - h
    k = int(np.flatnonzero(vals <= 0)[0])
    s = brentq(f, grid[k - 1], grid[k], xtol=1e-12)
    p = o + s * d
    return np.array([p[0], p[1], ground.height(p[None, :2])[0]])


@pytest.mark.parametrize("method", CENTER_METHODS)
def test_normal_position_within_1mm_on_exact_box_masks(method):
    g = bumpy_ground()
    boxes = [((0.0, 8.0), 4.5, 1.8, 1.5, 0.3), ((7.5, 15.0), 0.5, 0.5, 1.8, 0.0),
             ((-6.0, 25.0), 1.8, 0.6, 1.7, 2.0), ((4.0, 4.0), 4.2, 1.7, 1.4, -1.2)]
    rles, truth = [], []
    for xy, l, w, h, hd in boxes:
        rles.append(encode(render_box(box_corners(xy, g, l, w, h, hd))))
        truth.append(xy)
    centers = mask_centers(rles, H, W, method)
    heights = np.array([0.75, 0.9, 0.9, 0.75])
    X, status = normal_positions(CAM, g, centers, heights)
    assert (status == 0).all()
    for i in range(len(boxes)):
        want = paper_normal_position(centers[i], g, heights[i])
        assert np.linalg.norm(X[i] - want) < 1e-3
        # the point at default height projects onto the mask centre
        uv, _, _ = CAM.project_points((X[i] + [0, 0, heights[i]])[None])
        assert np.allclose(uv[0], centers[i], atol=1e-4)
        # and it sits on the ground surface
        assert X[i, 2] == pytest.approx(g.height(X[i:i + 1, :2])[0], abs=1e-6)
    # sanity: the baseline is in the right neighbourhood of the truth (decimetres, not metres)
    err = np.linalg.norm(X[:, :2] - np.array(truth), axis=1)
    assert np.all(err < 2.0)


def test_mask_centre_from_rle_equals_decoded():
    g = bumpy_ground()
    m = render_box(box_corners((1.0, 10.0), g, 4.0, 1.8, 1.5, 0.7))
    r = encode(m)
    ys, xs = np.nonzero(m)
    assert np.allclose(mask_centers([r], H, W, "centroid")[0], [xs.mean() + 0.5, ys.mean() + 0.5])
    assert np.allclose(mask_centers([r], H, W, "bbox")[0],
                       [(xs.min() + xs.max() + 1) / 2, (ys.min() + ys.max() + 1) / 2])


def test_missing_rays_are_nan_and_default_is_known():
    g = bumpy_ground()
    X, status = normal_positions(CAM, g, np.array([[640, 10.0], [640, 700]]), 0.9)
    # the top of the image looks above the horizon? this camera pitches down ~15 degrees,
    # f=900: row 10 is 350 px above the centre -> 21 degrees up from the axis: points up
    assert status.tolist() == [1, 0]
    assert np.isnan(X[0]).all() and np.isfinite(X[1]).all()
    assert DEFAULT_CENTER_METHOD in CENTER_METHODS
    assert normal_positions(CAM, g, np.zeros((0, 2)), 0.9)[0].shape == (0, 3)


def test_default_height_bisection_recovers_exact_height():
    g = bumpy_ground()
    rng = np.random.default_rng(0)
    truth = np.column_stack([rng.uniform(-8, 8, 200), rng.uniform(3, 35, 200)])
    h_true = 0.83
    P = np.column_stack([truth, g.height(truth) + h_true])
    centers, _, _ = CAM.project_points(P)
    h = default_height_bisection([(CAM, centers, truth)], g, tol=1e-5)
    assert h == pytest.approx(h_true, abs=1e-4)
    assert closer_share([(CAM, centers, truth)], g, h_true + 0.05)[0] == 1.0
    assert closer_share([(CAM, centers, truth)], g, h_true - 0.05)[0] == 0.0


def test_fuse_views_skips_unseen():
    est = np.array([[[1.0, 2.0], [np.nan, np.nan], [0, 0]],
                    [[3.0, 4.0], [5.0, 6.0], [np.nan, 1.0]]])
    out = fuse_views(est)
    assert np.allclose(out[0], [2, 3]) and np.allclose(out[1], [5, 6]) and np.allclose(out[2], [0, 0])
    out = fuse_views(np.full((2, 1, 2), np.nan))
    assert np.isnan(out).all()


def test_headings_eq2_by_hand():
    # track 1 moves +x (3 steps), then stands still (1 cm steps: ignored), then +y
    xy = np.array([[0, 0], [1, 0], [2, 0], [2.01, 0], [2.01, 1]], float)
    hd = headings_from_tracks(np.ones(5, int), np.arange(5), xy)
    assert math.isnan(hd[0])
    assert hd[1] == pytest.approx(0) and hd[2] == pytest.approx(0) and hd[3] == pytest.approx(0)
    # D = normalise(0.1 (0, 1) + 0.9 (1, 0))
    assert hd[4] == pytest.approx(math.atan2(0.1, 0.9))
    # rows in any order, two tracks, a NaN position is skipped
    tid = np.array([2, 1, 2, 1, 2])
    fr = np.array([2, 1, 0, 0, 1])
    pos = np.array([[0, 2.0], [0, -1], [0, 0], [0, 0], [np.nan, np.nan]])
    hd = headings_from_tracks(tid, fr, pos)
    assert hd[1] == pytest.approx(-math.pi / 2)  # track 1 moved -y
    assert hd[0] == pytest.approx(math.pi / 2)   # track 2: 0 -> (NaN) -> +y
