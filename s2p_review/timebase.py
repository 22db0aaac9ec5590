"""Frame numbers to times. Every recording and export has two clocks: the frame number (Rerun's
``frame`` timeline; recoverable from every MCAP message) and the wall-clock time of the frame,
``start + frame / fps`` when the scene's start time is known, else ``frame / fps`` since 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from s2p_review import layout as L


@dataclass(frozen=True)
class Timebase:
    """fps: frames per second; start_ns: UTC time of frame 0, nanoseconds since the Unix epoch
    (None: unknown, times count from 0)."""

    fps: float
    start_ns: int | None = None

    def ns(self, frames) -> np.ndarray:
        """(N,) int64 nanoseconds of frames (N,) (a scalar frame gives a 0-d array)."""
        rel = np.rint(np.asarray(frames, np.float64) * (1e9 / self.fps)).astype(np.int64)
        return rel + np.int64(self.start_ns or 0)

    def ns1(self, frame: int) -> int:
        return int(self.ns(frame))

    def frame_of(self, ns) -> np.ndarray:
        """The frame numbers (N,) int64 of times (N,) ns (inverse of ``ns``)."""
        rel = np.asarray(ns, np.int64) - np.int64(self.start_ns or 0)
        return np.rint(rel * (self.fps / 1e9)).astype(np.int64)

    def rerun_columns(self, frames) -> list:
        """Rerun index columns: ``frame`` (sequence) and ``time`` (timestamp when the start is
        known, else a duration since frame 0)."""
        import rerun as rr

        frames = np.asarray(frames, np.int64)
        ns = self.ns(frames)
        time = (rr.TimeColumn(L.TIME, timestamp=ns.astype("datetime64[ns]"))
                if self.start_ns is not None
                else rr.TimeColumn(L.TIME, duration=ns.astype("timedelta64[ns]")))
        return [rr.TimeColumn(L.TIMELINE, sequence=frames), time]


def scene_timebase(scene, start_ns: int | None = None) -> Timebase:
    """The clock of ``scene``: its fps, and ``start_ns`` when given, else the scene's own start
    time (None when it has none)."""
    own = getattr(scene, "start_time_ns", None)
    return Timebase(scene.fps, start_ns if start_ns is not None else own)
