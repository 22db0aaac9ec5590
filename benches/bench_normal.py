"""Benchmark: normal positions (paper 3.2) for 10,000 detections of 1280x720 RLE masks, end to end
from the compressed RLE strings (mask centres from runs, rays, ray/ground intersection on a
184-point ground surface as in the paper's CARLA scene).

    .venv/bin/python benches/bench_normal.py [--n 10000] [--center bbox|centroid]

Masks are realistic: filled convex hulls of projected road-user boxes (cars, pedestrians,
bicyclists) at random places on the road, 1,000 distinct ones repeated to 10,000. Prints
masks/s for each stage and the peak memory.
"""

from __future__ import annotations

import argparse
import math
import resource
import time
import tracemalloc

import cv2
import numpy as np

from seg2pose.geometry.camera import Camera
from seg2pose.geometry.ground import GroundSurface
from seg2pose.geometry.normal import normal_positions
from seg2pose.io.mots import MaskTable, read_mots, write_mots
from seg2pose.structures.masks import encode, mask_centers

W, H = 1280, 720
SIZES = {"car": (4.5, 1.8, 1.5), "pedestrian": (0.5, 0.5, 1.8), "bicyclist": (1.8, 0.6, 1.7)}


def make_scene(seed: int = 0):
    rng = np.random.default_rng(seed)
    xy = rng.uniform([-25, -5], [25, 45], (184, 2))
    z = 0.01 * xy[:, 1] + 0.15 * (np.abs(xy[:, 0]) > 7) + rng.normal(0, 0.01, 184)
    ground = GroundSurface(np.column_stack([xy, z]))
    cam = Camera.look_at("c", [0, -12, 10], [0, 15, 0], 1000, W, H)
    return ground, cam


def make_masks(ground, cam, n_unique: int, seed: int = 0) -> list[bytes]:
    rng = np.random.default_rng(seed)
    rles = []
    names = list(SIZES)
    while len(rles) < n_unique:
        l, w, h = SIZES[names[len(rles) % 3]]
        p = rng.uniform([-12, 0], [12, 40])
        hd = rng.uniform(-math.pi, math.pi)
        z0 = ground.height(p[None])[0]
        c, s = math.cos(hd), math.sin(hd)
        corners = np.array([(p[0] + c * dl - s * dw, p[1] + s * dl + c * dw, z0 + dz)
                            for dl in (-l / 2, l / 2) for dw in (-w / 2, w / 2) for dz in (0, h)])
        uv, _, front = cam.project_points(corners)
        if not front.all():
            continue
        m = np.zeros((H, W), np.uint8)
        cv2.fillConvexPoly(m, cv2.convexHull(np.round((uv - 0.5) * 16).astype(np.int32)), 1, shift=4)
        if m.any():
            rles.append(encode(m))
    return rles


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=10_000)
    ap.add_argument("--center", default="bbox", choices=["bbox", "centroid"])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()

    ground, cam = make_scene()
    t0 = time.perf_counter()
    uniq = make_masks(ground, cam, 1000)
    rles = [uniq[i % len(uniq)] for i in range(args.n)]
    heights = np.full(args.n, 0.8)
    print(f"setup: {len(uniq)} distinct masks rendered in {time.perf_counter() - t0:.1f} s; "
          f"mean RLE length {np.mean([len(r) for r in uniq]):.0f} chars")

    best = {"centres": 1e9, "normal": 1e9, "total": 1e9}
    tracemalloc.start()
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        cen = mask_centers(rles, H, W, args.center)
        t1 = time.perf_counter()
        X, status = normal_positions(cam, ground, cen, heights)
        t2 = time.perf_counter()
        best["centres"] = min(best["centres"], t1 - t0)
        best["normal"] = min(best["normal"], t2 - t1)
        best["total"] = min(best["total"], t2 - t0)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert np.isfinite(X).all() and (status == 0).all()
    n = args.n
    print(f"{n} masks {W}x{H}, centre={args.center}, ground points=184, best of {args.repeat}:")
    print(f"  mask centres from RLE : {n / best['centres']:>10,.0f} masks/s ({best['centres'] * 1e3:.0f} ms)")
    print(f"  normal positions      : {n / best['normal']:>10,.0f} masks/s ({best['normal'] * 1e3:.0f} ms)")
    print(f"  end to end from RLE   : {n / best['total']:>10,.0f} masks/s ({best['total'] * 1e3:.0f} ms)")
    print(f"  peak traced memory    : {peak / 2**20:.1f} MiB")

    # with the MOTS file parse included (what `s2p run` does per camera)
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "m.txt"
        write_mots(p, MaskTable(np.arange(n) // 20, np.arange(n) % 20, np.ones(n), H, W, rles))
        t0 = time.perf_counter()
        t = read_mots(p)
        cen = mask_centers(t.rles, H, W, args.center)
        normal_positions(cam, ground, cen, heights)
        dt = time.perf_counter() - t0
    print(f"  incl. MOTS file read  : {n / dt:>10,.0f} masks/s ({dt * 1e3:.0f} ms, {n // 20} frames)")
    print(f"  peak RSS (process)    : {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB")


if __name__ == "__main__":
    main()
