"""Where the remaining error of a paper-table run comes from (the issue-14 error budget),
measured from the run folders: per configuration and method, the mean error, its radial part
(along the line from the rig, where heights and occlusion act) and tangential part, the share
of the total error in the worst 10 % of poses (occlusion, merges, truncation), and the share of
the mean squared error that is a constant offset per road user (individual size and shape: no
smoothing along the track can remove it), and the share that is frame-to-frame noise (what a
centred mean over +-4 frames of the road user's errors removes: the most smoothing can gain).

    .venv/bin/python benches/error_budget.py SCENE TABLE [TABLE ...] [--configs mono-1,tri-I]
        [--smooth N] [--class pedestrian]

``--smooth N``: the runs' views fused again with positions smoothed along the tracks
(``s2p paper-table --smooth N``).

TABLE: an ``s2p paper-table`` output folder (its runs/<config>-<method>/ are read).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from seg2pose.eval.evaluate import match_poses
from seg2pose.geometry.smoothing import smooth_along_tracks
from seg2pose.io.poses import read_poses
from seg2pose.io.scene import load_scene

NOISE_WINDOW = 4  # frames either side


def budget(scene, run_dir: Path, smooth: int = 0, cls: str | None = None) -> dict:
    """Error terms of one run on the scene's test split (metres; shares in [0, 1])."""
    gt = read_poses(scene.gt_path)
    if smooth:
        from seg2pose.io.run import read_views
        from seg2pose.method.fusion import fuse

        est = fuse(read_views(run_dir / "views.csv"), scene, smooth)
    else:
        est = read_poses(run_dir / "poses.csv")
    lo, hi = scene.split_range("test")
    keep = (gt.frame >= lo) & (gt.frame <= hi) & ((gt.cls == cls) if cls else True)
    ie, ig = match_poses(est, gt)
    ok = keep[ig]
    ie, ig = ie[ok], ig[ok]
    e = est.xyz[ie, :2] - gt.xyz[ig, :2]                       # (K, 2) error vectors
    u = gt.xyz[ig, :2] - scene.rig.center[:2]
    u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-9)
    radial = np.abs((e * u).sum(1))
    tangential = np.abs(e[:, 0] * u[:, 1] - e[:, 1] * u[:, 0])
    d = np.linalg.norm(e, axis=1)
    worst = np.sort(d)[::-1][:max(1, len(d) // 10)]
    tracks = gt.track_id[ig]
    _, inv = np.unique(tracks, return_inverse=True)
    mean_per_track = np.stack([np.bincount(inv, e[:, k]) / np.bincount(inv) for k in range(2)], 1)
    bias_share = float((mean_per_track[inv] ** 2).sum() / max((e ** 2).sum(), 1e-12))
    # frame-to-frame noise: the part of each error vector that a centred mean over +-4 frames
    # of the same road user's errors removes (what smoothing along the track could reach)
    slow = smooth_along_tracks(tracks, gt.frame[ig], e, NOISE_WINDOW)
    noise_share = float(((e - slow) ** 2).sum() / max((e ** 2).sum(), 1e-12))
    return {"n": len(d), "mean": float(d.mean()), "radial": float(radial.mean()),
            "tangential": float(tangential.mean()), "worst10_share": float(worst.sum() / d.sum()),
            "per_user_bias_share": bias_share, "noise_share": noise_share}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene")
    ap.add_argument("tables", nargs="+")
    ap.add_argument("--configs", default="mono-1,tri-I")
    ap.add_argument("--smooth", type=int, default=0)
    ap.add_argument("--class", dest="cls", default=None, help="only this class's poses")
    a = ap.parse_args()
    scene = load_scene(a.scene)
    print(f"{'table':<14} {'run':<18} {'poses':>6} {'mean m':>7} {'radial':>7} {'tangential':>10} "
          f"{'worst 10 % share':>17} {'per-user offset share of MSE':>29} {'frame-noise share of MSE':>25}")
    for t in a.tables:
        for cfg in a.configs.split(","):
            for method in ("baseline", "s2pn"):
                rd = Path(t) / "runs" / f"{cfg}-{method}"
                if not (rd / "poses.csv").exists():
                    continue
                b = budget(scene, rd, a.smooth, a.cls)
                print(f"{Path(t).name:<14} {cfg + '-' + method:<18} {b['n']:>6} {b['mean']:>7.3f} "
                      f"{b['radial']:>7.3f} {b['tangential']:>10.3f} {b['worst10_share']:>17.2f} "
                      f"{b['per_user_bias_share']:>29.2f} {b['noise_share']:>25.2f}")


if __name__ == "__main__":
    main()
