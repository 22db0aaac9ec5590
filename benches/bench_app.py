"""Annotation app speed: click -> keyframe journalled, and edit -> viewer data sent, for a
1,000-frame track (keyframes every 25 frames), without a browser.

"Data sent" is measured where the notebook viewer gets it: the recording's callback sink
(``rerun.notebook.Viewer`` installs exactly this sink and hands each chunk to the widget), so
the figure is the Python side of an edit: engine edit + fsync'ed journal line + the changed
track's columns (3D box, trail, one projected box per camera) + flush. The browser's own
decoding and drawing come on top (not measured here).

    python benches/bench_app.py [--cameras 1 3] [--reps 30]
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
    ap.add_argument("--cameras", type=int, nargs="+", default=[1, 3])
    ap.add_argument("--reps", type=int, default=30)
    ap.add_argument("--frames", type=int, default=1000)
    args = ap.parse_args()

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


if __name__ == "__main__":
    main()
