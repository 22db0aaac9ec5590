"""Annotation app speed, as an annotator meets it (``--browser``, the default) and on the
Python side (``--engine``).

--browser: ``s2p annotate``'s server on a 400-frame synthetic scene with 5 cameras at
1280x720 whose videos carry a frame code (s2p_review/frame_code.py, over a texture with moving
blocks), driven through Debian chromium (Playwright, software rendering) with the layout the
annotator gets (one camera large). Measured: page load to a usable view (the large camera's
picture shows the current frame, its code read off a screenshot), frame step -> the picture
of the new frame shown (the page's own clock: the image's load event, before the key press;
the code is then read off the screen to check it is that frame), click -> the picture with
the keyframe's yellow box shown, the same steps with the 3D viewer on (Shift+V), and the
recording's size.

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
    from seg2pose.synth.generate import SynthOptions, generate_scene

    tmp = Path(tempfile.mkdtemp(prefix="bench_app_"))
    scene = generate_scene(tmp / "scene", SynthOptions(preset="small", frames=3, seed=1, video=False,
                           progress=False, workers=1))
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
# software WebGL with software compositing: what Chrome does on a machine without a usable GPU
CHROMIUM_ARGS = ["--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                 "--disable-gpu-compositing"]


def _stats(v) -> str:
    v = np.asarray(v, float)
    return f"median {np.median(v):.2f} s, p90 {np.percentile(v, 90):.2f} s, max {v.max():.2f} s (n={len(v)})"


def browser(args) -> None:
    import os
    import shutil

    import cv2
    from playwright.sync_api import sync_playwright

    from annotate.app import serve
    from s2p_review.frame_code import read_code, write_code_video
    from seg2pose.io.scene import load_scene
    from seg2pose.synth.generate import SynthOptions, generate_scene

    tmp = Path(tempfile.mkdtemp(prefix="bench_app_"))
    os.environ["XDG_CACHE_HOME"] = str(tmp / "cache")  # a cold start encodes the videos
    per_split = int(np.ceil((args.frames - 2) / 3))
    root = Path(generate_scene(tmp / "scene", SynthOptions(preset="small", frames=per_split, seed=1,
                               video=False, progress=False, workers=1)))
    scene = load_scene(root)
    n = max(b for _, b in scene.splits.values()) + 1
    cams = list(scene.cameras)
    t0 = time.perf_counter()
    for c in cams:
        cam = scene.cameras[c]
        write_code_video(root / "video" / f"{c}.mp4", cam.width, cam.height, n, fps=scene.fps,
                         texture=True)
    sizes = ', '.join(f'{c} {scene.cameras[c].width}x{scene.cameras[c].height}' for c in cams)
    print(f"scene: {n} frames, cameras {sizes}"
          f" (code videos written in {time.perf_counter() - t0:.0f} s)")
    from annotate.app.viewer_cache import prepare_viewer

    t0 = time.perf_counter()
    prepare_viewer(root)  # what `s2p annotate` does before it starts the server
    print(f"videos and outlines prepared for the viewer (once per scene): {time.perf_counter() - t0:.0f} s")
    large = cams[0]
    cam = scene.cameras[large]
    server = serve.start(root, wait=120)
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
                    time.sleep(0.02)
                raise SystemExit(f"timed out waiting for {what}")

            def picture():
                el = pg.query_selector("[data-testid=frame-image]")
                return el, (el.bounding_box() if el else None)

            def code():
                el, box = picture()
                g = cv2.imdecode(np.frombuffer(pg.screenshot(clip=box), np.uint8), cv2.IMREAD_GRAYSCALE)
                h, w = g.shape
                return read_code(lambda u, v: float(np.median(g[int(v * h) - 3:int(v * h) + 4,
                                                                int(u * w) - 3:int(u * w) + 4])))

            def shown_after(frame, t_page):
                return pg.evaluate(f"() => (window.__s2p_shown || {{}})[{int(frame)}] > {t_page} && "
                                   f"window.__s2p_shown[{int(frame)}]")

            def load():
                t = time.perf_counter()
                pg.goto(server.url)
                pg.wait_for_selector("[data-testid=frame-number]")
                wait(lambda: picture()[0] is not None and
                     picture()[0].get_attribute("data-frame") == panel("frame-number"), 300, "the picture")
                f = int(panel("frame-number"))
                wait(lambda: code() == f, 60, "the picture's code")
                return time.perf_counter() - t

            print(f"page load to usable view (the large camera shows the current frame): "
                  f"{load():.1f} s (first load of this browser)")
            print(f"page load to usable view, reload: {load():.1f} s")
            time.sleep(2)
            print("viewer:", panel("message"))

            def steps(label, count):
                out, wrong = [], 0
                for _ in range(count):
                    want = int(panel("frame-number")) + 1
                    t_page = pg.evaluate("() => performance.now()")
                    pg.keyboard.press("ArrowRight")
                    t_shown = wait(lambda: shown_after(want, t_page), 60, f"frame {want}")
                    out.append((t_shown - t_page) / 1e3)
                    wrong += code() != want
                print(f"frame step -> picture of the new frame shown ({label}):", _stats(out),
                      f"; frame code read off the screen wrong {wrong} times")
                return out

            steps("3D viewer as the page chose", args.steps)
            # clicks: a new track each time (nothing of it drawn before), click the ground
            # under the picture, time until the picture with its yellow box is shown
            drawn = []
            pg.keyboard.press("c")  # centre -> ground
            el, box = picture()
            k = box["width"] / cam.width
            for i in range(args.clicks):
                pg.keyboard.press("Escape")
                pg.keyboard.press("n")
                time.sleep(0.5)
                f = int(panel("frame-number"))
                uv = np.array([cam.width * (0.3 + 0.05 * i), cam.height * 0.75])
                x, y = box["x"] + k * uv[0], box["y"] + k * uv[1]
                t_page = pg.evaluate("() => performance.now()")
                pg.mouse.move(x, y)
                pg.mouse.down()
                pg.mouse.up()
                t_shown = wait(lambda: shown_after(f, t_page), 60, "the keyframe's picture")
                drawn.append((t_shown - t_page) / 1e3)
                img = cv2.imdecode(np.frombuffer(pg.screenshot(), np.uint8), cv2.IMREAD_COLOR)
                r = 60
                crop = img[int(y) - r:int(y) + r, int(x) - r:int(x) + r].astype(int)
                yellow = (crop[..., 2] > 200) & (crop[..., 1] > 170) & (crop[..., 0] < 90)
                assert yellow.sum() > 20, "no yellow box near the click"
            print("click -> keyframe box drawn:", _stats(drawn))
            pg.keyboard.press("Shift+V")
            time.sleep(5)
            print("viewer:", panel("message"))
            steps("3D viewer shown (Shift+V)", max(3, args.steps // 4))
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
