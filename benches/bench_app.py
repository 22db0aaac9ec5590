"""Annotation app speed, as an annotator meets it (``--browser``, the default) and on the
Python side (``--engine``).

--browser: ``s2p annotate``'s server on a 400-frame synthetic scene with 5 cameras at
1280x720 whose videos carry a frame code (s2p_review/frame_code.py, over a texture with moving
blocks), driven through Debian chromium (Playwright, software rendering) with the layout the
annotator gets (one camera large). Measured: page load to a usable view (the large camera
shows the current frame; cold = the videos encoded first, warm = a reload), frame step ->
the large camera showing the new frame (its code read off screenshots), click -> keyframe
box drawn (the selected track's yellow near the click), and the recording's size.

    python benches/bench_app.py --browser [--frames 400] [--steps 20] [--clicks 8]

--engine: click -> keyframe journalled, and edit -> viewer data sent, for a 1,000-frame
track (keyframes every 25 frames), without a browser.

"Data sent" is measured where the notebook viewer gets it: the recording's callback sink
(``rerun.notebook.Viewer`` installs exactly this sink and hands each chunk to the widget), so
the figure is the Python side of an edit: engine edit + fsync'ed journal line + the changed
track's columns (3D box, trail, one projected box per camera) + flush. The browser's own
decoding and drawing come on top (not measured here).

    python benches/bench_app.py --engine [--cameras 1 3] [--reps 30]
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--engine", action="store_true", help="the Python side only (no browser)")
    ap.add_argument("--browser", action="store_true", help="through chromium (the default)")
    ap.add_argument("--cameras", type=int, nargs="+", default=[1, 3])
    ap.add_argument("--reps", type=int, default=30)
    ap.add_argument("--frames", type=int, default=None)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--clicks", type=int, default=8)
    args = ap.parse_args()
    if args.engine:
        args.frames = args.frames or 1000
        engine(args)
    else:
        args.frames = args.frames or 400
        browser(args)


def engine(args) -> None:
    import rerun as rr

    from annotate import Project
    from annotate.app.controller import Controller
    from annotate.app.session import track_columns
    from annotate.place import pixel_to_ground
    from s2p_review.annotation_log import AnnotationLogger, new_recording
    from seg2pose.synth.generate import generate_scene

    tmp = Path(tempfile.mkdtemp(prefix="bench_app_"))
    scene = generate_scene(tmp / "scene", preset="small", frames=3, seed=1, video=False,
                           progress=False, workers=1)
    n = args.frames
    for ncam in args.cameras:
        import shutil

        shutil.rmtree(Path(scene) / "annotations", ignore_errors=True)
        project = Project.open(scene, frames=(0, n + 50))
        cams = list(project.scene.cameras)[:ncam]
        ctl = Controller(project, cams, (0, n + 50))
        cam = project.scene.cameras[cams[0]]
        x0, y0 = pixel_to_ground(cam, project.scene.ground, (640.0, 420.0))
        tid = project.create_track("car").track
        for f in range(0, n, 25):  # a car crossing the view: 1,000 frames, keyframes every 25
            project.set_keyframe(tid, f, x0 + 0.02 * f, y0 + 0.01 * f, heading=0.46)
        project.set_keyframe(tid, n - 1, x0 + 0.02 * (n - 1), y0 + 0.01 * (n - 1), heading=0.46)
        assert len(project.track_poses(tid)) == n

        rec = new_recording()
        got = {"bytes": 0, "chunks": 0}

        def sink(data: bytes) -> None:
            got["bytes"] += len(data)
            got["chunks"] += 1

        rr.bindings.set_callback_sink(recording=rec.to_native(), callback=sink)
        logger = AnnotationLogger(rec, project.scene, cams)
        logger.send_track(track_columns(project, tid), selected=True)
        rec.flush()

        def resend(ids, selected):
            for t in sorted(ids):
                logger.send_track(track_columns(project, t), selected=t == selected)
            rec.flush()

        ctl.on_tracks.append(resend)
        ctl.selected = tid
        edit_ms, click_ms, sizes = [], [], []
        uv, _, _ = cam.project_points(np.array([[x0, y0, project.scene.ground.height(
            np.array([[x0, y0]]))[0]]]))
        for i in range(args.reps):
            ctl.goto(100 + 7 * i)
            b0 = got["bytes"]
            t0 = time.perf_counter()
            ctl.do("nudge:0.1:0")            # edit -> journal -> re-send the track -> flush
            edit_ms.append((time.perf_counter() - t0) * 1e3)
            sizes.append(got["bytes"] - b0)
            ctl.click_mode = "ground"
            t0 = time.perf_counter()
            ctl.click(cams[0], uv[0] + [i % 5, 0])  # pixel -> ray -> ground -> journal -> re-send
            click_ms.append((time.perf_counter() - t0) * 1e3)
            assert "keyframe" in ctl.message, ctl.message
        journal_only = []
        ctl.on_tracks.clear()
        for i in range(args.reps):
            t0 = time.perf_counter()
            ctl.click(cams[0], uv[0] + [i % 5, 1])
            journal_only.append((time.perf_counter() - t0) * 1e3)
        q = lambda v: f"median {statistics.median(v):6.1f} ms, p90 {np.percentile(v, 90):6.1f} ms"  # noqa: E731
        print(f"{n}-frame track, {ncam} camera(s), {args.reps} reps:")
        print(f"  edit (nudge) -> viewer data sent : {q(edit_ms)}  ({statistics.median(sizes) / 1e3:.0f} kB per edit)")
        print(f"  click -> keyframe journalled+sent: {q(click_ms)}")
        print(f"  click -> keyframe journalled     : {q(journal_only)}  (no viewer)")
        project.close()


CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]


def _stats(v) -> str:
    v = np.asarray(v, float)
    return f"median {np.median(v):.2f} s, p90 {np.percentile(v, 90):.2f} s, max {v.max():.2f} s (n={len(v)})"


def browser(args) -> None:
    import os
    import shutil

    import cv2
    from playwright.sync_api import sync_playwright

    from annotate.app import serve
    from annotate.place import pixel_to_ground
    from s2p_review.frame_code import read_code, write_code_video
    from seg2pose.io.scene import load_scene
    from seg2pose.synth.generate import generate_scene

    tmp = Path(tempfile.mkdtemp(prefix="bench_app_"))
    os.environ["XDG_CACHE_HOME"] = str(tmp / "cache")  # a cold start encodes the videos
    per_split = int(np.ceil((args.frames - 2) / 3))
    root = Path(generate_scene(tmp / "scene", preset="small", frames=per_split, seed=1,
                               video=False, progress=False, workers=1))
    scene = load_scene(root)
    n = max(b for _, b in scene.splits.values()) + 1
    cams = list(scene.cameras)
    t0 = time.perf_counter()
    for c in cams:
        cam = scene.cameras[c]
        write_code_video(root / "video" / f"{c}.mp4", cam.width, cam.height, n, fps=scene.fps,
                         texture=True)
    print(f"scene: {n} frames, cameras {', '.join(f'{c} {scene.cameras[c].width}x{scene.cameras[c].height}' for c in cams)}"
          f" (code videos written in {time.perf_counter() - t0:.0f} s)")
    large = cams[0]
    cam = scene.cameras[large]
    server = serve.start(root, wait=120)
    out = {}
    try:
        with sync_playwright() as p:
            br = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
            pg = br.new_page(viewport={"width": 1800, "height": 1000})
            pg.set_default_timeout(300_000)
            panel = lambda tid: pg.inner_text(f"[data-testid={tid}]")  # noqa: E731

            def wait(cond, timeout, what):
                t = time.perf_counter()
                while time.perf_counter() - t < timeout:
                    v = cond()
                    if v:
                        return v
                    time.sleep(0.05)
                raise SystemExit(f"timed out waiting for {what}")

            def shot():
                return cv2.imdecode(np.frombuffer(pg.screenshot(), np.uint8), cv2.IMREAD_COLOR)

            def code(o, k, img=None):
                g = cv2.cvtColor(shot() if img is None else img, cv2.COLOR_BGR2GRAY)

                def sample(u, v):
                    x, y = o + k * np.array([u * cam.width, v * cam.height])
                    return float(np.median(g[int(y) - 3:int(y) + 4, int(x) - 3:int(x) + 4]))
                return read_code(sample)

            def clicks():
                el = pg.query_selector("[data-testid=last-click]")
                return int(el.get_attribute("data-n")) if el else 0

            def click(x, y):
                c0 = clicks()
                pg.mouse.move(x, y)
                time.sleep(0.2)
                pg.mouse.down()
                pg.mouse.up()
                t = time.perf_counter()
                wait(lambda: clicks() > c0, 60, "a click")
                el = pg.query_selector("[data-testid=last-click]")
                return json.loads(el.get_attribute("data-uv")), time.perf_counter() - t

            def load(label):
                t = time.perf_counter()
                pg.goto(server.url)
                wait(lambda: pg.query_selector("[data-testid=viewer-state]") is not None and
                     panel("viewer-state") == "ready", 600, "the viewer")
                return t

            t_start = load("cold")
            # the image map of the large camera (probe clicks), then "usable" = it shows frame 0
            box = pg.query_selector("canvas").bounding_box()
            vx, vy, vw, vh = box["x"], box["y"] + 40, box["width"] * 0.75, (box["height"] - 80) * 0.8
            s0 = min(vw / cam.width, vh / cam.height)
            o0 = np.array([vx + (vw - s0 * cam.width) / 2, vy + (vh - s0 * cam.height) / 2])
            pts = [o0 + s0 * np.array([0.35 * cam.width, 0.5 * cam.height]),
                   o0 + s0 * np.array([0.65 * cam.width, 0.7 * cam.height])]
            uvs = [np.array(click(*pt)[0], float) for pt in pts]
            k = (pts[1] - pts[0]) / (uvs[1] - uvs[0])
            o = pts[0] - k * uvs[0]
            f0 = int(panel("frame-number"))
            wait(lambda: code(o, k) == f0, 300, "the first frame")
            out["load_cold"] = time.perf_counter() - t_start
            print(f"page load to usable view, cold (videos encoded first): {out['load_cold']:.1f} s")
            t_start = load("warm")
            wait(lambda: code(o, k) == int(panel("frame-number")), 300, "the first frame")
            out["load_warm"] = time.perf_counter() - t_start
            print(f"page load to usable view, warm (reload, videos cached): {out['load_warm']:.1f} s")
            time.sleep(2)
            # frame steps: ArrowRight, then screenshots until the large camera shows the frame
            steps = []
            for i in range(args.steps):
                want = int(panel("frame-number")) + 1
                t = time.perf_counter()
                pg.keyboard.press("ArrowRight")
                wait(lambda: code(o, k) == want, 60, f"frame {want}")
                steps.append(time.perf_counter() - t)
            print("frame step -> correct image in the large camera:", _stats(steps))
            # clicks: a new track each time (nothing of it drawn before), click the ground
            # under the image centre, time until its yellow box is drawn near the click
            drawn = []
            pg.keyboard.press("c")  # centre -> ground
            for i in range(args.clicks):
                pg.keyboard.press("Escape")
                pg.keyboard.press("n")
                uv = np.array([cam.width * (0.3 + 0.05 * i), cam.height * 0.75])
                x, y = o + k * uv
                before = shot()
                t = time.perf_counter()
                c0 = clicks()
                pg.mouse.move(x, y)
                pg.mouse.down()
                pg.mouse.up()

                def yellow():
                    img = shot()
                    r = 50
                    crop = img[int(y) - r:int(y) + r, int(x) - r:int(x) + r].astype(int)
                    base = before[int(y) - r:int(y) + r, int(x) - r:int(x) + r].astype(int)
                    is_y = lambda a: (a[..., 2] > 200) & (a[..., 1] > 170) & (a[..., 0] < 90)  # noqa: E731
                    return clicks() > c0 and (is_y(crop) & ~is_y(base)).sum() > 20
                wait(yellow, 60, "the keyframe's box")
                drawn.append(time.perf_counter() - t)
            print("click -> keyframe box drawn:", _stats(drawn))
            br.close()
    finally:
        server.stop()
    size = sum(p.stat().st_size for p in (tmp / "cache").rglob("*.mp4"))
    print(f"video assets: {size / 1e6:.1f} MB for {len(cams)} cameras x {n} frames")
    from s2p_review.session import record

    t = time.perf_counter()
    rrd = record(scene, [], tmp / "scene.rrd").rrd  # the same logging path as the app's
    print(f"recording of the scene (s2p review SCENE -o x.rrd: video, masks, ground): "
          f"{rrd.stat().st_size / 1e6:.1f} MB, written in {time.perf_counter() - t:.0f} s (videos cached)")
    shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
