"""Against the real Rerun viewer, headless (Mesa's software Vulkan where there is no GPU).

Checks: the blueprint's views exist and none reports a warning or error; the camera views (the
right half of the window) show the video; the projected boxes are drawn in their class colours
where the camera projects them and the masks in theirs where they are (and not elsewhere); the
time cursor follows set_frame; ``s2p review --screenshot`` and ``take_screenshot`` write it.
Every viewer a test starts is stopped in a ``finally``.
"""

from __future__ import annotations

import time

import cv2
import numpy as np
import pytest
from review_fixtures import make_run, make_scene, video_rgb

from s2p_review import columns as C
from s2p_review import layout as L
from s2p_review import viewer as V
from s2p_review.recording import LogStyle
from s2p_review.session import RecordOptions, Targets, record
from seg2pose.io.mots import read_mots

_why = V.vulkan_problem()
pytestmark = pytest.mark.skipif(_why is not None, reason=f"no Vulkan for the headless viewer: {_why}")

N_FRAMES = 16
FRAME = 8
NO_IMAGES = RecordOptions(style=LogStyle(masks=False, video=False))


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
    record(video, runs, Targets(connect=viewer.url))
    st = V.wait_loaded(viewer, min_end=N_FRAMES - 1)
    V.set_frame(viewer, FRAME)
    time.sleep(1.5)  # let every view paint once so that it has reported
    st = viewer.get_state()
    names = sorted(v.name for v in st.views)
    # per run its error plot, then its road users' speed and error, one plot each (in tabs)
    assert names == sorted(["world", "camera c0", "camera c1"] +
                           [f"{what}: {r}" for r in ("run-base", "run-s2pn")
                            for what in ("error (m)", "speed (m/s)", "error against the truth (m)")])
    assert all(v.visible for v in st.views)
    assert V.view_reports(viewer) == []
    # the cameras sit on the right half and show the video there, not elsewhere
    img = _decode(viewer.take_screenshot(max_size=960))
    near = _near(img, video_rgb(FRAME))
    half = img.shape[1] // 2
    assert near[:, half:].mean() > 0.1, f"video pixels in the right half: {near[:, half:].mean():.3f}"
    assert near[:, :half].mean() < 0.1 * near[:, half:].mean()


def _near(img: np.ndarray, rgb, tol: float = 30.0) -> np.ndarray:
    """(H, W) bool: pixels within ``tol`` (RGB distance) of ``rgb``."""
    return np.linalg.norm(img - np.array(rgb), axis=2) < tol


def _view_shot(client, scene, name: str, cam: str):
    """Screenshot (H, W, 3) of the 2D view ``name`` and a function mapping image pixels (N, 2)
    of ``cam`` to screenshot pixels (the view fits the whole image, centred, aspect kept)."""
    st = client.get_state()
    view = next(v for v in st.views if v.name == name)
    assert view.reports == []
    shot = _decode(client.take_screenshot(view_id=view.view_id))
    sh, sw = shot.shape[:2]
    c = scene.cameras[cam]
    s = min(sw / c.width, sh / c.height)
    ox, oy = (sw - c.width * s) / 2, (sh - c.height * s) / 2

    def to_shot(uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x = np.clip((ox + uv[:, 0] * s).astype(int), 0, sw - 1)
        y = np.clip((oy + uv[:, 1] * s).astype(int), 0, sh - 1)
        return y, x

    return shot, to_shot


def test_camera_view_shows_video_and_projected_boxes(viewer, data):
    """Over the video, each fused box's projected edges are drawn in its class colour where
    the camera projects them, and the video shows away from every drawing."""
    from seg2pose.io.poses import read_poses

    _, video, runs, _ = data
    _fresh(viewer)
    record(video, runs[1:], Targets(connect=viewer.url), RecordOptions(style=LogStyle(masks=False)))
    V.wait_loaded(viewer, min_end=N_FRAMES - 1)
    V.set_frame(viewer, FRAME)
    time.sleep(1.5)
    shot, to_shot = _view_shot(viewer, video, "camera c0", "c0")
    cam = video.cameras["c0"]
    est = read_poses(runs[1] / "poses.csv").in_frames((FRAME, FRAME))
    gt = read_poses(video.gt_path).in_frames((FRAME, FRAME))
    drawn = np.zeros((cam.height * 4, cam.width * 4), np.uint8)  # everything drawn, 4x image px
    for t in (est, gt):
        segs, _ = C.projected_edges(cam, t.xyz, t.heading, t.size)
        for a, b in segs:
            cv2.line(drawn, tuple(int(v) for v in a * 4), tuple(int(v) for v in b * 4), 1, 24)
    segs, idx = C.projected_edges(cam, est.xyz, est.heading, est.size)
    assert len(idx) == 3
    for k, i in enumerate(idx):
        # the middle third of each edge (corners are shared with other edges)
        ab = segs[k * 12:(k + 1) * 12]
        pts = np.concatenate([ab[:, 0] + (ab[:, 1] - ab[:, 0]) * u for u in np.linspace(0.35, 0.65, 7)])
        pts = pts[cam.in_image(pts)]
        y, x = to_shot(pts)
        want = L.class_color(est.cls[i], 0)
        hit = _near(shot[y, x][None], want, tol=60)[0]
        assert hit.mean() > 0.6, f"{est.cls[i]}: {hit.mean():.2f} of its edge pixels in its colour"
    # video colour wherever nothing is drawn (and the points of the views are left out too)
    v = runs[1]
    from seg2pose.io.run import read_views

    vv = read_views(v / "views.csv")
    for uv in vv.uv[(vv.frame == FRAME) & (vv.camera == "c0")]:
        cv2.circle(drawn, tuple(int(c * 4) for c in uv), 40, 1, -1)
    gy, gx = np.mgrid[2:cam.height - 2:0.5, 2:cam.width - 2:0.5]
    free = drawn[(gy * 4).astype(int), (gx * 4).astype(int)] == 0
    y, x = to_shot(np.c_[gx[free], gy[free]])
    assert _near(shot[y, x][None], video_rgb(FRAME))[0].mean() > 0.95


def test_time_cursor(viewer, data):
    _, video, runs, _ = data
    _fresh(viewer)
    record(video, runs, Targets(connect=viewer.url), NO_IMAGES)
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
    record(plain, [], Targets(connect=viewer.url), RecordOptions(cameras=["c0"]))
    V.wait_loaded(viewer, min_end=N_FRAMES - 1)
    V.set_frame(viewer, FRAME)
    time.sleep(1.5)
    shot, to_shot = _view_shot(viewer, plain, "camera c0", "c0")
    cam = plain.cameras["c0"]
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
        y, x = to_shot(np.c_[c + 0.5, r + 0.5])
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
                                 str(png), "-o", str(root / "s.rrd"), "--frame", "4"])
    assert r.exit_code == 0, r.output
    for img in (_decode(png.read_bytes()),
                # and from the saved .rrd (the README path)
                _decode(V.take_screenshot(root / "s.rrd", root / "shot2.png", frame=4,
                                          max_size=800).read_bytes())):
        # the camera views (right half) show the video of frame 4
        near = _near(img, video_rgb(4))
        half = img.shape[1] // 2
        assert near[:, half:].mean() > 0.1 and near[:, :half].mean() < 0.1 * near[:, half:].mean()
    assert img.shape[1] == 800
    png2 = root / "shot2.png"
    with pytest.raises(Exception, match="--force"):
        V.take_screenshot(root / "s.rrd", png2)


def test_connect_sets_time_cursor(viewer, data):
    _, video, runs, _ = data
    _fresh(viewer)
    record(video, runs[:1], Targets(connect=viewer.url, frame=11), NO_IMAGES)
    st = viewer.get_state()
    rec = next(r for r in st.recordings if r.store_id == st.active_recording)
    assert rec.current_timeline == "frame" and rec.current_time == 11


def test_screenshot_of_an_mcap_export_shows_video(data):
    """`s2p screenshot F.mcap` works (Rerun's MCAP loader has a log-time timeline, not `frame`)
    and its camera views show the video."""
    from typer.testing import CliRunner

    from s2p_review.mcap_export import export_mcap
    from seg2pose.cli import app

    _, video, runs, root = data
    res = export_mcap(video, runs[1], root / "v.mcap")
    png = root / "mcap.png"
    r = CliRunner().invoke(app, ["screenshot", str(res.path), "-o", str(png), "--frame", "4"])
    assert r.exit_code == 0, r.output
    img = _decode(png.read_bytes())
    assert _near(img, video_rgb(4), tol=12).mean() > 0.05
    assert _near(img, video_rgb(12), tol=12).mean() < 0.01  # the frame asked for, not another
