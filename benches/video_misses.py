"""Why background-subtraction masks miss road users: a breakdown of the missed truth masks.

    PYTHONPATH=. .venv/bin/python benches/video_misses.py TRUTH_SCENE EST_MOTS [--camera c1]

TRUTH_SCENE: ``s2p synth -o T --seed S --no-detector-noise --match all`` (rendered silhouettes
of every visible road user); EST_MOTS: masks of the same seed's ``--video`` scene (from
``s2p masks-from-video``, with or without the tracker). Every truth mask of at least
``--min-area`` pixels that no estimated mask matches at IoU >= 0.5 (Hungarian per frame) gets
the first reason that applies, in this order:

1. ``merged``: the estimated mask that covers most of it also covers >= 30 % of another truth
   mask (neighbours in one blob);
2. ``occluded``: less than half of its silhouette is visible (others in front of it; the
   generator's world is rebuilt from the seed to know the whole silhouette);
3. ``fragmented``: two or more estimated masks each cover >= 10 % of it;
4. ``oversized``: one estimated mask covers >= 50 % of it but is > 1.5x its area (shadow
   or a background remnant attached);
5. ``faint``: the estimated masks cover less than half of it (pixels like the background);
6. ``other``.

Counted alongside: ``small`` (area < 400 px), ``still`` (the road user moved less than 3 cm
into and out of the frame, gt/poses.csv), and each reason without the order.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path

import numpy as np
from pycocotools import mask as mask_util
from scipy.optimize import linear_sum_assignment

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from seg2pose.io.mots import iter_mots  # noqa: E402
from seg2pose.io.poses import read_poses  # noqa: E402
from seg2pose.io.scene import load_scene  # noqa: E402
from seg2pose.structures.masks import iou, rle_stats  # noqa: E402

REASONS = ("merged", "occluded", "fragmented", "oversized", "faint", "other")


def moving_flags(truth: Path, step_m: float = 0.03) -> dict[tuple[int, int], bool]:
    """(frame, track) -> whether the road user moved > step_m metres into or out of the frame."""
    gt = read_poses(truth / "gt" / "poses.csv")
    o = np.lexsort((gt.frame, gt.track_id))
    tid, fr, xy = gt.track_id[o], gt.frame[o], gt.xyz[o, :2]
    same = np.r_[False, tid[1:] == tid[:-1]]
    step = np.where(same, np.r_[0, np.linalg.norm(np.diff(xy, axis=0), axis=1)], 0.0)
    nxt = np.r_[step[1:], 0.0] * np.r_[same[1:], False]
    moved = np.maximum(step, nxt) > step_m
    return {(int(f), int(t)): bool(m) for f, t, m in zip(fr, tid, moved)}


def visibility(truth: Path, camera: str):
    """A function frame -> {track id: visible share of its silhouette}, from the rebuilt world."""
    from seg2pose.synth.generate import DT, PRESETS
    from seg2pose.synth.noise import NoiseConfig
    from seg2pose.synth.render import FrameRenderer
    from seg2pose.synth.traffic import TrafficConfig, simulate
    from seg2pose.synth.world import build_world

    scene = load_scene(truth)
    g = scene.extra["generator"]
    n_frames = max(hi for _, hi in scene.splits.values()) + 1
    traffic = TrafficConfig(population=dict(g["traffic"]["population"]),
                            mean_pause_s=dict(g["traffic"]["mean_pause_s"]))
    assert g["preset"] in PRESETS and abs(g["dt"] - DT) < 1e-12
    world = build_world(simulate(traffic, n_frames, DT, g["seed"]), n_frames, g["seed"], ids=g["ids"])
    cams = list(scene.cameras)
    r = FrameRenderer(scene.cameras[camera], cams.index(camera), world, NoiseConfig(), g["seed"], "all")

    def vis(f: int) -> dict[int, float]:
        return {d.track_id: d.visible for d in r.visible(f)[1]}
    return vis


def breakdown(truth: Path, est: Path, camera: str, min_area: int = 150, small: int = 400) -> dict:
    moving = moving_flags(truth)
    vis = visibility(truth, camera)
    est_frames = {f: t for f, t in iter_mots(est)}
    first: Counter = Counter()
    flags: Counter = Counter()
    n = hit = 0
    n_small = miss_small = n_still = miss_still = 0
    by_cls: Counter = Counter()
    by_cls_miss: Counter = Counter()
    for f, tt in iter_mots(truth / "masks" / f"{camera}.txt"):
        h, w = tt.height, tt.width
        area = rle_stats(tt.rles, h, w)[0].astype(np.float64)
        big = area >= min_area
        ok = np.zeros(len(tt), bool)
        ee = est_frames.get(f)
        if ee is not None and len(ee):
            m = iou(tt.rles, ee.rles, h, w)
            r, c = linear_sum_assignment(-m)
            ok[r[m[r, c] >= 0.5]] = True
            eo = [{"size": [h, w], "counts": x} for x in ee.rles]
            # intersection areas from IoU: |A∩B| = iou (|A| + |B|) / (1 + iou)
            ea = mask_util.area(eo).astype(np.float64)
            inter = m * (area[:, None] + ea[None, :]) / (1.0 + m)
            cover = inter / np.maximum(area[:, None], 1)     # share of truth i inside est j
        else:
            cover = np.zeros((len(tt), 0))
            ea = np.zeros(0)
        v = None
        for i in np.flatnonzero(big):
            n += 1
            cls = int(tt.class_id[i])
            by_cls[cls] += 1
            is_small = area[i] < small
            n_small += int(is_small)
            n_still += int(not moving.get((f, int(tt.track_id[i])), False))
            if ok[i]:
                hit += 1
                continue
            by_cls_miss[cls] += 1
            miss_small += int(is_small)
            if v is None:
                v = vis(f)
            tid = int(tt.track_id[i])
            why = []
            if not moving.get((f, tid), False):
                miss_still += 1
            if cover.shape[1]:
                j = int(np.argmax(cover[i]))
                others = np.delete(cover[:, j], i)
                if cover[i, j] >= 0.3 and (others >= 0.3).any():
                    why.append("merged")
            if v.get(tid, 1.0) < 0.5:
                why.append("occluded")
            if cover.shape[1] and (cover[i] >= 0.1).sum() >= 2:
                why.append("fragmented")
            if cover.shape[1]:
                j = int(np.argmax(cover[i]))
                if cover[i, j] >= 0.5 and ea[j] > 1.5 * area[i]:
                    why.append("oversized")
            if cover.shape[1] == 0 or cover[i].sum() < 0.5:
                why.append("faint")
            why = why or ["other"]
            first[why[0]] += 1
            for k in why:
                flags[k] += 1
    miss = n - hit
    out = {"truth": n, "matched": hit, "recall": hit / max(n, 1), "missed": miss,
           "first_reason": {k: first[k] for k in REASONS},
           "any_reason": {k: flags[k] for k in REASONS},
           "still_truth": n_still, "still_missed": miss_still,
           "small_lt_px": small, "small_truth": n_small, "small_missed": miss_small,
           "recall_by_class": {k: 1 - by_cls_miss[k] / by_cls[k] for k in sorted(by_cls)},
           "truth_by_class": dict(sorted(by_cls.items()))}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("truth_scene", type=Path)
    ap.add_argument("est_mots", type=Path)
    ap.add_argument("--camera", default="c1")
    ap.add_argument("--min-area", type=int, default=150)
    a = ap.parse_args()
    res = breakdown(a.truth_scene, a.est_mots, a.camera, a.min_area)
    print(json.dumps(res, indent=1))
    m = max(res["missed"], 1)
    print(f"recall {res['recall']:.3f} ({res['matched']}/{res['truth']}); missed {res['missed']}:")
    for k in REASONS:
        print(f"  {k:11s} first {res['first_reason'][k]:5d} ({res['first_reason'][k] / m:5.1%})"
              f"   any {res['any_reason'][k]:5d} ({res['any_reason'][k] / m:5.1%})")
    print(f"  small (<{res['small_lt_px']} px): {res['small_missed']} of {res['small_truth']} missed")
    print(f"  standing still: {res['still_missed']} of {res['still_truth']} missed")


if __name__ == "__main__":
    main()
