"""Speed of cross-camera association (``seg2pose.video.associate.associate``): 5 cameras x
10,000 frames x 20 road users (1,000,000 masks), the issue's goal <= 10 s.

    PYTHONPATH=. .venv/bin/python benches/bench_associate.py [--frames 10000] [--users 20]
        [--cameras 5] [--seed 0]

The road users drive circles of 5-25 m radius around points of a 60 x 60 m junction at
1-10 m/s (10 frames/s), so they cross each other all the time. Each camera sees each of them
with its own default-height error (a shift of up to 0.5 m that turns with the camera), 5 cm
noise and 2 % of the masks missing; its tracker breaks every track into pieces of 200-800
frames under new ids. Timed: ``associate`` alone (the normal positions are the pipeline's, not
association's); printed also: how many masks carry the majority id of their road user (a check
that the work done is the real one).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from seg2pose.video.associate import CameraViews, associate  # noqa: E402


def make(frames: int, users: int, cameras: int, seed: int):
    rng = np.random.default_rng(seed)
    t = np.arange(frames)
    centre = rng.uniform(-20, 20, (users, 2))
    radius = rng.uniform(5, 25, users)
    speed = rng.uniform(1, 10, users) / 10.0 * rng.choice([-1, 1], users)  # metres per frame
    phase = rng.uniform(0, 2 * np.pi, users)
    ang = phase[:, None] + speed[:, None] / radius[:, None] * t[None, :]          # (U, F)
    xy = centre[:, None, :] + radius[:, None, None] * np.stack([np.cos(ang), np.sin(ang)], axis=2)
    views, truth = {}, {}
    for k in range(cameras):
        cam_pos = 40 * np.array([np.cos(2 * np.pi * k / cameras), np.sin(2 * np.pi * k / cameras)])
        u, f = np.meshgrid(np.arange(users), t, indexing="ij")
        u, f = u.ravel(), f.ravel()
        p = xy[u, f]
        ray = p - cam_pos
        ray /= np.linalg.norm(ray, axis=1, keepdims=True)
        bias = rng.uniform(-0.5, 0.5, users)[u][:, None] * ray
        p = p + bias + rng.normal(0, 0.05, p.shape)
        keep = rng.random(len(u)) > 0.02
        u, f, p = u[keep], f[keep], p[keep]
        # the camera's tracker: every road user's track cut into pieces under new ids
        piece = np.zeros(len(u), np.int64)
        for r in range(users):
            sel = np.flatnonzero(u == r)
            cuts = np.cumsum(rng.integers(200, 800, frames // 200 + 2))
            piece[sel] = np.searchsorted(cuts, f[sel], "right")
        _, track = np.unique(u * 1000 + piece, return_inverse=True)
        order = np.argsort(f, kind="stable")
        spread = np.linalg.norm(p - cam_pos, axis=1) * 0.3 / 10.0
        views[f"c{k}"] = CameraViews(f[order], track.reshape(-1)[order] + 1, np.ones(len(u), np.int64),
                                     p[order], spread[order])
        truth[f"c{k}"] = u[order]
    return views, truth


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=10_000)
    ap.add_argument("--users", type=int, default=20)
    ap.add_argument("--cameras", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    views, truth = make(a.frames, a.users, a.cameras, a.seed)
    n = sum(len(v) for v in views.values())
    t0, c0 = time.perf_counter(), time.process_time()
    res = associate(views)
    dt, cpu = time.perf_counter() - t0, time.process_time() - c0
    # majority id per true road user over all cameras and frames
    u = np.concatenate([truth[c] for c in views])
    g = np.concatenate([res.ids[c] for c in views])
    pairs, cnt = np.unique(np.stack([u, g], axis=1), axis=0, return_counts=True)
    top = np.zeros(a.users, np.int64)
    np.maximum.at(top, pairs[:, 0], cnt)
    print(f"{a.cameras} cameras x {a.frames} frames x {a.users} road users = {n:,} masks: "
          f"associate {dt:.2f} s ({cpu:.2f} s CPU); {res.road_users} ids, {res.cuts} cuts, {res.pieces} pieces; "
          f"masks with their road user's majority id: {top.sum() / n:.3f}")


if __name__ == "__main__":
    main()
