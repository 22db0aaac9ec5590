"""Video in: frames of a video file or an image folder, streamed one at a time.

A camera's frames come from ``video/<camera>.mp4`` (or .avi/.mkv/.mov) or an image folder
``video/<camera>/NNNNNN.jpg``. The k-th frame of a video is scene frame ``first + k * step``
(``scene.json`` ``extra.video_frames.<camera>``, default first 0, step 1), the k-th in
display order (presentation timestamps, decoded frame-exactly by ``io/video_decode.py``, also
for H.264 with B-frames and seeks): a variable-frame-rate video's frames are numbered by their
rank, not by their timestamps. An image's frame is the number in its file name. Nothing is
loaded whole: ``FrameReader`` yields (frame, image) pairs and remembers where a truncated file
stopped, so callers keep what was read.

Images are BGR uint8 (H, W, 3), OpenCV's order.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from seg2pose.core.errors import InputError
from seg2pose.io.video_decode import VideoDecoder, video_index

if TYPE_CHECKING:
    from seg2pose.io.scene import Scene

VIDEO_EXTS = (".mp4", ".avi", ".mkv", ".mov")
IMAGE_EXTS = (".jpg", ".jpeg", ".png")
_DIGITS = re.compile(r"(\d+)")


def image_files(folder: Path) -> list[tuple[int, Path]]:
    """(frame, file) of an image folder, by the last number in each file name, in frame order."""
    out = []
    for p in folder.iterdir():
        if p.suffix.lower() in IMAGE_EXTS and (m := _DIGITS.findall(p.stem)):
            out.append((int(m[-1]), p))
    out.sort()
    frames = [f for f, _ in out]
    if len(set(frames)) != len(frames):
        dup = next(f for f, g in zip(frames, frames[1:]) if f == g)
        raise InputError(f"two images have frame number {dup}", file=folder)
    return out


@dataclass
class FrameReader:
    """Streams (frame, BGR image) from a video file or image folder.

    first, step: the scene frame of the first video frame and the frame step (videos only).
    After iterating, ``last_good`` is the last frame read (None if none) and ``stopped`` a
    message when the source ended early (a truncated or unreadable file), else None."""

    path: Path
    first: int = 0
    step: int = 1
    last_good: int | None = None
    stopped: str | None = None
    n_read: int = 0
    _size: tuple[int, int] | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self.path = Path(self.path)
        if not self.path.exists():
            raise InputError("video file or image folder not found", file=self.path)
        if self.step < 1:
            raise InputError(f"frame step must be >= 1, got {self.step}", file=self.path)

    @property
    def is_folder(self) -> bool:
        return self.path.is_dir()

    def _decoder(self) -> VideoDecoder:
        return VideoDecoder(self.path)

    def header(self) -> tuple[int, int, int]:
        """(width, height, frame count) from the file header (image folders: first image);
        the count may be 0 when the container does not say."""
        import cv2

        if self.is_folder:
            files = image_files(self.path)
            if not files:
                raise InputError("no NNNNNN.jpg/.png images", file=self.path)
            im = cv2.imread(str(files[0][1]), cv2.IMREAD_COLOR)
            if im is None:
                raise InputError("cannot read image", file=files[0][1])
            return im.shape[1], im.shape[0], len(files)
        idx = video_index(self.path)
        return idx.width, idx.height, idx.n_expected

    def check_size(self, width: int, height: int) -> None:
        """Raise if the frames are not ``width`` x ``height`` pixels (the calibration's size)."""
        w, h, _ = self.header()
        if (w, h) != (int(width), int(height)):
            raise InputError(f"frames are {w}x{h} pixels but the camera calibration is "
                             f"{width}x{height}", file=self.path)

    def frame_numbers(self, n: int) -> np.ndarray:
        """Scene frames (n,) of the first n video frames."""
        return self.first + self.step * np.arange(n, dtype=np.int64)

    def __iter__(self) -> Iterator[tuple[int, np.ndarray]]:
        return self.frames()

    def frames(self, first: int | None = None, last: int | None = None, every: int = 1
               ) -> Iterator[tuple[int, np.ndarray]]:
        """(frame, image) for scene frames first..last (inclusive; None = open end); with
        ``every`` > 1 only every ``every``-th frame read (the first one, then every ``every``-th
        after it), the others skipped without converting them to images."""
        import cv2

        self.last_good, self.stopped, self.n_read = None, None, 0
        if self.is_folder:
            i = -1
            for f, p in image_files(self.path):
                if (first is not None and f < first) or (last is not None and f > last):
                    continue
                i += 1
                if i % every:
                    continue
                im = cv2.imread(str(p), cv2.IMREAD_COLOR)
                if im is None:
                    self.stopped = f"cannot read image {p.name}"
                    return
                if self._size is None:
                    self._size = im.shape[:2]
                elif im.shape[:2] != self._size:
                    self.stopped = (f"image {p.name} is {im.shape[1]}x{im.shape[0]}, the earlier "
                                    f"ones {self._size[1]}x{self._size[0]}")
                    return
                self.last_good, self.n_read = f, self.n_read + 1
                yield f, im
            return
        k0 = 0 if first is None else max(0, -(-(first - self.first) // self.step))
        k1 = None if last is None else (last - self.first) // self.step
        with self._decoder() as dec:
            k = k0 - 1
            # skipped frames are decoded (the next needs them) but not converted to images
            for k, im in dec.frames(k0, k1, every):
                assert im is not None   # images=True
                f = self.first + k * self.step
                self.last_good, self.n_read = f, self.n_read + 1
                yield f, im
            n = dec.index.n_expected
            end = n - 1 if k1 is None else min(k1, n - 1)
            if dec.stopped or k + every <= end:
                self.stopped = (f"video ends after {k + 1} of the {n} frames its header announces "
                                "(truncated or damaged)")

    def sample(self, frames: np.ndarray) -> list[tuple[int, np.ndarray]]:
        """The images of a few scene frames (sorted; frames past the end are skipped)."""
        want = set(int(f) for f in frames)
        out = []
        if self.is_folder:
            import cv2
            for f, p in image_files(self.path):
                if f in want and (im := cv2.imread(str(p), cv2.IMREAD_COLOR)) is not None:
                    out.append((f, im))
            return out
        if not want:
            return out
        ks = sorted((f - self.first) // self.step for f in want if (f - self.first) % self.step == 0)
        # one decoder: frames close together are decoded on, far ones sought (video_decode)
        with self._decoder() as dec:
            for k in ks:
                if (im := dec.read(k)) is not None:
                    out.append((self.first + k * self.step, im))
        return out


def camera_reader(scene: Scene, camera: str) -> FrameReader:
    """The camera's frames with the scene's numbering (``extra.video_frames.<camera>``: the
    first video frame's scene frame and the step; image folders: the number in each name)."""
    path = scene.video_path(camera)
    if path is None:
        raise InputError(f"camera {camera!r} has no video (video/{camera}.mp4 or an image folder "
                         f"video/{camera}/)", file=scene.root / "video")
    vf = (scene.extra.get("video_frames") or {}).get(camera) or {}
    try:
        first, step = int(vf.get("first", 0)), int(vf.get("step", 1))
    except (TypeError, ValueError, AttributeError):
        raise InputError("expected integers first, step", file=scene.root / "scene.json",
                         field=f"extra.video_frames.{camera}") from None
    return FrameReader(path, first=first, step=step)
