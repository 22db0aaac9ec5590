"""A scripted annotator on a held-out synthetic scene: pre-annotate from a baseline run, review
every track with the review mode, correct where the box is off the road user, export; counts
the actions (keys, clicks, drags) and the app's time, and measures the exported gt against
the truth.

    nice python benches/bench_annotate_scene.py /tmp/bench-annot [--frames 400] [--seed 7]
        [--tolerance 0.3] [--loads 20] [--loads-only]

The scene: ``s2p synth --preset small`` with 2.5 times its population (5 cameras at 1280x720,
seed 7: no tolerance here was tuned on it) over ``--frames`` frames, each camera's video a frame-code video (as
benches/bench_app.py) so that every picture is decoded and drawn as in the app; the run:
``s2p run --baseline`` (normal positions only: the worst starting point the app meets).

The annotator works through the app's controller (annotate/app, what the page's keys and
clicks call) and its page session (the pictures), one road user at a time:

1. ``Shift+p`` once: every road user of the run pre-annotated where its masks are;
2. per track: a click on it in the panel; ``p`` plays it from its first frame (each playback
   step is a frame move with its picture drawn, timed); where the box is off the road user by
   more than ``--tolerance`` metres (the annotator's eye: the truth here), the worst such frame
   is reached (one action: a click in the review list or ``f`` + number) and the box's base
   dragged onto the road user (one action; the drop point is off by one pixel of the camera
   that sees it best, at random); until none is off or ``--max-fixes`` were made; then
   ``Shift+r`` (reviewed).

Figures: actions per road user per 100 frames (of its track), the app's time per road user
(the controller's and the pictures' CPU time, the playback's waiting at the scene's frame rate
not counted; reported apart), frame step and playback frame times (median, p90, max), and the
exported gt's error against the truth per class (mean, p90, metres, every exported row).

``--loads N``: also the first frame step after each of N page loads in chromium (Playwright,
software rendering, as benches/bench_app.py), measured from the picture's appearance to the
next frame's picture.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np

POPULATION = {"pedestrian": 60, "bicyclist": 15, "car": 35}


def _pct(v, q):
    return float(np.percentile(np.asarray(v, float), q)) if len(v) else float("nan")


def make_scene(root: Path, frames: int, seed: int) -> Path:
    from s2p_review.frame_code import write_code_video
    from seg2pose.io.scene import load_scene
    from seg2pose.synth.generate import SynthOptions, generate_scene

    scene = root / "scene"
    if not (scene / "scene.json").exists():
        per_split = int(np.ceil((frames - 2) / 3))
        # the small junction with 2.5x its population: >= 25 road users in view over 400 frames
        generate_scene(scene, SynthOptions(preset="small", frames=per_split, seed=seed, video=False,
                                           progress=False, workers=1, population=POPULATION))
        s = load_scene(scene)
        n = max(b for _, b in s.splits.values()) + 1
        for c, cam in s.cameras.items():
            write_code_video(scene / "video" / f"{c}.mp4", cam.width, cam.height, n, fps=s.fps)
    return scene


def make_run(scene: Path, root: Path) -> Path:
    from seg2pose.io.scene import load_scene
    from seg2pose.method.pipeline import RunOptions, run_scene

    run = root / "run-baseline"
    if not (run / "poses.csv").exists():
        run_scene(load_scene(scene), run, RunOptions(baseline=True, progress=False, force=True))
    return run


class Annotator:
    """The scripted annotator (module docstring) on a page session."""

    def __init__(self, session, truth, tolerance: float, max_fixes: int, rng):
        self.s, self.ctl = session, session.ctl
        self.truth = truth
        self.tol, self.max_fixes, self.rng = tolerance, max_fixes, rng
        self.actions = 0
        self.app_s = 0.0          # controller + pictures (CPU side of the app)
        self.wait_s = 0.0         # playback waiting at the scene's frame rate (not app time)
        self.steps: list[float] = []   # one frame move + its picture, seconds

    def act(self, name: str) -> str:
        """One key or button: the action and the page's redraw, timed."""
        t0 = time.perf_counter()
        msg = self.ctl.do(name)
        self.s.refresh_panel()
        dt = time.perf_counter() - t0
        self.app_s += dt
        self.actions += 1
        if name in ("next_frame", "prev_frame"):
            self.steps.append(dt)
        return msg

    def play(self) -> None:
        """``p``, then the frames at the scene's rate until the playback stops."""
        self.act("play")
        dt = 1.0 / float(self.ctl.project.scene.fps)
        while True:
            t0 = time.perf_counter()
            going = self.ctl.play_step()
            self.s.refresh_panel()
            step = time.perf_counter() - t0
            if not going:
                break
            self.steps.append(step)
            self.app_s += step
            self.wait_s += max(0.0, dt - step)

    def errors(self, tid: int) -> tuple[np.ndarray, np.ndarray]:
        """(frames, metres) of a track's rows against its road user's truth (NaN: no truth)."""
        p = self.ctl.project
        rows = p.track_poses(tid)
        rt = p.track(tid).meta.get("run_track")
        t = self.truth.get(int(rt)) if rt is not None else None
        err = np.full(len(rows), np.nan)
        if t is not None:
            k = np.searchsorted(t.frame, rows.frame)
            ok = (k < len(t.frame)) & (t.frame[np.minimum(k, len(t.frame) - 1)] == rows.frame)
            err[ok] = np.linalg.norm(rows.xyz[ok, :2] - t.xyz[k[ok], :2], axis=1)
        return rows.frame, err

    def fix(self, tid: int, frame: int) -> None:
        """Drag the box's base at ``frame`` onto the road user (1 px off in the best camera)."""
        from annotate.place import pixel_to_ground

        p = self.ctl.project
        self.act(f"look:{tid}:{frame}")
        cam_name = self.ctl.best_camera(tid) or self.ctl.cameras[0]
        cam, g = p.scene.cameras[cam_name], p.scene.ground
        t = self.truth[int(p.track(tid).meta["run_track"])]
        want = t.xyz[int(np.searchsorted(t.frame, frame)), :2]
        x, y, _ = p.pose_at(tid, frame)
        pts = np.array([[x, y], want])
        uv, _, _ = cam.project_points(np.c_[pts, g.height(pts)])
        drop = uv[1] + self.rng.normal(0, 1.0, 2)
        try:
            pixel_to_ground(cam, g, drop)
        except Exception:  # noqa: BLE001 - a drop outside the image: the exact pixel then
            drop = uv[1]
        t0 = time.perf_counter()
        self.ctl.drag(cam_name, uv[0], drop)
        self.s.refresh_panel()
        self.app_s += time.perf_counter() - t0
        self.actions += 1

    def review(self, tid: int) -> int:
        """One track end to end; returns the fixes made."""
        self.act(f"select:{tid}")
        frames, _ = self.errors(tid)
        self.act(f"goto:{int(frames[0])}")
        fixes = plays = 0
        while plays < 4 * self.max_fixes:
            self.play()  # from where the last fix was made (or the start)
            plays += 1
            frames, err = self.errors(tid)
            bad = np.flatnonzero(np.nan_to_num(err) > self.tol)
            if not len(bad) or fixes >= self.max_fixes:
                if int(self.ctl.frame) < int(frames[-1]):
                    continue  # stopped early (plausibility, a gap): play on
                break
            worst = bad[int(np.argmax(err[bad]))]
            self.fix(tid, int(frames[worst]))
            fixes += 1
        self.act("mark_reviewed_all")
        return fixes


def annotate_scene(scene: Path, run: Path, args) -> dict:
    import shutil

    from annotate.app.session import Session
    from annotate.export import gt_table
    from seg2pose.io.poses import read_poses

    kept = scene / "gt" / "truth.csv"
    if not kept.exists():  # the annotator has no truth: kept aside for the measuring
        (scene / "gt" / "poses.csv").rename(kept)
    truth_all = read_poses(kept)
    truth = {int(t): truth_all.take(truth_all.track_id == t) for t in np.unique(truth_all.track_id)}
    shutil.rmtree(scene / "annotations", ignore_errors=True)  # a fresh project each time
    t0 = time.perf_counter()
    s = Session(scene, run=str(run))
    open_s = time.perf_counter() - t0
    a = Annotator(s, truth, args.tolerance, args.max_fixes, np.random.default_rng(args.seed))
    try:
        msg = a.act("preannotate")
        print(msg, flush=True)
        p = s.ctl.project
        tracks = sorted(p.tracks)
        fixes, frames = {}, 0
        t_start = time.perf_counter()
        for i, tid in enumerate(tracks):
            fixes[tid] = a.review(tid)
            frames += len(p.track_poses(tid))
            if i % 5 == 4:
                print(f"  {i + 1}/{len(tracks)} tracks reviewed, {a.actions} actions, "
                      f"{time.perf_counter() - t_start:.0f} s", flush=True)
        gt = gt_table(p)
    finally:
        s.ctl.close()
    by_cls: dict[str, list[float]] = {}
    for tid in np.unique(gt.track_id):
        rows = gt.take(gt.track_id == tid)
        rt = p.track(int(tid)).meta.get("run_track")
        t = truth.get(int(rt)) if rt is not None else None
        if t is None:
            continue
        k = np.searchsorted(t.frame, rows.frame)
        ok = (k < len(t.frame)) & (t.frame[np.minimum(k, len(t.frame) - 1)] == rows.frame)
        e = np.linalg.norm(rows.xyz[ok, :2] - t.xyz[k[ok], :2], axis=1)
        by_cls.setdefault(str(rows.cls[0]), []).extend(e.tolist())
    n = len(tracks)
    return {
        "road_users": n, "frames_annotated": frames, "open_s": open_s,
        "actions": a.actions, "actions_per_user_per_100_frames": a.actions / (frames / 100.0),
        "actions_per_user": a.actions / n, "fixes": int(sum(fixes.values())),
        "app_s_per_user": a.app_s / n, "playback_wait_s_per_user": a.wait_s / n,
        "step_s": {"median": statistics.median(a.steps), "p90": _pct(a.steps, 90),
                   "max": max(a.steps), "n": len(a.steps)},
        "gt_error_m": {c: {"mean": float(np.mean(v)), "p90": _pct(v, 90), "rows": len(v)}
                       for c, v in sorted(by_cls.items())},
        "sources": {k: int(v) for k, v in zip(*np.unique(gt.source, return_counts=True))},
    }


def _frame_changes(pg, f0: str, timeout: float) -> bool:
    """Whether the large camera's picture shows another frame than ``f0`` within ``timeout``
    seconds (polled every 20 ms from here)."""
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        f = pg.get_attribute("[data-testid=frame-image]", "data-frame")
        if f is not None and f != f0:
            return True
        time.sleep(0.02)
    return False


def first_steps(scene: Path, run: Path, loads: int) -> dict:
    """The first frame step after each of ``loads`` page loads in chromium: seconds from the
    picture's appearance (after the load) to the next frame's picture, a key (→) pressed as
    soon as the panel is there and again after 30 s without a step (counted as lost)."""
    from playwright.sync_api import sync_playwright

    from annotate.app import serve

    args = ["--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
            "--disable-gpu-compositing"]
    server = serve.start(scene, run=run, cameras=None, wait=120)
    out, panel, lost = [], [], []
    try:
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path="/usr/bin/chromium", args=args)
            pg = browser.new_page(viewport={"width": 1800, "height": 1000})
            pg.set_default_timeout(300_000)
            for _ in range(loads):
                pg.goto(server.url)
                pg.wait_for_selector("[data-testid=frame-image][data-frame]", timeout=300_000)
                f0 = pg.get_attribute("[data-testid=frame-image]", "data-frame")
                t0 = time.monotonic()  # the picture is there: the annotator presses a key
                pg.wait_for_selector("[data-testid=frame-number]", timeout=300_000)
                panel.append(time.monotonic() - t0)
                presses = 0
                while True:
                    # a step back, unless at the first frame (a step on from the last does nothing)
                    pg.keyboard.press("ArrowLeft" if int(f0) > 0 else "ArrowRight")
                    presses += 1
                    if _frame_changes(pg, f0, 30.0):
                        break
                    # the key was lost: press again (counted)
                    print(f"  load {len(out) + 1}: no step 30 s after the key (frame "
                          f"{pg.get_attribute('[data-testid=frame-image]', 'data-frame')}, "
                          f"panel {pg.inner_text('[data-testid=frame-number]')})", flush=True)
                    if presses >= 4:
                        pg.screenshot(path=str(scene.parent / "load-stall.png"))
                        raise RuntimeError(f"no frame step after {presses} keys")
                out.append(time.monotonic() - t0)
                lost.append(presses - 1)
                print(f"  load {len(out)}: first step {out[-1]:.2f} s after the picture", flush=True)
            browser.close()
    finally:
        server.stop()
    return {"loads": loads, "median": statistics.median(out), "max": max(out),
            "over_1s": int(sum(v > 1.0 for v in out)), "all": [round(v, 3) for v in out],
            "panel_after_picture_s": [round(v, 3) for v in panel], "keys_lost": lost}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("root", type=Path)
    ap.add_argument("--frames", type=int, default=400)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--tolerance", type=float, default=0.3)
    ap.add_argument("--max-fixes", type=int, default=12)
    ap.add_argument("--loads", type=int, default=0)
    ap.add_argument("--loads-only", action="store_true", help="only the page loads (a scene made "
                    "by an earlier run of this bench)")
    args = ap.parse_args()
    args.root.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    scene = make_scene(args.root, args.frames, args.seed)
    run = make_run(scene, args.root)
    print(f"scene and baseline run: {time.perf_counter() - t0:.0f} s", flush=True)
    if not args.loads_only:
        res = annotate_scene(scene, run, args)
        res["args"] = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}
        print(json.dumps(res, indent=1), flush=True)
    if args.loads:
        print(json.dumps({"first_step_after_load": first_steps(scene, run, args.loads)}, indent=1))


if __name__ == "__main__":
    main()
