"""Review aids: where to look next. Suggested keyframes (where the interpolation and the
Seg2Pose estimate, or the masks' normal positions, disagree), keyframe density per track, and a
report of gaps and implausible speeds or accelerations per class.

    from annotate.review import suggest_keyframes, keyframe_density, plausibility_report
    for s in suggest_keyframes(project, threshold=0.5)[:10]:
        print(s.track, s.frame, f"{s.distance:.2f} m")
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from annotate.model import EditError
from annotate.table import segments
from seg2pose.io.poses import PoseTable

# Plausible limits per class: speed m/s, acceleration m/s^2 (a sprinting pedestrian, a fast
# urban cyclist, a car braking hard). Classes not listed use DEFAULT_LIMITS.
LIMITS = {"pedestrian": (4.0, 4.0), "bicyclist": (12.0, 5.0), "car": (30.0, 9.0),
          "truck": (25.0, 6.0), "bus": (25.0, 6.0)}
DEFAULT_LIMITS = (40.0, 10.0)
GATE = 3.0  # metres: a reference point farther than this from a track never speaks for it


@dataclass(frozen=True)
class Suggestion:
    """A frame worth a keyframe: the interpolation is ``distance`` metres from the reference
    (``source``: "estimate" of a run or "normal" position of the masks) at ``reference`` x, y."""

    track: int
    frame: int
    distance: float
    reference: tuple[float, float]
    source: str


@dataclass(frozen=True)
class Issue:
    """Something implausible in a track: ``kind`` "gap", "speed" or "acceleration" over frames
    first..last, the worst ``value`` against ``limit`` (units in ``message``)."""

    track: int
    kind: str
    first: int
    last: int
    value: float
    limit: float
    message: str


def _reference(project, source: str) -> PoseTable:
    if source == "estimate":
        return project.run.table
    if source == "normal":
        return project.masks.fused_normal_positions()
    raise EditError(f"unknown reference {source!r}; use estimate (a run) or normal (the masks)")


def _pairs(a: PoseTable, b: PoseTable) -> tuple[np.ndarray, np.ndarray]:
    """Row pairs (i of a, j of b) in the same frame and class. b must be sorted by frame."""
    lo = np.searchsorted(b.frame, a.frame, side="left")
    hi = np.searchsorted(b.frame, a.frame, side="right")
    n = hi - lo
    i = np.repeat(np.arange(len(a)), n)
    j = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n) + np.repeat(lo, n)
    same = a.cls[i] == b.cls[j]
    return i[same], j[same]


def _matched(project, ann: PoseTable, ref: PoseTable, source: str
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Row pairs (i of ann, j of ref, distance metres) of each track with the reference road
    user that speaks for it: its run track (pre-annotated or made from a mask), else the one
    within GATE metres of it in the most frames. ref sorted by frame."""
    i, j = _pairs(ann, ref)
    d = np.linalg.norm(ann.xyz[i, :2] - ref.xyz[j, :2], axis=1)
    near = d < GATE
    match = {}
    for t in np.unique(ann.track_id):
        meta = project.track(int(t)).meta
        if source == "estimate" and "run_track" in meta:
            match[int(t)] = int(meta["run_track"])
            continue
        sel = near & (ann.track_id[i] == t)
        if sel.any():
            ids, counts = np.unique(ref.track_id[j[sel]], return_counts=True)
            match[int(t)] = int(ids[np.argmax(counts)])
    mine = np.array([match.get(int(t), -(10 ** 9)) for t in ann.track_id[i]]) == ref.track_id[j]
    return i[mine], j[mine], d[mine]


def reference(project, source: str = "estimate") -> PoseTable:
    """The reference poses (a run's estimates, or the masks' fused normal positions) sorted
    by frame, for ``distance_series`` (worth keeping: the normal positions take a while)."""
    ref = _reference(project, source)
    return ref.take(np.argsort(ref.frame, kind="stable"))


def distance_series(project, track_id: int, source: str = "estimate",
                    ref: PoseTable | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(frames (F,), distance (F,) metres) of one track over its span: how far its pose
    (keyframe or interpolation) is from the reference road user that speaks for it (see
    ``suggest_keyframes``); NaN where the reference has no pose. ref: ``reference(project,
    source)`` if already at hand."""
    ann = project.track_poses(track_id)
    out = np.full(len(ann), np.nan)
    if len(ann):
        ref = reference(project, source) if ref is None else ref
        if len(ref):
            i, _, d = _matched(project, ann, ref, source)
            out[i] = d
    return np.asarray(ann.frame, np.int64), out


def suggest_keyframes(project, source: str = "estimate", threshold: float = 0.5,
                      tracks=None, min_gap: int = 10, top: int | None = 100) -> list[Suggestion]:
    """Frames where a track's interpolation and the reference disagree by more than
    ``threshold`` metres, strongest first; at most one per ``min_gap`` frames of a track, none
    on keyframes or occluded frames.

    Each track is matched to the reference road user (a run's track, or a mask track) that is
    within GATE metres of it in the most frames (pre-annotated tracks keep their run track)."""
    ref = _reference(project, source)
    ref = ref.take(np.argsort(ref.frame, kind="stable"))
    ann = project.poses(tracks)
    ann = ann.take(ann.source == "interpolated")
    if not len(ann) or not len(ref):
        return []
    i, j, d = _matched(project, ann, ref, source)
    out = []
    for t in np.unique(ann.track_id[i]):
        sel = np.flatnonzero((ann.track_id[i] == t) & (d > threshold))
        taken: list[int] = []
        for k in sel[np.argsort(-d[sel], kind="stable")]:
            f = int(ann.frame[i[k]])
            if all(abs(f - g) >= min_gap for g in taken):
                taken.append(f)
                out.append(Suggestion(int(t), f, float(d[k]),
                                      (float(ref.xyz[j[k], 0]), float(ref.xyz[j[k], 1])), source))
    out.sort(key=lambda s: -s.distance)
    return out[:top] if top is not None else out


def keyframe_density(project) -> list[dict]:
    """Per track: keyframes, frames spanned, keyframes per 100 frames, the longest stretch
    between keyframes (frames) and the share of unchecked (``estimate``) keyframes."""
    rows = []
    for t in sorted(project.tracks):
        tr = project.track(t)
        f = np.array(tr.frames)
        span = int(f[-1] - f[0] + 1) if len(f) else 0
        rows.append({"track": t, "class": tr.cls, "keyframes": len(f), "frames": span,
                     "per_100_frames": 100.0 * len(f) / span if span else 0.0,
                     "longest_gap": int(np.diff(f).max()) if len(f) > 1 else 0,
                     "unchecked": float(np.mean(["estimate" in k.flags
                                                 for k in tr.keyframes.values()])) if len(f) else 0.0})
    return rows


def _runs(frames: np.ndarray, bad: np.ndarray) -> list[tuple[int, int, np.ndarray]]:
    """Consecutive runs of flagged frames: (first, last, index array)."""
    idx = np.flatnonzero(bad)
    if not len(idx):
        return []
    cut = np.flatnonzero(np.diff(frames[idx]) != 1) + 1
    return [(int(frames[g[0]]), int(frames[g[-1]]), g) for g in np.split(idx, cut)]


def plausibility_report(project, limits: dict | None = None) -> list[Issue]:
    """Gaps (frames inside a track without a pose that no outside span explains) and runs of
    frames whose speed or acceleration exceeds the class's limits (``LIMITS``, overridable
    per class as {class: (speed m/s, acceleration m/s^2)})."""
    lim = {**LIMITS, **(limits or {})}
    fps = float(project.scene.fps)
    issues = []
    for t in sorted(project.tracks):
        tr = project.track(t)
        segs = segments(tr)
        outside = [(a, b) for a, b, k in tr.spans if k == "outside"]
        for (_, _, l0), (_, f1, _) in zip(segs[:-1], segs[1:]):
            fr = np.arange(l0 + 1, f1)
            free = np.ones(len(fr), bool)
            for a, b in outside:
                free &= (fr < a) | (fr > b)
            for g0, g1, _ in _runs(fr, free):
                issues.append(Issue(t, "gap", g0, g1, float(g1 - g0 + 1), 0.0,
                                    f"track {t}: frames {g0}..{g1} have no pose (no keyframe "
                                    "next to the outside span)"))
        p = project.track_poses(t)
        if len(p) < 3:
            continue
        vmax, amax = lim.get(tr.cls, DEFAULT_LIMITS)
        xy, f = p.xyz[:, :2], p.frame
        step = np.diff(f) == 1
        v = np.full(len(f), 0.0)
        v[1:] = np.where(step, np.linalg.norm(np.diff(xy, axis=0), axis=1) * fps, 0.0)
        a = np.zeros(len(f))
        both = step[1:] & step[:-1]
        acc = np.linalg.norm(xy[2:] - 2 * xy[1:-1] + xy[:-2], axis=1) * fps * fps
        a[1:-1] = np.where(both, acc, 0.0)
        for kind, val, top, unit in (("speed", v, vmax, "m/s"), ("acceleration", a, amax, "m/s^2")):
            for g0, g1, g in _runs(f, val > top):
                worst = float(val[g].max())
                issues.append(Issue(t, kind, g0, g1, worst, top,
                                    f"track {t} ({tr.cls}): {kind} up to {worst:.1f} {unit} in "
                                    f"frames {g0}..{g1} (plausible: <= {top:g} {unit})"))
    return issues
