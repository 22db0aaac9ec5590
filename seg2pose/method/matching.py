"""Matching instance masks to ground-truth road users (paper 4.1).

"The instance segmentations were matched to the road user IDs by projecting the true 3D
positions into each camera and associating it with any segmentation mask that covered that
point, if they were of the same road user class."

The projected point is the centre of the road user's box (ground point + h/2) when sizes are
known, else the ground point raised by the class's default height. Matching is one-to-one and
only within equal frames; when several masks cover a point the smallest mask wins (a small
mask in front of a big one is the more specific evidence), and when one mask covers several
points the nearest road user (smallest depth) wins, since it occludes the others.
"""

from __future__ import annotations

import numpy as np

from seg2pose.geometry.camera import Camera
from seg2pose.geometry.normal import DEFAULT_HEIGHTS
from seg2pose.io.mots import MaskTable
from seg2pose.io.poses import PoseTable
from seg2pose.structures.masks import rle_contains, rle_stats


def truth_points(gt: PoseTable, default_heights: dict[str, float] | None = None) -> np.ndarray:
    """The 3D points (N, 3) metres that represent each ground-truth row for matching: box
    centre (ground point + h/2) when sizes are known, else ground point + default height."""
    dh = dict(DEFAULT_HEIGHTS)
    if default_heights:
        dh.update(default_heights)
    if gt.size is not None and np.all(np.isfinite(gt.size[:, 2])):
        lift = gt.size[:, 2] / 2
    else:
        lift = np.array([dh.get(str(c), 0.9) for c in gt.cls], dtype=np.float64)
        if gt.size is not None:  # per row: known sizes where finite
            ok = np.isfinite(gt.size[:, 2])
            lift[ok] = gt.size[ok, 2] / 2
    return gt.xyz + np.stack([np.zeros(len(gt)), np.zeros(len(gt)), lift], axis=1)


def candidate_pairs(mask_key: np.ndarray, gt_key: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All (mask, gt) index pairs with equal int64 keys, vectorised (sort + searchsorted)."""
    order = np.argsort(mask_key, kind="stable")
    mk = mask_key[order]
    lo = np.searchsorted(mk, gt_key, side="left")
    hi = np.searchsorted(mk, gt_key, side="right")
    n = hi - lo
    gi = np.repeat(np.arange(len(gt_key)), n)
    # position within each gt's run of candidates
    within = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    mi = order[np.repeat(lo, n) + within]
    return mi.astype(np.int64), gi.astype(np.int64)


def _assign(mi: np.ndarray, gi: np.ndarray, area: np.ndarray, depth: np.ndarray,
            n_masks: int, n_gt: int) -> np.ndarray:
    """One-to-one assignment from covering pairs: each gt proposes to its smallest free mask,
    each mask accepts its nearest proposer; repeat until no free pair is left."""
    result = np.full(n_masks, -1, dtype=np.int64)
    gt_done = np.zeros(n_gt, dtype=bool)
    alive = np.ones(len(mi), dtype=bool)
    while alive.any():
        m, g = mi[alive], gi[alive]
        o = np.lexsort((depth[g], area[m], g))  # per gt: smallest mask first
        m, g = m[o], g[o]
        first = np.r_[True, g[1:] != g[:-1]]
        pm, pg = m[first], g[first]  # proposals
        o2 = np.lexsort((depth[pg], pm))  # per mask: nearest proposer first
        pm, pg = pm[o2], pg[o2]
        acc = np.r_[True, pm[1:] != pm[:-1]]
        result[pm[acc]] = pg[acc]
        gt_done[pg[acc]] = True
        alive &= ~gt_done[gi] & (result[mi] < 0)
    return result


def match_masks_to_truth(camera: Camera, masks: MaskTable, gt: PoseTable,
                         class_names: dict[int, str],
                         default_heights: dict[str, float] | None = None) -> np.ndarray:
    """For each mask of one camera, the ground-truth row it shows, or -1.

    masks: detections of ``camera`` over any number of frames; gt: ground truth (any frames);
    class_names: class_id -> class name as used in ``gt.cls``; default_heights: class name ->
    metres, used when ``gt`` has no sizes. Returns (len(masks),) int64 indices into ``gt``.
    Masks without a known class (class_id 0 or not in ``class_names``) stay -1."""
    n_masks = len(masks)
    result = np.full(n_masks, -1, dtype=np.int64)
    if n_masks == 0 or len(gt) == 0:
        return result
    uv, depth, front = camera.project_points(truth_points(gt, default_heights))
    visible = front & camera.in_image(np.nan_to_num(uv, nan=-1.0))
    # shared dense key over (frame, class name)
    names = sorted(set(class_names.values()) | set(map(str, gt.cls.tolist())))
    name_id = {n: i for i, n in enumerate(names)}
    m_cls = np.array([name_id.get(class_names.get(int(c), ""), -1) if int(c) in class_names else -1
                      for c in masks.class_id], dtype=np.int64)
    g_cls = np.array([name_id[str(c)] for c in gt.cls], dtype=np.int64)
    f0 = min(int(masks.frame.min()), int(gt.frame.min()))
    nc = len(names) + 1
    m_key = np.where(m_cls >= 0, (masks.frame - f0) * nc + m_cls, -1)
    g_key = np.where(visible, (gt.frame - f0) * nc + g_cls, -2)
    mi, gi = candidate_pairs(m_key, g_key)
    if len(mi) == 0:
        return result
    cover = rle_contains(masks.rles, masks.height, masks.width, mi, uv[gi])
    mi, gi = mi[cover], gi[cover]
    if len(mi) == 0:
        return result
    area = rle_stats(masks.rles, masks.height, masks.width)[0]
    return _assign(mi, gi, area, depth, n_masks, len(gt))
