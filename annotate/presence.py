"""Where a road user is seen, so that pre-annotation and accepted estimates follow a run's track
only there: a track never spans frames in which no camera has its road user.

Presence comes from the masks: the frames in which some camera has a mask of the road user's
track id (the run's track ids are the masks' ones, as for a clicked mask). Short gaps (at most
``MAX_GAP`` frames: a missed detection, a brief occlusion) are bridged by the interpolation and
marked ``occluded``; longer ones become ``outside`` spans (no rows, never interpolated).

Road users already annotated are found by position, not by id: a run track whose estimates lie
within ``OVERLAP_RADIUS`` of an annotated track's poses in at least ``OVERLAP_SHARE`` of their
common frames (and ``OVERLAP_MIN`` frames) is that track's road user.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from seg2pose.io.poses import PoseTable

MAX_GAP = 3            # frames without a mask that a keyframed segment may bridge (occluded)
OVERLAP_RADIUS = 1.5   # metres: a centre-mode keyframe sits ~1 m from the run's estimate
OVERLAP_SHARE = 0.5    # of the common frames
OVERLAP_MIN = 3        # frames


def presence(mask_tables) -> dict[int, np.ndarray]:
    """Track id -> sorted unique frames (F,) in which any of ``mask_tables`` (MaskTables, one per
    camera) has a mask of it. Masks without a track id (< 0) are left out."""
    frames, ids = [], []
    for t in mask_tables:
        keep = t.track_id >= 0
        frames.append(np.asarray(t.frame)[keep])
        ids.append(np.asarray(t.track_id)[keep])
    if not frames:
        return {}
    f, i = np.concatenate(frames), np.concatenate(ids)
    out: dict[int, np.ndarray] = {}
    order = np.lexsort((f, i))
    f, i = f[order], i[order]
    cut = np.flatnonzero(np.diff(i)) + 1
    for fs, tid in zip(np.split(f, cut), np.split(i, cut)):
        if len(tid):
            out[int(tid[0])] = np.unique(fs)
    return out


def runs(frames: np.ndarray, max_gap: int = MAX_GAP) -> list[tuple[int, int]]:
    """Runs (first, last) of sorted frames (F,) in which consecutive frames are at most
    ``max_gap`` missing frames apart."""
    frames = np.asarray(frames, np.int64)
    if not len(frames):
        return []
    cut = np.flatnonzero(np.diff(frames) > max_gap + 1) + 1
    return [(int(g[0]), int(g[-1])) for g in np.split(frames, cut)]


@dataclass
class Plan:
    """Keyframes (frame, x, y, heading) and spans (first, last, kind) for one road user."""

    keyframes: list[tuple[int, float, float, float]] = field(default_factory=list)
    spans: list[tuple[int, int, str]] = field(default_factory=list)


def plan(est: PoseTable, seen: np.ndarray | None, every: int, max_gap: int = MAX_GAP) -> Plan:
    """Keyframes every ``every`` frames from a run track's estimates ``est`` (one track, sorted
    by frame), only in frames where it is ``seen`` (sorted frames; None: wherever the run has
    an estimate), with a keyframe at each end of every run of presence so that the
    interpolation covers exactly those runs; gaps inside a run are ``occluded`` spans, the
    frames between runs ``outside`` spans."""
    fr = np.asarray(est.frame, np.int64)
    use = np.ones(len(fr), bool) if seen is None else np.isin(fr, seen)
    idx = np.flatnonzero(use)
    out = Plan()
    if not len(idx):
        return out
    usable = fr[idx]
    parts = runs(usable, max_gap)
    for k, (a, b) in enumerate(parts):
        sel = idx[(usable >= a) & (usable <= b)]
        f = fr[sel]
        targets = np.unique(np.r_[np.arange(a, b + 1, int(every)), b])
        pick = np.unique(sel[np.clip(np.searchsorted(f, targets), 0, len(f) - 1)])
        out.keyframes += [(int(fr[i]), float(est.xyz[i, 0]), float(est.xyz[i, 1]),
                           float(est.heading[i])) for i in pick]
        missing = np.setdiff1d(np.arange(a, b + 1), f)
        out.spans += [(g0, g1, "occluded") for g0, g1 in runs(missing, 0)]
        if k + 1 < len(parts):
            out.spans.append((b + 1, parts[k + 1][0] - 1, "outside"))
    out.spans.sort()
    return out


def annotated_run_tracks(run: PoseTable, annotated: PoseTable) -> set[int]:
    """Run track ids whose estimates overlap an annotated track's poses (module docstring)."""
    if not len(run) or not len(annotated):
        return set()
    ann = annotated.take(np.argsort(annotated.frame, kind="stable"))
    lo = np.searchsorted(ann.frame, run.frame, side="left")
    hi = np.searchsorted(ann.frame, run.frame, side="right")
    n = hi - lo
    i = np.repeat(np.arange(len(run)), n)
    j = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n) + np.repeat(lo, n)
    if not len(i):
        return set()
    near = np.linalg.norm(run.xyz[i, :2] - ann.xyz[j, :2], axis=1) < OVERLAP_RADIUS
    pairs = np.stack([run.track_id[i], ann.track_id[j]], 1)
    keys, inv, common = np.unique(pairs, axis=0, return_inverse=True, return_counts=True)
    close = np.bincount(inv.reshape(-1), near, len(keys))
    hit = (close >= OVERLAP_MIN) & (close >= OVERLAP_SHARE * common)
    return {int(k) for k in keys[hit, 0]}
