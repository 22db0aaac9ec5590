"""Benchmark: the annotation engine's speed.

    PYTHONPATH=. .venv/bin/python benches/bench_annotate.py [--edits 100000]

1. Interpolation of a 10,000-frame track (keyframes every 25 frames), per method: x, y and
   heading alone, and whole poses with z from the ground surface (eq. 1, 184 ground points).
   Goal: <= 5 ms.
2. Replay of a journal of 100,000 edits (keyframes set, nudged, rotated, tracks created, some
   undos) on open. Goal: <= 2 s. The journal is written with fsync switched off (only to make
   it quickly; replay reads the same bytes either way).
3. An edit (nudge) written and fsync'ed to the journal, then the changed 1,000-frame track's
   poses recomputed. Goal: <= 20 ms. Also shown apart: the fsync'ed append alone.

Median of repeated runs; the scene is the tiny test scene (184 ground points like the paper's).
"""

from __future__ import annotations

import argparse
import os

# eq. (1)'s products for one track are too small to gain from BLAS threads, and on a shared
# machine the threads only wait: one thread (say so before numpy loads)
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
import random
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from annotate import Project  # noqa: E402
from annotate.interpolate import METHODS, interpolate  # noqa: E402
from annotate.model import Track, keyframe  # noqa: E402
from annotate.table import track_poses  # noqa: E402
from seg2pose.geometry.ground import GroundSurface  # noqa: E402


def median_ms(fn, repeat: int) -> str:
    """'wall ms (CPU ms)': medians of ``repeat`` calls. On a shared machine the CPU time is
    the fairer figure (the wall time includes waiting for a core)."""
    fn()
    ts, cs = [], []
    for _ in range(repeat):
        t, c = time.perf_counter(), time.process_time()
        fn()
        ts.append(time.perf_counter() - t)
        cs.append(time.process_time() - c)
    return f"{1000 * float(np.median(ts)):6.2f} ms (CPU {1000 * float(np.median(cs)):5.2f})"


def winding_track(n_frames: int, every: int, rng) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    kf = np.r_[np.arange(0, n_frames, every), n_frames - 1]
    ang = np.cumsum(rng.normal(0, 0.2, len(kf)))
    step = rng.uniform(5, 15, len(kf))
    xy = np.cumsum(np.column_stack([np.cos(ang), np.sin(ang)]) * step[:, None], axis=0)
    xy -= xy.mean(axis=0)
    return kf, xy * 0.02, ang  # shrunk to stay on a 50 m ground patch


def bench_interpolation(ground: GroundSurface, repeat: int) -> None:
    rng = np.random.default_rng(0)
    kf, xy, hd = winding_track(10_000, 25, rng)
    q = np.arange(kf[0], kf[-1] + 1)
    track = Track(1, "car", (4.5, 1.8, 1.5),
                  keyframes={int(f): keyframe(x, y, h) for f, (x, y), h in zip(kf, xy, hd)})
    print(f"1. 10,000-frame track, {len(kf)} keyframes (goal <= 5 ms)")
    for m in METHODS:
        t_xy = median_ms(lambda: interpolate(kf, xy, hd, q, m), repeat)
        t_all = median_ms(lambda: track_poses(track, ground, m), repeat)
        print(f"   {m:8s} x, y, heading {t_xy}   whole poses with z (eq. 1) {t_all}")


def write_journal(scene_root: Path, n_edits: int) -> float:
    """n_edits edits through the API with fsync off; returns the file size in MB."""
    real_fsync = os.fsync
    os.fsync = lambda fd: None  # only while writing the bench's journal
    rng = random.Random(0)
    try:
        with Project.open(scene_root, snapshot_every=10 ** 9) as p:
            for _ in range(n_edits):
                ids = list(p.tracks)
                r = rng.random()
                if not ids or r < 0.01:
                    p.create_track(rng.choice(["car", "pedestrian"]))
                    continue
                t = rng.choice(ids)
                kfs = p.track(t).keyframes
                if r < 0.6 or not kfs:
                    p.set_keyframe(t, rng.randrange(30), rng.uniform(-10, 10),
                                   rng.uniform(-8, 8), heading=rng.uniform(-3, 3))
                elif r < 0.8:
                    p.nudge(t, rng.choice(list(kfs)), 0.02, 0.0)
                elif r < 0.95:
                    p.rotate(t, rng.choice(list(kfs)), 5)
                else:
                    p.undo()
    finally:
        os.fsync = real_fsync
    size = sum(f.stat().st_size for f in (scene_root / "annotations").glob("journal-*"))
    return size / 1e6


def bench_replay(scene_root: Path, n_edits: int) -> None:
    t = time.perf_counter()
    mb = write_journal(scene_root, n_edits)
    print(f"2. replay of {n_edits:,} edits ({mb:.1f} MB journal, written in "
          f"{time.perf_counter() - t:.0f} s) (goal <= 2 s)")
    ts, cs = [], []
    for _ in range(3):
        t, c = time.perf_counter(), time.process_time()
        with Project.open(scene_root, read_only=True) as p:
            n = p.seq
        ts.append(time.perf_counter() - t)
        cs.append(time.process_time() - c)
    print(f"   open + replay {min(ts):.2f} s, CPU {min(cs):.2f} s (best of 3; {n:,} records)")


def bench_edit(scene_root: Path, repeat: int) -> None:
    shutil.rmtree(scene_root / "annotations", ignore_errors=True)
    with Project.open(scene_root, frames=(0, 10_000)) as p:
        p.create_track("car")
        rng = np.random.default_rng(1)
        kf, xy, hd = winding_track(1000, 25, rng)
        for f, (x, y), h in zip(kf, xy, hd):
            p.set_keyframe(1, int(f), x, y, heading=h)
        p.track_poses(1)

        def edit():
            p.nudge(1, 500, 0.02, 0.0)
            p.track_poses(1)

        def append():
            p._write({"kind": "note", "text": "bench"})

        t_edit = median_ms(edit, repeat)
        t_app = median_ms(append, repeat)
        t_poses = median_ms(lambda: (p._cache.clear(), p.track_poses(1)), repeat)
    print("3. edit -> new poses of a 1,000-frame track (goal <= 20 ms)")
    print(f"   nudge (journal append + fsync) + poses {t_edit}")
    print(f"   of which the fsync'ed append {t_app}, the poses {t_poses}")


def main() -> None:
    ap = argparse.ArgumentParser(description="annotation engine speed")
    ap.add_argument("--edits", type=int, default=100_000)
    ap.add_argument("--repeat", type=int, default=30)
    args = ap.parse_args()
    from review_fixtures import make_scene
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-25, 25, (184, 2)), rng.normal(0, 0.05, 184)])
    ground = GroundSurface(pts)
    print(f"machine: {os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}, "
          f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}")
    bench_interpolation(ground, args.repeat)
    with tempfile.TemporaryDirectory() as tmp:
        scene = make_scene(Path(tmp) / "scene", n_frames=30)
        scene.ground_points = pts
        scene.save()
        bench_replay(scene.root, args.edits)
        bench_edit(scene.root, args.repeat)


if __name__ == "__main__":
    main()
