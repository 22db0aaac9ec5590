"""Join the fragments of one road user that background subtraction cut into several tracks.

A road user whose colour is close to the road's (a dark grey car on asphalt, a car standing so
long that the background model took in most of it) comes out of background subtraction as
pieces: its wheels, its lower edge, a lit flank, each a mask of its own, tracked as a road user
of its own in every lens -- the same road user counted two or three times.

Pieces of one body differ from road users that walk or drive side by side in three ways, all
measured over the frames two tracks of one camera share:

- they touch: their boxes are at most ``max(4 px, half the smaller box side)`` apart in at
  least ``join_near`` of the shared frames;
- they move as one rigid body: the offset between their box centres varies (standard
  deviation per image axis) by at most ``join_rigid`` of the boxes' size;
- together they look more like a road user than any piece alone: the box around both is, on
  average over the shared frames, at least ``join_gain`` (natural log) more likely under its
  best size class (``seg2pose.video.classify``) than the best of the pieces under theirs (a
  track already joined is judged by its best piece, so three pieces need not pass through a
  pair that fits better than each of them).
  Two pedestrians side by side fit the pedestrian class better apart; two cars in a queue fit
  the car class better apart; a wheel and a lower edge fit it better together.

Pairs that pass are joined greedily, the largest gain first (three pieces become one in two
steps; each join is judged again with the joined boxes). The joined track keeps the longer
track's id; in frames where both pieces are seen, their masks become one (the union of the
RLEs). Constants were chosen on synthetic seeds 107, 108 and 110 (docs/RESULTS.md).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
from pycocotools import mask as mask_util

from seg2pose.geometry.camera import Camera
from seg2pose.geometry.ground import GroundSurface
from seg2pose.io.mots import MaskTable, iter_mots, write_mots
from seg2pose.video.classify import SizeRules, border_cuts, foot_and_sizes, mask_boxes, size_loglik
from seg2pose.video.track import TrackConfig

NEAR_PX = 4.0           # boxes this close (pixels) touch whatever their size
NEAR_SHARE = 0.5        # ... or closer than this share of the smaller box's smaller side


def best_loglik(xyxy: np.ndarray, height: int, width: int, camera: Camera,
                ground: GroundSurface, rules: SizeRules) -> np.ndarray:
    """(N,) log-likelihood of boxes (N, 4) x0, y0, x1, y1 pixels under their most likely size
    class; NaN where the size is unknown (the foot ray misses the ground)."""
    xywh = np.c_[xyxy[:, :2], xyxy[:, 2:] - xyxy[:, :2]]
    _, sizes = foot_and_sizes(xywh, camera, ground)
    ll = size_loglik(sizes, rules, border_cuts(xywh, height, width)).max(axis=1)
    return np.where(np.isfinite(sizes).all(axis=1), ll, np.nan)


def _box_gap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N,) pixels between boxes (N, 4) x0, y0, x1, y1 (0 where they overlap)."""
    gx = np.maximum(0.0, np.maximum(a[:, 0], b[:, 0]) - np.minimum(a[:, 2], b[:, 2]))
    gy = np.maximum(0.0, np.maximum(a[:, 1], b[:, 1]) - np.minimum(a[:, 3], b[:, 3]))
    return np.hypot(gx, gy)


def _touching(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N,) bool: boxes a, b (N, 4) touch (see the module docstring)."""
    side = np.minimum((a[:, 2:] - a[:, :2]).min(axis=1), (b[:, 2:] - b[:, :2]).min(axis=1))
    return _box_gap(a, b) <= np.maximum(NEAR_PX, NEAR_SHARE * side)


def _pairs_per_frame(frame: np.ndarray, track: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row pairs (P,), (P,) of two different tracks in the same frame (rows with track >= 0),
    every frame's pairs at once, grouped by how many masks the frame has."""
    rows = np.flatnonzero(track >= 0)
    rows = rows[np.argsort(frame[rows], kind="stable")]
    _, start, count = np.unique(frame[rows], return_index=True, return_counts=True)
    ra, rb = [], []
    for k in np.unique(count[count > 1]):
        grid = rows[start[count == k][:, None] + np.arange(k)[None, :]]      # (frames, k)
        i, j = np.triu_indices(k, 1)
        ra.append(grid[:, i].ravel())
        rb.append(grid[:, j].ravel())
    if not ra:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(ra), np.concatenate(rb)


class _Pieces:
    """Per-mask columns of one camera's file (stream order) and the joins made so far."""

    def __init__(self, frame, track, box, height, width, camera, ground, rules):
        self.frame, self.track, self.box = frame, track.copy(), box.astype(float)
        self.size = (height, width)
        self.cam, self.ground, self.rules = camera, ground, rules
        self._ll = np.full(len(frame), np.nan)     # of the piece; computed when first needed
        self._known = np.zeros(len(frame), bool)
        self.into = np.arange(len(frame))      # row -> the row its mask is merged into

    def ll(self, rows: np.ndarray) -> np.ndarray:
        """best_loglik of the rows' pieces (a joined row: its best piece)."""
        new = rows[~self._known[rows]]
        if len(new):
            self._ll[new] = best_loglik(self.box[new], *self.size, self.cam, self.ground, self.rules)
            self._known[new] = True
        return self._ll[rows]

    def rows(self, t: int) -> np.ndarray:
        r = np.flatnonzero((self.track == t) & (self.into == np.arange(len(self.into))))
        return r[np.argsort(self.frame[r], kind="stable")]

    def judge(self, a: int, b: int, cfg: TrackConfig, min_shared: int) -> float:
        """The gain of joining tracks a and b, or NaN if they fail a test."""
        ra, rb = self.rows(a), self.rows(b)
        _, ia, ib = np.intersect1d(self.frame[ra], self.frame[rb], return_indices=True)
        if len(ia) < max(min_shared, 2):
            return np.nan
        ba, bb = self.box[ra[ia]], self.box[rb[ib]]
        if _touching(ba, bb).mean() < cfg.join_near:
            return np.nan
        size = np.maximum(ba[:, 2:] - ba[:, :2], bb[:, 2:] - bb[:, :2]).mean(axis=0)
        offset = (bb[:, :2] + bb[:, 2:]) / 2 - (ba[:, :2] + ba[:, 2:]) / 2
        if (offset.std(axis=0) / np.maximum(size, 1.0)).max() > cfg.join_rigid:
            return np.nan
        union = np.c_[np.minimum(ba[:, :2], bb[:, :2]), np.maximum(ba[:, 2:], bb[:, 2:])]
        lu = best_loglik(union, *self.size, self.cam, self.ground, self.rules)
        with np.errstate(all="ignore"):
            gain = np.nanmean(lu) - max(np.nanmean(self.ll(ra[ia])), np.nanmean(self.ll(rb[ib])))
        return gain if gain >= cfg.join_gain else np.nan

    def join(self, a: int, b: int) -> None:
        """Track b becomes part of track a: shared frames' masks merge into a's row."""
        ra, rb = self.rows(a), self.rows(b)
        _, ia, ib = np.intersect1d(self.frame[ra], self.frame[rb], return_indices=True)
        keep, gone = ra[ia], rb[ib]
        self.box[keep] = np.c_[np.minimum(self.box[keep, :2], self.box[gone, :2]),
                               np.maximum(self.box[keep, 2:], self.box[gone, 2:])]
        # a joined mask is judged by its best piece: together they must beat every piece
        self._ll[keep] = np.fmax(self.ll(keep), self.ll(gone))
        remap = np.arange(len(self.into))
        remap[gone] = keep                     # rows merged into a gone row follow it
        self.into = remap[self.into]
        self.track[self.track == b] = a


def find_joins(frame: np.ndarray, track: np.ndarray, box: np.ndarray, height: int, width: int,
               camera: Camera, ground: GroundSurface, rules: SizeRules, cfg: TrackConfig,
               fps: float) -> tuple[np.ndarray, np.ndarray, list[tuple[int, int]]]:
    """Decide the joins of one camera's masks: ``frame``, ``track`` (N,), boxes (N, 4) x0, y0,
    x1, y1 pixels. Returns the new track id per row (N,), the row each row's mask is merged
    into (N,; itself if kept) and the joins made, (kept id, joined id) in order."""
    p = _Pieces(frame, track, box, height, width, camera, ground, rules)
    min_shared = int(np.ceil(cfg.join_min_s * fps))
    ra, rb = _pairs_per_frame(frame, track)
    near = _touching(p.box[ra], p.box[rb])
    lo, hi = np.minimum(track[ra], track[rb]), np.maximum(track[ra], track[rb])
    span = int(track.max(initial=0)) + 1                 # one integer key per track pair
    keys, inv, n_shared = np.unique(lo * span + hi, return_inverse=True, return_counts=True)
    n_near = np.bincount(inv.ravel(), weights=near, minlength=len(keys))
    ok = (n_shared >= max(min_shared, 2)) & (n_near >= cfg.join_near * n_shared)
    cand = {(int(k // span), int(k % span)) for k in keys[ok]}
    length = {int(t): int(n) for t, n in zip(*np.unique(track[track >= 0], return_counts=True))}
    # a join changes only the two tracks' rows: pairs without them keep their score
    score = {pair: p.judge(*pair, cfg, min_shared) for pair in cand}
    joins = []
    while True:
        passed = [(g, a, b) for (a, b), g in score.items() if np.isfinite(g)]
        if not passed:
            break
        _, a, b = max(passed)
        if length[b] > length[a]:
            a, b = b, a
        p.join(a, b)
        length[a] += length.pop(b)
        joins.append((a, b))
        moved = {(min(x, y), max(x, y)) for x, y in ((a if u == b else u, a if v == b else v)
                                                     for u, v in score if a in (u, v) or b in (u, v))
                 if x != y}
        score = {pair: g for pair, g in score.items() if a not in pair and b not in pair}
        score.update({pair: p.judge(*pair, cfg, min_shared) for pair in moved})
    return p.track, p.into, joins


def join_fragments(src: str | Path, out: str | Path, camera: Camera, ground: GroundSurface,
                   rules: SizeRules, fps: float, cfg: TrackConfig | None = None,
                   log: Callable[[str], None] = print) -> list[tuple[int, int]]:
    """Join the fragment tracks of MOTS file ``src`` into ``out`` (may be ``src``; atomic):
    two streaming passes, boxes first. Returns the joins (kept id, joined id)."""
    cfg = cfg or TrackConfig()
    frames, tracks, boxes, size = [], [], [], None
    for f, t in iter_mots(src):
        frames.append(np.full(len(t), f, np.int64))
        tracks.append(t.track_id)
        b = mask_boxes(t.rles, t.height, t.width)
        boxes.append(np.c_[b[:, :2], b[:, :2] + b[:, 2:]])
        size = (t.height, t.width)
    if size is None or cfg.join_gain <= 0:
        if Path(src) != Path(out):
            write_mots(out, (t for _, t in iter_mots(src, check_rles=False)))
        return []
    frame, track, box = np.concatenate(frames), np.concatenate(tracks), np.concatenate(boxes)
    new_id, into, joins = find_joins(frame, track, box, *size, camera, ground, rules, cfg, fps)

    def rewritten() -> Iterator[MaskTable]:
        k = 0
        for _, t in iter_mots(src, check_rles=False):
            rows = np.arange(k, k + len(t))
            k += len(t)
            rles = list(t.rles)
            for r in np.flatnonzero(into[rows] != rows):
                keep = int(into[rows[r]]) - rows[0]
                rles[keep] = mask_util.merge(
                    [{"size": [t.height, t.width], "counts": rles[keep]},
                     {"size": [t.height, t.width], "counts": rles[r]}], intersect=False)["counts"]
            kept = into[rows] == rows
            yield MaskTable(t.frame, new_id[rows], t.class_id, t.height, t.width, rles,
                            t.score).take(kept)

    write_mots(out, rewritten())
    if joins:
        log(f"joined {len(joins)} fragment track(s) into the road user they belong to")
    return joins
