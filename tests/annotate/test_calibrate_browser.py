"""End to end in a real browser: ``s2p calibrate-camera``'s page on a synthetic junction, headless
Debian chromium driven by Playwright.

The frame is the junction's aerial image seen through the scene's camera c1 (synth/aerial.py),
the aerial image is the same junction from above at 5 cm/px with its world file. The walk: 8
pairs clicked where a user would (each side zoomed in on its point first), one with an
elevation typed in, a wrong ninth pair undone, a reload that keeps the pairs (the journal), Solve
and Save; then ``s2p new-scene`` takes the written calib.json and ground, the scene's masks are
copied in, and ``s2p run --baseline`` accepts the scene. The camera is the truth camera within
what the clicks know (one elevation).

Skipped with the reason when chromium or Playwright is missing.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
        "--disable-gpu-compositing"]
CAM = "c1"
S2P = str(Path(sys.executable).with_name("s2p"))

playwright_api = pytest.importorskip("playwright.sync_api",
                                     reason="playwright is not installed (pip install -e '.[app]')")
if not Path(CHROMIUM).exists():
    pytest.skip("Debian chromium is not installed (apt-get install chromium; `make test` does it as root)",
                allow_module_level=True)


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """(root, scene folder, aerial map A, truth camera): a small synthetic scene with c1's
    frame as its video, the aerial image and its world file."""
    import cv2

    from seg2pose.io.atomic import atomic_write_bytes
    from seg2pose.io.calib_files import write_world_file
    from seg2pose.io.scene import load_scene
    from seg2pose.synth.aerial import camera_view, render_aerial
    from seg2pose.synth.generate import SynthOptions, generate_scene

    root = tmp_path_factory.mktemp("calpage")
    scene = root / "scene"
    generate_scene(scene, SynthOptions(preset="small", frames=12, seed=3, progress=False, workers=1))
    cam = load_scene(scene).cameras[CAM]
    aerial, A = render_aerial((-15.0, -15.0), (40.0, 40.0), 0.05)
    atomic_write_bytes(root / "aerial.png", cv2.imencode(".png", aerial)[1].tobytes())
    write_world_file(root / "aerial.pgw", A)
    png = cv2.imencode(".png", camera_view(aerial, A, cam))[1].tobytes()
    (scene / "video" / CAM).mkdir(parents=True)
    last = max(b for _, b in load_scene(scene).splits.values())
    for f in range(last + 1):  # a still video as long as the masks (s2p run checks their frames)
        atomic_write_bytes(scene / "video" / CAM / f"{f:06d}.png", png)
    return root, scene, A, cam


def _start(root: Path, scene: Path) -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen([S2P, "calibrate-camera", str(scene), "--camera", CAM, "--aerial",
                             str(root / "aerial.png"), "-o", str(root / "out" / "calib.json"),
                             "--no-browser"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, start_new_session=True)
    t0 = time.monotonic()
    for line in proc.stdout:
        if "calibration page at " in line:
            return proc, line.split("calibration page at ", 1)[1].split()[0]
        if time.monotonic() - t0 > 120:
            break
    proc.kill()
    raise AssertionError("the page did not start")


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(5)


def _ready(pg) -> None:
    pg.wait_for_function("window.calib && window.calib.ready && window.calib.views.frame.loaded "
                         "&& window.calib.views.aerial.loaded", timeout=120_000)


def _click(pg, view: str, u: float, v: float, zoom: float) -> None:
    """Zoom the view onto (u, v) as a user would, then click it."""
    pg.evaluate(f"window.calib.zoomTo('{view}', {u}, {v}, {zoom})")
    x, y = pg.evaluate(f"window.calib.toScreen('{view}', {u}, {v})")
    pg.mouse.click(x, y)


def test_clicking_eight_pairs_gives_a_scene_that_runs(site):
    from seg2pose.io.calib_files import world_to_aerial
    from seg2pose.io.jsonl_log import read_log
    from seg2pose.io.scene import load_scene
    from seg2pose.synth.clicks import spread_clicks

    root, scene, A, cam = site
    uv, X = spread_clicks(cam, 8, np.random.default_rng(11))
    axy = world_to_aerial(A, X[:, :2])
    proc, url = _start(root, scene)
    try:
        with playwright_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
            try:
                pg = browser.new_page(viewport={"width": 1400, "height": 900})
                pg.goto(url)
                _ready(pg)
                for i in range(8):
                    _click(pg, "frame", uv[i, 0], uv[i, 1], 4.0)
                    if i == 0:
                        pg.fill("#elev", f"{X[0, 2]:.3f}")
                    _click(pg, "aerial", axy[i, 0], axy[i, 1], 2.0)
                    pg.wait_for_function(f"window.calib.state().pairs.length === {i + 1}")
                # a wrong ninth pair, undone
                _click(pg, "frame", 640, 500, 2.0)
                _click(pg, "aerial", 10, 10, 1.0)
                pg.wait_for_function("window.calib.state().pairs.length === 9")
                pg.click("#undo")
                pg.wait_for_function("window.calib.state().pairs.length === 8")
                pg.reload()  # the pairs come back from the server's journal
                _ready(pg)
                assert pg.evaluate("window.calib.state().pairs.length") == 8
                pg.click("#solve")
                pg.wait_for_function("document.getElementById('msg').textContent === 'solved'",
                                     timeout=120_000)
                assert "camera c1: focal" in pg.inner_text("#report")
                pg.check("#showcost")
                pg.click("#save")
                pg.wait_for_function("document.getElementById('msg').textContent === 'saved'")
            finally:
                browser.close()
    finally:
        _stop(proc)
    records, _, note = read_log(root / "out" / "calib.points.jsonl")
    assert note is None and [r["kind"] for r in records].count("undo") == 1
    clicked = [r for r in records if r["kind"] == "pair"][:8]
    np.testing.assert_allclose([[r["u"], r["v"]] for r in clicked], uv, atol=0.5)
    np.testing.assert_allclose([[r["x"], r["y"]] for r in clicked], X[:, :2], atol=0.05)
    assert clicked[0]["z"] == pytest.approx(X[0, 2], abs=1e-3)
    new = root / "new"
    r = subprocess.run([S2P, "new-scene", "-o", str(new), "--video", f"{CAM}={scene / 'video' / CAM}",
                        "--calibration", str(root / "out" / "calib.json"), "--ground",
                        str(root / "out" / "calib.ground.csv"), "--fps", "13.333"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    shutil.copy(scene / "masks" / f"{CAM}.txt", new / "masks" / f"{CAM}.txt")
    r = subprocess.run([S2P, "run", str(new), "-o", str(root / "run"), "--baseline"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert (root / "run" / "poses.csv").stat().st_size > 100
    got = load_scene(new).cameras[CAM]
    # one elevation known: the others sit on a flat ground, off by the kerbs' 0.15 m and the
    # east arm's slope; that costs decimetres of the camera centre
    assert abs(got.K[0, 0] / cam.K[0, 0] - 1) < 0.03
    assert np.linalg.norm(got.center - cam.center) < 0.6
