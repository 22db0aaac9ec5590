"""Size classes: world sizes of masks with known geometry, the log-normal likelihood and its
border-cut censoring (hand computations), track speeds, the per-track sum, and whole tracks of
rendered rectangles (cut by the border, touching it, moving fast)."""

import numpy as np
import pytest
from scipy import integrate, stats
from video_fixtures import upright_box

import seg2pose.video.classify as C
from seg2pose.core.errors import InputError
from seg2pose.geometry.camera import Camera
from seg2pose.geometry.ground import GroundSurface
from seg2pose.io.mots import MaskTable, read_mots, write_mots
from seg2pose.io.scene import ClassSpec
from seg2pose.structures.masks import encode
from seg2pose.video.classify import (
    CUT_BOTTOM,
    CUT_SIDE,
    CUT_TOP,
    border_cuts,
    classify_mots,
    classify_sizes,
    size_loglik,
    size_rules,
    track_classes,
    track_speeds,
    world_sizes,
)

H, W = 720, 1280
CLASSES = [ClassSpec(1, "pedestrian", 0.9), ClassSpec(2, "bicyclist", 0.9), ClassSpec(3, "car", 0.75)]


def setup():
    g = [(x, y, 0.0) for x in range(-30, 31, 10) for y in range(-10, 61, 10)]
    cam = Camera.look_at("c0", np.array([0.0, -12.0, 9.0]), np.array([0.0, 15.0, 0.0]), 900.0, W, H)
    return cam, GroundSurface(np.array(g, float))


def upright_rectangle_mask(cam, xy, width, height):
    """Mask of a vertical rectangle standing at ground point xy, facing the camera (its box,
    clipped to the image: a rectangle partly outside is cut by the border)."""
    x0, y0, x1, y1 = upright_box(cam, xy, width, height)
    x0, y0 = max(x0, 0), max(y0, 0)
    m = np.zeros((H, W), np.uint8)
    m[y0:y1, x0:x1] = 1
    return encode(m)


def classify_track(tmp_path, masks, fps=None, frames=None):
    """One track (id 1) of the given masks through classify_mots; its class."""
    n = len(masks)
    frames = np.arange(n) if frames is None else np.asarray(frames)
    write_mots(tmp_path / "m.txt", MaskTable(frames, np.ones(n, int), np.zeros(n, int), H, W, masks))
    cam, ground = setup()
    votes = classify_mots(tmp_path / "m.txt", tmp_path / "m.txt", cam, ground,
                          size_rules(CLASSES, {}), fps=fps, log=lambda s: None)
    assert set(read_mots(tmp_path / "m.txt").class_id.tolist()) == {votes[1]}
    return votes[1]


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


def test_size_loglik_is_the_log_normal_density_with_the_outlier_share():
    """One class, width range [0.5, 2] and height [1, 4] m: log-normal with median 1 and 2 m,
    sigma = ln 4 / (2 * 1.6449) in both; outliers log-uniform on [0.1, 20] m per dimension."""
    rules = size_rules(CLASSES[:1], {"size_classes": {"pedestrian": {"width": [0.5, 2.0],
                                                                     "height": [1.0, 4.0]}}})
    sg = np.log(4.0) / (2 * 1.6449)
    w, h = 1.0, 2.0 * np.exp(sg)                                 # height one sigma above
    pw = 1 / (sg * np.sqrt(2 * np.pi) * w)
    ph = np.exp(-0.5) / (sg * np.sqrt(2 * np.pi) * h)
    out = 1 / (np.log(200.0) ** 2 * w * h)
    want = np.log((1 - C.OUTLIER) * pw * ph + C.OUTLIER * out)
    assert size_loglik(np.array([[w, h]]), rules)[0, 0] == pytest.approx(want, rel=1e-9)
    assert size_loglik(np.array([[np.nan, 1.0]]), rules)[0, 0] == 0.0   # unknown: no evidence


@pytest.mark.parametrize("x", [0.1, 0.7, 1.0, 2.5])
def test_a_cut_size_is_a_uniform_share_of_the_true_size(monkeypatch, x):
    """Cut at the side, the visible width x of a road user of width S ~ log-normal is uniform
    on [0, S]: density E[1/S; S >= x], checked by numerical integration; with CUT_WHOLE the
    mask may also be whole."""
    monkeypatch.setattr(C, "OUTLIER", 1e-12)
    lo, hi = 0.5, 2.0
    rules = size_rules(CLASSES[:1], {"size_classes": {"pedestrian": {"width": [lo, hi],
                                                                     "height": [1.0, 4.0]}}})
    sg = np.log(hi / lo) / (2 * 1.6449)
    S = stats.lognorm(s=sg, scale=1.0)
    part = integrate.quad(lambda s: S.pdf(s) / s, x, np.inf)[0]
    size = np.array([[x, 2.0]])
    height = np.log(stats.lognorm(s=sg, scale=2.0).pdf(2.0))
    monkeypatch.setattr(C, "CUT_WHOLE", 0.0)
    got = size_loglik(size, rules, np.array([CUT_SIDE], np.uint8))[0, 0]
    assert got == pytest.approx(np.log(part) + height, rel=1e-6, abs=1e-9)
    monkeypatch.setattr(C, "CUT_WHOLE", 0.3)
    got = size_loglik(size, rules, np.array([CUT_SIDE], np.uint8))[0, 0]
    assert got == pytest.approx(np.log(0.3 * S.pdf(x) + 0.7 * part) + height, rel=1e-6)


def test_border_cuts():
    boxes = np.array([[0, 100, 50, 50], [1230, 100, 50, 50], [500, 0, 50, 50],
                      [500, 670, 50, 50], [0, 0, 1280, 720], [2, 2, 100, 100]], float)
    assert border_cuts(boxes, H, W).tolist() == [CUT_SIDE, CUT_SIDE, CUT_TOP, CUT_BOTTOM,
                                                 CUT_SIDE | CUT_TOP | CUT_BOTTOM, 0]


def test_classify_sizes_and_scene_overrides():
    rules = size_rules(CLASSES, {})
    got = classify_sizes(np.array([[0.6, 1.8], [4.0, 2.2], [1.3, 1.9], [np.nan, 1.0]]), rules)
    assert got.tolist() == [1, 3, 2, 0]
    own = size_rules(CLASSES, {"size_classes": {"bicyclist": {"width": [2.0, 2.5], "height": [1, 2.5]}}})
    assert classify_sizes(np.array([[1.3, 1.9]]), own).tolist() == [1]   # nearer the pedestrian
    assert own.speed.tolist() == [3.0, np.inf, np.inf]                   # replaced whole
    with pytest.raises(InputError, match=r"extra.size_classes.car'.*0 < lo < hi"):
        size_rules(CLASSES, {"size_classes": {"car": {"width": [3, 1], "height": [1, 2]}}})
    with pytest.raises(InputError, match=r"extra.size_classes.car.speed'.*> 0"):
        size_rules(CLASSES, {"size_classes": {"car": {"width": [1, 3], "height": [1, 2], "speed": 0}}})


def test_track_speeds_by_hand():
    """fps 10, window 0.5 s = 5 frames. Track 1 walks 0.2 m a frame: 2 m/s. Track 2 stands for
    16 frames, then moves 1 m a frame: its 15 five-frame speeds are eleven 0 and 2, 4, 6, 8 m/s,
    whose 80th percentile is 2 + 0.2 * 2 = 2.4 (the median would say 0). Track 3 (one mask)
    and untracked masks get none; a gap is bridged by the first mask at least 5 frames on."""
    f = np.arange(20)
    tid = np.r_[np.ones(20), np.full(20, 2), 3, -1, -1].astype(int)
    frame = np.r_[f, f, 0, 0, 5]
    xy = np.r_[np.c_[0.2 * f, np.zeros(20)], np.c_[np.maximum(f - 15, 0), np.ones(20)],
               [[0, 0]], [[0, 0]], [[9, 9]]].astype(float)
    order = np.random.default_rng(0).permutation(len(tid))           # any order
    v = track_speeds(tid[order], frame[order], xy[order], fps=10.0)
    assert set(v) == {1, 2}
    assert v[1] == pytest.approx(2.0) and v[2] == pytest.approx(2.4)
    keep = (frame % 4 != 1) | (tid != 1)                               # track 1 seen 3 of 4 frames
    assert track_speeds(tid[keep], frame[keep], xy[keep], fps=10.0)[1] == pytest.approx(2.0)


def test_track_classes_weighted_sum():
    ll = np.array([[0.0, -1.0], [0.0, -1.0], [-3.0, 0.0], [-5.0, 0.0], [0.0, -1.0], [0.0, -9.0]])
    tid = np.array([1, 1, 1, 2, 3, -1])
    got = track_classes(tid, ll, np.array([1, 1, 1, 0.1, 0.0, 1]), np.array([1, 3]))
    assert got == {1: 3, 2: 3}         # track 1: -3 vs -2 -> class 3; track 3 weighs 0: none


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


def test_a_car_cut_by_the_border_most_of_the_time_stays_a_car(tmp_path):
    """A 4.2 m car waits with only 0.6 m of it inside the image's left edge for 8 frames (a
    pedestrian-sized piece: a majority vote of the masks made it a pedestrian), and is seen
    whole in 4."""
    cam, ground = setup()
    cut = upright_rectangle_mask(cam, (-18.6, 10.0), 4.2, 1.5)
    size = world_sizes([cut], H, W, cam, ground)[0]
    assert classify_sizes(size[None], size_rules(CLASSES, {}))[0] == 1   # alone: pedestrian-like
    assert size[0] == pytest.approx(0.6, abs=0.05)
    whole = upright_rectangle_mask(cam, (-10.0, 10.0), 4.2, 1.5)
    assert classify_track(tmp_path, [cut] * 8 + [whole] * 4) == 3


def test_a_pedestrian_touching_the_border_stays_a_pedestrian(tmp_path):
    """A pedestrian standing at the right edge, its box touching it (a few pixels cut): its
    size is not treated as a mere lower bound, which would favour the bigger bicyclist."""
    cam, ground = setup()
    m = upright_rectangle_mask(cam, (12.8, 5.0), 0.5, 1.8)
    box = C.mask_boxes([m], H, W)
    assert border_cuts(box, H, W)[0] == CUT_SIDE
    assert classify_track(tmp_path, [m] * 20) == 1


def test_speed_rules_out_a_pedestrian(tmp_path):
    """A pedestrian-sized road user moving at 6 m/s is no pedestrian (top speed 3 m/s) but a
    bicyclist (8 m/s); without the frame rate the size alone says pedestrian."""
    cam, ground = setup()
    fast = [upright_rectangle_mask(cam, (-4.0 + 0.6 * f, 12.0), 0.6, 1.8) for f in range(15)]
    assert classify_track(tmp_path, fast) == 1
    assert classify_track(tmp_path, fast, fps=10.0) == 2
    slow = [upright_rectangle_mask(cam, (-4.0 + 0.15 * f, 12.0), 0.6, 1.8) for f in range(15)]
    assert classify_track(tmp_path, slow, fps=10.0) == 1
