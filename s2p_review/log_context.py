"""What every review logging function gets: the style (``LogStyle``), where and what to log
(``LogContext``: the stream, the scene, its timebase, the frame range) and what was logged
(``LogStats``); shared by ``recording``, ``recording_images`` and ``road_users``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from s2p_review import layout as L
from s2p_review.timebase import Timebase
from seg2pose.io.scene import Scene

IMAGE_BATCH = 64  # frames per send_columns call for images (bounds memory)
VIDEO_FORMATS = ("asset", "jpeg")


@dataclass(frozen=True)
class LogStyle:
    """How things look. trail: frames of trail behind each road user (<= 1: none);
    image_plane_distance: metres from a camera to its image in the 3D view; video_format:
    "asset" (every frame, one H.264 video per camera decoded by the viewer: video_asset.py) or
    "jpeg" (JPEG images on the video cadence); jpeg_quality and image_scale: how video frames
    are stored (shrunk to image_scale of the camera's size and shown at full size again);
    mask_outlines: every frame's masks as outlines; mask_fills: the filled masks on the mask
    cadence, blank on the frames between (off in the annotation app: a 1280x720 fill is 0.9 MB
    a frame, outlines a few kB)."""

    masks: bool = True
    video: bool = True
    gt: bool = True  # ground truth, when the scene has it (off in the annotation app)
    trail: int = L.TRAIL_FRAMES
    image_plane_distance: float = 2.0
    video_format: str = "asset"
    jpeg_quality: int = 75
    image_scale: float = 1.0
    mask_outlines: bool = True
    mask_fills: bool = True  # the filled masks on the cadence (the annotation app: outlines only)


@dataclass(frozen=True)
class LogStats:
    """What was logged: frames in the range, mask and video rows, whether errors were plotted,
    notes for the user (e.g. a video shorter than the range), per camera the frames that
    have video (``video_frames``), and per run its road users' track ids (``tracks``) and
    the series they have (``series``: keys of ``layout.ROAD_USER_SERIES``)."""

    frames: int
    mask_rows: int
    video_rows: int
    metrics: bool
    notes: tuple[str, ...] = ()
    video_frames: dict = field(default_factory=dict)
    tracks: dict = field(default_factory=dict)  # run name -> track ids logged (road users)
    series: dict = field(default_factory=dict)  # run name -> road-user series logged


@dataclass(frozen=True)
class LogContext:
    """Where and what every ``log_*`` function logs: ``rec`` (a RecordingStream or anything
    with ``log``/``send_columns``), the scene, its timebase ``tb``, frames first..last, style."""

    rec: Any
    scene: Scene
    tb: Timebase
    first: int
    last: int
    style: LogStyle = LogStyle()

    @property
    def frames(self) -> np.ndarray:
        return np.arange(self.first, self.last + 1)

    def static(self, ent: str, archetype) -> None:
        self.rec.log(ent, archetype, static=True)

    def send(self, ent: str, frames, columns) -> None:
        """Rows of ``columns`` at scene ``frames``."""
        self.rec.send_columns(ent, indexes=self.tb.rerun_columns(frames), columns=columns)

    def send_range(self, ent: str, columns) -> None:
        """One (partitioned) row per frame of the range."""
        self.send(ent, self.frames, columns)


def batched(items, send, size: int = IMAGE_BATCH) -> int:
    """Call ``send(batch)`` on lists of up to ``size`` items of an iterator (bounds memory);
    returns how many items were sent."""
    n, batch = 0, []
    for item in items:
        batch.append(item)
        if len(batch) == size:
            send(batch)
            n, batch = n + len(batch), []
    if batch:
        send(batch)
        n += len(batch)
    return n
