"""Frame-exact decoding of a video file by presentation timestamp (PyAV).

A camera's video may be H.264 with B-frames (stored out of display order) and a variable frame
rate (irregular timestamps). Seeking by a frame count (OpenCV's ``CAP_PROP_POS_FRAMES``) can
then land on another frame; for ground truth a wrong frame is a wrong answer. Here:

- **the index**: the video stream's packets are read once per file without decoding (tens of ms
  for a 640-frame 720p file), and their presentation timestamps (pts) sorted: **video frame k
  is the frame with the k-th smallest pts**. The frame number is the rank, not the time: a
  variable-frame-rate video's frames are numbered 0, 1, 2, ... in display order whatever the
  gaps between their timestamps (the scene's numbering, ``io/video.py``, is then
  ``first + k * step``).
- **a read of frame k** decodes on from the last frame read when no keyframe lies between the
  two (a seek would decode as much), else seeks to the last keyframe at or before frame k's pts
  and decodes forward until the frame whose pts is k's. Frames come out of the decoder in
  display order, so B-frames land where they belong.

Packets without a pts (some AVI files) fall back to their decode timestamps, which for codecs
without B-frames (MJPG, the AVIs that lack pts) are in display order too. Images are BGR uint8
(H, W, 3), converted as OpenCV converts (the same pixels, checked in the tests).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from seg2pose.core.errors import InputError


@dataclass(frozen=True)
class VideoIndex:
    """The frames of one video stream in display order: ``pts`` (K,) int64 presentation
    timestamps in ``time_base`` seconds, sorted; ``keyframe`` (K,) bool; the stream's size,
    average rate (frames per second; for a variable frame rate, the mean) and the frame count
    its header announces (0 when it does not say; more than K for a truncated file) and the
    empty packets (AVI's "repeat the last frame" marks: no frame of their own)."""

    pts: np.ndarray
    keyframe: np.ndarray
    time_base: float
    width: int
    height: int
    fps: float
    n_header: int = 0
    n_empty: int = 0

    @property
    def n_expected(self) -> int:
        """The frames the file should hold: its header's count less empty packets, or K."""
        return max(self.n_header - self.n_empty, len(self.pts))

    def __len__(self) -> int:
        return len(self.pts)

    def seconds(self) -> np.ndarray:
        """(K,) each frame's presentation time, seconds from the stream's first frame."""
        return (self.pts - self.pts[0]) * self.time_base if len(self.pts) else np.zeros(0)


_INDEX_CACHE: dict[tuple[str, int, int], VideoIndex] = {}


def _open(path: Path):
    import av

    try:
        container = av.open(str(path))
    except (av.error.FFmpegError, OSError) as e:
        raise InputError(f"cannot open video ({e})", file=path) from None
    if not container.streams.video:
        container.close()
        raise InputError("no video stream in the file", file=path)
    return container


def video_index(path: str | Path) -> VideoIndex:
    """The display-order index of ``path``'s first video stream (module docstring); built once
    per file and kept for the process (keyed by path, size and modification time)."""
    import av

    path = Path(path)
    st = path.stat()
    key = (str(path.resolve()), st.st_size, st.st_mtime_ns)
    if key in _INDEX_CACHE:
        return _INDEX_CACHE[key]
    container = _open(path)
    try:
        stream = container.streams.video[0]
        ts, kf, empty = [], [], 0
        try:
            for p in container.demux(stream):
                t = p.pts if p.pts is not None else p.dts
                if p.size and t is not None:
                    ts.append(t)
                    kf.append(p.is_keyframe)
                elif t is not None:
                    empty += 1
        except av.error.FFmpegError:
            pass  # a damaged tail: the frames before it stay readable
        o = np.argsort(np.asarray(ts, np.int64), kind="stable")
        rate = stream.average_rate or stream.guessed_rate or 0
        idx = VideoIndex(np.asarray(ts, np.int64)[o], np.asarray(kf, bool)[o],
                         float(stream.time_base or 0), int(stream.codec_context.width),
                         int(stream.codec_context.height), float(rate), int(stream.frames or 0), empty)
    finally:
        container.close()
    if len(np.unique(idx.pts)) != len(idx.pts):
        raise InputError("two frames of the video share a presentation timestamp: their order "
                         "is unknown", file=path)
    if len(_INDEX_CACHE) > 64:
        _INDEX_CACHE.clear()
    _INDEX_CACHE[key] = idx
    return idx


class VideoDecoder:
    """Frame-exact random access to one video file by display-order frame number (module
    docstring): ``read(k)`` -> BGR image or None past the end; ``frames(k0, k1)`` streams
    frames k0..k1. Sequential reads never seek; a jump seeks to the keyframe before it."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.index = video_index(self.path)
        self._keys = np.flatnonzero(self.index.keyframe)   # frame numbers of the keyframes
        self._container: Any = None       # av.InputContainer while open
        self._frames: Iterator | None = None
        self._next = -1          # the frame number the decoder yields next (-1: none)
        self.stopped: str | None = None    # why decoding ended early (damaged data), else None

    def __len__(self) -> int:
        return len(self.index)

    def close(self) -> None:
        if self._container is not None:
            self._container.close()
        self._container, self._frames, self._next = None, None, -1

    def __enter__(self) -> VideoDecoder:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _seek(self, k: int) -> None:
        """Position the decoder so that the next frame out is frame k."""
        if self._container is None:
            self._container = _open(self.path)
            stream = self._container.streams.video[0]
            stream.thread_type = "AUTO"   # frame threads: the decoder's own parallelism
        stream = self._container.streams.video[0]
        start = self._keyframe_before(k)
        self._container.seek(int(self.index.pts[start]), stream=stream, backward=True, any_frame=False)
        self._frames = self._decoded(stream)
        self._next = -2  # unknown until the first frame's pts is seen

    def _keyframe_before(self, k: int) -> int:
        """The last keyframe at or before frame k (0 when none is marked)."""
        i = int(np.searchsorted(self._keys, k, side="right")) - 1
        return int(self._keys[i]) if i >= 0 else 0

    def _decoded(self, stream) -> Iterator:
        import av

        try:
            yield from self._container.decode(stream)
        except av.error.FFmpegError as e:
            self.stopped = f"decoding stopped: {e}"

    def _frame_at(self, k: int):
        """The av.VideoFrame of frame k (decoder positioned by the caller), or None."""
        want = int(self.index.pts[k])
        assert self._frames is not None
        for fr in self._frames:
            t = fr.pts if fr.pts is not None else fr.dts
            if t is None:
                continue
            if t < want:
                continue
            if t == want:
                self._next = k + 1
                return fr
            # past it: the wanted frame did not come out of the decoder (damaged data)
            self._next = int(np.searchsorted(self.index.pts, t)) + 1
            return None
        self._next = -1
        return None

    def read_frame(self, k: int):
        """av.VideoFrame of frame k (display order), or None past the end or where it cannot be
        decoded. Decodes on from the last frame read when no keyframe lies between, else seeks."""
        if k < 0 or k >= len(self.index):
            return None
        on = self._frames is not None and 0 <= self._next <= k and self._keyframe_before(k) <= self._next
        if not on:
            self._seek(k)
        return self._frame_at(k)

    def read(self, k: int) -> np.ndarray | None:
        """BGR image (H, W, 3) uint8 of frame k, or None (``read_frame``)."""
        fr = self.read_frame(k)
        return None if fr is None else fr.to_ndarray(format="bgr24")

    def frames(self, k0: int = 0, k1: int | None = None, every: int = 1, images: bool = True
               ) -> Iterator[tuple[int, np.ndarray | None]]:
        """(k, BGR image) for frames k0..k1 (inclusive; None: to the end), every ``every``-th
        from k0; the frames between are decoded (they must be, to reach the next) but not
        converted. ``images=False`` yields None instead of images. Stops at a frame that
        cannot be decoded (``stopped`` says why)."""
        last = len(self.index) - 1 if k1 is None else min(k1, len(self.index) - 1)
        for k in range(max(0, k0), last + 1, every):
            fr = self.read_frame(k)
            if fr is None:
                self.stopped = self.stopped or f"frame {k} of {len(self.index)} could not be decoded"
                return
            yield k, (fr.to_ndarray(format="bgr24") if images else None)
