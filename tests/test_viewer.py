"""Against the real Rerun viewer, headless (Mesa's software Vulkan where there is no GPU).

Checks: the blueprint's views exist and none reports a warning or error; a screenshot is not
blank and shows the class colours where the masks are (and not elsewhere); the time cursor
follows set_frame; ``s2p review --screenshot`` and ``take_screenshot`` write a PNG.
Every viewer a test starts is stopped in a ``finally``.
"""

from __future__ import annotations

import time

import cv2
import numpy as np
import pytest

from seg2pose.io.mots import read_mots
from s2p_review import columns as C
from s2p_review import layout as L
from s2p_review import viewer as V
from s2p_review.recording import RecordOptions, record

from review_fixtures import make_run, make_scene

_why = V.vulkan_problem()
pytestmark = pytest.mark.skipif(_why is not None, reason=f"no Vulkan for the headless viewer: {_why}")

N_FRAMES = 16
FRAME = 8


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = tmp_path_factory.mktemp("viewer")
    plain = make_scene(root / "plain", n_frames=N_FRAMES, video=False)
    video = make_scene(root / "video", n_frames=N_FRAMES, video=True)
    runs = [make_run(video, root / "video" / "out" / "run-base"),
            make_run(video, root / "video" / "out" / "run-s2pn", method="seg2posenet", residual=0.2)]
    return plain, video, runs, root


@pytest.fixture(scope="module")
def viewer():
    client = V.spawn_viewer(headless=True)
    try:
        yield client
    finally:
        V.stop(client)


def _decode(png: bytes) -> np.ndarray:
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    assert img is not None, "screenshot is not a PNG"
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB).astype(np.int32)


def _fresh(client) -> None:
    st = client.get_state()
    if st.recordings:
        client.close("all")


def test_views_report_no_warnings(viewer, data):
    _, video, runs, _ = data
    _fresh(viewer)
    record(video, runs, connect=viewer.url)
    st = V.wait_loaded(viewer, min_end=N_FRAMES - 1)
    V.set_frame(viewer, FRAME)
    time.sleep(1.5)  # let every view paint once so that it has reported
    st = viewer.get_state()
    names = sorted(v.name for v in st.views)
    assert names == sorted(["world", "camera c0", "camera c1", "error (m) vs frame"])
    assert all(v.visible for v in st.views)
    assert V.view_reports(viewer) == []
    png = viewer.take_screenshot(max_size=960)
    img = _decode(png)
    assert img.std() > 10, "the screenshot is blank"


def test_time_cursor(viewer, data):
    _, video, runs, _ = data
    _fresh(viewer)
    record(video, runs, connect=viewer.url, options=RecordOptions(masks=False, video=False))
    V.wait_loaded(viewer, min_end=N_FRAMES - 1)
    V.set_frame(viewer, 5)
    st = viewer.get_state()
    rec = next(r for r in st.recordings if r.store_id == st.active_recording)
    assert rec.current_timeline == "frame" and rec.current_time == 5
    tl = next(t for t in rec.timelines if t.name == "frame")
    assert (tl.start, tl.end) == (0, N_FRAMES - 1)
    V.follow(viewer)  # live-review mode must be accepted


def test_screenshot_shows_mask_colours_where_masks_are(viewer, data):
    plain = data[0]
    _fresh(viewer)
    # scene only (no runs): the only class-coloured pixels are the masks
    record(plain, [], connect=viewer.url, options=RecordOptions(cameras=["c0"]))
    V.wait_loaded(viewer, min_end=N_FRAMES - 1)
    V.set_frame(viewer, FRAME)
    time.sleep(1.5)
    st = viewer.get_state()
    view = next(v for v in st.views if v.name == "camera c0")
    assert view.reports == []
    shot = _decode(viewer.take_screenshot(view_id=view.view_id))
    sh, sw = shot.shape[:2]
    cam = plain.cameras["c0"]
    # the 2D view fits the whole image, centred, aspect kept
    s = min(sw / cam.width, sh / cam.height)
    ox, oy = (sw - cam.width * s) / 2, (sh - cam.height * s) / 2
    mt = read_mots(plain.masks_path("c0"), frame_range=(FRAME, FRAME))
    cls_img = C.paint_masks(mt.rles, mt.class_id, np.zeros(len(mt), np.int64), cam.height, cam.width, 1)[0]
    border = np.concatenate([shot[0], shot[-1], shot[:, 0], shot[:, -1]])
    bg = np.median(border, axis=0)
    by_id = {c.id: np.array(L.class_color(c.name, c.id)) for c in plain.classes}
    ids = np.array(sorted(by_id))
    dirs = np.array([by_id[i] - bg for i in ids], float)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)

    def sample(mask: np.ndarray) -> np.ndarray:
        r, c = np.nonzero(mask)
        x = np.clip((ox + (c + 0.5) * s).astype(int), 0, sw - 1)
        y = np.clip((oy + (r + 0.5) * s).astype(int), 0, sh - 1)
        return shot[y, x] - bg

    def nearest_class(v: np.ndarray) -> np.ndarray:
        n = np.linalg.norm(v, axis=1)
        cls = ids[np.argmax((v / np.maximum(n, 1e-9)[:, None]) @ dirs.T, axis=1)]
        return np.where(n > 40, cls, 0)  # 0: no colour (background-like)

    present = [int(c) for c in np.unique(cls_img) if c]
    assert len(present) == 3
    for c in present:
        inner = cv2.erode((cls_img == c).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        assert inner.sum() >= 3
        got = nearest_class(sample(inner))
        assert np.mean(got == c) > 0.7, f"class {c}: {np.mean(got == c):.2f} of mask pixels in its colour"
    far = cv2.dilate((cls_img > 0).astype(np.uint8), np.ones((9, 9), np.uint8)) == 0
    got = nearest_class(sample(far))
    assert np.mean(got > 0) < 0.02, "class colours away from the masks"


def test_cli_screenshot_and_take_screenshot(data):
    from typer.testing import CliRunner

    from seg2pose.cli import app

    _, video, runs, root = data
    png = root / "shot.png"
    r = CliRunner().invoke(app, ["review", str(video.root), "--run", str(runs[1]), "--screenshot",
                                 str(png), "--save", str(root / "s.rrd"), "--frame", "4"])
    assert r.exit_code == 0, r.output
    img = _decode(png.read_bytes())
    assert img.shape[0] >= 600 and img.std() > 10
    # and from the saved .rrd (the README path)
    png2 = V.take_screenshot(root / "s.rrd", root / "shot2.png", frame=4, max_size=800)
    assert max(_decode(png2.read_bytes()).shape[:2]) == 800
    with pytest.raises(Exception, match="--force"):
        V.take_screenshot(root / "s.rrd", png2)


def test_connect_sets_time_cursor(viewer, data):
    _, video, runs, _ = data
    _fresh(viewer)
    record(video, runs[:1], connect=viewer.url, screenshot_frame=11,
           options=RecordOptions(masks=False, video=False))
    st = viewer.get_state()
    rec = next(r for r in st.recordings if r.store_id == st.active_recording)
    assert rec.current_timeline == "frame" and rec.current_time == 11
