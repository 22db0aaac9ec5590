"""Classes from world size, for masks whose source gives none (background subtraction).

The ground surface and the calibration make a mask's size metric. The bottom centre of the
mask's bounding box is cast onto the ground: that foot point F is where the road user touches
the ground nearest the camera. Then

- width  = distance between the rays through the box's bottom corners where they cross the
  vertical plane through F facing the camera (the apparent width);
- height = how far above F the ray through the box's top edge passes, in that plane.

Each class has a width and a height interval (``scene.json`` ``extra.size_classes``, defaults
from ``DEFAULT_SIZE_CLASSES``, measured on synthetic truth masks); a mask gets the class whose
intervals it misses by least (log-ratio), ties going to the nearer interval centre. A track
gets one class, the majority of its masks (``vote``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Iterator

import numpy as np
from pycocotools import mask as mask_util

from seg2pose.camera import Camera
from seg2pose.errors import InputError
from seg2pose.ground import GroundSurface
from seg2pose.io.mots import MaskTable, iter_mots, write_mots

# apparent width and height intervals, metres. Measured on rendered truth masks of synthetic
# scenes (seed 101, cameras c0 and c1; medians and 5th-95th percentiles): pedestrians 0.72 m
# (0.3-1.0) wide, 1.81 m high; bicyclists 1.16 m (0.8-1.2) wide, 1.84 m high; cars 3.8 m
# (1.45-4.6) wide, 2.4 m (0.8-3.5) "high" (the far roof edge lies behind F, so the ray through
# a car's box top passes higher than its roof).
DEFAULT_SIZE_CLASSES = {
    "pedestrian": {"width": [0.25, 0.95], "height": [1.2, 2.3]},
    "bicyclist": {"width": [0.95, 1.5], "height": [1.3, 2.4]},
    "car": {"width": [1.4, 6.0], "height": [0.8, 3.8]},
    "truck": {"width": [2.2, 12.0], "height": [2.6, 5.0]},
    "bus": {"width": [2.4, 14.0], "height": [2.8, 5.0]},
}


def size_rules(classes: list, extra: dict, file: Path | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(class ids (C,), width intervals (C, 2), height intervals (C, 2)) for a scene's classes
    that have a rule (``extra.size_classes`` over the defaults)."""
    given = extra.get("size_classes") or {}
    if not isinstance(given, dict):
        raise InputError("expected an object class name -> {width: [lo, hi], height: [lo, hi]}",
                         file=file, field="extra.size_classes")
    ids, wid, hei = [], [], []
    for c in classes:
        rule = given.get(c.name, DEFAULT_SIZE_CLASSES.get(c.name))
        if rule is None:
            continue
        try:
            w = [float(v) for v in rule["width"]]
            h = [float(v) for v in rule["height"]]
        except (TypeError, KeyError, ValueError):
            raise InputError("expected {width: [lo, hi], height: [lo, hi]} in metres", file=file,
                             field=f"extra.size_classes.{c.name}") from None
        if len(w) != 2 or len(h) != 2 or not (0 < w[0] < w[1] and 0 < h[0] < h[1]):
            raise InputError("intervals must be [lo, hi] with 0 < lo < hi", file=file,
                             field=f"extra.size_classes.{c.name}")
        ids.append(c.id)
        wid.append(w)
        hei.append(h)
    if not ids:
        raise InputError("no class has a size rule", file=file, field="extra.size_classes")
    return np.array(ids, np.int64), np.array(wid), np.array(hei)


def world_sizes(rles: list[bytes], height: int, width: int, camera: Camera,
                ground: GroundSurface) -> np.ndarray:
    """(N, 2) apparent width and height in metres of the masks (see the module docstring);
    NaN where the foot ray misses the ground."""
    n = len(rles)
    if n == 0:
        return np.zeros((0, 2))
    box = mask_util.toBbox([{"size": [height, width], "counts": r} for r in rles]).reshape(n, 4)
    x0, y0, bw, bh = box.T
    foot_px = np.stack([x0 + bw / 2, y0 + bh], axis=1)
    top_px = np.stack([x0 + bw / 2, y0], axis=1)
    o = camera.center
    F, _ = ground.intersect_rays(o, camera.unproject(foot_px), 0.0)
    # the vertical plane through F facing the camera (normal: horizontal direction camera -> F)
    nrm = np.c_[F[:, :2] - o[:2], np.zeros(n)]
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)

    def on_plane(px: np.ndarray) -> np.ndarray:
        d = camera.unproject(px)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.einsum("ij,ij->i", nrm, F - o) / np.einsum("ij,ij->i", nrm, d)
        return o + s[:, None] * d

    left = on_plane(np.stack([x0, y0 + bh], axis=1))
    right = on_plane(np.stack([x0 + bw, y0 + bh], axis=1))
    w_m = np.linalg.norm(right - left, axis=1)
    h_m = on_plane(top_px)[:, 2] - F[:, 2]
    out = np.stack([w_m, h_m], axis=1)
    out[~np.isfinite(out).all(axis=1)] = np.nan
    return out


def classify_sizes(sizes: np.ndarray, rules: tuple[np.ndarray, np.ndarray, np.ndarray]
                   ) -> np.ndarray:
    """Class id (N,) per (width, height) row (0 where the size is unknown)."""
    ids, wi, hi = rules
    s = np.asarray(sizes, float).reshape(-1, 2)
    with np.errstate(invalid="ignore", divide="ignore"):
        lw, lh = np.log(s[:, :1]), np.log(s[:, 1:])
        lwi, lhi = np.log(wi), np.log(hi)
        miss = (np.maximum(lwi[:, 0] - lw, 0) + np.maximum(lw - lwi[:, 1], 0)
                + np.maximum(lhi[:, 0] - lh, 0) + np.maximum(lh - lhi[:, 1], 0))   # (N, C)
        centre = np.abs(lw - lwi.mean(axis=1)) + np.abs(lh - lhi.mean(axis=1))
    score = miss * 1e3 + centre
    out = ids[np.argmin(np.where(np.isfinite(score), score, np.inf), axis=1)]
    return np.where(np.isfinite(s).all(axis=1), out, 0)


def vote(track_id: np.ndarray, cls: np.ndarray) -> dict[int, int]:
    """Track id -> its majority class (ties: the smaller class id); class 0 (unknown) and
    track -1 do not vote."""
    t = np.asarray(track_id, np.int64)
    c = np.asarray(cls, np.int64)
    ok = (t >= 0) & (c > 0)
    if not ok.any():
        return {}
    pairs, counts = np.unique(np.stack([t[ok], c[ok]], axis=1), axis=0, return_counts=True)
    # per track: highest count, then smallest class (np.lexsort: last key first)
    order = np.lexsort((pairs[:, 1], -counts, pairs[:, 0]))
    p = pairs[order]
    first = np.r_[True, p[1:, 0] != p[:-1, 0]]
    return {int(a): int(b) for a, b in p[first]}


def classify_mots(src: str | Path, out: str | Path, camera: Camera, ground: GroundSurface,
                  rules: tuple[np.ndarray, np.ndarray, np.ndarray], overwrite_known: bool = False,
                  log: Callable[[str], None] = print) -> dict[int, int]:
    """Give the masks of MOTS file ``src`` classes by size and per-track vote, into ``out``
    (may be ``src``; atomic). Masks that already have a class keep it unless
    ``overwrite_known``. Untracked masks (-1) get their own size class. Returns the votes."""
    tids, cls = [], []
    for _, t in iter_mots(src):
        tids.append(t.track_id)
        cls.append(classify_sizes(world_sizes(t.rles, t.height, t.width, camera, ground), rules))
    if not tids:
        write_mots(out, [])
        return {}
    tid, c = np.concatenate(tids), np.concatenate(cls)
    votes = vote(tid, c)

    def rewritten() -> Iterator[MaskTable]:
        k = 0
        for _, t in iter_mots(src, check_rles=False):
            own = c[k:k + len(t)]
            k += len(t)
            v = np.array([votes.get(int(i), 0) if i >= 0 else 0 for i in t.track_id], np.int64)
            new = np.where(v > 0, v, own)
            if not overwrite_known:
                new = np.where(t.class_id > 0, t.class_id, new)
            yield MaskTable(t.frame, t.track_id, new, t.height, t.width, t.rles)

    write_mots(out, rewritten())
    return votes
