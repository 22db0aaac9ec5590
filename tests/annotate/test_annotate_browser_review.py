"""End to end in a real browser (Playwright + headless Debian chromium, software WebGL): the
pre-annotate-then-review workflow of issue 40. On a scene with camera video and a run whose
estimate of one car has an outlier at one pre-annotated keyframe:

Shift+p pre-annotates every road user (only where its masks are); the car's track is picked in
the panel, played from its first frame (p) and the playback stops before the outlier, where
the interpolation leaves the estimates; the keyframe is fixed by dragging its base in the
picture and the box made longer (l); the rest is played, the track marked reviewed (Shift+r),
and the set exported: every exported row of the reviewed track is a checked row within 1 m of
its road user, and no row of any track lies in a frame far from any of its road user's masks.

Shares the skips of test_annotate_browser.py (chromium, Playwright, load).
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from test_annotate_browser import ARGS, CAM, CHROMIUM, _open, _panel, _road_user, _shown_frame, _wait

from s2p_review.frame_code import write_code_video

playwright_api = pytest.importorskip("playwright.sync_api")
OFFSET = np.array([0.3, -0.4])   # the run = truth + this (metres)
OUTLIER = np.array([2.5, 0.0])   # and this more at one keyframe of the car


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    from annotate.presence import plan
    from seg2pose.io.poses import PoseTable, read_poses
    from seg2pose.io.run import write_run_folder
    from seg2pose.io.scene import load_scene
    from seg2pose.synth.generate import SynthOptions, generate_scene

    base = tmp_path_factory.mktemp("review")
    root = base / "scene"
    generate_scene(root, SynthOptions(preset="small", frames=40, seed=1, video=False, progress=False,
                                      workers=1))
    s = load_scene(root)
    n = max(b for _, b in s.splits.values()) + 1
    write_code_video(root / "video" / f"{CAM}.mp4", s.cameras[CAM].width, s.cameras[CAM].height, n)
    gt = read_poses(s.gt_path)
    tid, *_ = _road_user(s, (20, 35, 50, 65, 80))
    from annotate.estimates import MaskIndex

    seen = MaskIndex(s).seen(tid)
    mine = gt.take(gt.track_id == tid)
    kf = [k[0] for k in plan(mine, seen, 25).keyframes]
    outlier = kf[1]
    xyz = gt.xyz.copy()
    xyz[:, :2] += OFFSET
    xyz[(gt.track_id == tid) & (gt.frame == outlier), :2] += OUTLIER
    est = PoseTable(gt.frame, gt.track_id, gt.cls, xyz, gt.heading, gt.size)
    run = write_run_folder(base / "run", est, None, {
        "scene": str(root), "scene_fingerprint": s.fingerprint(), "method": "baseline",
        "cameras": list(s.cameras)})
    return root, run, tid, outlier, gt


@pytest.fixture(scope="module")
def page(setup):
    from annotate.app import serve

    root, run, *_ = setup
    server = serve.start(root, run=run, cameras=[CAM], wait=90)
    try:
        with playwright_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
            try:
                pg = browser.new_page(viewport={"width": 1800, "height": 1000})
                pg.set_default_timeout(120_000)
                _open(pg, server.url)
                yield pg
            finally:
                browser.close()
    finally:
        server.stop()


def _project(root):
    from annotate import Project

    return Project.open(root, read_only=True)


def _track_of(root, road_user: int) -> int:
    with _project(root) as p:
        return next(t.id for t in p.tracks.values() if t.meta.get("run_track") == road_user)


def _message(page) -> str:
    return _panel(page, "message")


def test_preannotate_review_fix_and_export(page, setup, monkeypatch, capsys):
    from scene_fixtures import s2p

    from annotate.presence import MAX_GAP
    from seg2pose.io.poses import read_poses
    from seg2pose.io.scene import load_scene

    root, _run, road_user, outlier, gt = setup
    s = load_scene(root)
    page.keyboard.press("Shift+p")
    _wait(lambda: "pre-annotated" in _message(page), 60, "the pre-annotation")
    tid = _track_of(root, road_user)
    page.click(f"[data-testid=tracks] tr[data-track='{tid}']")
    with _project(root) as p:
        first = int(p.track_poses(tid).frame[0])
    page.keyboard.press("f")
    time.sleep(0.2)
    page.keyboard.type(str(first))
    page.keyboard.press("Enter")
    _wait(lambda: _shown_frame(page) == str(first), 30, f"the picture of frame {first}")

    # play: it stops before the outlier, where the interpolation leaves the estimates
    page.keyboard.press("p")
    _wait(lambda: "stopped at frame" in _message(page), 60, "the playback to stop")
    stop = int(_panel(page, "frame-number"))
    assert first < stop < outlier, (first, stop, outlier, _message(page))
    assert "from its road user's estimate" in _message(page)

    # to the outlier keyframe (]), drag its base back onto the road user, one size step longer
    page.keyboard.press("]")
    _wait(lambda: _shown_frame(page) == str(outlier), 30, "the outlier's keyframe")
    cam = s.cameras[CAM]
    with _project(root) as p:
        x, y, _ = p.pose_at(tid, outlier)
        size0 = p.track(tid).size
    i = int(np.flatnonzero((gt.track_id == road_user) & (gt.frame == outlier))[0])
    want = gt.xyz[i, :2] + OFFSET
    pts = np.array([[x, y], want])
    uv, _, _ = cam.project_points(np.c_[pts, s.ground.height(pts)])
    el = page.query_selector("[data-testid=frame-image]")
    box = el.bounding_box()
    k = box["width"] / cam.width
    a, b = [np.array([box["x"], box["y"]]) + k * u for u in uv]
    page.mouse.move(*a)
    page.mouse.down()
    for t in np.linspace(0, 1, 6)[1:]:
        page.mouse.move(*(a + t * (b - a)))
    page.mouse.up()
    _wait(lambda: "moved by" in _message(page), 30, "the drag")
    with _project(root) as p:
        x1, y1, _ = p.pose_at(tid, outlier)
        assert np.hypot(x1 - want[0], y1 - want[1]) < 0.15, (x1, y1, want)
        assert "estimate" not in p.track(tid).keyframes[outlier].flags
    page.keyboard.press("l")
    _wait(lambda: "l, w, h" in _message(page), 20, "the size edit")
    with _project(root) as p:
        assert p.track(tid).size[0] == pytest.approx(size0[0] + 0.1)

    # play on to the end (each stop looked at), then the whole track reviewed
    for _ in range(6):
        page.keyboard.press("p")
        _wait(lambda: "stopped at frame" in _message(page) or "nothing to play" in _message(page),
              60, "the playback")
        if "the end of the track" in _message(page):
            break
    page.keyboard.press("Shift+r")
    _wait(lambda: "all its frames reviewed" in _message(page), 20, "the review mark")

    code, out, err = s2p(monkeypatch, capsys, "annotate", "export", root, "--allow-unreviewed",
                         "--no-mcap", "--no-tanalyst", "--force")
    assert code == 0, err
    rows = read_poses(s.gt_path)
    mine = rows.take(rows.track_id == tid)
    assert set(mine.source) <= {"keyframe", "estimate-accepted", "reviewed", "occluded"}
    truth = gt.take(gt.track_id == road_user)
    at = {int(f): j for j, f in enumerate(truth.frame)}
    d = [np.hypot(*(mine.xyz[j, :2] - truth.xyz[at[int(f)], :2])) for j, f in enumerate(mine.frame)]
    assert max(d) < 1.0, f"the reviewed track is {max(d):.2f} m from its road user"
    # no row of any track where its road user is in no camera (beyond a bridged short gap)
    from annotate.estimates import MaskIndex

    seen = MaskIndex(s).presence()
    with _project(root) as p:
        link = {t.id: t.meta.get("run_track") for t in p.tracks.values()}
    for t in np.unique(rows.track_id):
        fr = seen[link[int(t)]]
        f = rows.frame[rows.track_id == t]
        gap = np.abs(f[:, None] - fr[None, :]).min(axis=1)
        assert gap.max() <= MAX_GAP, f"track {t} has rows {gap.max()} frames from its masks"
