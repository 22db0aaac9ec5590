"""End to end in a real browser: ``s2p annotate``'s server on a small synthetic scene (masks, no
video), headless Debian chromium driven by Playwright, clicks on a road user in a camera view
and the panel's keyboard shortcuts; the journal (read back with the engine) is the judge.

One server and one browser for the module; both are always stopped. Skipped with the reason
when chromium or Playwright is missing (``make test`` installs them where it can).
"""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
CAM = "c1"

playwright_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (pip install -e '.[app]')")
pytest.importorskip("marimo", reason="marimo is not installed (pip install -e '.[app]')")
pytest.importorskip("rerun_notebook", reason="rerun-notebook is not installed (pip install -e '.[app]')")
if not Path(CHROMIUM).exists():
    pytest.skip("Debian chromium is not installed (apt-get install chromium; `make test` does it as root)",
                allow_module_level=True)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    from seg2pose.synth.generate import generate_scene

    root = tmp_path_factory.mktemp("annot") / "scene"
    generate_scene(root, preset="small", frames=3, seed=1, video=False, progress=False, workers=1)
    return root


@pytest.fixture(scope="module")
def server(scene, tmp_path_factory):
    from annotate.app import serve

    log = tmp_path_factory.mktemp("log") / "server.log"
    s = serve.start(scene, cameras=[CAM], log=log, wait=90)
    yield s
    s.stop()


@pytest.fixture(scope="module")
def page(server):
    with playwright_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        try:
            pg = browser.new_page(viewport={"width": 1800, "height": 1000})
            pg.set_default_timeout(120_000)  # a loaded 2-core machine compiles the viewer slowly
            pg.goto(server.url)
            pg.wait_for_selector("canvas", timeout=300_000)
            pg.wait_for_selector("[data-testid=frame-number]", timeout=300_000)
            # the viewer has the data and its time cursor (it reported the frame timeline)
            _wait(lambda: _panel(pg, "viewer-state") == "ready", 300, "the viewer")
            time.sleep(2)
            yield pg
        finally:
            browser.close()


def _panel(page, testid: str) -> str:
    return page.inner_text(f"[data-testid={testid}]")


def _wait(cond, timeout: float, what: str):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        v = cond()
        if v:
            return v
        time.sleep(0.25)
    raise AssertionError(f"timed out waiting for {what}")


def _clicks(page) -> int:
    el = page.query_selector("[data-testid=last-click]")
    return int(el.get_attribute("data-n")) if el else 0


def _click(page, x: float, y: float, patience: float = 45) -> dict:
    """Click the viewer at page point (x, y) until the app reports it: software rendering on a
    busy machine drops an occasional click, and the viewer takes a while to lay itself out
    after the data arrives. Retries for ``patience`` seconds. Returns the reported click."""
    t0 = time.monotonic()
    while True:
        n = _clicks(page)
        page.mouse.move(x, y)
        time.sleep(0.5)  # let the viewer see the hover before the press
        page.mouse.down()
        page.mouse.up()
        try:
            _wait(lambda: _clicks(page) > n, 6, "the click to reach the app")
        except AssertionError:
            if _clicks(page) > n:  # it came late
                break
            if time.monotonic() - t0 > patience:
                page.screenshot(path="/tmp/s2p-annotate-failed-click.png")
                raise AssertionError(f"no click event from the viewer within {patience:.0f} s at "
                                     f"({x:.0f}, {y:.0f}); screenshot /tmp/s2p-annotate-failed-click.png")
            continue
        break
    el = page.query_selector("[data-testid=last-click]")
    return {"camera": el.get_attribute("data-camera"), "uv": json.loads(el.get_attribute("data-uv"))}


def _press(page, key: str, expect_frame: int | None = None):
    page.keyboard.press(key)
    if expect_frame is not None:
        _wait(lambda: _panel(page, "frame-number") == str(expect_frame), 10, f"frame {expect_frame}")


def _image_map(page, scene_obj) -> tuple[np.ndarray, np.ndarray]:
    """Page point = o + s * image pixel for the camera view, read from the layout: a first guess
    from the blueprint (world | camera, side by side, image letterboxed), then two probe clicks
    whose pixel positions the viewer reports fix scale and offset."""
    cam = scene_obj.cameras[CAM]
    box = page.query_selector("canvas").bounding_box()
    # the blueprint puts the camera view in the right half, between the top bar and time panel
    vx, vy, vw, vh = box["x"] + box["width"] / 2, box["y"] + 60, box["width"] / 2, box["height"] - 110
    s0 = min(vw / cam.width, vh / cam.height)
    o0 = np.array([vx + (vw - s0 * cam.width) / 2, vy + (vh - s0 * cam.height) / 2])
    probes = np.array([[0.35 * cam.width, 0.4 * cam.height], [0.65 * cam.width, 0.6 * cam.height]])
    got = []
    for i, uv in enumerate(probes):
        pt = o0 + s0 * uv
        c = _click(page, *pt, patience=120 if i == 0 else 45)  # the first waits for the layout
        assert c["camera"] == CAM, c
        got.append((pt, np.array(c["uv"], float)))
    (p1, u1), (p2, u2) = got
    s = (p2 - p1) / (u2 - u1)
    assert np.allclose(s[0], s[1], rtol=0.05), s  # one scale: the image is not stretched
    return p1 - s * u1, s


def _road_user(scene_obj, frames=(0, 2)):
    """A moving road user seen inside camera CAM in both frames, the one whose ground position
    is least sensitive to a pixel's error: its true poses, the pixels of its body centre (the
    class's default height over the scene's ground surface) and its class."""
    from annotate.place import pixel_to_ground
    from seg2pose.io.poses import read_poses

    gt = read_poses(scene_obj.gt_path)
    cam = scene_obj.cameras[CAM]
    heights = {c.name: c.default_height for c in scene_obj.classes}
    best = None
    for tid in np.unique(gt.track_id):
        rows = [np.flatnonzero((gt.track_id == tid) & (gt.frame == f)) for f in frames]
        if not all(len(r) for r in rows):
            continue
        rows = [r[0] for r in rows]
        h = heights[str(gt.cls[rows[0]])]
        xy = gt.xyz[rows, :2]
        pts = np.c_[xy, scene_obj.ground.height(xy) + h]
        uv, _, front = cam.project_points(pts)
        inside = (uv[:, 0] > 0.03 * cam.width) & (uv[:, 0] < 0.97 * cam.width) & \
                 (uv[:, 1] > 0.03 * cam.height) & (uv[:, 1] < 0.97 * cam.height)
        if not (front.all() and inside.all() and np.hypot(*(uv[0] - uv[1])) > 5):
            continue
        g0 = np.array(pixel_to_ground(cam, scene_obj.ground, uv[0], h))
        sens = max(np.hypot(*(np.array(pixel_to_ground(cam, scene_obj.ground, uv[0] + d, h)) - g0))
                   for d in ([2, 0], [0, 2]))
        if best is None or sens < best[0]:
            best = (sens, tid, xy, uv, str(gt.cls[rows[0]]))
    assert best is not None, "no moving road user in view in both frames"
    return best[1:]


def _journal(scene: Path):
    from annotate import Project

    with Project.open(scene, read_only=True) as p:
        return {tid: dict(t.keyframes) for tid, t in p.tracks.items()}


def _yellow_near(png: Path, x: float, y: float, r: int = 60) -> int:
    import cv2

    img = cv2.imread(str(png))
    crop = img[max(0, int(y) - r):int(y) + r, max(0, int(x) - r):int(x) + r].astype(int)
    b, g, rr = crop[..., 0], crop[..., 1], crop[..., 2]
    return int(((rr > 200) & (g > 170) & (b < 90)).sum())


def test_click_places_keyframe_and_shortcuts_edit(page, scene, tmp_path):
    from seg2pose.io.scene import load_scene

    s = load_scene(scene)
    _, truth, uv_true, cls = _road_user(s)
    assert _panel(page, "frame-number") == "0"
    o, k = _image_map(page, s)
    assert "no track selected" in _panel(page, "message")  # probes place nothing

    page.select_option("select[data-prefix='class:']", cls)
    _wait(lambda: cls in _panel(page, "message"), 10, "the class choice")
    _press(page, "n")
    _wait(lambda: "click it in a camera view" in _panel(page, "message"), 10, "a new track")
    target = o + k * uv_true[0]
    _click(page, *target)
    _wait(lambda: "keyframe 0 at" in _panel(page, "message"), 10, "the keyframe")
    kf = _journal(scene)
    (tid, frames), = kf.items()
    err = np.hypot(frames[0].x - truth[0][0], frames[0].y - truth[0][1])
    assert err < 0.3, f"keyframe {err:.2f} m from the road user"
    row = page.query_selector(f"[data-testid=tracks] tr[data-track='{tid}']")
    assert row is not None and cls in row.inner_text() and "\t1\t" in row.inner_text()

    # the selected track's box is drawn (highlight colour) where the road user is
    time.sleep(3)
    shot = tmp_path / "app.png"
    page.screenshot(path=str(shot))
    assert _yellow_near(shot, *target) > 30
    if os.environ.get("S2P_APP_SCREENSHOT"):  # README's picture: S2P_APP_SCREENSHOT=docs/annotate_app.png
        shutil.copy(shot, os.environ["S2P_APP_SCREENSHOT"])

    # nudge +x 10 cm (d), undo (Ctrl+z), redo (Ctrl+y): the journal follows each
    x0 = frames[0].x
    _press(page, "d")
    _wait(lambda: abs(_journal(scene)[tid][0].x - (x0 + 0.10)) < 1e-9, 10, "the nudge")
    _press(page, "Control+z")
    _wait(lambda: abs(_journal(scene)[tid][0].x - x0) < 1e-9, 10, "the undo")
    _press(page, "Control+y")
    _wait(lambda: abs(_journal(scene)[tid][0].x - (x0 + 0.10)) < 1e-9, 10, "the redo")

    # frame steps (the scene's frames are 0..10), a second keyframe by clicking at frame 2,
    # then previous / next keyframe
    _press(page, "Shift+ArrowRight", expect_frame=10)
    _press(page, "Shift+ArrowLeft", expect_frame=0)
    _press(page, "ArrowRight", expect_frame=1)
    _press(page, "ArrowRight", expect_frame=2)
    _click(page, *(o + k * uv_true[1]))
    _wait(lambda: "keyframe 2 at" in _panel(page, "message"), 10, "the second keyframe")
    k2 = _journal(scene)[tid][2]
    assert np.hypot(k2.x - truth[1][0], k2.y - truth[1][1]) < 0.3
    _press(page, "[", expect_frame=0)
    _press(page, "]", expect_frame=2)
    assert [int(r.get_attribute("data-frame"))
            for r in page.query_selector_all("[data-testid=keyframes] tr[data-frame]")] == [0, 2]

    # a click on the 3D view is ignored with a hint, and places nothing
    box = page.query_selector("canvas").bounding_box()
    _click(page, box["x"] + box["width"] * 0.25, box["y"] + box["height"] * 0.5)
    assert "click ignored" in _panel(page, "message")
    assert sorted(_journal(scene)[tid]) == [0, 2]
