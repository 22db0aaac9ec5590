"""Default heights (paper 3.2): per class, the height above the ground at which the normal
position's ray is cut so that about half of the normal positions of the training split lie
closer to the camera than the truth (bisection on masks matched to ground truth)."""

from __future__ import annotations

import numpy as np

from seg2pose.core.errors import S2PError
from seg2pose.core.say import say
from seg2pose.geometry.normal import DEFAULT_CENTER_METHOD, closer_share, default_height_bisection
from seg2pose.io.mots import MaskTable
from seg2pose.io.poses import read_poses
from seg2pose.io.scene import SCENE_FILE, Scene
from seg2pose.method.matching import match_masks_to_truth
from seg2pose.structures.masks import mask_centers


def collect_height_views(scene: Scene, split: str | None = "train", center: str | None = None,
                         chunk: int = 20000) -> dict[str, list]:
    """Per class name, the bisection input of ``default_height_bisection``: a list of
    (camera, mask centres (N, 2) pixels, true ground positions (N, 2) metres), from the split's
    masks matched to ground truth (paper 4.1 matching)."""
    center = center or DEFAULT_CENTER_METHOD
    if not scene.gt_path.exists():
        raise S2PError(f"{scene.gt_path}: no ground truth; default heights need it (paper 3.2)")
    fr = scene.split_range(split)
    names = scene.class_names_by_id()
    heights = scene.default_heights()
    gt = read_poses(scene.gt_path, known_classes=set(names.values())).in_frames(fr)
    views: dict[str, list] = {}
    for cam in scene.cameras.values():
        path = scene.masks_path(cam.name)
        if not path.exists():
            continue
        pending: list = []

        def flush():
            t = MaskTable.concat(pending)
            pending.clear()
            idx = match_masks_to_truth(cam, t, gt, names, heights)
            ok = idx >= 0
            if not ok.any():
                return
            cen = mask_centers([t.rles[i] for i in np.flatnonzero(ok)], t.height, t.width, center)
            g = idx[ok]
            for cname in np.unique(gt.cls[g]):
                sel = gt.cls[g] == cname
                views.setdefault(str(cname), []).append((cam, cen[sel], gt.xyz[g[sel], :2]))

        n = 0
        for _, t in scene.iter_masks(cam.name, fr):
            pending.append(t)
            n += len(t)
            if n >= chunk:
                flush()
                n = 0
        if pending:
            flush()
    return views


def subsample_views(views: list, max_n: int, seed: int = 0) -> list:
    """At most ``max_n`` detections in total, drawn uniformly (the share of 'closer' is a
    median-like statistic: 20,000 detections pin it to about +-0.4 %)."""
    total = sum(len(c) for _, c, _ in views)
    if total <= max_n:
        return views
    rng = np.random.default_rng(seed)
    keep = np.zeros(total, bool)
    keep[rng.choice(total, max_n, replace=False)] = True
    out, a = [], 0
    for cam, cen, txy in views:
        k = keep[a:a + len(cen)]
        a += len(cen)
        if k.any():
            out.append((cam, cen[k], txy[k]))
    return out


def update_default_heights(scene: Scene, split: str | None = "train", center: str | None = None,
                           log=say, write: bool = True, max_per_class: int = 20000,
                           views: dict[str, list] | None = None) -> dict[str, dict]:
    """Paper 3.2: per-class default heights by bisection on ``split``, set on ``scene`` and
    (with ``write``) saved into its scene.json by ``Scene.save``. At most
    ``max_per_class`` matched detections per class are used (a uniform sample).

    Returns per class name {"old", "new", "closer_share", "n"}; classes without matched masks
    keep their height (n = 0). ``views``: the bisection input per class, when it comes from
    elsewhere (rough models: ``seg2pose.training.rough_heights``) rather than the split's masks."""
    if views is None:
        views = collect_height_views(scene, split, center)
    views = {k: subsample_views(v, max_per_class) for k, v in views.items()}
    report: dict[str, dict] = {}
    for c in scene.classes:
        v = views.get(c.name, [])
        old = c.default_height
        if not v:
            report[c.name] = {"old": old, "new": old, "closer_share": None, "n": 0}
            log(f"{c.name:>12}: no matched masks in split {split!r}; kept {old:.3f} m")
            continue
        new = default_height_bisection(v, scene.ground)
        share, n = closer_share(v, scene.ground, new)
        c.default_height = float(round(new, 4))
        report[c.name] = {"old": old, "new": c.default_height, "closer_share": share, "n": n}
        log(f"{c.name:>12}: {old:.3f} m -> {c.default_height:.3f} m   closer than truth: "
            f"{100 * share:.1f}% of {n} normal positions")
    if write:
        scene.save()
        log(f"wrote default heights into {scene.root / SCENE_FILE}")
    return report
