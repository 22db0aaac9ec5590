"""Evaluating run folders: ``s2p eval`` (one run against the truth) and ``s2p paper-table``
(Table 1 / Figure 6 of the paper on a scene: every configuration with and without Seg2PoseNet,
computed from each camera's views once and fused per configuration)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from seg2pose.core.errors import InputError, S2PError
from seg2pose.eval.evaluate import evaluate, format_table, plot_error_vs_distance
from seg2pose.eval.tracking_inputs import in_view, sequence_from_poses
from seg2pose.eval.tracking_metrics import summary
from seg2pose.io.atomic import atomic_write_text
from seg2pose.io.nofollow import refuse_linked_folder
from seg2pose.io.poses import read_poses
from seg2pose.io.run import read_run_meta, read_run_poses, read_views
from seg2pose.io.scene import Scene
from seg2pose.method.checkpoint import load_models, model_dirs
from seg2pose.method.fusion import fuse
from seg2pose.method.pipeline import RunOptions, compute_views, write_run


def evaluate_run(scene: Scene, run_dir: str | Path, split: str | None = None,
                 match: str = "ids", gate: float = 3.0, track_d0: float | None = None):
    """EvalResult of RUN/poses.csv against SCENE/gt/poses.csv; distances from the rig centre
    (mean of all camera centres); ``split`` restricts both to that split's frames; ``match``,
    ``gate``: see ``evaluate.evaluate`` (``nearest`` for a tracker's ids); ``track_d0``: also
    the tracking metrics (HOTA, IDF1, MOTA) with similarity 1 - d / track_d0 metres
    (``tracking_inputs.sequence_from_poses``) against the truth in view of the run's cameras
    (``tracking_inputs.in_view``)."""
    if not scene.gt_path.exists():
        raise InputError("no ground truth to evaluate against", file=scene.gt_path)
    run_dir = Path(run_dir)
    meta = check_run_of_scene(run_dir, scene)
    classes = [c.name for c in scene.classes]
    est = read_run_poses(run_dir, known_classes=classes)
    gt = read_poses(scene.gt_path, known_classes=classes)
    res = evaluate(est, gt, scene.rig.center[:2], frame_range=scene.split_range(split),
                   match=match, gate=gate)
    if track_d0 is not None:
        fr = scene.split_range(split)
        cams = [scene.cameras[c] for c in meta.get("cameras") or scene.cameras if c in scene.cameras]
        seen = in_view(gt.in_frames(fr), cams)
        res.tracking = {"similarity": f"max(0, 1 - d / {track_d0:g} m)", "match_within_m": track_d0 / 2,
                        "truth": f"{len(seen.frame)} rows in view of {', '.join(c.name for c in cams)}",
                        **summary(sequence_from_poses(est.in_frames(fr), seen, track_d0))}
    views_path = run_dir / "views.csv"
    if res.match == "nearest" and views_path.exists():  # video input: ids of trackers
        from seg2pose.eval.evaluate import id_consistency
        from seg2pose.io.run import read_views

        v = read_views(views_path)
        fr = scene.split_range(split)
        keep = np.ones(len(v.frame), bool) if fr is None else (v.frame >= fr[0]) & (v.frame <= fr[1])
        if len(np.unique(v.camera[keep])) > 1:
            xy = v.normal[:, :2] + v.residual
            res.id_consistency, res.n_multi_view = id_consistency(
                v.frame[keep], v.camera[keep], v.track_id[keep], xy[keep], gt, gate)
    return res


def check_run_of_scene(run_dir: Path, scene: Scene) -> dict:
    """run.json of a finished run of ``scene``: refuses a folder without run.json or
    poses.csv (an interrupted or foreign folder) and a run of another scene (by the scene
    fingerprint: calibration and ground points). Returns run.json's content."""
    meta_path = run_dir / "run.json"
    if not run_dir.is_dir():
        raise InputError("run folder not found", file=run_dir)
    if not meta_path.exists():
        raise InputError("not a finished run: run.json is missing (was `s2p run` interrupted?)",
                         file=meta_path)
    meta = read_run_meta(run_dir)
    if not (run_dir / "poses.csv").exists():
        raise InputError("not a finished run: poses.csv is missing", file=run_dir / "poses.csv")
    fp = meta.get("scene_fingerprint")
    if fp != scene.fingerprint():
        raise InputError(f"this run was made on another scene (fingerprint {fp!r}; {scene.root} "
                         f"has {scene.fingerprint()!r}): its poses cannot be compared with this "
                         "scene's truth", file=meta_path, field="scene_fingerprint")
    return meta


PAPER_CONFIG_ORDER = ["mono-1", "mono-2", "mono-3", "stereo-30", "stereo-40", "stereo-10",
                      "tri-I", "tri-L", "tri-T"]


def paper_table(scene: Scene, models_dir: str | Path | list[Path] | None = None,
                split: str = "test", out_dir: str | Path | None = None,
                configs: list[str] | None = None, baseline_only: bool = False,
                force: bool = False, progress: bool = True, smooth: int = 0) -> tuple[Path, str]:
    """Table 1 / Figure 6 on this scene: every configuration with and without Seg2PoseNet.
    ``smooth``: every run's fused positions (the baseline's too) smoothed along each track over
    this many frames either side (``fusion.fuse``).

    Writes OUT/runs/<config>-<method>/ (run folders), OUT/table.txt, OUT/results.json and
    OUT/error_vs_distance.png (OUT defaults to SCENE/out/paper-table). Returns (OUT, table)."""
    out = Path(out_dir) if out_dir else scene.root / "out" / "paper-table"
    refuse_linked_folder(out, root=None if out_dir else scene.root)  # SCENE/out linked: refused first
    if (out / "results.json").exists() and not force:
        raise S2PError(f"{out} holds a paper table already; pass --force to redo it")
    if configs is None:
        configs = [c for c in PAPER_CONFIG_ORDER if c in scene.rig.configs]
        configs += [c for c in scene.rig.configs if c not in configs]
    if not configs:
        raise InputError("the scene defines no camera configurations", file=scene.root / "scene.json",
                         field="configs")
    results = {}
    # a view's estimate does not depend on the configuration it is fused in: compute every
    # camera's views once per method, then fuse per configuration
    all_cams = [c for c in scene.cameras if any(c in scene.rig.configs[k] for k in configs)]
    for baseline in ([False, True] if not baseline_only else [True]):
        models = None if baseline else load_models(scene, all_cams, models_dir)
        views, nframes = compute_views(scene, all_cams, scene.split_range(split), models,
                                       progress=progress)
        for cfg in configs:
            name = f"{cfg} {'baseline' if baseline else 'S2PN'}"
            rd = out / "runs" / f"{cfg}-{'baseline' if baseline else 's2pn'}"
            cams = scene.rig.configs[cfg]
            write_run(scene, rd, views.of_cameras(cams), cams, models, nframes,
                      RunOptions(config=cfg, split=split, force=True, smooth=smooth))
            results[name] = evaluate_run(scene, rd, split=split)
    text = format_table(results)
    s2pn = [r.mean_error for k, r in results.items() if k.endswith("S2PN")]
    base = [r.mean_error for k, r in results.items() if k.endswith("baseline")]
    if s2pn and base:
        ratios = {k.split()[0]: results[k].mean_error / results[k.split()[0] + " baseline"].mean_error
                  for k in results if k.endswith("S2PN")}
        text += "\nS2PN / baseline mean error: " + ", ".join(f"{k} {v:.3f}" for k, v in ratios.items()) + "\n"
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "table.txt", text)
    atomic_write_text(out / "results.json", json.dumps(
        {"scene": str(scene.root), "split": split, "smooth_frames": int(smooth),
         "models": None if baseline_only else (
             [str(d) for d in dirs] if len(dirs := model_dirs(scene, models_dir)) > 1 else str(dirs[0])),
         "results": {k: r.to_dict() for k, r in results.items()}}, indent=1) + "\n")
    plot_error_vs_distance(results, out / "error_vs_distance.png",
                           title=f"{scene.name}: mean error by distance ({split} split)")
    return out, text


def refuse_table(scene: Scene, table_dir: str | Path, smooth: int) -> dict:
    """The runs of a finished paper table fused again from their views.csv with ``smooth``
    (see ``fusion.fuse``; no network run) and evaluated on the table's split:
    {"<config> baseline" | "<config> S2PN": EvalResult}, as ``paper_table`` names them."""
    table_dir = Path(table_dir)
    try:
        split = json.loads((table_dir / "results.json").read_text())["split"]
    except (OSError, ValueError, KeyError) as e:
        raise InputError(f"not a finished paper table ({e})", file=table_dir / "results.json") from None
    gt = read_poses(scene.gt_path, known_classes=scene.class_names)
    out = {}
    for rd in sorted(p for p in (table_dir / "runs").iterdir() if (p / "views.csv").exists()):
        cfg, method = rd.name.rsplit("-", 1)
        poses = fuse(read_views(rd / "views.csv"), scene, smooth)
        out[f"{cfg} {'baseline' if method == 'baseline' else 'S2PN'}"] = evaluate(
            poses, gt, scene.rig.center[:2], frame_range=scene.split_range(split))
    return out
