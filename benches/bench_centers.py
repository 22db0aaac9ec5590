"""Which mask centre should the normal position start from? Paper 3.2 says the mask's centre
point (here: the centroid of its pixels), section 5 the centre of its bounding box.

For each centre method this script tunes the per-class default heights by bisection on the
train split (paper 3.2, as ``s2p heights`` does), then measures the baseline normal-position
error (ground plane, per view, before fusion) on the test split of synthetic scenes with known
truth, with and without detector noise:

    .venv/bin/python benches/bench_centers.py [--frames 600] [--seeds 1 2] [--workdir /tmp/s2p-centers]
        [--kinds noise exact] [--fused mono-1 stereo-40 tri-T]

Prints one table per scene and a summary; docs/NORMAL_POSITIONS.md records the outcome.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from seg2pose.geometry.normal import CENTER_METHODS, default_height_bisection, normal_positions
from seg2pose.io.mots import iter_mots
from seg2pose.io.poses import read_poses
from seg2pose.io.scene import load_scene
from seg2pose.method.heights import collect_height_views, subsample_views
from seg2pose.method.matching import match_masks_to_truth
from seg2pose.structures.masks import mask_centers


def tuned_heights(scene, center: str) -> dict[str, float]:
    views = collect_height_views(scene, "train", center)
    out = {c.name: c.default_height for c in scene.classes}
    for name, v in views.items():
        out[name] = default_height_bisection(subsample_views(v, 20000), scene.ground)
    return out


def test_errors(scene, center: str, heights: dict[str, float]) -> dict[str, np.ndarray]:
    """Per class, the ground-plane errors (metres) of all test-split normal positions."""
    fr = scene.split_range("test")
    names = {c.id: c.name for c in scene.classes}
    gt = read_poses(scene.gt_path).in_frames(fr)
    errs: dict[str, list] = {}
    for cam in scene.cameras.values():
        for _, t in iter_mots(scene.masks_path(cam.name), names.keys(), fr):
            idx = match_masks_to_truth(cam, t, gt, names, heights)
            ok = np.flatnonzero(idx >= 0)
            if not len(ok):
                continue
            g = idx[ok]
            cen = mask_centers([t.rles[i] for i in ok], t.height, t.width, center)
            h = np.array([heights[str(c)] for c in gt.cls[g]])
            X, _ = normal_positions(cam, scene.ground, cen, h)
            e = np.linalg.norm(X[:, :2] - gt.xyz[g, :2], axis=1)
            for c in np.unique(gt.cls[g]):
                errs.setdefault(str(c), []).append(e[gt.cls[g] == c])
    return {k: np.concatenate(v) for k, v in errs.items()}


def fused_errors(scene, center: str, heights: dict[str, float], configs: list[str],
                 workdir: Path) -> dict[str, float]:
    """Mean error of the fused baseline (``s2p run --baseline``) per configuration, test split."""
    from seg2pose.eval.evaluate import evaluate
    from seg2pose.method.pipeline import RunOptions, run_scene

    for c in scene.classes:
        c.default_height = heights[c.name]
    gt = read_poses(scene.gt_path)
    out = {}
    for cfg in configs:
        run = workdir / f"run-{scene.root.name}-{center}-{cfg}"
        run_scene(scene, run, RunOptions(config=cfg, baseline=True, split="test", force=True,
                  center_method=center, progress=False))
        est = read_poses(run / "poses.csv")
        out[cfg] = evaluate(est, gt, scene.rig.center[:2], frame_range=scene.split_range("test")).mean_error
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=600, help="frames per split")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/s2p-centers"))
    ap.add_argument("--fused", nargs="*", default=["mono-1", "stereo-40", "tri-T"],
                    help="configurations for the fused baseline (s2p run --baseline)")
    ap.add_argument("--kinds", nargs="+", default=["noise", "exact"])
    args = ap.parse_args()
    from seg2pose.synth.generate import SynthOptions, generate_scene
    from seg2pose.synth.noise import NoiseConfig

    summary = {m: {"noise": [], "exact": []} for m in CENTER_METHODS}
    for seed in args.seeds:
        for kind in args.kinds:
            path = args.workdir / f"{kind}-{seed}-{args.frames}"
            if not (path / "scene.json").exists():
                t0 = time.perf_counter()
                generate_scene(path, SynthOptions(preset="small", frames=args.frames, seed=seed, force=True,
                               noise=None if kind == "noise" else NoiseConfig.off(), progress=False))
                print(f"generated {path} in {time.perf_counter() - t0:.0f} s")
            scene = load_scene(path)
            print(f"\n{path.name}: {len(scene.cameras)} cameras, test frames {scene.split_range('test')}")
            print(f"{'centre':>9} {'class':>11} {'height m':>9} {'n':>7} {'mean m':>8} {'median m':>9}")
            for m in CENTER_METHODS:
                hs = tuned_heights(scene, m)
                errs = test_errors(scene, m, hs)
                for c, e in sorted(errs.items()):
                    print(f"{m:>9} {c:>11} {hs[c]:>9.3f} {len(e):>7} {e.mean():>8.4f} {np.median(e):>9.4f}")
                allv = np.concatenate(list(errs.values()))
                print(f"{m:>9} {'all':>11} {'':>9} {len(allv):>7} {allv.mean():>8.4f} {np.median(allv):>9.4f}")
                summary[m][kind].append(allv.mean())
                if args.fused:
                    fe = fused_errors(scene, m, hs, args.fused, args.workdir)
                    print(f"{m:>9} fused baseline mean m: "
                          + "  ".join(f"{k} {v:.4f}" for k, v in fe.items()))
    print("\nmean normal-position error over all test detections (m), per scene:")
    for m in CENTER_METHODS:
        print(f"  {m:>9}: detector noise {np.round(summary[m]['noise'], 4).tolist()}  "
              f"exact silhouettes {np.round(summary[m]['exact'], 4).tolist()}")


if __name__ == "__main__":
    main()
