"""Benchmark of the synthetic-scene generator (issue 3).

Prints:
1. masks-only rendering speed for one camera with 20 visible road users at 1280x720
   (painter's-order id buffer + crops + COCO RLE), noise off and on, one process;
2. rough 3D models rasterised per second (paper 3.5, used by training);
3. the paper preset (3 splits x 7,000 frames x 5 lenses): simulation time measured in full,
   rendering time estimated from a sample of its frames (or measured with --full);
4. peak memory (ru_maxrss).

Usage:  .venv/bin/python benches/bench_synth.py [--frames 300] [--full]
"""

from __future__ import annotations

import argparse
import resource
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from seg2pose.geometry.ground import GroundSurface
from seg2pose.synth import junction as J
from seg2pose.synth.generate import DT, PRESETS, SynthOptions, generate_scene, split_ranges
from seg2pose.synth.noise import NoiseConfig
from seg2pose.synth.render import FrameRenderer
from seg2pose.synth.rig import make_device
from seg2pose.synth.rough import render_rough_examples
from seg2pose.synth.traffic import TrafficConfig, Visit, simulate
from seg2pose.synth.world import build_world


def twenty_in_view(cam, n_frames: int, seed: int = 0):
    """A world with 20 road users (8 pedestrians, 4 bicyclists, 8 cars) walking/driving
    slowly inside the camera's view for ``n_frames`` frames."""
    rng = np.random.default_rng(seed)
    visits = []
    classes = ["pedestrian"] * 8 + ["bicyclist"] * 4 + ["car"] * 8
    frames = np.arange(n_frames)
    for member, cls in enumerate(classes):
        while True:
            xy0 = rng.uniform([-8, -8], [30, 30])
            hd = rng.uniform(-np.pi, np.pi)
            v = {"pedestrian": 1.3, "bicyclist": 5.0, "car": 8.0}[cls] * 0.2  # stay in view
            xy = xy0 + np.outer(frames * DT * v, [np.cos(hd), np.sin(hd)])
            X = np.column_stack([xy, J.true_height(xy)])
            uv, _, front = cam.project_points(X)
            if front.all() and cam.in_image(uv).all():
                break
        visits.append(Visit(cls, frames, xy, np.full(n_frames, hd), frames * 0.3, 0.0, member))
    return build_world(visits, n_frames, seed)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=300, help="frames for the 20-road-user test")
    ap.add_argument("--full", action="store_true", help="really generate the paper preset (minutes)")
    args = ap.parse_args()
    rig = make_device()
    cam = rig.cameras["c1"]

    w = twenty_in_view(cam, args.frames)
    for label, noise in (("noise off", NoiseConfig.off()), ("noise on ", NoiseConfig())):
        r = FrameRenderer(cam, 1, w, noise, 0)
        r.mots_lines(0, 5)  # warm-up
        t = time.perf_counter()
        _, n = r.mots_lines(0, args.frames)
        dt = time.perf_counter() - t
        print(f"masks, 1 camera, 20 road users in view, 1280x720, {label}: "
              f"{args.frames / dt:7.1f} frames/s  ({n / args.frames:.1f} masks/frame, 1 process)")

    # rough models
    g = GroundSurface(np.array([[x, y, 0.0] for x in np.linspace(-40, 60, 11)
                                for y in np.linspace(-40, 60, 11)]))
    render_rough_examples(cam, g, "car", 1, np.random.default_rng(0))  # caches the visible region
    for cls in ("car", "pedestrian", "bicyclist"):
        rng = np.random.default_rng(0)
        t = time.perf_counter()
        rles, _, _ = render_rough_examples(cam, g, cls, 1000, rng)
        dt = time.perf_counter() - t
        print(f"rough models ({cls:10s}): {len(rles) / dt:7.0f} masks/s (batches of 1000)")
    rng = np.random.default_rng(0)
    t = time.perf_counter()
    for _ in range(100):
        render_rough_examples(cam, g, "car", 4, rng)
    print(f"rough models (car, batches of 4): {400 / (time.perf_counter() - t):7.0f} masks/s")

    # paper preset
    p = PRESETS["paper"]
    splits = split_ranges(p["split"], p["gap"])
    n_frames = splits["test"][1] + 1
    t = time.perf_counter()
    visits = simulate(TrafficConfig(p["population"], p["mean_pause_s"]), n_frames, DT, 0)
    world = build_world(visits, n_frames, 0)
    t_sim = time.perf_counter() - t
    on_stage = np.diff(world.frame_ptr).mean()
    sample = range(0, n_frames, max(n_frames // 400, 1))
    r = FrameRenderer(cam, 1, world, NoiseConfig(), 0)
    t = time.perf_counter()
    n_det = sum(len(r.render(f)) for f in sample)
    fps = len(sample) / (time.perf_counter() - t)
    renders = n_frames * len(rig.cameras)
    workers = 2
    est = t_sim + renders / fps / workers
    print(f"paper preset: {n_frames} frames, {len(np.unique(world.track))} road users making "
          f"{len(visits)} visits, {on_stage:.1f} road users on "
          f"stage/frame, {n_det / len(sample):.1f} masks/frame in c1")
    print(f"paper preset: simulation {t_sim:.1f} s; rendering {fps:.0f} frames/s/process "
          f"-> estimate {est / 60:.1f} min for {renders} camera frames with {workers} processes "
          f"(goal < 30 min)")
    if args.full:
        out = Path(tempfile.mkdtemp()) / "paper"
        t = time.perf_counter()
        generate_scene(out, SynthOptions(preset="paper", seed=0, progress=True))
        print(f"paper preset generated in {(time.perf_counter() - t) / 60:.1f} min (measured), "
              f"{sum(f.stat().st_size for f in out.rglob('*') if f.is_file()) / 1e6:.0f} MB")
        shutil.rmtree(out.parent)
    print(f"peak memory (ru_maxrss): {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")


if __name__ == "__main__":
    main()
