"""Post-hoc variants of finished paper-table runs (issue 14), no retraining: smoothing of the
Seg2PoseNet residuals along each track (per camera), smoothing of the fused positions along
each track (for the baseline too, so that the comparison stays honest), and the ensemble of
the annotated and zero-annotation models (their residuals averaged per view).

Reads the views.csv files of ``s2p bench-accuracy`` folders (ROOT/bench-seed<N>/table-<variant>/
runs/<config>-<method>/) and re-fuses them exactly as ``s2p run`` does (seg2pose.method.fusion.fuse).

    PYTHONPATH=. .venv/bin/python benches/posthoc.py ROOT --seeds 0,1,2 [--configs mono-1,tri-I]
        [--windows 2,4,8,12] [--zero]

Prints, per configuration, each variant's mean error ratio to the raw baseline and to the
baseline smoothed the same way, mean (min-max) over the seeds, and per class.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from seg2pose.eval.evaluate import evaluate
from seg2pose.geometry.smoothing import smooth_along_tracks
from seg2pose.io.poses import read_poses
from seg2pose.io.run import ViewTable, read_views
from seg2pose.io.scene import load_scene
from seg2pose.method.fusion import fuse


def view_key(views: ViewTable) -> np.ndarray:
    """(N,) one track key per (camera, track id); -1 for untracked detections."""
    _, cam = np.unique(views.camera.astype(str), return_inverse=True)
    return np.where(views.track_id >= 0, cam.astype(np.int64) * 10**7 + views.track_id, -1)


def with_residual(views: ViewTable, residual: np.ndarray) -> ViewTable:
    return ViewTable(views.frame, views.track_id, views.camera, views.cls, views.uv,
                     views.normal, residual)


def smooth_residuals(views: ViewTable, half_window: int, degree: int = 0) -> ViewTable:
    return with_residual(views, smooth_along_tracks(view_key(views), views.frame, views.residual,
                                                    half_window, degree))


def run_errors(scene, gt, views: ViewTable, pos_window: int = 0, pos_degree: int = 1):
    """EvalResult of the fused views on the test split; fused positions smoothed along the
    track with ``pos_window`` (0: not)."""
    poses = fuse(views, scene)
    if pos_window:
        poses.xyz[:, :2] = smooth_along_tracks(poses.track_id, poses.frame, poses.xyz[:, :2],
                                               pos_window, pos_degree)
    return evaluate(poses, gt, scene.rig.center[:2], frame_range=scene.split_range("test"))


def seed_variants(root: Path, seed: int, configs: list[str], windows: list[int], zero: bool,
                  pos_windows: list[int]) -> dict:
    """config -> variant name -> EvalResult for one scene seed."""
    sd = root / f"bench-seed{seed}"
    scene = load_scene(sd)
    gt = read_poses(scene.gt_path, scene.class_names)
    out = {}
    for cfg in configs:
        base = read_views(sd / "table-s2pn" / "runs" / f"{cfg}-baseline" / "views.csv")
        s2pn = read_views(sd / "table-s2pn" / "runs" / f"{cfg}-s2pn" / "views.csv")
        r = {"baseline": run_errors(scene, gt, base), "s2pn": run_errors(scene, gt, s2pn)}
        for w in pos_windows:
            r[f"baseline pos{w}"] = run_errors(scene, gt, base, w)
            r[f"s2pn pos{w}"] = run_errors(scene, gt, s2pn, w)
        for w in windows:
            for deg in (0, 1):
                r[f"s2pn res{w}d{deg}"] = run_errors(scene, gt, smooth_residuals(s2pn, w, deg))
        if zero:
            z = read_views(sd / "table-zero" / "runs" / f"{cfg}-s2pn" / "views.csv")
            assert np.array_equal(z.frame, s2pn.frame) and np.array_equal(z.track_id, s2pn.track_id)
            r["zero"] = run_errors(scene, gt, z)
            ens = with_residual(s2pn, (s2pn.residual + z.residual) / 2)
            r["ens s2pn+zero"] = run_errors(scene, gt, ens)
            for w in windows:
                r[f"zero res{w}d0"] = run_errors(scene, gt, smooth_residuals(z, w))
        out[cfg] = r
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("root")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--configs", default="mono-1,tri-I")
    ap.add_argument("--windows", default="2,4,8,12,20")
    ap.add_argument("--pos-windows", default="2,4,8")
    ap.add_argument("--zero", action="store_true", help="also the zero-annotation table")
    a = ap.parse_args()
    seeds = [int(s) for s in a.seeds.split(",")]
    configs = a.configs.split(",")
    windows = [int(w) for w in a.windows.split(",") if w]
    pos_windows = [int(w) for w in a.pos_windows.split(",") if w]
    res = {s: seed_variants(Path(a.root), s, configs, windows, a.zero, pos_windows) for s in seeds}
    for cfg in configs:
        names = list(res[seeds[0]][cfg])
        classes = sorted(res[seeds[0]][cfg]["baseline"].per_class)
        print(f"\n{cfg}: ratio to the raw baseline, mean (min-max) over seeds {a.seeds}; per class")
        for n in names:
            rat = np.array([res[s][cfg][n].mean_error / res[s][cfg]["baseline"].mean_error
                            for s in seeds])

            def class_ratio(c: str, n: str = n) -> float:
                return float(np.mean([res[s][cfg][n].per_class[c] / res[s][cfg]["baseline"].per_class[c]
                                      for s in seeds]))

            pc = " ".join(f"{c[:4]} {class_ratio(c):.3f}" for c in classes)
            m = np.mean([res[s][cfg][n].mean_error for s in seeds])
            print(f"  {n:<22} {m:.4f} m  {rat.mean():.3f}x ({rat.min():.3f}-{rat.max():.3f})  {pc}")


if __name__ == "__main__":
    main()
