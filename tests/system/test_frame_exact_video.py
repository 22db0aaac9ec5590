"""Frame-exact video in every reader: an H.264 video with B-frames (stored out of display order)
and a variable frame rate (irregular timestamps), made here with PyAV, whose frames show their
own number (s2p_review/frame_code.py), read back at random seeks by the decoder
(seg2pose/io/video_decode.py), a scene's camera reader (seg2pose/io/video.py), the review's
video asset (s2p_review/video_asset.py), the annotation app's frame picture
(annotate/app/frame_image.py) and masks-from-video (seg2pose/video/video_masks.py). The
MJPG and mp4v videos the other tests use stay exact, with OpenCV's pixels."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from s2p_review.frame_code import code_image, read_code, write_code_video_h264
from seg2pose.io.video_decode import VideoDecoder, video_index

W, H = 320, 240          # the tiny scene's cameras (tests/scene_fixtures.py)
N = 90                   # video frames
FIRST, STEP = 5, 2       # scene frame of video frame k: FIRST + STEP * k


def code(img: np.ndarray) -> int:
    g = img.mean(axis=2) if img.ndim == 3 else img
    h, w = g.shape

    def sample(u, v):
        x, y = int(u * w), int(v * h)
        return float(np.median(g[y - 3:y + 4, x - 3:x + 4]))
    return read_code(sample)


@pytest.fixture(scope="module")
def bvideo(tmp_path_factory) -> Path:
    import av

    p = tmp_path_factory.mktemp("bframes") / "c1.mp4"
    pts = write_code_video_h264(p, W, H, N, bframes=3, gop=25, vfr=True)
    # the file is what the test claims: B-frames (decode order != display order), variable rate
    with av.open(str(p)) as c:
        st = c.streams.video[0]
        stored = [pk.pts for pk in c.demux(st) if pk.size]
    assert stored != sorted(stored), "no B-frames: the test would not test reordering"
    assert len(set(np.diff(pts).tolist())) > 2, "constant frame rate"
    return p


def test_decoder_random_seeks_and_sequence(bvideo):
    dec = VideoDecoder(bvideo)
    idx = video_index(bvideo)
    assert len(dec) == N and (idx.width, idx.height) == (W, H)
    rng = np.random.default_rng(1)
    # jumps both ways, steps, repeats, the first and the last frame
    order = [0, N - 1, 1, 2, 3, 2, 40, 26, 25, 24, 89, 0] + rng.integers(0, N, 120).tolist()
    got = [code(dec.read(int(k))) for k in order]
    assert got == order
    assert [code(im) for _, im in dec.frames()] == list(range(N))
    assert [k for k, _ in dec.frames(7, 60, every=9)] == list(range(7, 61, 9))
    assert all(code(im) == k for k, im in dec.frames(7, 60, every=9))
    assert dec.read(N) is None and dec.read(-1) is None
    dec.close()


@pytest.fixture(scope="module")
def scene(tmp_path_factory, bvideo):
    from scene_fixtures import make_tiny_scene

    from seg2pose.io.scene import load_scene

    root = tmp_path_factory.mktemp("bscene") / "scene"
    s = make_tiny_scene(root, frames=FIRST + STEP * N)
    (root / "video").mkdir()
    (root / "video" / "c1.mp4").hardlink_to(bvideo)
    s.extra["video_frames"] = {"c1": {"first": FIRST, "step": STEP}}
    s.save(root)
    return load_scene(root)


def test_camera_reader(scene):
    from seg2pose.io.video import camera_reader

    r = camera_reader(scene, "c1")
    assert r.header() == (W, H, N)
    rng = np.random.default_rng(2)
    want = np.unique(FIRST + STEP * rng.integers(0, N, 30))
    got = r.sample(want)
    assert [f for f, _ in got] == want.tolist()
    assert all(code(im) == (f - FIRST) // STEP for f, im in got)
    for a, b, every in ((FIRST + STEP * 33, FIRST + STEP * 70, 1), (FIRST + STEP * 12, None, 5), (None, 40, 3)):
        frames = list(r.frames(a, b, every))
        assert frames and all(code(im) == (f - FIRST) // STEP for f, im in frames), (a, b, every)
        assert r.stopped is None
    assert [f for f, _ in r.frames(FIRST + STEP * 86)] == [FIRST + STEP * k for k in range(86, N)]


def test_review_video_asset(scene, tmp_path):
    """The viewer's asset: the frame at each of its timestamps shows the scene frame it is sent
    for (s2p_review/recording_images.py sends ``asset.frames`` at ``asset.timestamps_ns``)."""
    import av

    from s2p_review import imagery
    from s2p_review.video_asset import video_asset

    lo, hi = FIRST + STEP * 20, FIRST + STEP * 64
    assert [(f, code(im)) for f, im in imagery.video_frames(scene, "c1", lo, hi, every=3)] == [
        (FIRST + STEP * k, k) for k in range(20, 65) if (STEP * (k - 20)) % 3 == 0]
    asset = video_asset(scene, "c1", lo, hi, folder=tmp_path / "cache")
    assert asset is not None and asset.frames.tolist() == [FIRST + STEP * k for k in range(20, 65)]
    with av.open(str(asset.path)) as c:
        st = c.streams.video[0]
        shown = {int(round(fr.pts * st.time_base * 1e9)): code(fr.to_ndarray(format="gray")) for fr in c.decode(st)}
    assert [shown[t] for t in asset.timestamps_ns] == [(f - FIRST) // STEP for f in asset.frames]


def test_annotation_app_frame_picture(scene, tmp_path, monkeypatch):
    from annotate.app.frame_image import FrameImages

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    lo, hi = FIRST, FIRST + STEP * (N - 1)
    fi = FrameImages(scene, ["c1"], lo, hi)
    rng = np.random.default_rng(3)
    order = [0, 1, 2, 1, 50, 13, 89, 88, 30] + rng.integers(0, N, 40).tolist()
    try:
        got = [code(fi.video_frame("c1", FIRST + STEP * k)) for k in order]
    finally:
        fi.close()
    assert got == order


def test_masks_from_video_reads_the_right_frames(scene, tmp_path, monkeypatch):
    """masks-from-video on a segment in the middle (as s2p batch cuts long videos): every image
    it reads (the starting background's samples, the cleaning pass, the frames) is the frame
    it believes it is."""
    from seg2pose.io import video as V
    from seg2pose.video.video_masks import BgConfig, masks_from_video

    seen: list[tuple[int, int]] = []
    frames, sample = V.FrameReader.frames, V.FrameReader.sample

    def checked_frames(self, *a, **k):
        for f, im in frames(self, *a, **k):
            seen.append((f, code(im)))
            yield f, im

    def checked_sample(self, want):
        out = sample(self, want)
        seen.extend((f, code(im)) for f, im in out)
        return out

    monkeypatch.setattr(V.FrameReader, "frames", checked_frames)
    monkeypatch.setattr(V.FrameReader, "sample", checked_sample)
    lo, hi = FIRST + STEP * 30, FIRST + STEP * 70
    res = masks_from_video(scene.video_path("c1"), tmp_path / "m.txt", BgConfig(min_area=40, init_samples=9),
                           first_frame=FIRST, frame_step=STEP, frames=(lo, hi), log=lambda s: None)
    assert res.n_frames == 41 and res.last_good == hi and res.stopped is None
    assert len(seen) > 41 and all(c == (f - FIRST) // STEP for f, c in seen)


@pytest.mark.parametrize("fourcc,ext", [("MJPG", ".avi"), ("mp4v", ".mp4")])
def test_intra_and_mpeg4_videos_exact_with_opencvs_pixels(tmp_path, fourcc, ext):
    import cv2

    p = tmp_path / f"v{ext}"
    vw = cv2.VideoWriter(str(p), cv2.VideoWriter_fourcc(*fourcc), 10.0, (W, H))
    for k in range(40):
        img = code_image(k, W, H)
        img[H // 5:, :] = (np.arange(W)[None, :, None] * 3 + k * 5) % 256
        vw.write(img)
    vw.release()
    dec = VideoDecoder(p)
    cap = cv2.VideoCapture(str(p))
    for k in range(40):
        ok, want = cap.read()
        assert ok and np.array_equal(dec.read(k), want), k     # OpenCV's conversion, pixel for pixel
    cap.release()
    order = np.random.default_rng(4).integers(0, 40, 30).tolist()
    assert [code(dec.read(k)) for k in order] == order
    dec.close()
