"""Rendering one frame (synth/render.py, synth/raster.py): masks are the projected convex
silhouettes, nearer road users hide farther ones, the image border cuts masks, and the crop RLE
encoder agrees with pycocotools."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from matplotlib.path import Path as MplPath
from scipy.spatial import ConvexHull

from seg2pose.structures.masks import decode, encode
from seg2pose.synth import junction as J
from seg2pose.synth.noise import NoiseConfig
from seg2pose.synth.raster import rle_from_crop_t
from seg2pose.synth.render import FrameRenderer
from seg2pose.synth.rig import make_device
from seg2pose.synth.shapes import hexa
from seg2pose.synth.world import World


def one_frame_world(boxes: list[np.ndarray], xyz: np.ndarray, cls=None) -> World:
    """A World of one frame with one single-part road user per box (local verts (8, 3))."""
    n = len(boxes)
    xyz = np.asarray(xyz, float).reshape(n, 3)
    return World(frame=np.zeros(n, np.int64), track=np.arange(1, n + 1), cls=np.array(cls or [2] * n, np.int8),
                 xyz=xyz, heading=np.zeros(n), phase=np.zeros(n), frame_ptr=np.array([0, n]),
                 verts=np.stack(boxes), swing=np.zeros(n), kind=np.zeros(n, np.int8),
                 part_ptr=np.arange(n + 1), size=np.ones((n, 3)), colour=np.zeros((n, 3), np.uint8))


def silhouette(cam, world_verts: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixel centres inside the convex hull of the projected vertices."""
    uv, _, _ = cam.project_points(world_verts)
    hull = uv[ConvexHull(uv).vertices]
    yy, xx = np.mgrid[0:cam.height, 0:cam.width]
    centres = np.column_stack([xx.ravel() + 0.5, yy.ravel() + 0.5])
    return MplPath(hull).contains_points(centres).reshape(cam.height, cam.width)


def boundary_band(m: np.ndarray) -> np.ndarray:
    """Pixels within one pixel of the mask boundary."""
    import cv2
    k = np.ones((3, 3), np.uint8)
    m8 = m.astype(np.uint8)
    return (cv2.dilate(m8, k) - cv2.erode(m8, k)).astype(bool)


@pytest.fixture(scope="module")
def cam():
    return make_device().cameras["c1"]


def test_lone_box_mask_is_projected_convex_silhouette(cam):
    box = hexa(-2.0, 2.0, -0.9, 0.9, 0.0, 1.5)
    pos = np.array([[3.0, 2.0, 0.1]])
    w = one_frame_world([box], pos)
    dets = FrameRenderer(cam, 0, w, NoiseConfig.off(), 0).render(0)
    assert len(dets) == 1 and dets[0][0] == 1 and dets[0][1] == 3
    got = decode(dets[0][2], cam.height, cam.width).astype(bool)
    ref = silhouette(cam, box + pos)
    diff = got ^ ref
    assert ref.sum() > 5000
    assert not (diff & ~boundary_band(ref)).any()  # disagreements only on the boundary
    assert diff.sum() < 0.02 * ref.sum()


def test_occlusion_nearer_road_user_wins(cam):
    # two boxes on the line of sight: the far one partly hidden behind the near one
    c = cam.center
    far_xy = np.array([6.0, 6.0])
    toward = (c[:2] - far_xy) / np.linalg.norm(c[:2] - far_xy)
    near_xy = far_xy + 3.2 * toward + np.array([0.4, -0.4])
    tall = hexa(-1.0, 1.0, -1.0, 1.0, 0.0, 3.5)  # a van in front of a car
    box = hexa(-1.0, 1.0, -1.0, 1.0, 0.0, 1.8)
    pos = np.array([[*near_xy, 0.0], [*far_xy, 0.0]])
    # list the near one first: painter's order must not depend on input order
    w = one_frame_world([tall, box], pos, cls=[0, 0])
    dets = {t: decode(r, cam.height, cam.width).astype(bool)
            for t, _, r in FrameRenderer(cam, 0, w, NoiseConfig.off(), 0).render(0)}
    near_ref, far_ref = silhouette(cam, tall + pos[0]), silhouette(cam, box + pos[1])
    overlap = near_ref & far_ref
    assert overlap.sum() > 200  # the test geometry really overlaps
    band = boundary_band(near_ref) | boundary_band(far_ref)
    assert not ((dets[1] ^ near_ref) & ~band).any()
    assert not ((dets[2] ^ (far_ref & ~near_ref)) & ~band).any()
    assert not (dets[1] & dets[2]).any()
    assert dets[2].sum() < far_ref.sum() - 200
    # the detector-noise model knows how much of each road user is hidden
    _, dd = FrameRenderer(cam, 0, w, NoiseConfig(), 0).visible(0)
    vis = {d.track_id: d.visible for d in dd}
    assert vis[1] == 1.0
    assert abs(vis[2] - dets[2].sum() / far_ref.sum()) < 0.02
    # reversed input order gives the same masks
    w2 = one_frame_world([box, tall], pos[::-1], cls=[0, 0])
    dets2 = {t: decode(r, cam.height, cam.width).astype(bool)
             for t, _, r in FrameRenderer(cam, 0, w2, NoiseConfig.off(), 0).render(0)}
    assert (dets2[2] == dets[1]).all() and (dets2[1] == dets[2]).all()


def test_truncation_at_image_border(cam):
    # a car whose contact point is left of the image: the mask is cut at column 0
    uv_target = np.array([[-40.0, 500.0]])
    X, _ = J.ray_ground_points(cam.center, cam.unproject(uv_target)), None
    box = hexa(-2.0, 2.0, -0.9, 0.9, 0.0, 1.5)
    w = one_frame_world([box], X)
    dets = FrameRenderer(cam, 0, w, NoiseConfig.off(), 0).render(0)
    assert len(dets) == 1
    m = decode(dets[0][2], cam.height, cam.width).astype(bool)
    assert m[:, 0].any()
    ref = silhouette(cam, box + X)
    assert not ((m ^ ref) & ~boundary_band(ref)).any()


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 40), st.integers(1, 40), st.data())
def test_crop_rle_matches_pycocotools(h, w, data):
    x0 = data.draw(st.integers(0, w - 1))
    y0 = data.draw(st.integers(0, h - 1))
    x1 = data.draw(st.integers(x0 + 1, w))
    y1 = data.draw(st.integers(y0 + 1, h))
    seed = data.draw(st.integers(0, 2 ** 31))
    m = np.zeros((h, w), bool)
    m[y0:y1, x0:x1] = np.random.default_rng(seed).random((y1 - y0, x1 - x0)) < 0.5
    assert rle_from_crop_t(m[y0:y1, x0:x1].T.copy(), x0, y0, h, w) == encode(m)
