"""Background-subtraction masks on small rendered videos with known masks."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pycocotools import mask as mask_util
from video_fixtures import H, W, single_threaded_opencv, truth_mask, write_folder, write_video

from seg2pose.core.errors import InputError
from seg2pose.geometry.camera import Camera
from seg2pose.io.mots import read_mots
from seg2pose.io.video import FrameReader
from seg2pose.structures.masks import decode
from seg2pose.structures.rle_runs import labels_to_rles
from seg2pose.video.video_masks import BgConfig, masks_from_video

opencv_one_thread = pytest.fixture(autouse=True)(single_threaded_opencv)

BOXES = [dict(id=1, x=10, y=20, w=24, h=30, vx=3, vy=0),
         dict(id=2, x=120, y=70, w=30, h=16, vx=-2, vy=-0.5)]
CFG = BgConfig(min_area=40, init_samples=15)


def _iou(a, b):
    return np.logical_and(a, b).sum() / np.logical_or(a, b).sum()


@settings(max_examples=40, deadline=None)
@given(st.lists(st.integers(0, 4), min_size=6 * 5, max_size=6 * 5))
def test_labels_to_rles_equals_pycocotools(vals):
    lab = np.array(vals, np.int32).reshape(6, 5)
    ids = np.unique(lab[lab > 0])
    rles = labels_to_rles(lab, ids)
    for k, r in zip(ids, rles):
        want = mask_util.encode(np.asfortranarray((lab == k).astype(np.uint8)))["counts"]
        assert r == want


@settings(max_examples=30, deadline=None)
@given(st.lists(st.integers(0, 3), min_size=6 * 3, max_size=6 * 3), st.integers(0, 4))
def test_labels_to_rles_of_a_column_strip(vals, x0):
    strip = np.array(vals, np.int32).reshape(6, 3)
    full = np.zeros((6, 3 + 4), np.int32)
    full[:, x0:x0 + 3] = strip
    ids = np.unique(strip[strip > 0])
    assert labels_to_rles(strip, ids, x0=x0, width=7) == labels_to_rles(full, ids)


@settings(max_examples=30, deadline=None)
@given(st.lists(st.integers(0, 3), min_size=4 * 3, max_size=4 * 3), st.integers(0, 4),
       st.integers(0, 3))
def test_labels_to_rles_of_a_box(vals, x0, y0):
    box = np.array(vals, np.int32).reshape(4, 3)
    full = np.zeros((4 + 3, 3 + 4), np.int32)
    full[y0:y0 + 4, x0:x0 + 3] = box
    ids = np.unique(box[box > 0])
    assert labels_to_rles(box, ids, x0=x0, width=7, y0=y0, height=7) == labels_to_rles(full, ids)


def test_moving_boxes_are_recovered_exactly(tmp_path):
    folder = write_folder(tmp_path / "c0", 30, BOXES)
    res = masks_from_video(folder, tmp_path / "m.txt", CFG, log=lambda s: None)
    assert (res.n_frames, res.first_frame, res.last_good, res.stopped) == (30, 0, 29, None)
    t = read_mots(tmp_path / "m.txt")
    assert (t.track_id == -1).all() and (t.class_id == 0).all()
    ious = []
    for f in range(30):
        got = [decode(t.rles[i], H, W) for i in np.flatnonzero(t.frame == f)]
        assert len(got) == 2, f
        for bid in (1, 2):
            truth = truth_mask(f, BOXES, bid)
            ious.append(max(_iou(g, truth) for g in got))
    # the opening rounds the corners off; sensor noise flips a few edge pixels
    assert min(ious) > 0.9 and np.mean(ious) > 0.96, (min(ious), np.mean(ious))


def test_empty_video_gives_an_empty_file_and_size_is_checked(tmp_path):
    folder = write_folder(tmp_path / "c0", 12, [])
    res = masks_from_video(folder, tmp_path / "m.txt", CFG, log=lambda s: None)
    assert res.n_frames == 12 and res.n_masks == 0
    assert (tmp_path / "m.txt").read_text() == ""
    cam = Camera.look_at("c0", np.array([0, -10, 5.0]), np.zeros(3), 100.0, W + 2, H)
    with pytest.raises(InputError, match=r"c0: frames are 160x120 pixels but the camera calibration is 162x120"):
        masks_from_video(folder, tmp_path / "m2.txt", CFG, camera=cam)
    assert not (tmp_path / "m2.txt").exists()


def test_light_change_is_reported_with_its_frames(tmp_path):
    folder = write_folder(tmp_path / "c0", 30, BOXES[:1], light={f: 70.0 for f in range(20, 26)})
    logs = []
    res = masks_from_video(folder, tmp_path / "m.txt", CFG, log=logs.append)
    assert res.unsettled == [(20, 25)]
    assert any("did not settle in frames 20..25" in m for m in logs)


def test_truncated_video_keeps_what_was_read(tmp_path):
    p = write_video(tmp_path / "c0.avi", 40, BOXES)
    data = p.read_bytes()
    p.write_bytes(data[:int(len(data) * 0.6)])
    logs = []
    res = masks_from_video(p, tmp_path / "m.txt", BgConfig(min_area=40, init_samples=5,
                                                           init_frames=10), log=logs.append)
    assert res.stopped is not None and "of the 40 frames" in res.stopped
    assert 5 < res.last_good < 39 and res.n_frames == res.last_good + 1
    t = read_mots(tmp_path / "m.txt")
    assert t.frame.max() == res.last_good
    assert any(f"kept the masks of frames 0..{res.last_good}" in m for m in logs)
    # a file that is not a video at all
    (tmp_path / "bad.mp4").write_bytes(b"not a video")
    with pytest.raises(InputError, match="bad.mp4: cannot open video"):
        masks_from_video(tmp_path / "bad.mp4", tmp_path / "m3.txt", CFG)


def test_frame_numbering_and_reader(tmp_path):
    p = write_video(tmp_path / "c0.avi", 6, BOXES)
    r = FrameReader(p, first=100, step=2)
    assert r.header() == (W, H, 6)
    assert [f for f, _ in r.frames()] == [100, 102, 104, 106, 108, 110]
    assert [f for f, _ in r.frames(first=104, last=108)] == [104, 106, 108]
    assert [f for f, _ in r.sample(np.array([100, 110, 999]))] == [100, 110]


def test_config_from_scene_is_validated(tmp_path):
    assert BgConfig.from_dict({"min_area": 10, "threshold": 20}).threshold == 20.0
    with pytest.raises(InputError, match=r"extra.video_masks.speed'.*unknown setting"):
        BgConfig.from_dict({"speed": 1})
    with pytest.raises(InputError, match=r"extra.video_masks.method'.*mog2 or knn"):
        BgConfig.from_dict({"method": "magic"})
    with pytest.raises(InputError, match=r"extra.video_masks.min_area'.*expected an integer"):
        BgConfig.from_dict({"min_area": "x"})
    with pytest.raises(InputError, match=r"extra.video_masks.exposure_band'.*expected a finite number in \[0, 0.999\]"):
        BgConfig.from_dict({"exposure_band": 1.5})


def _best_iou(t, f, truth):
    got = [decode(t.rles[i], H, W) for i in np.flatnonzero(t.frame == f)]
    return max((_iou(g, truth) for g in got), default=0.0)


def test_a_road_user_that_stops_stays_foreground(tmp_path):
    """A box drives in (frames 0-9) and waits for 70 frames. The background comes from the
    first 10 frames; OpenCV's own update (history 20) absorbs the waiting box within a few
    dozen frames, the selective update never learns it."""
    boxes = [dict(id=1, x=-40, y=20, w=24, h=30, vx=8, frames=(0, 9)),
             dict(id=1, x=40, y=20, w=24, h=30, vx=0, frames=(10, 79))]
    folder = write_folder(tmp_path / "c0", 80, boxes)
    seen = {}
    for update in ("selective", "all"):
        cfg = BgConfig(min_area=40, init_samples=10, init_frames=10, history=20, update=update)
        masks_from_video(folder, tmp_path / f"{update}.txt", cfg, log=lambda s: None)
        t = read_mots(tmp_path / f"{update}.txt")
        seen[update] = np.array([_best_iou(t, f, truth_mask(f, boxes, 1)) for f in range(80)])
    assert seen["selective"][3:].min() > 0.9          # on the image from frame 3
    assert seen["all"][60:].max() < 0.5


def test_slow_lighting_drift_is_followed(tmp_path):
    """An empty scene brightens by 0.2 grey levels per frame (16 in all, a cloud moving off):
    the selective update follows it (no foreground, nothing unsettled); a background kept
    from the start does not settle. (Without the exposure scaling, which would undo the drift
    for both: the update itself is tested.)"""
    folder = write_folder(tmp_path / "c0", 80, [], light={f: 0.2 * f for f in range(80)})
    got = {}
    for update in ("selective", "none"):
        cfg = BgConfig(min_area=40, init_samples=5, init_frames=5, history=10, update=update,
                       exposure_band=0.0)
        got[update] = masks_from_video(folder, tmp_path / f"{update}.txt", cfg, log=lambda s: None)
    assert got["selective"].unsettled == [] and got["selective"].n_masks == 0
    assert got["none"].unsettled and got["none"].unsettled[-1][1] == 79


def test_a_cloud_is_scaled_away_and_the_road_users_stay(tmp_path):
    """Frames 24-41 are 20 % darker (a cloud over the sun: the ground, the boxes, everything),
    frames 30-34 30 % brighter than the rest instead. Scaled to the model's brightness, the
    two boxes are found as in steady light and nothing else; without the scaling the brighter
    frames do not settle and lose a box in the foreground around it (the darker ones pass
    MOG2's shadow test here: a grey, untextured background)."""
    gain = {f: 0.8 for f in range(24, 42)} | {f: 1.3 for f in range(30, 35)}
    folder = write_folder(tmp_path / "c0", 50, BOXES, gain=gain)
    got = {}
    for band in (0.03, 0.0):
        cfg = BgConfig(min_area=40, init_samples=15, exposure_band=band)
        logs = []
        got[band] = masks_from_video(folder, tmp_path / f"m{band}.txt", cfg, log=logs.append)
        got[band].logs = logs
    res = got[0.03]
    assert res.n_rescaled == 18 and res.unsettled == []
    assert any("18 of 50 frames were brighter or darker than the background model by over 3%"
               in m for m in res.logs)
    t = read_mots(tmp_path / "m0.03.txt")
    for f in range(43):  # box 1 leaves the image after frame 42
        assert (t.frame == f).sum() == 2, f  # the two boxes and nothing else
        for bid in (1, 2):
            assert _best_iou(t, f, truth_mask(f, BOXES, bid)) > 0.85, (f, bid)
    off = got[0.0]
    assert off.n_rescaled == 0 and off.unsettled == [(30, 34)]
    t_off = read_mots(tmp_path / "m0.0.txt")
    assert all((t_off.frame == f).sum() < 2 for f in range(30, 35))


def test_exposure_ratio_is_the_grounds():
    """The median ratio over the ground: a quarter of the frame covered by a bright road user
    does not move it; saturated background is left out."""
    from video_fixtures import background

    from seg2pose.video.bg_checks import exposure_ratio

    bg = background(3)
    grey = cv2_grey(bg)
    img = np.clip(np.round(bg * 0.8), 0, 255).astype(np.uint8)
    img[:60, :80] = 250  # a road user over a quarter of the image
    assert exposure_ratio(img, grey) == pytest.approx(0.8, abs=0.01)
    assert exposure_ratio(bg, grey) == pytest.approx(1.0, abs=1e-6)
    hold = np.zeros(bg.shape[:2], np.uint8)
    hold[60:] = 1  # only the top half counts, and a quarter of it is the road user
    assert exposure_ratio(img, grey, hold) > 0.8 * 1.05


def cv2_grey(img):
    import cv2

    return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY).astype(np.float32)


@pytest.mark.parametrize("kind", ["video", "folder"])
def test_every_nth_frame_is_read_as_a_full_read_gives_it(tmp_path, kind):
    """FrameReader.frames(every=3) (the first pass over a video) yields scene frames
    first, first+3, ... with the same images as reading every frame."""
    if kind == "video":
        src = write_video(tmp_path / "v.avi", 20, BOXES)
    else:
        src = write_folder(tmp_path / "c0", 20, BOXES)
    r = FrameReader(src, first=5 if kind == "video" else 0)
    full = dict(r.frames(first=None if kind == "folder" else 7))
    some = list(r.frames(first=None if kind == "folder" else 7, every=3))
    lo = min(full)
    assert [f for f, _ in some] == list(range(lo, max(full) + 1, 3))
    for f, im in some:
        assert np.array_equal(im, full[f])


def test_start_image_of_samples_under_clouds():
    """Five of twelve samples in full sun, four 15 % and three 30 % darker (clouds), over a
    background from 40 to 220 grey levels: the per-pixel mode of the samples as they are is the
    sunny group where the groups part (bright pixels) and a blend where they overlap (dark
    ones: within the mode's 12 levels), so it darkens the dark end by up to a fifth; of the
    samples scaled to one brightness it is one level everywhere (the samples' median, 0.85)."""
    from seg2pose.video.bg_start import same_exposure, start_image

    bg = np.repeat(np.linspace(40, 220, W)[None, :, None], H, 0).repeat(3, 2)
    rng = np.random.default_rng(0)
    ims = [np.clip(bg * g + rng.normal(0, 2.0, bg.shape), 0, 255).round().astype(np.uint8)
           for g in [1.0] * 5 + [0.85] * 4 + [0.7] * 3]
    assert same_exposure(ims, 0.0) is ims
    scaled = same_exposure(ims, 0.03)
    assert max(np.abs(a.astype(int) - b.astype(int)).mean() for a in scaled for b in scaled) < 5  # noise
    ratio = {band: (start_image(ims, "mode", band).astype(float) / bg).mean(axis=2)
             for band in (0.0, 0.03)}
    lo, hi = np.percentile(ratio[0.03], [1, 99])
    assert 0.83 < lo and hi < 0.88  # one level
    lo, hi = np.percentile(ratio[0.0], [1, 99])
    assert lo < 0.82 and hi > 0.99  # patchy: sunny at the bright end, darker at the dark end
