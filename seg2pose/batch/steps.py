"""The library's steps of ``s2p batch`` (seg2pose/batch/study.py): masks-from-video (long videos in
segments, seg2pose/batch/segments.py), run and eval, each calling the function its single-scene
command calls. Export and review come from the command layer (seg2pose/cli/batch.py).

The command layer imports this module when ``s2p`` starts, so the steps' libraries (scipy,
pycocotools, torch through the scene, video, method and eval modules) are imported inside the
step functions, on first use: ``s2p --help`` does not wait for them."""

from __future__ import annotations

import json
from pathlib import Path

from seg2pose.batch.study import BATCH_DIR, BatchOptions, Step
from seg2pose.io.atomic import atomic_write_text


def run_dir(scene_dir: Path, opts: BatchOptions) -> Path:
    return scene_dir / BATCH_DIR / opts.run_name


def scene_inputs(scene_dir: Path) -> list[Path]:
    """The files of a scene that every step reads: scene.json, the ground points, the masks."""
    from seg2pose.io.scene import SCENE_FILE

    return [scene_dir / SCENE_FILE, scene_dir / "ground_points.csv", scene_dir / "masks"]


def _masks_run(scene_dir: Path, opts: BatchOptions, force: bool) -> dict:
    from seg2pose.batch.segments import scene_masks_segmented
    from seg2pose.video.video_scene import scene_masks_from_video

    if opts.segment_frames > 0:  # long videos in segments (their tasks ran first: skipped here)
        res = scene_masks_segmented(scene_dir, opts.segment_frames, force=force, log=lambda s: None)
        return {"frames": max((r["frames"] for r in res.values()), default=0),
                "masks": sum(r["masks"] for r in res.values()),
                "segments": sum(r["segments"] for r in res.values()),
                "seams": {c: r["seams"] for c, r in res.items() if r["seams"]},
                "seam_id_changes": sum(x["id_changes"] for r in res.values() for x in r["seams"]),
                "seam_unlinked": sum(x["unlinked"] for r in res.values() for x in r["seams"])}
    res = scene_masks_from_video(scene_dir, force=force, progress=False, log=lambda s: None)
    return {"frames": max((r.n_frames for r in res.values()), default=0),
            "masks": sum(r.n_masks for r in res.values())}


def _masks_parts(scene_dir: Path, opts: BatchOptions) -> list:
    from seg2pose.batch.segments import plan_scene
    from seg2pose.io.atomic import check_writable
    from seg2pose.io.scene import load_scene

    if opts.segment_frames <= 0:
        return []
    plans = plan_scene(scene_dir, opts.segment_frames)
    scene = load_scene(scene_dir)
    for c in plans:  # refused before the segments' work, not after it
        check_writable(scene.masks_path(c), opts.force)
    return [s for segs in plans.values() if len(segs) > 1 for s in segs]


def _masks_part(scene_dir: Path, part) -> dict:
    from seg2pose.batch.segments import run_segment

    return run_segment(scene_dir, part)


def _run_inputs(scene_dir: Path, opts: BatchOptions) -> list[Path]:
    models = [] if opts.baseline else [Path(m) for m in opts.models] or [scene_dir / "models"]
    return scene_inputs(scene_dir) + models


def _run_run(scene_dir: Path, opts: BatchOptions, force: bool) -> dict:
    from seg2pose.io.run import read_run_meta, read_run_poses
    from seg2pose.io.scene import load_scene
    from seg2pose.method.pipeline import RunOptions, run_scene

    d = run_scene(load_scene(scene_dir), run_dir(scene_dir, opts), RunOptions(baseline=opts.baseline,
                  models_dir=list(opts.models) or None, force=force, progress=False))
    meta = read_run_meta(d)
    poses = read_run_poses(d)
    return {"frames": int(meta["n_frames"]), "detections": int(meta["n_views"]),
            "poses": int(meta["n_poses"]), "road_users": int(len(set(poses.track_id.tolist())))}


def eval_path(scene_dir: Path, opts: BatchOptions) -> Path:
    return scene_dir / BATCH_DIR / f"{opts.run_name}.eval.json"


def _eval_run(scene_dir: Path, opts: BatchOptions, force: bool) -> dict:
    from seg2pose.eval.paper_table import evaluate_run
    from seg2pose.eval.tracking_inputs import WORLD_D0
    from seg2pose.io.scene import load_scene

    scene = load_scene(scene_dir)
    if not scene.gt_path.exists():  # nothing to evaluate: not a failure
        atomic_write_text(eval_path(scene_dir, opts), json.dumps(None))
        return {"ground_truth": False}
    # as s2p eval --json: the errors and the tracking metrics (HOTA, IDF1, MOTA) of the world tracks
    res = evaluate_run(scene, run_dir(scene_dir, opts), track_d0=WORLD_D0).to_dict()
    atomic_write_text(eval_path(scene_dir, opts), json.dumps(res, indent=1))
    return {"ground_truth": True, "mean_error": res["mean_error"], "recall": res["recall"],
            "HOTA": res["tracking"]["HOTA"], "IDF1": res["tracking"]["IDF1"], "MOTA": res["tracking"]["MOTA"]}


MASKS_FROM_VIDEO = Step("masks-from-video", lambda s, o: [s / "scene.json", s / "video"],
                        lambda s, o: [s / "masks"], _masks_run, owns_outputs=False,
                        parts=_masks_parts, run_part=_masks_part)
RUN = Step("run", _run_inputs, lambda s, o: [run_dir(s, o)], _run_run)
EVAL = Step("eval", lambda s, o: [s / "scene.json", s / "gt", run_dir(s, o)],
            lambda s, o: [eval_path(s, o)], _eval_run)
LIBRARY_STEPS = {s.name: s for s in (MASKS_FROM_VIDEO, RUN, EVAL)}
