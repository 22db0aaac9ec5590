"""Size classes: world sizes of masks with known geometry, the class rule, the per-track vote."""

import numpy as np
import pytest

from seg2pose.camera import Camera
from seg2pose.classify import classify_mots, classify_sizes, size_rules, vote, world_sizes
from seg2pose.errors import InputError
from seg2pose.ground import GroundSurface
from seg2pose.io.mots import MaskTable, read_mots, write_mots
from seg2pose.io.scene import ClassSpec
from seg2pose.masks import encode

H, W = 720, 1280
CLASSES = [ClassSpec(1, "pedestrian", 0.9), ClassSpec(2, "bicyclist", 0.9), ClassSpec(3, "car", 0.75)]


def setup():
    g = [(x, y, 0.0) for x in range(-30, 31, 10) for y in range(-10, 61, 10)]
    cam = Camera.look_at("c0", np.array([0.0, -12.0, 9.0]), np.array([0.0, 15.0, 0.0]), 900.0, W, H)
    return cam, GroundSurface(np.array(g, float))


def upright_rectangle_mask(cam, xy, width, height):
    """Mask of a vertical rectangle standing at ground point xy, facing the camera."""
    F = np.array([xy[0], xy[1], 0.0])
    view = F[:2] - cam.center[:2]
    u = np.array([-view[1], view[0], 0.0]) / np.linalg.norm(view)
    corners = np.array([F - u * width / 2, F + u * width / 2,
                        F + u * width / 2 + [0, 0, height], F - u * width / 2 + [0, 0, height]])
    uv, _, _ = cam.project_points(corners)
    x0, y0 = np.floor(uv.min(axis=0)).astype(int)
    x1, y1 = np.ceil(uv.max(axis=0)).astype(int)
    m = np.zeros((H, W), np.uint8)
    m[y0:y1, x0:x1] = 1
    return encode(m)


@pytest.mark.parametrize("xy,w,h,tol", [((0.0, 5.0), 0.6, 1.8, 0.06), ((0.3, 30.0), 1.2, 1.7, 0.07),
                                        ((-6.0, 20.0), 4.2, 1.5, 0.18), ((8.0, 35.0), 1.2, 1.7, 0.13)])
def test_world_sizes_of_upright_rectangles(xy, w, h, tol):
    """Near the image's centre line the sizes are exact to the pixel; off it the rectangle's
    edges project slanted, so its box (and the size) grows by up to tol."""
    cam, ground = setup()
    s = world_sizes([upright_rectangle_mask(cam, xy, w, h)], H, W, cam, ground)
    assert s[0, 0] == pytest.approx(w, rel=tol)
    assert s[0, 1] == pytest.approx(h, rel=tol)
    assert s[0, 0] >= w - 0.02 and s[0, 1] >= h - 0.02          # a box never shrinks


def test_classify_sizes_and_scene_overrides():
    rules = size_rules(CLASSES, {})
    got = classify_sizes(np.array([[0.6, 1.8], [4.0, 2.2], [1.2, 1.8], [np.nan, 1.0], [0.7, 0.5]]),
                         rules)
    assert got.tolist() == [1, 3, 2, 0, 1]        # a too-short pedestrian is still the nearest
    assert classify_sizes(np.array([[1.3, 1.8]]), rules).tolist() == [2]
    own = size_rules(CLASSES, {"size_classes": {"bicyclist": {"width": [0.95, 1.1], "height": [1, 2.5]}}})
    assert classify_sizes(np.array([[1.3, 1.8]]), own).tolist() == [3]   # nearest: car's 1.4 m
    with pytest.raises(InputError, match=r"extra.size_classes.car'.*0 < lo < hi"):
        size_rules(CLASSES, {"size_classes": {"car": {"width": [3, 1], "height": [1, 2]}}})


def test_vote_majority_and_ties():
    assert vote(np.array([1, 1, 1, 2, 2, 3, -1, 4]), np.array([3, 3, 1, 1, 3, 0, 3, 2])) == \
        {1: 3, 2: 1, 4: 2}


def test_classify_mots_gives_each_track_one_class(tmp_path):
    cam, ground = setup()
    ped = [upright_rectangle_mask(cam, (0.0, 5.0 + 0.1 * f), 0.6, 1.8) for f in range(5)]
    car = [upright_rectangle_mask(cam, (-6.0, 20.0), 4.2, 1.5) for f in range(5)]
    car[2] = upright_rectangle_mask(cam, (-6.0, 20.0), 0.7, 1.6)      # one odd mask
    t = MaskTable(np.repeat(np.arange(5), 2), np.tile([1, 2], 5), np.zeros(10), H, W,
                  [m for pair in zip(ped, car) for m in pair])
    write_mots(tmp_path / "m.txt", t)
    votes = classify_mots(tmp_path / "m.txt", tmp_path / "m.txt", cam, ground,
                          size_rules(CLASSES, {}), log=lambda s: None)
    assert votes == {1: 1, 2: 3}
    out = read_mots(tmp_path / "m.txt")
    assert out.class_id.tolist() == [1, 3] * 5
