"""s2p batch: a study of small synthetic scenes serially in-process vs on a local Ray with 2
workers (issue 16; goal: wall-time ratio >= 1.7 on this 2-core machine), the overhead per Ray
task, and each step's speed per core (frames per CPU-second) for docs/SCALE.md.

    OMP_NUM_THREADS=1 .venv/bin/python benches/bench_batch.py [--scenes 8] [--frames 40]
        [--video 3000] [--models]

Steps: run --baseline, eval, export (MCAP). The machine may be shared: the driver's CPU time
and the load average are printed beside the wall times.

--video N: one long 1280x720 video (benches/bench_video.py's, 20 road users) of N frames,
masks-from-video uncut in-process (each stage timed on one core: background subtraction,
tracker, size classes) vs cut into 2 segments on a local Ray with 2 workers (wall ratio), and
the seam against the uncut run (ID switches, recall). The scene's background history is 50
frames, so the warm-up before the border is 150 frames (10 % of a 1,500-frame segment; the
defaults, history 500 and 36,000-frame segments, give 1,500 frames = 4 %).

--models: per core, one epoch of ``--protocol quick`` training (lite-hr, 64 batches of 32) and
``s2p run`` with those models (exact sparse inference) on a synthetic 5-camera scene.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench_video's video


def noop_run(scene_dir, opts, force):  # the cost of a task that does nothing
    return {}


def bench_video_segments(root: Path, n_frames: int) -> None:
    import json

    import cv2
    import numpy as np
    import ray
    from bench_video import H, W, write_video

    from seg2pose.batch.steps import MASKS_FROM_VIDEO
    from seg2pose.batch.study import BatchOptions, run_study
    from seg2pose.eval.mask_eval import score_masks
    from seg2pose.geometry.camera import Camera
    from seg2pose.io.mots import iter_mots
    from seg2pose.io.scene import load_scene
    from seg2pose.video.classify import classify_mots, size_rules
    from seg2pose.video.track import TrackConfig, track_mots
    from seg2pose.video.video_masks import BgConfig, masks_from_video
    from seg2pose.video.video_scene import new_scene

    cv2.setNumThreads(1)  # per core
    cam = Camera.look_at("c0", np.array([0.0, -25.0, 14.0]), np.array([0.0, 15.0, 0.0]), 1000.0, W, H)
    (root / "calib.json").write_text(json.dumps({"cameras": [
        {"name": "c0", "K": cam.K.tolist(), "R": cam.R.tolist(), "t": cam.t.tolist()}]}))
    (root / "ground.csv").write_text("".join(f"{x},{y},0\n" for x in range(-30, 31, 10)
                                             for y in range(-10, 51, 10)))
    t0 = time.perf_counter()
    write_video(root / "long.mp4", n_frames, 20)
    print(f"\nlong video: {n_frames} frames 1280x720 rendered in {time.perf_counter() - t0:.0f} s")
    study = root / "vstudy"
    sc = new_scene(study / "long", {"c0": root / "long.mp4"}, root / "calib.json",
                   root / "ground.csv", fps=25, log=lambda s: None)
    d = json.loads((sc.root / "scene.json").read_text())
    d.setdefault("extra", {})["video_masks"] = {"history": 50}
    (sc.root / "scene.json").write_text(json.dumps(d))
    scene = load_scene(sc.root)
    uncut = root / "uncut.txt"
    stages = []
    c0, t0 = time.process_time(), time.perf_counter()
    t = time.process_time()
    masks_from_video(root / "long.mp4", uncut, BgConfig.from_dict({"history": 50}), log=lambda s: None)
    stages.append(("masks (decode, bg-sub, components, RLE)", time.process_time() - t))
    t = time.process_time()
    track_mots(uncut, uncut, scene.cameras["c0"], scene.ground, TrackConfig(), log=lambda s: None)
    stages.append(("tracker", time.process_time() - t))
    t = time.process_time()
    classify_mots(uncut, uncut, scene.cameras["c0"], scene.ground,
                  size_rules(scene.classes, scene.extra), fps=scene.fps, log=lambda s: None)
    stages.append(("size classes", time.process_time() - t))
    t_ser, c_ser = time.perf_counter() - t0, time.process_time() - c0
    print(f"uncut, in-process: {t_ser:.1f} s wall, {c_ser:.1f} s CPU; load {os.getloadavg()[0]:.1f}")
    for name, sec in stages:
        print(f"  {name:<40} {n_frames / sec:8.1f} frames per CPU-second")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        @ray.remote
        def warm():  # start both workers and import what the segments need, before timing
            import seg2pose.batch.segments  # noqa: F401
            time.sleep(1.0)

        ray.get([warm.remote() for _ in range(2)])

        @ray.remote
        def uncut_task(scene_dir):  # the uncut run as one Ray task: its CPU seconds there
            from seg2pose.video.video_scene import scene_masks_from_video

            c = time.process_time()
            scene_masks_from_video(scene_dir, log=lambda s: None)
            return time.process_time() - c

        shutil.copytree(sc.root, root / "uncut-scene")
        c_uncut_ray = ray.get(uncut_task.remote(str(root / "uncut-scene")))
        t0 = time.perf_counter()
        res = run_study(study, [MASKS_FROM_VIDEO], BatchOptions(segment_frames=n_frames // 2),
                        progress=False, log=lambda s: None)
        t_par = time.perf_counter() - t0
    finally:
        ray.shutdown()
    row = res.rows[0]
    assert not row["failures"], row
    segs = json.loads(sorted((sc.root / "batch" / "segments" / "c0").glob("*.json"))[-1].read_text())
    stitch = res.results["masks-from-video"][0]["seconds"]
    seg_cpu = [r["cpu_seconds"] for r in res.parts["masks-from-video"]]
    path = max(seg_cpu) + res.results["masks-from-video"][0]["cpu_seconds"]
    print(f"2 segments on Ray (2 warm workers): {t_par:.1f} s wall, of which the stitch and size "
          f"classes {stitch:.1f} s; the later "
          f"segment read {segs['info']['read']} frames (warm-up {segs['inputs']['segment']['n_warm']}); "
          f"load {os.getloadavg()[0]:.1f}")
    print(f"wall-time ratio uncut / 2 segments: {t_ser / t_par:.2f} "
          f"(at most {n_frames / segs['info']['read']:.2f} with this warm-up)")
    print(f"CPU: the segments' tasks {' + '.join(f'{c:.1f}' for c in seg_cpu)} s, stitch + classes "
          f"{res.results['masks-from-video'][0]['cpu_seconds']:.1f} s; critical path {path:.1f} s vs "
          f"{c_ser:.1f} s uncut in-process, {c_uncut_ray:.1f} s uncut as one Ray task: ratio "
          f"{c_uncut_ray / path:.2f} on 2 cores of one's own (CPU time: little dependent on load)")
    s = score_masks(iter_mots(uncut), iter_mots(sc.root / "masks" / "c0.txt"), min_area=0)
    at = switch_frames(uncut, sc.root / "masks" / "c0.txt")
    border, warm = n_frames // 2, segs["inputs"]["segment"]["n_warm"]
    near = sum(1 for f in at if abs(f - border) <= warm)
    print(f"against the uncut run: {s.switches} ID switches over {s.tracks} tracks, {near} of them "
          f"within the warm-up ({warm} frames) of the border {border}, the others at frames "
          f"{[f for f in at if abs(f - border) > warm]}; recall {s.recall:.4f}, precision "
          f"{s.precision:.4f}; the stitch's own count: {row['seams']}")


def switch_frames(truth: Path, est: Path) -> list[int]:
    """Frames where a track of ``truth`` changes its matched id in ``est`` (as score_masks)."""
    from scipy.optimize import linear_sum_assignment

    from seg2pose.io.mots import iter_mots
    from seg2pose.structures.masks import iou

    other = {f: t for f, t in iter_mots(est)}
    last: dict[int, int] = {}
    out = []
    for f, tt in iter_mots(truth):
        ee = other.get(f)
        if ee is None or not len(ee):
            continue
        m = iou(tt.rles, ee.rles, tt.height, tt.width)
        r, c = linear_sum_assignment(-m)
        for i, j in zip(r, c):
            if m[i, j] < 0.5:
                continue
            a, b = int(tt.track_id[i]), int(ee.track_id[j])
            if a in last and last[a] != b:
                out.append(f)
            last[a] = b
    return out


def bench_models(root: Path) -> None:
    import torch

    from seg2pose.io.run import read_run_meta
    from seg2pose.io.scene import load_scene
    from seg2pose.method.pipeline import RunOptions, run_scene
    from seg2pose.synth.generate import SynthOptions, generate_scene
    from seg2pose.training.config import TrainConfig, TrainSettings
    from seg2pose.training.train import train_scene

    torch.set_num_threads(1)
    sd = generate_scene(root / "train", SynthOptions(frames=150, seed=5, progress=False, workers=1))
    scene = load_scene(sd)
    cfg = TrainConfig.quick().replace(epochs=1, rough_every=0)
    t0 = time.process_time()
    models = train_scene(scene, root / "models", cfg, progress=False, settings=TrainSettings(threads=1))
    t_train = time.process_time() - t0
    n_models = len(list(models.glob("*.safetensors")))
    print(f"\ntrain, --protocol quick, 1 epoch ({cfg.batches_per_epoch} batches of {cfg.batch_size}, "
          f"lite-hr) for {n_models} models: {t_train:.1f} CPU-s incl. examples = "
          f"{t_train / n_models:.1f} CPU-s per model-epoch; load {os.getloadavg()[0]:.1f}")
    for name, kw in (("baseline", dict(baseline=True)), ("Seg2PoseNet sparse", dict(models_dir=models))):
        t0 = time.process_time()
        d = run_scene(scene, root / f"run-{len(name)}", RunOptions(progress=False, **kw))
        sec = time.process_time() - t0
        meta = read_run_meta(d)
        print(f"run, {name}: {meta['n_frames'] / sec:.1f} five-camera frames per CPU-second, "
              f"{meta['n_views'] / sec:.1f} masks per CPU-second")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", type=int, default=8)
    ap.add_argument("--frames", type=int, default=40, help="frames per split (3 splits a scene)")
    ap.add_argument("--video", type=int, default=0, help="also: a long video of this many frames, "
                                                         "uncut vs 2 segments on Ray")
    ap.add_argument("--models", action="store_true", help="also: train epoch and run with models")
    ap.add_argument("--only", action="store_true", help="skip the 8-scene study")
    args = ap.parse_args()
    if args.video or args.models:
        root = Path(tempfile.mkdtemp(prefix="bench_batch_"))
        try:
            if args.video:
                bench_video_segments(root, args.video)
            if args.models:
                bench_models(root)
        finally:
            shutil.rmtree(root, ignore_errors=True)
        if args.only:
            return

    import ray

    from seg2pose.batch.study import BATCH_DIR, BatchOptions, Step, run_study
    from seg2pose.cli.batch import STEPS
    from seg2pose.synth.generate import SynthOptions, generate_scene

    steps = [STEPS["run"], STEPS["eval"], STEPS["export"]]
    opts = BatchOptions()
    root = Path(tempfile.mkdtemp(prefix="bench_batch_"))
    try:
        for i in range(args.scenes):
            generate_scene(root / f"s{i:02d}", SynthOptions(frames=args.frames, seed=i, progress=False, workers=1))

        def clear():
            for s in root.iterdir():
                shutil.rmtree(s / BATCH_DIR, ignore_errors=True)

        quiet = dict(progress=False, log=lambda s: None)
        c0, t0 = time.process_time(), time.perf_counter()
        ser = run_study(root, steps, opts, use_ray=False, **quiet)
        t_ser, c_ser = time.perf_counter() - t0, time.process_time() - c0
        assert ser.n_failed == 0
        frames = sum(r["info"]["frames"] for r in ser.results["run"])
        print(f"{args.scenes} scenes, {frames} frames x 5 cameras; load average {os.getloadavg()[0]:.1f}")
        print(f"serial: {t_ser:.2f} s wall, {c_ser:.2f} s CPU")
        for name, rs in ser.results.items():  # per-core speed: one step on one core
            sec = sum(r["seconds"] for r in rs)
            print(f"  {name:<7} {sec:6.2f} s  {frames / sec:8.1f} frames/s per core")

        t0 = time.perf_counter()
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
        t_init = time.perf_counter() - t0
        try:
            noop = Step("noop", lambda s, o: [], lambda s, o: [], noop_run)
            run_study(root, [noop], opts, **quiet)  # starts the two workers
            clear()
            t0 = time.perf_counter()
            run_study(root, [noop], opts, **quiet)
            t_noop = time.perf_counter() - t0
            clear()
            c0, t0 = time.process_time(), time.perf_counter()
            par = run_study(root, steps, opts, **quiet)
            t_par, c_par = time.perf_counter() - t0, time.process_time() - c0
            assert par.n_failed == 0
            task_sec = sum(r["seconds"] for rs in par.results.values() for r in rs)
        finally:
            ray.shutdown()
        n_tasks = args.scenes * len(steps)
        print(f"ray (2 workers): {t_par:.2f} s wall (+ {t_init:.1f} s ray.init, once), "
              f"driver CPU {c_par:.2f} s, tasks' own time {task_sec:.2f} s over 2 workers; "
              f"load average {os.getloadavg()[0]:.1f}")
        print(f"wall-time ratio serial / ray: {t_ser / t_par:.2f} (goal >= 1.7 on 2 idle cores)")
        print(f"overhead per task: {t_noop / args.scenes * 1e3:.1f} ms (empty task, 2 workers); "
              f"{(t_par - task_sec / 2) / n_tasks * 1e3:.1f} ms per task of this study "
              f"(wall minus the tasks' own time / 2)")
    finally:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
