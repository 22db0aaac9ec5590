"""Tracking-metric sequences (``tracking_metrics.Sequence``) from masks and from world tracks.

- **Masks** (MOTS txt, TrackEval's MOTS format): similarity = mask IoU (pycocotools on the
  RLEs, as TrackEval's MOTS Challenge reader). Truth masks smaller than ``min_area`` pixels are
  ignore regions, as MOTChallenge's distractors: an estimate matched to one (IoU >= 0.5, in the
  frame's one-to-one matching) is neither TP nor FP, and the small truth mask is no FN.
- **World tracks** (poses.csv): similarity = max(0, 1 - d / d0) with d the ground-plane
  distance between the positions, metres, and ``d0`` = 2 m by default; the truth is the rows in
  view of the run's cameras (``in_view``). CLEAR and IDF1 match at
  similarity >= 0.5, i.e. within d0 / 2 = 1 m; HOTA averages its alphas 0.05..0.95, i.e.
  distance thresholds 1.9 m down to 0.1 m, and LocA is 1 - mean distance / d0 of the matches.
  (The distance-thresholded matching of nuScenes and of CLEAR MOT's 3D use, as a similarity.)

Both are class-agnostic: a pedestrian estimated as a car still counts as found, as in
``eval/mask_eval.py``. Track id -1 ("no track") gives every such detection an id of its own.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

from seg2pose.core.errors import InputError
from seg2pose.eval.tracking_metrics import Sequence, summary
from seg2pose.io.mots import MaskTable, iter_mots
from seg2pose.io.poses import PoseTable
from seg2pose.structures.masks import iou, rle_stats

WORLD_D0 = 2.0     # metres: similarity 0 at this distance, 0.5 (a CLEAR / IDF1 match) at half


class _Ids:
    """Dense ids 0..n-1 in order of first appearance; -1 gets a new id each time."""

    def __init__(self) -> None:
        self.map: dict[int, int] = {}
        self.n = 0

    def __call__(self, ids: np.ndarray) -> np.ndarray:
        out = np.empty(len(ids), np.int64)
        for k, i in enumerate(ids.tolist()):
            if i < 0:
                out[k] = self.n
                self.n += 1
                continue
            j = self.map.get(i)
            if j is None:
                j = self.map[i] = self.n
                self.n += 1
            out[k] = j
        return out


def _dense(ids: np.ndarray) -> np.ndarray:
    """Dense ids 0..n-1 of a whole column at once (sorted order; each -1 a new id)."""
    out = np.empty(len(ids), np.int64)
    known = ids >= 0
    uniq, inv = np.unique(ids[known], return_inverse=True)
    out[known] = inv
    out[~known] = len(uniq) + np.arange(int((~known).sum()))
    return out


def _paired(truth: Iterable[tuple[int, MaskTable]], est: Iterable[tuple[int, MaskTable]]
            ) -> Iterator[tuple[int, MaskTable | None, MaskTable | None]]:
    """(frame, truth, estimate) over the frames of either frame-ordered stream."""
    ti, ei = iter(truth), iter(est)
    t, e = next(ti, None), next(ei, None)
    while t is not None or e is not None:
        f = min(x[0] for x in (t, e) if x is not None)
        yield f, (t[1] if t is not None and t[0] == f else None), (e[1] if e is not None and e[0] == f else None)
        if t is not None and t[0] == f:
            t = next(ti, None)
        if e is not None and e[0] == f:
            e = next(ei, None)


def sequence_from_masks(truth: Iterable[tuple[int, MaskTable]], est: Iterable[tuple[int, MaskTable]],
                        min_area: int = 0) -> Sequence:
    """A Sequence of one camera from two frame-ordered MOTS streams (``io.mots.iter_mots``);
    truth masks under ``min_area`` pixels are ignore regions (module docstring)."""
    gid, tid = _Ids(), _Ids()
    gts, trs, sims, frames = [], [], [], []
    for f, tt, ee in _paired(truth, est):
        g_raw = tt.track_id if tt is not None else np.zeros(0, np.int64)
        t_raw = ee.track_id if ee is not None else np.zeros(0, np.int64)
        if tt is not None and ee is not None:
            if (tt.height, tt.width) != (ee.height, ee.width):
                raise InputError(f"frame {f}: estimated masks are {ee.width}x{ee.height} pixels, the truth's "
                                 f"{tt.width}x{tt.height}")
            s = iou(tt.rles, ee.rles, tt.height, tt.width)
        else:
            s = np.zeros((len(g_raw), len(t_raw)))
        if min_area > 0 and tt is not None and len(tt):
            area, _, _ = rle_stats(tt.rles, tt.height, tt.width)
            small = area < min_area
            if small.any():
                drop_est = np.zeros(len(t_raw), bool)
                if s.size:   # MOTChallenge's distractor rule: a one-to-one match at IoU >= 0.5
                    score = np.where(s >= 0.5 - np.finfo(float).eps, s, 0.0)
                    r, c = linear_sum_assignment(-score)
                    hit = score[r, c] > np.finfo(float).eps
                    drop_est[c[hit & small[r]]] = True
                g_raw, t_raw = g_raw[~small], t_raw[~drop_est]
                s = s[~small][:, ~drop_est]
        gts.append(gid(g_raw))
        trs.append(tid(t_raw))
        sims.append(np.asarray(s, float))
        frames.append(f)
    return Sequence(gts, trs, sims, gid.n, tid.n, np.asarray(frames, np.int64))


def in_view(poses: PoseTable, cameras: Iterable) -> PoseTable:
    """The rows of ``poses`` whose position (the ground point, world metres) projects in front
    of and inside the image of at least one of ``cameras`` (``geometry.camera.Camera``): the
    truth a configuration's cameras can see, occlusion aside (a mono run is not charged for
    road users outside its view)."""
    keep = np.zeros(len(poses.frame), bool)
    for cam in cameras:
        with np.errstate(invalid="ignore", over="ignore"):   # points at depth 0: NaN pixels, not kept
            uv, _, front = cam.project_points(poses.xyz)
            keep |= front & cam.in_image(uv)
    return poses.take(np.flatnonzero(keep))


def sequence_from_poses(est: PoseTable, gt: PoseTable, d0: float = WORLD_D0) -> Sequence:
    """A Sequence of world tracks: per frame, similarity max(0, 1 - d / d0) of every truth
    and estimated position, d the ground-plane distance in metres (module docstring)."""
    if not d0 > 0:
        raise ValueError(f"d0 must be > 0 metres, got {d0}")
    # a row without a position (NaN) is no detection
    est = est.take(np.flatnonzero(np.isfinite(est.xyz[:, :2]).all(axis=1)))
    gt = gt.take(np.flatnonzero(np.isfinite(gt.xyz[:, :2]).all(axis=1)))
    frames = np.union1d(gt.frame, est.frame)
    og, oe = np.argsort(gt.frame, kind="stable"), np.argsort(est.frame, kind="stable")
    gf, ef = gt.frame[og], est.frame[oe]
    g_lo, g_hi = np.searchsorted(gf, frames, "left"), np.searchsorted(gf, frames, "right")
    e_lo, e_hi = np.searchsorted(ef, frames, "left"), np.searchsorted(ef, frames, "right")
    gxy, exy = gt.xyz[og, :2], est.xyz[oe, :2]
    g_all, e_all = _dense(gt.track_id[og]), _dense(est.track_id[oe])
    gts, trs, sims = [], [], []
    for a, b, c, d in zip(g_lo, g_hi, e_lo, e_hi):
        dist = np.linalg.norm(gxy[a:b, None, :] - exy[None, c:d, :], axis=2)
        gts.append(g_all[a:b])
        trs.append(e_all[c:d])
        sims.append(np.maximum(0.0, 1.0 - dist / d0))
    n_g = int(g_all.max()) + 1 if len(g_all) else 0
    n_e = int(e_all.max()) + 1 if len(e_all) else 0
    return Sequence(gts, trs, sims, n_g, n_e, frames.astype(np.int64))


def mots_summary(truth: str | Path, est: str | Path, frame_range: tuple[int, int] | None = None,
                 min_area: int = 0) -> dict:
    """HOTA, IDF1, MOTSA... (``tracking_metrics.summary``, kind "masks") of the MOTS file
    ``est`` against the truth MOTS file ``truth`` of the same camera, over ``frame_range``
    (inclusive; None: all frames); truth masks under ``min_area`` pixels are ignore regions."""
    seq = sequence_from_masks(iter_mots(truth, frame_range=frame_range),
                              iter_mots(est, frame_range=frame_range), min_area=min_area)
    return {"similarity": "mask IoU", "ignored_below_px": int(min_area), **summary(seq, kind="masks")}
