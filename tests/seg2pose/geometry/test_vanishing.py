"""A camera from the traffic (geometry/vanishing.py): vanishing points, focal, rotation and
height ratios against a known camera."""

from __future__ import annotations

import numpy as np
import pytest

from seg2pose.core.errors import InputError
from seg2pose.geometry import vanishing as V
from seg2pose.geometry.camera import Camera

W, H = 1280, 720


def cam() -> Camera:
    return Camera.look_at("c", np.array([-12.0, -12.0, 10.0]), np.array([-1.0, -1.0, 0.0]), 900.0, W, H)


def motion_tracks(c: Camera, rng: np.random.Generator, n: int = 24) -> list[np.ndarray]:
    """Road users driving along x or y on the ground, 1 m apart per step, their pixels."""
    tracks = []
    for k in range(n):
        start = rng.uniform(-5, 25, 2)
        step = np.array([1.0, 0.0]) if k % 2 else np.array([0.0, 1.0])
        xy = start + np.arange(16)[:, None] * step
        uv, _, front = c.project_points(np.column_stack([xy, np.zeros(16)]))
        keep = front & c.in_image(uv)
        if keep.sum() >= 8:
            tracks.append(uv[keep])
    return tracks


def test_focal_and_rotation_from_two_orthogonal_vanishing_points():
    c = cam()
    v1 = c.K @ c.R @ np.array([1.0, 0.0, 0.0])  # the direction x, seen from the camera
    v2 = c.K @ c.R @ np.array([0.0, 1.0, 0.0])
    assert V.focal_from_vps(v1, v2, np.array([W / 2, H / 2])) == pytest.approx(900.0, rel=1e-12)
    R = V.rotation_from_vps(v1, v2, c.K)
    np.testing.assert_allclose(R[:, 2], c.R[:, 2], atol=1e-12)  # the vertical, exactly
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    assert V.focal_from_vps(v1, v1, np.array([W / 2, H / 2])) is None  # one direction twice


def test_vanishing_points_from_tracks():
    c = cam()
    seg = V.track_segments(motion_tracks(c, np.random.default_rng(0)))
    v1, v2, f = V.orthogonal_vps(seg, W, H, np.random.default_rng(1))
    assert f == pytest.approx(900.0, rel=1e-6)
    truth = {tuple(np.round(c.K @ c.R @ e / (c.K @ c.R @ e)[2], 3)) for e in np.eye(3)[:2]}
    got = {tuple(np.round(v / v[2], 3)) for v in (v1, v2)}
    assert got == truth


def test_turning_tracks_are_left_out_and_one_road_is_not_enough():
    c = cam()
    t = np.linspace(0, np.pi / 2, 16)
    arc = np.column_stack([10 + 8 * np.cos(t), 10 + 8 * np.sin(t), np.zeros(16)])
    seg = V.track_segments([c.project_points(arc)[0]])
    assert len(seg.lines) == 0
    one_road = [tr for k, tr in enumerate(motion_tracks(c, np.random.default_rng(2))) if k % 2]
    with pytest.raises(InputError, match="no two orthogonal directions|too few"):
        V.orthogonal_vps(V.track_segments(one_road), W, H, np.random.default_rng(3))


def test_height_ratio_of_a_person():
    """A 1.7 m person under a camera 10 m up: 0.17 of the camera's height, wherever they stand."""
    c = cam()
    xy = np.array([[0.0, 0.0], [8.0, 3.0], [-4.0, 12.0]])
    feet = c.project_points(np.column_stack([xy, np.zeros(3)]))[0]
    heads = c.project_points(np.column_stack([xy, np.full(3, 1.7)]))[0]
    np.testing.assert_allclose(V.height_ratios(c.K, c.R, feet, heads), 0.17, rtol=1e-9)


def test_height_ratio_from_the_near_edge_of_the_footprint():
    """The lowest pixel of a standing person is the near edge of the footprint, 0.2 m nearer the
    camera than below the head: taken as below the head, the height comes out too large by
    (H - h) delta / D; the foot offset (in camera heights) puts the vertical back."""
    c = cam()
    xy = np.array([[0.0, 0.0], [8.0, 3.0]])
    foot_xy = xy - 0.2 * (xy - c.center[:2]) / np.linalg.norm(xy - c.center[:2], axis=1, keepdims=True)
    feet = c.project_points(np.column_stack([foot_xy, np.zeros(2)]))[0]
    heads = c.project_points(np.column_stack([xy, np.full(2, 1.7)]))[0]
    D = np.linalg.norm(xy - c.center[:2], axis=1)
    naive = V.height_ratios(c.K, c.R, feet, heads)
    np.testing.assert_allclose(naive, (1.7 + (10 - 1.7) * 0.2 / D) / 10, rtol=1e-9)
    np.testing.assert_allclose(V.height_ratios(c.K, c.R, feet, heads, 0.2 / 10), 0.17, rtol=1e-9)
