"""How good are the self-training's pseudo poses (seg2pose.training.self_training)? Their error
against the ground truth of the train split, per flavour and class: the rough-only models'
views as they are ("raw", each lens), "track" (each lens smoothed along its tracks) and
"views" (per-track heights, fused over the lenses, smoothed). The truth is read here only to
measure; the pseudo poses never see it. Also "fused" (over the lenses at the default heights).

    PYTHONPATH=. .venv/bin/python benches/pseudo_label_error.py SCENE ROUGH_MODELS [--smooth 4]

ROUGH_MODELS: a folder of finished rough-only (zero-annotation) models; their run on the train
split is written to (or reused from) ROUGH_MODELS/train-run.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from seg2pose.io.poses import read_poses
from seg2pose.io.scene import load_scene
from seg2pose.training.self_training import PseudoLabels, pseudo_poses, rough_stage_views


def errors(scene, labels: PseudoLabels) -> dict[str, tuple[float, float, int]]:
    """Per class (and "all"): (mean error m, mean |radial error| m, views); the truth is
    matched by frame and track id (synthetic scenes keep the truth's ids)."""
    gt = read_poses(scene.gt_path, scene.class_names)
    truth = PseudoLabels(np.zeros(len(gt), object), gt.frame, gt.track_id, gt.xyz[:, :2])
    out = {}
    t = np.full((len(labels), 2), np.nan)
    cls = np.zeros(len(labels), object)
    tcls = dict(zip(zip(gt.frame.tolist(), gt.track_id.tolist()), gt.cls))
    for cam in np.unique(labels.camera):
        i = np.flatnonzero(labels.camera == cam)
        truth.camera[:] = cam
        t[i] = truth.lookup(cam, labels.frame[i], labels.track_id[i])
        for j in i:
            cls[j] = tcls.get((int(labels.frame[j]), int(labels.track_id[j])), "")
    d = labels.xy - t
    u = t - np.array([scene.cameras[str(c)].center[:2] for c in labels.camera])
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    rad = np.abs(np.sum(d * u, axis=1))
    e = np.linalg.norm(d, axis=1)
    ok = np.isfinite(e)
    for c in ["all", *scene.class_names]:
        s = ok & ((cls == c) if c != "all" else True)
        out[c] = (float(e[s].mean()), float(rad[s].mean()), int(s.sum()))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("models")
    ap.add_argument("--smooth", type=int, default=4)
    a = ap.parse_args()
    scene = load_scene(a.scene)
    cams = list(scene.cameras)
    views = rough_stage_views(scene, Path(a.models), cams, progress=False)
    rows = {"raw": pseudo_poses(scene, views, "track", 0),
            "track": pseudo_poses(scene, views, "track", a.smooth),
            "fused": pseudo_poses(scene, views, "fused", a.smooth),
            "views": pseudo_poses(scene, views, "views", a.smooth)}
    print(f"pseudo poses vs the truth, train split of {scene.root.name}: mean error / mean |radial| m (views)")
    for name, lab in rows.items():
        e = errors(scene, lab)
        print(f"{name:6s} " + "  ".join(f"{c} {m:.3f}/{r:.3f} ({n})" for c, (m, r, n) in e.items()))


if __name__ == "__main__":
    main()
