"""Which interpolant reproduces the truth best? Keyframes every N frames taken from a synthetic
scene's ground truth (gt/poses.csv), interpolated per class with each method, compared with the
truth on the frames between the keyframes.

    PYTHONPATH=. python benches/annotate_interp.py --tune 0 1 --report 4 5 [--work DIR]

Scenes: ``s2p synth --seed S --ids visit --no-detector-noise`` (small preset, 3 x 240 frames), generated
into --work once. One visit = one track; keyframes at its first frame, every N frames, and its
last frame (a track exists from its first to its last keyframe). Errors: mean ground-plane
distance (cm) and mean absolute heading error (degrees) over the interpolated frames; "smooth"
counts only keyframe intervals where the true acceleration stays below 4 m/s^2 (pedestrians
stop dead and turn on the spot at path corners: those intervals are not smooth; their smooth
intervals are straight walks at constant speed, which every interpolant gets right). The
default per class is chosen on the --tune seeds at spacing 25 (error over all interpolated
frames) and reported on the --report seeds with the spread over them.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from annotate.interpolate import METHODS, interpolate, wrap_angle  # noqa: E402
from seg2pose.io.poses import read_poses  # noqa: E402

SPACINGS = (5, 10, 25, 50, 100)
CLASSES = ("car", "bicyclist", "pedestrian")
SMOOTH_ACC = 4.0  # m/s^2


def scene_for(seed: int, work: Path) -> Path:
    out = work / f"interp-seed{seed}"
    if not (out / "gt" / "poses.csv").exists():
        from seg2pose.synth.generate import SynthOptions, generate_scene
        from seg2pose.synth.noise import NoiseConfig
        generate_scene(out, SynthOptions(seed=seed, ids="visit", noise=NoiseConfig.off(), progress=False,
                       workers=1, force=True))
    return out


def track_errors(frames, xy, heading, fps, spacing, method):
    """Errors (M,) cm, heading errors (M,) degrees and smooth flags (M,) on the frames between
    keyframes of one contiguous track."""
    kidx = np.unique(np.r_[np.arange(0, len(frames), spacing), len(frames) - 1])
    kf = frames[kidx]
    between = np.setdiff1d(np.arange(len(frames)), kidx)
    if not len(between):
        return np.zeros(0), np.zeros(0), np.zeros(0, bool)
    q = frames[between]
    pxy, ph = interpolate(kf, xy[kidx], heading[kidx], q, method)
    err = 100 * np.linalg.norm(pxy - xy[between], axis=1)
    herr = np.degrees(np.abs(wrap_angle(ph - heading[between])))
    # true acceleration per frame (second differences), worst per keyframe interval
    acc = np.zeros(len(frames))
    if len(frames) >= 3:
        acc[1:-1] = np.linalg.norm(xy[2:] - 2 * xy[1:-1] + xy[:-2], axis=1) * fps * fps
    interval = np.searchsorted(kidx, between, side="right") - 1
    worst = np.maximum.reduceat(acc, kidx[:-1]) if len(kidx) > 1 else np.zeros(1)
    # reduceat covers kidx[i]..kidx[i+1]-1; include the closing keyframe too
    worst = np.maximum(worst, acc[kidx[1:]])
    return err, herr, worst[interval] <= SMOOTH_ACC


def evaluate(scene: Path, fps: float):
    gt = read_poses(scene / "gt" / "poses.csv")
    order = np.lexsort((gt.frame, gt.track_id))
    gt = gt.take(order)
    out = {}  # (cls, spacing, method) -> (errors, heading errors, smooth)
    starts = np.flatnonzero(np.r_[True, (gt.track_id[1:] != gt.track_id[:-1])
                                  | (np.diff(gt.frame) != 1)])
    ends = np.r_[starts[1:], len(gt)]
    for a, b in zip(starts, ends):
        if b - a < 3:
            continue
        cls = str(gt.cls[a])
        f, xy, h = gt.frame[a:b], gt.xyz[a:b, :2], gt.heading[a:b]
        for n in SPACINGS:
            for m in METHODS:
                e, he, sm = track_errors(f, xy, h, fps, n, m)
                acc = out.setdefault((cls, n, m), ([], [], []))
                acc[0].append(e)
                acc[1].append(he)
                acc[2].append(sm)
    return {k: tuple(np.concatenate(v) for v in vals) for k, vals in out.items()}


def summary(results: list[dict], cls: str, n: int, m: str, smooth: bool, col: int = 0):
    """Mean over frames per seed -> (mean over seeds, min, max)."""
    per_seed = []
    for r in results:
        e, he, sm = r[(cls, n, m)]
        v = (e, he)[col]
        v = v[sm] if smooth else v
        per_seed.append(float(v.mean()) if len(v) else float("nan"))
    a = np.array(per_seed)
    return float(np.mean(a)), float(np.min(a)), float(np.max(a))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tune", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--report", type=int, nargs="+", default=[4, 5])
    ap.add_argument("--work", type=Path, default=Path("/tmp/s2p-annotate-interp"))
    args = ap.parse_args()
    t0 = time.perf_counter()
    res = {}
    for s in args.tune + args.report:
        path = scene_for(s, args.work)
        from seg2pose.io.scene import load_scene
        res[s] = evaluate(path, load_scene(path).fps)
    tune = [res[s] for s in args.tune]
    report = [res[s] for s in args.report]
    best = {c: min(METHODS, key=lambda m: summary(tune, c, 25, m, False)[0]) for c in CLASSES}
    print(f"chosen on seeds {args.tune} (spacing 25, all interpolated frames): {best}")
    print(f"\nreport seeds {args.report}: mean position error, cm (smooth intervals / all "
          "frames), mean over seeds [min-max]; heading error, degrees (all frames)\n")
    print("| class | spacing | " + " | ".join(METHODS) + " | heading " + " / ".join(METHODS) + " |")
    print("|---|---|" + "---|" * (len(METHODS) + 1))
    for c in CLASSES:
        for n in SPACINGS:
            cells = []
            for m in METHODS:
                sm = summary(report, c, n, m, True)
                al = summary(report, c, n, m, False)
                mark = "**" if m == best[c] else ""
                cells.append(f"{mark}{sm[0]:.1f}{mark} [{sm[1]:.1f}-{sm[2]:.1f}] / {al[0]:.1f}")
            hd = " / ".join(f"{summary(report, c, n, m, False, 1)[0]:.1f}" for m in METHODS)
            print(f"| {c} | {n} | " + " | ".join(cells) + f" | {hd} |")
    share = {c: float(np.mean(np.concatenate([r[(c, 25, "linear")][2] for r in report])))
             for c in CLASSES}
    print("\nshare of interpolated frames in smooth intervals at spacing 25: "
          + ", ".join(f"{c} {100 * v:.0f} %" for c, v in share.items()))
    print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
