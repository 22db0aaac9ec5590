"""Per-frame poses of annotated tracks: ``track_poses`` interpolates one track into a PoseTable
with sizes and the ``source`` column.

source: ``keyframe`` (placed by the annotator), ``interpolated``, or ``occluded`` (inside an
occluded span, keyframe or not: training skips these). Frames inside ``outside`` spans, and the
frames of a track beyond the keyframes on either side of an outside span, have no rows.
"""

from __future__ import annotations

import numpy as np

from annotate.interpolate import interpolate
from annotate.model import Track
from seg2pose.geometry.ground import GroundSurface
from seg2pose.io.poses import SOURCES, PoseTable

__all__ = ["SOURCES", "segments", "track_poses", "empty"]


def empty() -> PoseTable:
    """A table without rows, with the size and source columns."""
    return PoseTable(np.zeros(0), np.zeros(0), np.zeros(0, object), np.zeros((0, 3)), np.zeros(0),
                     np.zeros((0, 3)), np.zeros(0, object))


def segments(track: Track) -> list[tuple[np.ndarray, int, int]]:
    """The track's interpolation segments: (keyframe frames (K,), first, last) between outside
    spans; keyframes inside outside spans are ignored."""
    frames = np.array(track.frames, dtype=np.int64)
    if not len(frames):
        return []
    outside = [(a, b) for a, b, k in track.spans if k == "outside"]
    if not outside:
        return [(frames, int(frames[0]), int(frames[-1]))]
    starts = np.array([a for a, _ in outside])
    inside = np.zeros(len(frames), bool)
    for a, b in outside:
        inside |= (frames >= a) & (frames <= b)
    group = np.searchsorted(starts, frames, side="right")
    out = []
    for g in np.unique(group[~inside]):
        kf = frames[~inside & (group == g)]
        out.append((kf, int(kf[0]), int(kf[-1])))
    return out


def track_poses(track: Track, ground: GroundSurface, method: str,
                frame_range: tuple[int, int] | None = None,
                previous: PoseTable | None = None) -> PoseTable:
    """Every frame's pose of one track: interpolated with ``method`` between its keyframes,
    z from the ground surface (eq. 1), size from the track, ``source`` per row.

    previous: this track's earlier table; z is reused wherever the frame and x, y are exactly
    the same (an edit moves only the frames near the changed keyframe, and eq. (1) is the
    costly part)."""
    parts = []
    for kf, first, last in segments(track):
        lo, hi = first, last
        if frame_range is not None:
            lo, hi = max(lo, frame_range[0]), min(hi, frame_range[1])
        if hi < lo:
            continue
        q = np.arange(lo, hi + 1, dtype=np.int64)
        rows = [track.keyframes[int(f)] for f in kf]
        xy_k = np.array([(r.x, r.y) for r in rows], dtype=np.float64).reshape(-1, 2)
        hd_k = np.array([r.heading for r in rows], dtype=np.float64)
        xy, hd = interpolate(kf, xy_k, hd_k, q, method)
        is_kf = np.zeros(len(q), bool)
        is_kf[kf[(kf >= lo) & (kf <= hi)] - lo] = True
        source = np.where(is_kf, "keyframe", "interpolated").astype(object)
        for a, b, k in track.spans:
            if k == "occluded":
                source[(q >= a) & (q <= b)] = "occluded"
        parts.append((q, xy, hd, source))
    if not parts:
        return empty()
    q = np.concatenate([p[0] for p in parts])
    xy = np.concatenate([p[1] for p in parts])
    n = len(q)
    z = _heights(ground, q, xy, previous)
    return PoseTable(q, np.full(n, track.id), np.full(n, track.cls, dtype=object),
                           np.column_stack([xy, z]), np.concatenate([p[2] for p in parts]),
                           np.tile(np.asarray(track.size, float), (n, 1)),
                           np.concatenate([p[3] for p in parts]))


def _heights(ground: GroundSurface, q: np.ndarray, xy: np.ndarray, previous: PoseTable | None
             ) -> np.ndarray:
    """Ground heights (N,) at xy (N, 2) for frames q (N,), reusing ``previous`` rows where frame
    and position are bit-identical."""
    if previous is None or not len(previous):
        return ground.height(xy)
    k = np.clip(np.searchsorted(previous.frame, q), 0, len(previous) - 1)
    same = (previous.frame[k] == q) & (previous.xyz[k, 0] == xy[:, 0]) & \
        (previous.xyz[k, 1] == xy[:, 1])
    z = np.empty(len(q))
    z[same] = previous.xyz[k[same], 2]
    if not same.all():
        z[~same] = ground.height(xy[~same])
    return z
