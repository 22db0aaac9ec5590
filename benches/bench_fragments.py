"""Speed of joining fragment tracks (``seg2pose.video.fragments.find_joins``, a step of ``s2p
masks-from-video``): one camera, 10,000 frames x 20 road users (200,000 masks), some of them cut
into pieces.

    PYTHONPATH=. .venv/bin/python benches/bench_fragments.py [--frames 10000] [--users 20]
        [--pieces 4] [--seed 0]

The road users walk and drive back and forth across a 1280 x 720 image of a junction filmed
from 9 m (pedestrians 0.6 x 1.8 m, cars 4.5 x 2.0 m as the camera sees them, boxes from the
world sizes), so their boxes pass and touch each other all the time; ``--pieces`` of the cars
come out of background subtraction as two touching pieces (a lower front corner and a band
along the rear) tracked separately. Timed: ``find_joins`` on the boxes (the RLE merge of the
joined masks is a second streaming pass, as cheap as writing the file). Printed also: how many
of the cut cars were joined, and whether any other pair was (a check that the work done is the
real one).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from seg2pose.geometry.camera import Camera  # noqa: E402
from seg2pose.geometry.ground import GroundSurface  # noqa: E402
from seg2pose.io.scene import ClassSpec  # noqa: E402
from seg2pose.video.classify import size_rules  # noqa: E402
from seg2pose.video.fragments import find_joins  # noqa: E402
from seg2pose.video.track import TrackConfig  # noqa: E402

H, W, FPS = 720, 1280, 10.0
CLASSES = [ClassSpec(1, "pedestrian", 0.9), ClassSpec(2, "bicyclist", 0.9), ClassSpec(3, "car", 0.75)]


def world_boxes(cam: Camera, xy: np.ndarray, width: np.ndarray, height: np.ndarray) -> np.ndarray:
    """(N, 4) pixel boxes x0, y0, x1, y1 of upright rectangles (N,) standing at ground points
    xy (N, 2), facing the camera."""
    F = np.c_[xy, np.zeros(len(xy))]
    view = F[:, :2] - cam.center[:2]
    u = np.c_[-view[:, 1], view[:, 0], np.zeros(len(xy))] / np.linalg.norm(view, axis=1)[:, None]
    up = np.array([0.0, 0.0, 1.0])
    corners = np.stack([F - u * width[:, None] / 2, F + u * width[:, None] / 2,
                        F + u * width[:, None] / 2 + up * height[:, None],
                        F - u * width[:, None] / 2 + up * height[:, None]], axis=1)
    uv, _, _ = cam.project_points(corners.reshape(-1, 3))
    uv = uv.reshape(-1, 4, 2)
    return np.c_[uv.min(axis=1), uv.max(axis=1)]


def make(frames: int, users: int, pieces: int, seed: int):
    rng = np.random.default_rng(seed)
    cam = Camera.look_at("c0", np.array([0.0, -12.0, 9.0]), np.array([0.0, 15.0, 0.0]), 900.0, W, H)
    ground = GroundSurface(np.array([(x, y, 0.0) for x in range(-40, 41, 10)
                                     for y in range(-10, 71, 10)], float))
    car = np.arange(users) < users // 2
    size = np.where(car[:, None], [4.5, 2.0], [0.6, 1.8])
    y0 = rng.uniform(8, 40, users)
    amp, period = rng.uniform(3, 12, users), rng.uniform(100, 600, users)
    t = np.arange(frames)
    x = amp[:, None] * np.sin(2 * np.pi * t[None, :] / period[:, None] + rng.uniform(0, 6, users)[:, None])
    xy = np.stack([x, np.broadcast_to(y0[:, None], x.shape)], axis=2).reshape(-1, 2)
    uid = np.repeat(np.arange(users), frames)
    frame = np.tile(t, users)
    box = world_boxes(cam, xy, size[uid, 0], size[uid, 1])
    # cut cars: a lower front corner and a band along the rear, two tracks
    cut = np.isin(uid, np.flatnonzero(car)[:pieces])
    bw, bh = box[:, 2] - box[:, 0], box[:, 3] - box[:, 1]
    front = np.c_[box[:, 0], box[:, 1] + 0.55 * bh, box[:, 0] + 0.3 * bw, box[:, 3]]
    rear = np.c_[box[:, 0] + 0.31 * bw, box[:, 1] + 0.1 * bh, box[:, 2], box[:, 1] + 0.55 * bh]
    track = uid + 1
    frame = np.r_[frame[~cut], frame[cut], frame[cut]]
    box = np.r_[box[~cut], front[cut], rear[cut]]
    piece_id = np.r_[track[~cut], track[cut], track[cut] + 1000]
    truth = {(int(a), int(a) + 1000) for a in np.unique(track[cut])}
    return frame, piece_id, box, cam, ground, truth


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=10_000)
    ap.add_argument("--users", type=int, default=20)
    ap.add_argument("--pieces", type=int, default=4)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    frame, track, box, cam, ground, truth = make(a.frames, a.users, a.pieces, a.seed)
    rules = size_rules(CLASSES, {})
    t0, c0 = time.perf_counter(), time.process_time()
    _, _, joins = find_joins(frame, track, box, H, W, cam, ground, rules, TrackConfig(), FPS)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    made = {tuple(sorted(j)) for j in joins}
    print(f"find_joins, {len(frame):,} masks ({a.frames:,} frames x {a.users} road users, "
          f"{a.pieces} cut in two): {wall:.2f} s wall, {cpu:.2f} s CPU; joined {len(made & truth)} "
          f"of {len(truth)} cut road users, {len(made - truth)} other pairs")


if __name__ == "__main__":
    main()
