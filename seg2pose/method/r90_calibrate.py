"""``s2p calibrate``: fit the error bars (``seg2pose.method.uncertainty``) on a run whose truth
is known and write the calibration JSON where runs look for it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from seg2pose.core.digest import file_sha256
from seg2pose.core.errors import InputError
from seg2pose.io.atomic import atomic_write_text, check_writable
from seg2pose.io.poses import read_poses
from seg2pose.io.run import read_run, relative_path
from seg2pose.method.pipeline import ViewGroups, default_r90_path, fuse
from seg2pose.method.uncertainty import Calibration, fit_calibration, pose_features



def calibrate_run(scene, run_dir: str | Path, out: str | Path | None = None,
                  force: bool = False) -> tuple[Path, Calibration]:
    """Fit the error bars on a run (of the validation split, say) against the scene's truth
    and write the calibration JSON to ``out`` (default: where runs of that method look for it,
    ``seg2pose.method.pipeline.default_r90_path``). Returns its path and the calibration."""
    run = read_run(run_dir)
    if run.views is None or run.views.cues is None:
        raise InputError("this run's views.csv has no cut,far,spread_m columns (made by an older "
                         "s2p): run it again", file=Path(run_dir) / "views.csv")
    if not scene.gt_path.exists():
        raise InputError("the scene has no ground truth to calibrate on", file=scene.gt_path)
    meta = run.meta
    baseline = meta.get("method") == "baseline"
    if out is None:
        paths = [e.get("path") for e in (meta.get("models") or {}).values() if isinstance(e, dict)]
        dirs = [Path(run_dir) / (p[0] if isinstance(p, list) else p) for p in paths if p]
        out = default_r90_path(scene, [d.parent for d in dirs][:1] or None, baseline)
    out = Path(out)
    check_writable(out, force)
    smooth = int(meta.get("smooth_frames") or 0)
    views = run.views
    gt = read_poses(scene.gt_path)
    poses = fuse(views, scene, smooth)  # the run's poses (sorted), recomputed from its views
    g = ViewGroups.of(views)
    order = np.lexsort((g.track_id, g.keys[:, 0]))  # PoseTable.sorted()'s order
    est_stack = g.stack((views.normal[:, :2] + views.residual)[g.keep])

    def pose_X(r_view: np.ndarray) -> np.ndarray:
        return pose_features(est_stack[:, order], g.stack(r_view[g.keep])[:, order])

    cal, cov = fit_calibration(
        scene, views, np.column_stack([poses.frame, poses.track_id]), poses.xyz[:, :2], poses.cls,
        pose_X, gt, {"method": meta.get("method"), "smooth_frames": smooth,
                     "fitted_on": {"run": relative_path(run_dir, out.parent),
                                   "split": meta.get("split"),
                                   "scene_fingerprint": meta.get("scene_fingerprint"),
                                   "poses_sha256": file_sha256(Path(run_dir) / "poses.csv")}})
    atomic_write_text(out, cal.to_json())
    return out, cal
