"""``s2p calibrate-errors``: fit the error bars (``seg2pose.method.uncertainty``) on a run whose truth
is known and write the calibration JSON where runs look for it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from seg2pose.core.digest import file_sha256
from seg2pose.core.errors import InputError
from seg2pose.io.atomic import atomic_write_text, check_writable, holding
from seg2pose.io.poses import read_poses
from seg2pose.io.run import read_run, relative_path
from seg2pose.io.scene import load_scene
from seg2pose.method.fusion import ViewGroups, fuse
from seg2pose.method.pipeline import default_r90_path
from seg2pose.method.r90_features import pose_features
from seg2pose.method.uncertainty import Calibration, FitRun, fit_calibration


def scene_of_run(scene, run_dir: Path, meta: dict):
    """The scene a run was made on: the scene its run.json names when that is another folder
    (several recordings of one site share the calibration and so the fingerprint, not the
    truth), else ``scene``; either must have the fingerprint the run recorded (runs of several
    scenes, e.g. several sites, seeds or days, can be calibrated together, each against its
    own truth)."""
    fp = meta.get("scene_fingerprint")
    named = meta.get("scene")
    if isinstance(named, str) and (Path(run_dir) / named / "scene.json").is_file() \
            and (Path(run_dir) / named).resolve() != Path(scene.root).resolve():
        other = load_scene(Path(run_dir) / named)
        if fp is None or other.fingerprint() == fp:
            return other
    if fp is None or fp == scene.fingerprint():
        return scene
    raise InputError(f"this run was made on another scene (fingerprint {fp!r}; {scene.root} "
                     f"has {scene.fingerprint()!r}) and the scene its run.json names is not "
                     "found with that fingerprint", file=Path(run_dir) / "run.json",
                     field="scene_fingerprint")


def fit_run(scene, run_dir: str | Path) -> tuple[FitRun, dict]:
    """A run (with cues) and its scene's truth as the fit needs them, and the run's run.json
    (``scene``: the scene given; a run of another scene is read against the scene its run.json
    names, ``scene_of_run``)."""
    run = read_run(run_dir)
    if run.views is not None and len(run.views) == 0:  # not "an older s2p": nothing was seen
        raise InputError("this run has no views (no camera saw a road user in its frames): "
                         "nothing to calibrate the error bars on", file=Path(run_dir) / "views.csv")
    if run.views is None or run.views.cues is None:
        raise InputError("this run's views.csv has no cut,far,spread_m columns (made by an older "
                         "s2p): run it again", file=Path(run_dir) / "views.csv")
    if run.views.box is None:
        raise InputError("this run's views.csv has no box_x0,box_y0,box_x1,box_y1 columns (made "
                         "by an older s2p; the error bars' size cue needs them): run it again",
                         file=Path(run_dir) / "views.csv")
    scene = scene_of_run(scene, Path(run_dir), run.meta)
    if not scene.gt_path.exists():
        raise InputError("the scene has no ground truth to calibrate on", file=scene.gt_path)
    smooth = int(run.meta.get("smooth_frames") or 0)
    views = run.views
    poses = fuse(views, scene, smooth)  # the run's poses (sorted), recomputed from its views
    g = ViewGroups.of(views)
    order = np.lexsort((g.track_id, g.keys[:, 0]))  # PoseTable.sorted()'s order
    est_stack = g.stack((views.normal[:, :2] + views.residual)[g.keep])

    def pose_X(r_view: np.ndarray) -> np.ndarray:
        return pose_features(est_stack[:, order], g.stack(r_view[g.keep])[:, order])

    return FitRun(scene, views, np.column_stack([poses.frame, poses.track_id]), poses.xyz[:, :2],
                  poses.cls, pose_X, read_poses(scene.gt_path)), run.meta


def calibrate_run(scene, run_dir: str | Path | list, out: str | Path | None = None,
                  force: bool = False) -> tuple[Path, Calibration]:
    """Fit the error bars on one run or several (of the validation split, say, or its train
    and val splits: more road users give steadier bars) against the scene's truth and write
    the calibration JSON to ``out`` (default: where runs of that method look for it,
    ``seg2pose.method.pipeline.default_r90_path``). The runs must share the method and
    ``--smooth`` (and, within one scene, the models; runs of other scenes may use their own
    scene's models). Returns its path and the calibration."""
    run_dirs = [Path(r) for r in (run_dir if isinstance(run_dir, (list, tuple)) else [run_dir])]
    fits, metas = zip(*(fit_run(scene, r) for r in run_dirs))
    meta = metas[0]
    first_root = Path(fits[0].scene.root).resolve()
    for r, m, f in zip(run_dirs[1:], metas[1:], fits[1:]):
        # each scene may have its own Seg2PoseNet models (trained on that scene): pooling several
        # scenes' val splits gives the bars more road users; within one scene the models must agree
        same_scene = Path(f.scene.root).resolve() == first_root
        for key in ("method", "smooth_frames") + (("models",) if same_scene else ()):
            if m.get(key) != meta.get(key):
                raise InputError(f"this run's {key} ({m.get(key)!r}) differs from the first run's "
                                 f"({meta.get(key)!r}): calibrate runs of one method"
                                 + (" and, within one scene, one set of models"
                                    if key == "models" else ""),
                                 file=r / "run.json", field=key)
    baseline = meta.get("method") == "baseline"
    if out is None:
        paths = [e.get("path") for e in (meta.get("models") or {}).values() if isinstance(e, dict)]
        dirs = [run_dirs[0] / (p[0] if isinstance(p, list) else p) for p in paths if p]
        out = default_r90_path(scene, [d.parent for d in dirs][:1] or None, baseline)
    out = Path(out)
    with holding(out):  # from the start of the fit: a second calibration into it is refused
        return _fit_and_write(out, force, meta, run_dirs, metas, fits)


def _fit_and_write(out: Path, force: bool, meta: dict, run_dirs: list[Path], metas, fits
                   ) -> tuple[Path, Calibration]:
    check_writable(out, force)
    smooth = int(meta.get("smooth_frames") or 0)
    fitted_on = [{"run": relative_path(r, out.parent), "split": m.get("split"),
                  "scene_fingerprint": m.get("scene_fingerprint"),
                  "poses_sha256": file_sha256(r / "poses.csv")} for r, m in zip(run_dirs, metas)]
    cal, _ = fit_calibration(list(fits), {"method": meta.get("method"), "smooth_frames": smooth,
                                          "fitted_on": fitted_on})
    atomic_write_text(out, cal.to_json())
    return out, cal
