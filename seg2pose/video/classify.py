"""Classes from world size (and speed), for masks whose source gives none (background subtraction).

The ground surface and the calibration make a mask's size metric. The bottom centre of the
mask's bounding box is cast onto the ground: that foot point F is where the road user touches
the ground nearest the camera. Then

- width  = distance between the rays through the box's bottom corners where they cross the
  vertical plane through F facing the camera (the apparent width);
- height = how far above F the ray through the box's top edge passes, in that plane.

Each class has a width and a height range (``scene.json`` ``extra.size_classes``, defaults from
``DEFAULT_SIZE_CLASSES``): about the 5th-95th percentiles of that class's sizes, read as a
log-normal distribution. A mask's evidence for a class is the log-likelihood of its size under
it, mixed with a share ``OUTLIER`` of "any size" so that merged blobs and fragments cannot
outvote many good masks. A mask whose box touches the image border says less:

- at the left or right (or top) edge: the road user may be cut there. With probability
  ``CUT_WHOLE`` it is whole anyway (it just touches the border); otherwise the visible width
  (height) x is a uniform share of the true size S, whose density is E[1/S; S >= x]: small
  classes explain a small visible piece better, big ones a big piece;
- at the bottom edge: the foot point is not seen, so the sizes are measured at a wrong
  distance; such masks weigh ``BOTTOM_CUT_WEIGHT``.

A class may have a top ``speed`` (m/s): a track faster than that (the ``SPEED_QUANTILE`` th
percentile of its ground-point speeds over ``SPEED_WINDOW_S``) loses ``SPEED_WEIGHT *
log(speed / top)`` per mask for that class: a car cut by the border down to a pedestrian-sized
piece is still no pedestrian if it drove there. Each track gets one class, the one with the
largest weighted sum over its masks (masks without a track id get their own most likely class).
Defaults and constants were chosen on synthetic seeds 101-102 (docs/RESULTS.md).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pycocotools import mask as mask_util
from scipy.special import log_ndtr

from seg2pose.core.errors import InputError
from seg2pose.geometry.camera import Camera
from seg2pose.geometry.ground import GroundSurface
from seg2pose.io.mots import MaskTable, iter_mots, write_mots

# width and height ranges (5th-95th percentiles, metres) and top speeds (m/s).
DEFAULT_SIZE_CLASSES = {
    "pedestrian": {"width": [0.5, 1.0], "height": [1.5, 2.2], "speed": 3.0},
    "bicyclist": {"width": [0.9, 1.7], "height": [1.5, 2.4], "speed": 8.0},
    "car": {"width": [2.0, 5.5], "height": [1.5, 3.9]},
    "truck": {"width": [2.2, 12.0], "height": [2.6, 5.0]},
    "bus": {"width": [2.4, 14.0], "height": [2.8, 5.0]},
}
Z90 = 1.6449                # a 5th-95th percentile range spans +-Z90 standard deviations
OUTLIER = 0.1               # share of masks whose size says nothing (merged blobs, fragments)
OUTLIER_RANGE = (0.1, 20.0)  # metres: the sizes an outlier may have (log-uniform)
BOTTOM_CUT_WEIGHT = 0.3     # weight of a mask cut by the image's bottom edge
CUT_WHOLE = 0.3             # share of border-touching masks that still show the whole size
SPEED_WINDOW_S = 0.5        # seconds between the foot points a speed is measured from
SPEED_QUANTILE = 80         # a track's speed: this percentile of its speeds
SPEED_WEIGHT = 10.0         # log-likelihood lost per mask and per unit of log(speed / top)
CUT_SIDE, CUT_TOP, CUT_BOTTOM = 1, 2, 4   # border_cuts bits
_CHUNK = 50_000             # masks whose rays are cast together


@dataclass(frozen=True)
class SizeRules:
    """The scene's size classes: ids (C,), width and height ranges (C, 2) metres (5th-95th
    percentiles), top speeds (C,) m/s (inf: none)."""

    ids: np.ndarray
    width: np.ndarray
    height: np.ndarray
    speed: np.ndarray


def size_rules(classes: list, extra: dict, file: Path | None = None) -> SizeRules:
    """The size classes of a scene's classes that have a rule (``extra.size_classes`` over
    the defaults; a class given there replaces its default whole)."""
    given = extra.get("size_classes") or {}
    if not isinstance(given, dict):
        raise InputError("expected an object class name -> {width: [lo, hi], height: [lo, hi]}",
                         file=file, field="extra.size_classes")
    ids, wid, hei, spd = [], [], [], []
    for c in classes:
        rule = given.get(c.name, DEFAULT_SIZE_CLASSES.get(c.name))
        if rule is None:
            continue
        field = f"extra.size_classes.{c.name}"
        try:
            w = [float(v) for v in rule["width"]]
            h = [float(v) for v in rule["height"]]
        except (TypeError, KeyError, ValueError):
            raise InputError("expected {width: [lo, hi], height: [lo, hi]} in metres", file=file,
                             field=field) from None
        if len(w) != 2 or len(h) != 2 or not (0 < w[0] < w[1] and 0 < h[0] < h[1]):
            raise InputError("ranges must be [lo, hi] with 0 < lo < hi", file=file, field=field)
        s = rule.get("speed")
        if s is not None:
            try:
                s = float(s)
            except (TypeError, ValueError):
                s = -1.0
            if not s > 0:
                raise InputError("expected a top speed > 0 in m/s", file=file, field=f"{field}.speed")
        ids.append(c.id)
        wid.append(w)
        hei.append(h)
        spd.append(np.inf if s is None else s)
    if not ids:
        raise InputError("no class has a size rule", file=file, field="extra.size_classes")
    return SizeRules(np.array(ids, np.int64), np.array(wid), np.array(hei), np.array(spd))


def mask_boxes(rles: list[bytes], height: int, width: int) -> np.ndarray:
    """(N, 4) bounding boxes x0, y0, w, h in pixels."""
    if not rles:
        return np.zeros((0, 4))
    return mask_util.toBbox([{"size": [height, width], "counts": r} for r in rles]).reshape(-1, 4)


def border_cuts(boxes: np.ndarray, height: int, width: int, margin: float = 1.0) -> np.ndarray:
    """(N,) uint8 bits: CUT_SIDE (box at the left or right edge), CUT_TOP, CUT_BOTTOM."""
    x0, y0, bw, bh = np.asarray(boxes, float).reshape(-1, 4).T
    side = (x0 <= margin) | (x0 + bw >= width - margin)
    return (side * CUT_SIDE + (y0 <= margin) * CUT_TOP
            + (y0 + bh >= height - margin) * CUT_BOTTOM).astype(np.uint8)


def foot_and_sizes(boxes: np.ndarray, camera: Camera, ground: GroundSurface
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Foot points F (N, 3) and apparent (width, height) (N, 2) metres of boxes (N, 4) (see
    the module docstring); NaN where the foot ray misses the ground."""
    n = len(boxes)
    if n == 0:
        return np.zeros((0, 3)), np.zeros((0, 2))
    x0, y0, bw, bh = np.asarray(boxes, float).T
    o = camera.center
    F, _ = ground.intersect_rays(o, camera.unproject(np.stack([x0 + bw / 2, y0 + bh], axis=1)), 0.0)
    # the vertical plane through F facing the camera (normal: horizontal direction camera -> F)
    nrm = np.c_[F[:, :2] - o[:2], np.zeros(n)]
    with np.errstate(divide="ignore", invalid="ignore"):
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)

    def on_plane(px: np.ndarray) -> np.ndarray:
        d = camera.unproject(px)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.einsum("ij,ij->i", nrm, F - o) / np.einsum("ij,ij->i", nrm, d)
        return o + s[:, None] * d

    left = on_plane(np.stack([x0, y0 + bh], axis=1))
    right = on_plane(np.stack([x0 + bw, y0 + bh], axis=1))
    out = np.stack([np.linalg.norm(right - left, axis=1),
                    on_plane(np.stack([x0 + bw / 2, y0], axis=1))[:, 2] - F[:, 2]], axis=1)
    out[~np.isfinite(out).all(axis=1)] = np.nan
    return F, out


def track_points(boxes: np.ndarray, width: int, camera: Camera, ground: GroundSurface,
                 foot: np.ndarray | None = None) -> np.ndarray:
    """(N, 2) metres: ground points that move with the road user, for its speed: below the
    box's bottom centre, or below its inner edge when the box is cut at one side (a road user
    driving in from the border grows from there: its centre moves at half its speed). boxes
    (N, 4) pixels, width: the image's, pixels; foot: (N, 3) the boxes' foot points when known
    (foot_and_sizes), so that only the cut boxes cast new rays."""
    b = np.asarray(boxes, float).reshape(-1, 4)
    if not len(b):
        return np.zeros((0, 2))
    x0, y0, bw, bh = b.T
    left, right = x0 <= 1.0, x0 + bw >= width - 1.0
    x = np.where(left & ~right, x0 + bw, np.where(right & ~left, x0, x0 + bw / 2))
    out = np.full((len(b), 2), np.nan)
    cast = left != right if foot is not None else np.ones(len(b), bool)
    if foot is not None:
        out[~cast] = foot[~cast, :2]
    if cast.any():
        px = np.stack([x[cast], (y0 + bh)[cast]], axis=1)
        out[cast] = ground.intersect_rays(camera.center, camera.unproject(px), 0.0)[0][:, :2]
    return out


def world_sizes(rles: list[bytes], height: int, width: int, camera: Camera,
                ground: GroundSurface) -> np.ndarray:
    """(N, 2) apparent width and height in metres of the masks (see the module docstring);
    NaN where the foot ray misses the ground."""
    return foot_and_sizes(mask_boxes(rles, height, width), camera, ground)[1]


def _loglik_1d(x: np.ndarray, lo: np.ndarray, hi: np.ndarray, cut: np.ndarray) -> np.ndarray:
    """(N, C) log density of sizes x (N,) under log-normal classes whose 5th-95th percentiles
    are lo, hi (C,); where ``cut``, x is a uniform share of the size: E[1/S; S >= x]."""
    mu = (np.log(lo) + np.log(hi)) / 2
    sg = (np.log(hi) - np.log(lo)) / (2 * Z90)
    lx = np.log(x)[:, None]
    whole = -0.5 * ((lx - mu) / sg) ** 2 - np.log(sg * np.sqrt(2 * np.pi)) - lx
    part = -mu + sg ** 2 / 2 + log_ndtr((mu - sg ** 2 - lx) / sg)
    with np.errstate(divide="ignore"):                 # CUT_WHOLE 0 or 1: log 0 = -inf
        part = np.logaddexp(np.log(CUT_WHOLE) + whole, np.log1p(-CUT_WHOLE) + part)
    return np.where(cut[:, None], part, whole)


def size_loglik(sizes: np.ndarray, rules: SizeRules, cuts: np.ndarray | None = None
                ) -> np.ndarray:
    """(N, C) log-likelihood of each mask's (width, height) (N, 2) metres under each class of
    ``rules``, with the outlier share (see the module docstring); ``cuts`` (N,) border_cuts
    bits. Rows of unknown size are 0."""
    s = np.asarray(sizes, float).reshape(-1, 2)
    cuts = np.zeros(len(s), np.uint8) if cuts is None else np.asarray(cuts, np.uint8)
    ok = np.isfinite(s).all(axis=1) & (s > 0).all(axis=1)
    w, h = np.where(ok, s[:, 0], 1.0), np.where(ok, s[:, 1], 1.0)
    ll = (_loglik_1d(w, rules.width[:, 0], rules.width[:, 1], (cuts & CUT_SIDE) > 0)
          + _loglik_1d(h, rules.height[:, 0], rules.height[:, 1], (cuts & CUT_TOP) > 0))
    lo, hi = OUTLIER_RANGE
    out = -2 * np.log(np.log(hi / lo)) - np.log(w) - np.log(h)
    ll = np.logaddexp(np.log1p(-OUTLIER) + ll, np.log(OUTLIER) + out[:, None])
    return np.where(ok[:, None], ll, 0.0)


def classify_sizes(sizes: np.ndarray, rules: SizeRules, cuts: np.ndarray | None = None
                   ) -> np.ndarray:
    """Class id (N,) per (width, height) row: the most likely class (0 where the size is
    unknown)."""
    s = np.asarray(sizes, float).reshape(-1, 2)
    best = rules.ids[np.argmax(size_loglik(s, rules, cuts), axis=1)]
    return np.where(np.isfinite(s).all(axis=1) & (s > 0).all(axis=1), best, 0)


def track_speeds(track_id: np.ndarray, frame: np.ndarray, xy: np.ndarray, fps: float,
                 window_s: float = SPEED_WINDOW_S, quantile: float = SPEED_QUANTILE
                 ) -> dict[int, float]:
    """Track id -> its speed, m/s: the ``quantile`` th percentile over its masks of the
    distance to its foot point ``window_s`` later (positions xy (N, 2) metres, the first mask
    at least that many frames on, at most twice), over the time between. Tracks too short or
    without positions get none."""
    t = np.asarray(track_id, np.int64)
    f = np.asarray(frame, np.int64)
    p = np.asarray(xy, float).reshape(-1, 2)
    k = max(1, int(round(window_s * fps)))
    keep = (t >= 0) & np.isfinite(p).all(axis=1)
    t, f, p = t[keep], f[keep], p[keep]
    o = np.lexsort((f, t))
    t, f, p = t[o], f[o], p[o]
    # the first mask of the same track at least k frames later: searchsorted on (track, frame)
    key = t * (int(f.max(initial=0)) + k + 1) + f
    j = np.minimum(np.searchsorted(key, key + k), max(len(key) - 1, 0))
    good = (t[j] == t) & (f[j] - f >= k) & (f[j] - f <= 2 * k)
    t, v = t[good], np.linalg.norm(p[j] - p, axis=1)[good] / ((f[j] - f)[good] / fps)
    if not len(t):
        return {}
    # per track, the quantile of its sorted speeds (linear between neighbours, as np.percentile)
    o = np.lexsort((v, t))
    t, v = t[o], v[o]
    u, start, n = np.unique(t, return_index=True, return_counts=True)
    pos = start + (n - 1) * quantile / 100.0
    lo = np.floor(pos).astype(np.int64)
    hi = np.minimum(lo + 1, start + n - 1)
    q = v[lo] + (pos - lo) * (v[hi] - v[lo])
    return {int(a): float(b) for a, b in zip(u, q)}


def track_classes(track_id: np.ndarray, loglik: np.ndarray, weight: np.ndarray, ids: np.ndarray
                  ) -> dict[int, int]:
    """Track id -> the class (of ``ids`` (C,)) with the largest weighted sum of its masks'
    log-likelihoods (N, C); tracks whose masks all weigh 0 (sizes unknown) and track -1 get
    none."""
    t = np.asarray(track_id, np.int64)
    ok = t >= 0
    if not ok.any():
        return {}
    u, inv = np.unique(t[ok], return_inverse=True)
    w = np.asarray(weight, float)[ok]
    ll = np.asarray(loglik, float)[ok]
    tot = np.zeros((len(u), ll.shape[1]))
    np.add.at(tot, inv, w[:, None] * ll)
    seen = np.bincount(inv, weights=w, minlength=len(u)) > 0
    return {int(a): int(ids[b]) for a, b in zip(u[seen], np.argmax(tot[seen], axis=1))}


def classify_mots(src: str | Path, out: str | Path, camera: Camera, ground: GroundSurface,
                  rules: SizeRules, fps: float | None = None, overwrite_known: bool = False,
                  log: Callable[[str], None] = print) -> dict[int, int]:
    """Give the masks of MOTS file ``src`` classes by size (and by speed with ``fps``), one
    per track, into ``out`` (may be ``src``; atomic). Masks that already have a class keep it
    unless ``overwrite_known``. Untracked masks (-1) get their own most likely class. Returns
    track id -> class."""
    tids, frames, boxes, size = [], [], [], None
    for f, t in iter_mots(src):             # boxes first: the rays are cast for all at once
        tids.append(t.track_id)
        frames.append(np.full(len(t), f, np.int64))
        boxes.append(mask_boxes(t.rles, t.height, t.width))
        size = (t.height, t.width)
    if size is None:
        write_mots(out, [])
        return {}
    tid, box = np.concatenate(tids), np.concatenate(boxes)
    ll, wt, points = np.zeros((len(tid), len(rules.ids))), np.zeros(len(tid)), np.zeros((len(tid), 2))
    for a in range(0, len(tid), _CHUNK):
        b = slice(a, a + _CHUNK)
        foot, sizes = foot_and_sizes(box[b], camera, ground)
        cuts = border_cuts(box[b], *size)
        ll[b] = size_loglik(sizes, rules, cuts)
        wt[b] = np.where(cuts & CUT_BOTTOM, BOTTOM_CUT_WEIGHT, 1.0) * np.isfinite(sizes).all(axis=1)
        if fps:
            points[b] = track_points(box[b], size[1], camera, ground, foot)
    if fps and np.isfinite(rules.speed).any():
        speeds = track_speeds(tid, np.concatenate(frames), points, fps)
        v = np.array([speeds.get(int(i), np.nan) for i in tid])
        with np.errstate(invalid="ignore", divide="ignore"):
            over = np.log(v[:, None] / rules.speed[None, :])
        ll = ll - SPEED_WEIGHT * np.where(over > 0, over, 0.0)          # NaN (no speed) compares False
    votes = track_classes(tid, ll, wt, rules.ids)
    own = rules.ids[np.argmax(ll, axis=1)]
    own = np.where(wt > 0, own, 0)

    def rewritten() -> Iterator[MaskTable]:
        k = 0
        for _, t in iter_mots(src, check_rles=False):
            mine = own[k:k + len(t)]
            k += len(t)
            v = np.array([votes.get(int(i), 0) if i >= 0 else 0 for i in t.track_id], np.int64)
            new = np.where(v > 0, v, mine)
            if not overwrite_known:
                new = np.where(t.class_id > 0, t.class_id, new)
            yield MaskTable(t.frame, t.track_id, new, t.height, t.width, t.rles)

    write_mots(out, rewritten())
    return votes
