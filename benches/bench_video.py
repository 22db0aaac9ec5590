"""Speed and memory of the video path (issue 13): background subtraction + components, the
mask tracker, and peak memory of masks-from-video over growing videos (flat = streaming).

    .venv/bin/python benches/bench_video.py [--frames 600] [--memory 300,1000,3000] [--users 20]
        [--tracker-only] [--repeat 1]

The video: 1280x720, a textured background with sensor noise, ``--users`` road users (coloured
blobs of pedestrian to car size) moving across, written as mp4v like ``s2p synth --video``.
Goals: >= 25 frames/s for background subtraction + components, >= 500 frames/s for the tracker.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

W, H = 1280, 720


def users(n: int, seed: int = 0) -> list[dict]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        car = i % 3 == 0
        w, h = (int(rng.integers(90, 200)), int(rng.integers(50, 90))) if car else \
            (int(rng.integers(14, 30)), int(rng.integers(40, 90)))
        out.append(dict(x=rng.uniform(0, W), y=rng.uniform(60, H - 100), w=w, h=h,
                        vx=rng.uniform(-6, 6), vy=rng.uniform(-1, 1),
                        col=tuple(int(c) for c in rng.integers(0, 255, 3))))
    return out


def write_video(path: Path, n_frames: int, n_users: int) -> None:
    import cv2

    rng = np.random.default_rng(1)
    small = rng.integers(60, 140, size=(18, 32, 3)).astype(np.uint8)
    bg = cv2.resize(small, (W, H), interpolation=cv2.INTER_CUBIC)
    bank = [rng.normal(0, 3, (H, W, 3)).astype(np.int16) for _ in range(4)]
    us = users(n_users)
    wr = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 13.3, (W, H))
    for f in range(n_frames):
        img = bg.copy()
        for u in us:
            x = int((u["x"] + u["vx"] * f) % (W + u["w"])) - u["w"]
            y = int(u["y"] + u["vy"] * f) % (H - u["h"])
            cv2.rectangle(img, (x, y), (x + u["w"], y + u["h"]), u["col"], -1)
        wr.write(np.clip(img + bank[f % 4], 0, 255).astype(np.uint8))
    wr.release()


def _masks_child(video: str, out: str, q) -> None:
    from seg2pose.video.video_masks import BgConfig, masks_from_video

    t = time.perf_counter()
    res = masks_from_video(video, out, BgConfig(), log=lambda s: None)
    # VmHWM, not ru_maxrss: Linux carries ru_maxrss over fork + exec from the parent
    hwm = next(int(line.split()[1]) for line in open("/proc/self/status") if line.startswith("VmHWM"))
    q.put((res.n_frames, res.n_masks, time.perf_counter() - t, hwm / 1024))


def masks_from_video_run(video: Path, out: Path) -> tuple[int, int, float, float]:
    """(frames, masks, seconds, peak RSS MiB) of masks_from_video in a fresh process."""
    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    p = ctx.Process(target=_masks_child, args=(str(video), str(out), q))
    p.start()
    r = q.get()
    p.join()
    return r


def bgsub_only(video: Path, n: int) -> float:
    """frames/s of background subtraction + morphology + components + RLE on decoded frames."""
    import cv2

    from seg2pose.video.video_masks import BackgroundMasks, BgConfig

    cap = cv2.VideoCapture(str(video))
    frames = []
    for _ in range(n):
        ok, im = cap.read()
        if not ok:
            break
        frames.append(im)
    seg = BackgroundMasks(BgConfig(), H, W)
    seg.prime(frames[::max(len(frames) // 25, 1)])
    t = time.perf_counter()
    for im in frames:
        seg.apply(im)
    return len(frames) / (time.perf_counter() - t)


def tracker_fps(n_frames: int, n_users: int, repeat: int = 1
                ) -> tuple[list[tuple[float, float]], list[tuple[float, float]],
                           list[tuple[float, float]], float]:
    """frames/s of the tracker on 20 moving masks per frame: IoU only and IoU + world distances
    (both without splitting), and the default (world distances + splitting of merged masks),
    each ``repeat`` times, interleaved (so all three see the same load): (frames per second
    of wall time, frames per second of this process's CPU time) per run; plus the share of
    frames with a split. On a loaded machine the CPU figure is the steadier one.
    The blobs overlap often (they are drawn at random and wrap around): a worst case."""
    from seg2pose.geometry.camera import Camera
    from seg2pose.geometry.ground import GroundSurface
    from seg2pose.io.mots import MaskTable
    from seg2pose.structures.masks import encode
    from seg2pose.video.track import track_frames

    us = users(n_users)
    tabs = []
    for f in range(n_frames):
        rles = []
        for u in us:
            m = np.zeros((H, W), np.uint8)
            x = int((u["x"] + u["vx"] * f) % (W + u["w"])) - u["w"]
            y = int(u["y"] + u["vy"] * f) % (H - u["h"])
            m[max(y, 0):y + u["h"], max(x, 0):max(x + u["w"], 0)] = 1
            if m.any():
                rles.append(encode(m))
        z = np.zeros(len(rles), np.int64)
        tabs.append((f, MaskTable(z + f, z - 1, z, H, W, rles)))
    cam = Camera.look_at("c", np.array([-12.0, -12.0, 10.0]), np.array([-1.0, -1.0, 0.0]), 900.0, W, H)
    g = np.array([(x, y, 0.0) for x in range(-30, 31, 10) for y in range(-30, 31, 10)], float)
    ground = GroundSurface(g)
    from seg2pose.video.track import TrackConfig, Tracker, _run

    out: list[list[tuple[float, float]]] = [[], [], []]
    for _ in range(repeat):
        for k, (c, gr, split) in enumerate(((None, None, 0.0), (cam, ground, 0.0),
                                            (cam, ground, TrackConfig().split_min))):
            t, cpu = time.perf_counter(), time.process_time()
            track_frames(iter(tabs), H, W, c, gr, TrackConfig(split_min=split))
            out[k].append((n_frames / (time.perf_counter() - t), n_frames / (time.process_time() - cpu)))
    tr = Tracker(H, W, TrackConfig())
    split_frames = sum(len(m) > len(t) for (m, _), (_, t) in zip(_run(iter(tabs), tr, cam, ground), tabs))
    return out[0], out[1], out[2], split_frames / n_frames


def tracker_report(a) -> None:
    def one(v: list[float]) -> str:
        v = sorted(v)
        return f"{v[len(v) // 2]:.0f}" + (f" ({v[0]:.0f}-{v[-1]:.0f})" if len(v) > 1 else "")

    def fig(runs: list[tuple[float, float]]) -> str:
        return f"{one([w for w, _ in runs])} [CPU {one([c for _, c in runs])}]"

    iou_fps, world_fps, split_fps, share = tracker_fps(min(a.frames, 1000), a.users, a.repeat)
    print(f"tracker, {a.users} masks/frame, no splitting: IoU only {fig(iou_fps)} frames/s, IoU + "
          f"world distance {fig(world_fps)} frames/s; default (with merged-mask splitting) "
          f"{fig(split_fps)} frames/s ({100 * share:.0f} % of frames had a split)"
          + (f"; median (min-max) of {a.repeat} runs" if a.repeat > 1 else "")
          + "; [CPU ...]: frames per second of the process's CPU time")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=600, help="frames of the speed video")
    ap.add_argument("--memory", default="300,1000,3000", help="video lengths for peak memory")
    ap.add_argument("--users", type=int, default=20)
    ap.add_argument("--tracker-only", action="store_true", help="only the tracker figures")
    ap.add_argument("--repeat", type=int, default=1, help="tracker runs (under load: the spread)")
    a = ap.parse_args()
    import cv2

    print(f"OpenCV {cv2.__version__}, threads {cv2.getNumThreads()}, load {open('/proc/loadavg').read().split()[0]}")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if a.tracker_only:
            tracker_report(a)
            return
        v = tmp / "v.mp4"
        write_video(v, a.frames, a.users)
        print(f"bg-sub + morphology + components + RLE (decoded frames): {bgsub_only(v, a.frames):.1f} frames/s")
        n, m, s, rss = masks_from_video_run(v, tmp / "m.txt")
        print(f"masks-from-video end to end (decode, init, write): {n / s:.1f} frames/s, "
              f"{m / n:.1f} masks/frame, peak RSS {rss:.0f} MiB")
        tracker_report(a)
        for n_frames in [int(x) for x in a.memory.split(",") if x]:
            vm = tmp / f"m{n_frames}.mp4"
            write_video(vm, n_frames, a.users)
            n, m, s, rss = masks_from_video_run(vm, tmp / f"m{n_frames}.txt")
            print(f"peak memory, {n} frames: {rss:.0f} MiB ({n / s:.1f} frames/s)")
            vm.unlink()


if __name__ == "__main__":
    main()
