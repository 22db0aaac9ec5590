"""Per-frame poses of annotated tracks: ``AnnotationTable`` (PoseTable's columns + ``source``)
and ``track_poses``, which interpolates one track.

source: ``keyframe`` (placed by the annotator), ``interpolated``, or ``occluded`` (inside an
occluded span, keyframe or not: training skips these). Frames inside ``outside`` spans, and the
frames of a track beyond the keyframes on either side of an outside span, have no rows.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import numpy as np

from annotate.interpolate import interpolate
from annotate.model import Track
from seg2pose.ground import GroundSurface
from seg2pose.io.poses import PoseTable

SOURCES = ("keyframe", "interpolated", "occluded")


@dataclass
class AnnotationTable:
    """Columns of N annotated poses. frame, track_id: (N,) int64; cls: (N,) str; xyz: (N, 3)
    metres (ground contact point, z on the ground surface); heading: (N,) radians; size: (N, 3)
    l, w, h metres; source: (N,) str, one of ``SOURCES``."""

    frame: np.ndarray
    track_id: np.ndarray
    cls: np.ndarray
    xyz: np.ndarray
    heading: np.ndarray
    size: np.ndarray
    source: np.ndarray

    def __post_init__(self) -> None:
        self.frame = np.asarray(self.frame, dtype=np.int64).reshape(-1)
        self.track_id = np.asarray(self.track_id, dtype=np.int64).reshape(-1)
        self.cls = np.asarray(self.cls, dtype=object).reshape(-1)
        self.xyz = np.asarray(self.xyz, dtype=np.float64).reshape(-1, 3)
        self.heading = np.asarray(self.heading, dtype=np.float64).reshape(-1)
        self.size = np.asarray(self.size, dtype=np.float64).reshape(-1, 3)
        self.source = np.asarray(self.source, dtype=object).reshape(-1)
        n = len(self.frame)
        if not all(len(a) == n for a in (self.track_id, self.cls, self.xyz, self.heading,
                                         self.size, self.source)):
            raise ValueError("AnnotationTable columns differ in length")

    def __len__(self) -> int:
        return len(self.frame)

    def take(self, idx) -> "AnnotationTable":
        return AnnotationTable(self.frame[idx], self.track_id[idx], self.cls[idx], self.xyz[idx],
                               self.heading[idx], self.size[idx], self.source[idx])

    def sorted(self) -> "AnnotationTable":
        """Rows by frame, then track id (the order of pose files)."""
        return self.take(np.lexsort((self.track_id, self.frame)))

    def in_frames(self, frame_range: tuple[int, int] | None) -> "AnnotationTable":
        if frame_range is None:
            return self
        return self.take((self.frame >= frame_range[0]) & (self.frame <= frame_range[1]))

    def of_sources(self, *sources: str) -> "AnnotationTable":
        """Only the rows whose source is one of ``sources``."""
        return self.take(np.isin(self.source, list(sources)))

    def pose_table(self) -> PoseTable:
        """The poses as seg2pose's PoseTable (with sizes), for evaluation and writing."""
        return PoseTable(self.frame, self.track_id, self.cls, self.xyz, self.heading, self.size)

    @classmethod
    def empty(cls) -> "AnnotationTable":
        return cls(np.zeros(0), np.zeros(0), np.zeros(0, object), np.zeros((0, 3)), np.zeros(0),
                   np.zeros((0, 3)), np.zeros(0, object))

    @classmethod
    def concat(cls, tables: Iterable["AnnotationTable"]) -> "AnnotationTable":
        tables = [t for t in tables if len(t)]
        if not tables:
            return cls.empty()
        cols = ("frame", "track_id", "cls", "xyz", "heading", "size", "source")
        return cls(*(np.concatenate([getattr(t, c) for t in tables]) for c in cols))


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
                frame_range: tuple[int, int] | None = None) -> AnnotationTable:
    """Every frame's pose of one track: interpolated with ``method`` between its keyframes,
    z from the ground surface (eq. 1), flagged by source."""
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
        source = np.where(np.isin(q, kf), "keyframe", "interpolated").astype(object)
        for a, b, k in track.spans:
            if k == "occluded":
                source[(q >= a) & (q <= b)] = "occluded"
        parts.append((q, xy, hd, source))
    if not parts:
        return AnnotationTable.empty()
    q = np.concatenate([p[0] for p in parts])
    xy = np.concatenate([p[1] for p in parts])
    n = len(q)
    z = ground.height(xy)
    return AnnotationTable(q, np.full(n, track.id), np.full(n, track.cls, dtype=object),
                           np.column_stack([xy, z]), np.concatenate([p[2] for p in parts]),
                           np.tile(np.asarray(track.size, float), (n, 1)),
                           np.concatenate([p[3] for p in parts]))
