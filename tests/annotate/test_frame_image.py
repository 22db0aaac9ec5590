"""The large camera's picture (annotate.app.frame_image): the exact frame asked for, in any
order of steps and jumps (read back from a frame-code video), the selected track's box drawn
where its box projects, and a plain note where there is no video."""

from __future__ import annotations

import numpy as np
import pytest

from s2p_review.frame_code import read_code, write_code_video


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    from seg2pose.io.scene import load_scene
    from seg2pose.synth.generate import SynthOptions, generate_scene

    root = tmp_path_factory.mktemp("frameimg") / "scene"
    generate_scene(root, SynthOptions(preset="small", frames=12, seed=3, video=False,
                                      progress=False, workers=1))
    s = load_scene(root)
    n = max(b for _, b in s.splits.values()) + 1
    cam = s.cameras["c0"]
    write_code_video(root / "video" / "c0.mp4", cam.width, cam.height, n)
    return load_scene(root), n


@pytest.fixture
def pictures(scene, tmp_path, monkeypatch):
    from annotate.app.frame_image import FrameImages

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))  # the asset made here
    s, n = scene
    fi = FrameImages(s, ["c0", "c1"], 0, n - 1)
    yield fi
    fi.close()


def _decode(pic) -> np.ndarray:
    import cv2

    return cv2.imdecode(np.frombuffer(pic.jpeg, np.uint8), cv2.IMREAD_COLOR)


def _code(img) -> int:
    g = img.mean(axis=2)
    h, w = g.shape

    def sample(u, v):
        x, y = int(u * w), int(v * h)
        return float(np.median(g[y - 3:y + 4, x - 3:x + 4]))
    return read_code(sample)


def test_every_frame_is_the_frame_asked_for(scene, pictures):
    s, n = scene
    rng = np.random.default_rng(0)
    # steps forward, steps back, short and long jumps both ways, repeats
    order = [0, 1, 2, 3, 2, 1, 15, 16, n - 1, 5, 5, 30, 18, 6] + list(rng.integers(0, n, 25))
    for f in order:
        pic = pictures.render("c0", int(f), [], None)
        assert (pic.width, pic.height, pic.note) == (s.cameras["c0"].width, s.cameras["c0"].height, "")
        assert _code(_decode(pic)) == f, f"frame {f}"


def test_no_video_is_said_and_grey(scene, pictures):
    pic = pictures.render("c1", 4, [], None)  # c1 has no video in this scene
    assert pic.note == "no video for frame 4 in camera c1"
    img = _decode(pic)
    assert img.shape == (pictures.scene.cameras["c1"].height, pictures.scene.cameras["c1"].width, 3)
    assert abs(np.median(img) - 90) <= 2
    pic = pictures.render("c0", 10_000, [], None)  # beyond the video
    assert "no video for frame 10000" in pic.note


def test_selected_track_drawn_where_its_box_projects(scene, pictures):
    from annotate.place import pixel_to_ground
    from s2p_review import columns as C
    from s2p_review.annotation_log import TrackColumns

    s, _ = scene
    cam = s.cameras["c0"]
    x, y = pixel_to_ground(cam, s.ground, (cam.width * 0.5, cam.height * 0.7))
    z = float(s.ground.height(np.array([[x, y]]))[0])
    t = TrackColumns(7, "car", np.array([3, 4]), np.array([[x, y, z], [x + 1, y, z]]),
                     np.zeros(2), np.array([[4.4, 1.8, 1.5]] * 2), np.array(["keyframe", "interpolated"]))
    paths, idx = C.projected_paths(cam, t.xyz[:1], t.heading[:1], t.size[:1])
    assert len(idx) == 1
    yellow = lambda a: (a[..., 2] > 200) & (a[..., 1] > 170) & (a[..., 0] < 90)  # noqa: E731
    sel = _decode(pictures.render("c0", 3, [t], 7))
    other = _decode(pictures.render("c0", 3, [t], None))
    none = _decode(pictures.render("c0", 5, [t], 7))  # the track has no pose at frame 5
    ys, xs = np.nonzero(yellow(sel))
    assert len(xs) > 200
    # the yellow pixels lie on the projected box's outline (within the line's width)
    p = paths[0]
    seg_a, seg_b = p[:-1], p[1:]
    pts = np.c_[xs, ys].astype(float)[:, None, :]
    d = seg_b - seg_a
    tt = np.clip(((pts - seg_a) * d).sum(-1) / np.maximum((d * d).sum(-1), 1e-9), 0, 1)
    dist = np.linalg.norm(pts - (seg_a + tt[..., None] * d), axis=-1).min(axis=1)
    near = dist < 4.0
    label = (ys < p[:, 1].min() + 2)  # the label is written above the box
    assert (near | label).mean() > 0.97
    assert yellow(other).sum() < 20 and yellow(none).sum() < 20


def test_small_picture_keeps_the_camera_size_and_the_frame(scene, pictures):
    import cv2

    pic = pictures.render("c0", 7, [], None, width=320)
    img = cv2.imdecode(np.frombuffer(pic.jpeg, np.uint8), cv2.IMREAD_COLOR)
    cam = pictures.scene.cameras["c0"]
    assert img.shape[1] == 320 and abs(img.shape[0] - 320 * cam.height / cam.width) <= 1
    assert (pic.width, pic.height) == (cam.width, cam.height)  # clicks map to camera pixels
    assert _code(img) == 7
