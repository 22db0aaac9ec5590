"""Splitting merged masks for the tracker (``seg2pose.video.track``): where road users
overlap in the image, background subtraction gives one blob for several of them. A mask that
holds at least ``split_min`` of the predicted masks of two or more established tracks (each
track's shape, its last whole mask carried along by its pixel motion) is split between those
tracks: a pixel inside several predicted masks goes to the nearest road user (the one
reaching lowest in the image), a pixel outside all of them to the nearest predicted mask.

Cheap first: boxes, then exact upper bounds of each share from box overlaps, and only then
the masks' runs decoded (docs/BENCHMARKS.md, the tracker's speed)."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
from pycocotools import mask as mask_util

from seg2pose.structures.masks import decode_counts
from seg2pose.structures.rle_runs import box_of_runs, labels_to_rles, shift_counts, shift_rles

SPLIT_MIN_AGE = 3     # masks a track needs before a blob is split for it (not a fragment)


class BlobSplitting:
    """The splitting of ``Tracker`` (a mixin): ``_split_merged`` per frame before the
    assignment, ``_predicted`` for a track whose mask was a part of a split blob. Needs the
    tracker's ``cfg``, ``size``, ``live``, ``length``, ``positions``, and sets its ``_pred``
    (predicted masks by track row) and ``_lazy`` (rows with a predicted mask: their shift)."""

    if TYPE_CHECKING:  # Tracker's (seg2pose.video.track: naming its types would be an import cycle)
        cfg: Any                # TrackConfig
        live: Any               # LiveTracks
        size: list[int]         # [height, width] pixels
        length: list[int]
        positions: Callable[[list[bytes]], np.ndarray] | None
        _pred: dict[int, bytes]
        _lazy: dict[int, int]

    def _split_merged(self, frame: int, rles: list[bytes], xy: np.ndarray, bd: np.ndarray,
                      ad: np.ndarray) -> tuple[list[bytes], np.ndarray, np.ndarray]:
        """Masks holding >= split_min of two or more established tracks' predicted masks,
        split between those tracks. Returns masks, positions (NaN for split parts, filled in
        by ``positions`` when set) and, per output mask, the index of the input mask it came
        from."""
        src = np.arange(len(rles))
        recent = np.flatnonzero((frame - self.live.last == 1)
                                & (np.asarray(self.length, np.int64)[self.live.ids] >= SPLIT_MIN_AGE)
                                if len(self.live.ids) else np.zeros(0, bool))
        if self.cfg.split_min <= 0 or len(recent) < 2 or not rles:
            return rles, xy, src
        # each track's shape moved on by its pixel motion: where the road user is expected
        h = self.size[0]
        shift = np.round(np.nan_to_num(self.live.pxvel[recent])).astype(np.int64)
        # boxes first (cheap): only tracks whose predicted box meets a mask's box that meets
        # two or more of them can take part
        bt = self.live.shape_box[recent]
        bt[:, :2] += shift
        meet = ((bt[:, None, 0] < bd[None, :, 0] + bd[None, :, 2])
                & (bd[None, :, 0] < bt[:, None, 0] + bt[:, None, 2])
                & (bt[:, None, 1] < bd[None, :, 1] + bd[None, :, 3])
                & (bd[None, :, 1] < bt[:, None, 1] + bt[:, None, 3]))
        cand = meet[:, meet.sum(axis=0) >= 2].any(axis=1)
        if cand.sum() < 2:
            return rles, xy, src
        recent, shift, bt = recent[cand], shift[cand], bt[cand]
        # exact upper bounds before any decoding: a track's share inside a mask is at most
        # the overlap of their boxes over the track's predicted area (exact where the shape
        # moves without leaving the image: no pixel wraps into the next column or falls off)
        at0 = self.live.shape_area[recent]
        ow = np.minimum(bt[:, None, 0] + bt[:, None, 2], bd[None, :, 0] + bd[None, :, 2]) \
            - np.maximum(bt[:, None, 0], bd[None, :, 0])
        oh = np.minimum(bt[:, None, 1] + bt[:, None, 3], bd[None, :, 1] + bd[None, :, 3]) \
            - np.maximum(bt[:, None, 1], bd[None, :, 1])
        inner = ((bt[:, 0] >= 0) & (bt[:, 0] + bt[:, 2] <= self.size[1])
                 & (bt[:, 1] >= 0) & (bt[:, 1] + bt[:, 3] <= h))
        bound = np.minimum(np.maximum(ow, 0) * np.maximum(oh, 0), ad[None, :]) / np.maximum(at0, 1.0)[:, None]
        may = ~inner[:, None] | (bound >= self.cfg.split_min - 1e-9)          # (T, D)
        need = may[:, may.sum(axis=0) >= 2].any(axis=1)
        if not need.any():
            return rles, xy, src
        # every track of ``recent`` has a predicted mask (a part matched to it takes that
        # mask as its shape); only those that may be inside a merged mask are moved now
        lazy = {int(i): int(dx) * h + int(dy) for i, (dx, dy) in zip(recent, shift)}
        sel = recent[need]
        # masks that none of them may be inside cannot hold a share >= split_min: leaving them
        # out changes no share's row maximum that matters
        cols = np.flatnonzero(may[need].any(axis=0))
        # the runs of their shapes and of those masks, decoded at once (reused by _split)
        vals, off = decode_counts([self.live.shape[i] for i in sel] + [rles[k] for k in cols])
        runs = [vals[off[j]:off[j + 1]] for j in range(len(off) - 1)]
        blob_runs = dict(zip(cols.tolist(), runs[len(sel):]))
        moved, pred_runs = [], {}
        for j, i in enumerate(sel.tolist()):
            k = lazy[i]
            pred_runs[i] = shift_counts(runs[j], k, h * self.size[1]) if k else runs[j]
            moved.append(mask_util.frPyObjects({"size": self.size, "counts": pred_runs[i].tolist()},
                                               *self.size)["counts"] if k else self.live.shape[i])
        pred = dict(zip(sel.tolist(), moved))
        objs_t = [{"size": self.size, "counts": r} for r in moved]
        objs_d = [{"size": self.size, "counts": rles[k]} for k in cols]
        iou = np.asarray(mask_util.iou(objs_t, objs_d, [0] * len(cols)), float).reshape(len(sel), len(cols))
        at = mask_util.area(objs_t).astype(np.float64)
        frac = iou * (at[:, None] + ad[None, cols]) / (1.0 + iou) / np.maximum(at[:, None], 1.0)
        inside = np.zeros((len(sel), len(rles)), bool)
        inside[:, cols] = (frac >= self.cfg.split_min) & (frac == frac.max(axis=1, keepdims=True))
        merged = set(np.flatnonzero(inside.sum(axis=0) >= 2).tolist())
        if not merged:
            return rles, xy, src
        recent = sel
        out_r, out_src, split_rows = [], [], []
        for d in range(len(rles)):
            if d not in merged:
                out_r.append(rles[d])
                out_src.append(d)
                continue
            members = recent[inside[:, d]]
            for part in self._split(rles[d], [pred[int(i)] for i in members],
                                    [blob_runs[d], *(pred_runs[int(i)] for i in members)]):
                split_rows.append(len(out_r))
                out_r.append(part)
                out_src.append(d)
        self._pred, self._lazy = pred, lazy
        out_xy = xy[out_src].reshape(-1, 2)
        out_xy[split_rows] = np.nan
        if self.positions is not None and split_rows:
            out_xy[split_rows] = self.positions([out_r[i] for i in split_rows])
        return out_r, out_xy, np.array(out_src, np.int64)

    def _predicted(self, r: int) -> bytes:
        """Track row ``r``'s predicted mask this frame (its shape moved on), made on demand."""
        if r not in self._pred:
            self._pred[r] = shift_rles([self.live.shape[r]], [self._lazy[r]], self.size)[0]
        return self._pred[r]

    def _split(self, blob: bytes, predicted: list[bytes], runs: list[np.ndarray],
               min_px: int = 20) -> list[bytes]:
        """The blob's pixels shared out between road users with the ``predicted`` masks (their
        shapes moved on by their motion): a pixel inside predicted masks goes to the nearest
        of those road users (the lowest mask bottom in the image: the camera looks down on the
        ground, so lower is nearer and hides the others); a pixel outside all of them to the
        nearest predicted mask (distance transform). Works in the blob's box; parts under
        ``min_px`` pixels are dropped. ``runs``: the run lengths of the blob and the predicted
        masks (uncompressed RLE counts)."""
        import cv2

        h, w = self.size
        x0, y0, bw, bh = (int(v) for v in mask_util.toBbox({"size": self.size, "counts": blob}))
        strips = box_of_runs(runs, h, x0, x0 + bw, y0, y0 + bh)
        m = strips[0]
        covered = strips[1:]
        # the predicted mask's lowest row, over the whole mask (it may reach past the blob)
        pb = mask_util.toBbox([{"size": self.size, "counts": r} for r in predicted]).reshape(-1, 4)
        bottom = np.where(pb[:, 3] > 0, pb[:, 1] + pb[:, 3], -1.0)
        held = covered.any(axis=0)
        if (m & ~held).any():      # pixels outside every predicted mask: the nearest one
            # the first of the nearest (as argmin): a later one must be strictly nearer
            best = cv2.distanceTransform((~covered[0]).astype(np.uint8), cv2.DIST_L2, 3)
            owner = np.zeros((bh, bw), np.int64)
            for k in range(1, len(covered)):
                dk = cv2.distanceTransform((~covered[k]).astype(np.uint8), cv2.DIST_L2, 3)
                nearer = dk < best
                owner[nearer] = k
                best = np.where(nearer, dk, best)
        else:
            owner = np.zeros((bh, bw), np.int64)
        # among the predicted masks that hold a pixel, the nearest road user takes it: paint
        # them from the farthest to the nearest (equal bottoms: the first track last)
        for k in sorted(range(len(predicted)), key=lambda k: (bottom[k], -k)):
            owner[covered[k]] = k
        lab = np.where(m, owner + 1, 0)
        counts = np.bincount(lab.ravel(), minlength=len(predicted) + 1)
        keep = np.flatnonzero(counts[1:] >= min_px) + 1
        return labels_to_rles(lab, keep, x0=x0, width=w, y0=y0, height=h)  # all parts in one pass
