"""Rough models filmed over a video's background and background-subtracted (seg2pose.training.rough_video):
the background and noise measured from the video, examples that are the subtractor's masks of
the filmed models, merged blobs from neighbours, and when training uses them."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scene_fixtures import make_tiny_scene
from video_fixtures import single_threaded_opencv

from seg2pose.structures.masks import decode
from seg2pose.synth.raster import fill_parts, project_parts
from seg2pose.synth.rough import place, rough_model
from seg2pose.training.rough_video import VideoLook, render_video_examples, video_look
from seg2pose.video.video_masks import BgConfig

opencv_one_thread = pytest.fixture(autouse=True)(single_threaded_opencv)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    return make_tiny_scene(tmp_path_factory.mktemp("rough_video"), frames=8, n_users=2, seed=3)


def _background(h: int, w: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    small = rng.integers(70, 130, size=(h // 20, w // 20, 3)).astype(np.uint8)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)


def _clean(camera, xyz, heading, cls) -> np.ndarray:
    """The clean silhouette (H, W) of a rough model at xyz, heading (no size jitter)."""
    uv, ok = project_parts(camera, place(rough_model(cls), heading, xyz))
    assert ok.all()
    buf = np.zeros((camera.width, camera.height), np.uint8)
    fill_parts(buf, uv, np.ones(len(uv), np.int64))
    return buf.T


def _iou(a, b) -> float:
    return float(np.logical_and(a, b).sum() / max(np.logical_or(a, b).sum(), 1))


def test_video_look_measures_the_background_and_the_noise(tiny):
    cam = tiny.cameras["c1"]
    bg = _background(cam.height, cam.width)
    folder = tiny.root / "video" / "c1"
    folder.mkdir(parents=True)
    rng = np.random.default_rng(1)
    for f in range(30):
        img = bg.astype(np.int16) + rng.normal(0, 4.0, bg.shape).round().astype(np.int16)
        x = 10 + 8 * f  # a box passing through: not in the median
        img[100:140, x:x + 30] = (20, 220, 240)
        cv2.imwrite(str(folder / f"{f:06d}.png"), np.clip(img, 0, 255).astype(np.uint8))
    look = video_look(tiny, "c1", samples=15)
    assert look.background.shape == bg.shape
    # the median of 15 noisy frames: within 2 grey levels of the true background on average
    assert np.abs(look.background.astype(int) - bg).mean() < 2.0
    # frame minus median: the noise of one frame (4) and a little of the median's own
    assert 3.6 < look.noise_sigma < 4.8


def _filmed(scene, cls: str, n: int, seed: int, neighbours: float):
    """``n`` filmed rough-model examples of ``cls`` on camera c1 over a synthetic background."""
    cam = scene.cameras["c1"]
    look = VideoLook(_background(cam.height, cam.width), 2.0, BgConfig(min_area=20))
    return cam, *render_video_examples(cam, scene.ground, cls, n, np.random.default_rng(seed), look,
                                       neighbours=neighbours, occlusion=0.0, scale_jitter=0.0)


def test_isolated_examples_are_the_subtractors_masks_of_the_filmed_models(tiny):
    cam, rles, xyz, hd, stats = _filmed(tiny, "car", 24, seed=0, neighbours=0.0)
    assert len(rles) == 24 and xyz.shape == (24, 3) and hd.shape == (24,)
    assert stats["merged"] == 0 and stats["targets"] >= 24 and stats["frames"] >= 3
    ious = []
    for r, p, h in zip(rles, xyz, hd):
        m = decode(r, cam.height, cam.width).astype(bool)
        assert m.sum() >= 20
        ious.append(_iou(m, _clean(cam, p, h, "car")))
    # the masks are the filmed models (shadow remnants, closing and colour-alike holes
    # change them a little, but every one is the right road user)
    assert np.median(ious) > 0.9 and min(ious) > 0.6
    # and they are not the clean silhouettes: the subtractor's artefacts are in them
    assert np.mean(ious) < 0.99
    # the truth is the model's ground contact point: on the ground
    np.testing.assert_allclose(xyz[:, 2], tiny.ground.height(xyz[:, :2]), atol=1e-9)


def test_neighbours_make_merged_blobs_larger_than_the_target(tiny):
    cam, rles, xyz, hd, stats = _filmed(tiny, "pedestrian", 40, seed=2, neighbours=1.0)
    assert stats["merged"] >= 5
    area = np.array([decode(r, cam.height, cam.width).sum() for r in rles])
    clean = np.array([_clean(cam, p, h, "pedestrian").sum() for p, h in zip(xyz, hd)])
    # some blobs hold a neighbour too: much larger than the pedestrian alone
    assert (area > 1.8 * clean).sum() >= 3


def test_size_mismatch_is_refused(tiny):
    from seg2pose.core.errors import InputError

    cam = tiny.cameras["c1"]
    look = VideoLook(np.zeros((10, 10, 3), np.uint8), 2.0, BgConfig())
    with pytest.raises(InputError, match="calibration"):
        render_video_examples(cam, tiny.ground, "car", 3, np.random.default_rng(0), look)


@pytest.mark.parametrize("flag,video,expect", [(False, True, False), (True, True, True),
                                               (True, False, False)])
def test_training_films_rough_models_only_when_asked_and_there_is_video(tiny, monkeypatch, flag,
                                                                       video, expect):
    import seg2pose.training.rough_video as rv
    from seg2pose.training.config import TrainConfig
    from seg2pose.training.training_data import rough_looks

    monkeypatch.setattr(rv, "video_look", lambda scene, cam: ("look", cam))
    monkeypatch.setattr(type(tiny), "video_path",
                        lambda self, cam: (self.root / "v.mp4") if video else None)
    cfg = TrainConfig(zero_annotation=True, rough_video=flag)
    looks = rough_looks(tiny, ["c1"], cfg)
    assert looks == ({"c1": ("look", "c1")} if expect else {})
    assert TrainConfig().rough_video is False  # measured worse than clean rough models
