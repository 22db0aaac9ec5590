"""Per-frame poses of annotated tracks: ``track_poses`` interpolates one track into a PoseTable
with sizes and the ``source`` column.

source (provenance, one of ``SOURCES``):

- a keyframe: ``keyframe`` (placed or corrected by the annotator), ``estimate-accepted`` (a
  Seg2Pose estimate the annotator accepted one by one, flag ``accepted``, or inside a reviewed
  span) or ``estimate-unchecked`` (pre-annotation, estimates taken every N frames);
- between keyframes: ``reviewed`` inside a reviewed span, else ``estimate-unchecked`` where
  either neighbouring keyframe is an unchecked estimate (nobody looked at either end), else
  ``interpolated``;
- ``occluded`` inside an occluded span, whatever the above (training skips these).

Frames inside ``outside`` spans, and the frames of a track beyond the keyframes on either side
of an outside span, have no rows. ``UNCHECKED`` rows are what an export refuses unless asked.
"""

from __future__ import annotations

import numpy as np

from annotate.interpolate import interpolate
from annotate.model import Track
from seg2pose.geometry.ground import GroundSurface
from seg2pose.io.poses import SOURCES, PoseTable

__all__ = ["SOURCES", "UNCHECKED", "segments", "track_poses", "empty", "source_counts"]

UNCHECKED = "estimate-unchecked"


def _keyframe_sources(track: Track, kf: np.ndarray) -> np.ndarray:
    """Provenance (K,) of the keyframes at frames kf (K,)."""
    out = np.empty(len(kf), object)
    for i, f in enumerate(kf):
        flags = track.keyframes[int(f)].flags
        if "estimate" not in flags:
            out[i] = "keyframe"
        elif "accepted" in flags or track.is_reviewed(int(f)):
            out[i] = "estimate-accepted"
        else:
            out[i] = UNCHECKED
    return out


def _sources(track: Track, kf: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Provenance (F,) of the frames q (F,) of one segment with keyframes kf (K,), K >= 1."""
    ks = _keyframe_sources(track, kf)
    unchecked = ks == UNCHECKED
    # the keyframes on either side of each frame (the same one at a keyframe)
    right = np.clip(np.searchsorted(kf, q, side="left"), 0, len(kf) - 1)
    left = np.clip(np.searchsorted(kf, q, side="right") - 1, 0, len(kf) - 1)
    source = np.where(unchecked[left] | unchecked[right], UNCHECKED, "interpolated").astype(object)
    for a, b in track.reviewed:
        source[(q >= a) & (q <= b)] = "reviewed"
    at = np.searchsorted(q, kf)
    ok = (at < len(q)) & (q[np.minimum(at, len(q) - 1)] == kf)
    source[at[ok]] = ks[ok]
    for a, b, k in track.spans:
        if k == "occluded":
            source[(q >= a) & (q <= b)] = "occluded"
    return source


def source_counts(table: PoseTable) -> dict[int, dict[str, int]]:
    """Rows per provenance per track: {track id: {source: rows}} (sources without rows left
    out)."""
    out: dict[int, dict[str, int]] = {}
    if not len(table) or table.source is None:
        return out
    keys, n = np.unique(np.stack([table.track_id.astype(object), table.source], 1).astype(str),
                        axis=0, return_counts=True)
    for (t, src), c in zip(keys, n):
        out.setdefault(int(t), {})[str(src)] = int(c)
    return out


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
        source = _sources(track, kf, q)
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
