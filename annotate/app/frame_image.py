"""The large camera's picture, made on the server: the exact video frame the panel names, with
the mask outlines and every annotation track's box of that frame drawn on it, as a JPEG.

Why on the server and not in the Rerun viewer: on a machine without a GPU the browser renders
the viewer in software (SwiftShader), where one repaint of a 1176x760 viewer canvas took
2-3 s on the 2-core development machine and a frame step needs three repaints (seek, decode,
draw): 7-15 s before the new frame showed (docs/BENCHMARKS.md, "Annotation app"). A JPEG in
an ``<img>`` is decoded and composited by the browser in milliseconds, and a click on it
gives the image pixel exactly (no selection events to interpret). The Rerun viewer keeps the
3D world, the other cameras and the keyframe timeline.

Frames come from the viewer's cached H.264 asset of the camera (``s2p_review.video_asset``:
a keyframe every 12 frames), decoded frame-exactly by presentation timestamp
(``seg2pose.io.video_decode``): a step to the next frame decodes one frame, a jump seeks (at
most 11 frames decoded after the keyframe). Tracks are drawn from the same
columns the viewer gets (``TrackColumns``), projected with ``s2p_review.columns``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from s2p_review import columns as C
from s2p_review import layout as L
from s2p_review.annotation_log import OCCLUDED_SHADE, SELECTED_COLOR, TrackColumns
from s2p_review.video_asset import video_asset
from seg2pose.io.video_decode import VideoDecoder

JPEG_QUALITY = 82
THICKNESS = {"keyframe": 3, "estimate-accepted": 3, "estimate-unchecked": 1, "interpolated": 1,
             "reviewed": 2, "occluded": 1}
LABEL_MARK = {"keyframe": " key", "estimate-accepted": " key", "estimate-unchecked": " ?"}
NO_VIDEO_GREY = 90


@dataclass
class Picture:
    """One rendered frame: ``jpeg`` bytes, the image size, and ``note`` (why the picture is
    not the video frame, else "")."""

    jpeg: bytes
    width: int
    height: int
    note: str = ""


class _Reader:
    """Frame-exact random access to one camera's video asset (scene frame -> BGR), by
    presentation timestamp (``seg2pose.io.video_decode``): a step forward decodes on, a jump
    seeks to the keyframe before it."""

    def __init__(self, asset):
        self.asset = asset
        self.index = {int(f): i for i, f in enumerate(asset.frames)}
        self.decoder = VideoDecoder(asset.path)
        self.last = None  # (index, image) of the last frame read

    def read(self, frame: int) -> np.ndarray | None:
        i = self.index.get(int(frame))
        if i is None:
            return None
        if self.last is not None and self.last[0] == i:  # redrawn after an edit: no seek back
            return self.last[1].copy()
        img = self.decoder.read(i)
        self.last = (i, img) if img is not None else None
        return None if img is None else img.copy()

    def close(self) -> None:
        self.decoder.close()


class FrameImages:
    """Pictures of ``cameras`` over scene frames first..last (see the module docstring)."""

    def __init__(self, scene, cameras: list[str], first: int, last: int):
        self.scene, self.first, self.last = scene, int(first), int(last)
        self.cameras = list(cameras)
        self._readers: dict[str, _Reader | None] = {}
        self._outlines: dict[str, tuple | None] = {}

    def _reader(self, cam: str) -> _Reader | None:
        if cam not in self._readers:
            asset = video_asset(self.scene, cam, self.first, self.last)  # cached by prepare_viewer
            self._readers[cam] = _Reader(asset) if asset is not None else None
        return self._readers[cam]

    def _outline_index(self, cam: str):
        if cam not in self._outlines:
            from s2p_review.recording import outline_table

            out = None
            if self.scene.masks_path(cam).exists():
                frames, per_frame, lengths, points, colors = outline_table(
                    self.scene, cam, self.first, self.last)
                strip0 = np.r_[0, np.cumsum(per_frame)]
                pt0 = np.r_[0, np.cumsum(lengths)]
                out = ({int(f): i for i, f in enumerate(frames)}, strip0, pt0, lengths, points, colors)
            self._outlines[cam] = out
        return self._outlines[cam]

    def video_frame(self, cam: str, frame: int) -> np.ndarray | None:
        """The camera's video frame (H, W, 3) BGR at scene frame ``frame``, None without one."""
        r = self._reader(cam)
        return None if r is None else r.read(frame)

    def render(self, cam: str, frame: int, tracks: list[TrackColumns], selected: int | None,
               width: int | None = None) -> Picture:
        """The picture of ``cam`` at ``frame``: the video frame (grey with a note where there
        is none), mask outlines, each track's box at that frame (the selected one yellow,
        keyframes thick) and its label. ``width``: scaled down to this many pixels wide (the
        small pictures of the other cameras); ``Picture.width``/``height`` stay the camera's."""
        import cv2

        camera = self.scene.cameras[cam]
        img = self.video_frame(cam, frame)
        note = ""
        if img is None:
            img = np.full((camera.height, camera.width, 3), NO_VIDEO_GREY, np.uint8)
            note = f"no video for frame {frame} in camera {cam}"
        elif img.shape[1] != camera.width or img.shape[0] != camera.height:
            img = cv2.resize(img, (camera.width, camera.height), interpolation=cv2.INTER_LINEAR)
        self._draw_outlines(img, cam, frame)
        for t in sorted(tracks, key=lambda t: t.track_id == selected):  # the selected one on top
            self._draw_track(img, camera, t, frame, t.track_id == selected)
        if width is not None and width < img.shape[1]:
            img = cv2.resize(img, (int(width), max(1, round(img.shape[0] * width / img.shape[1]))),
                             interpolation=cv2.INTER_AREA)
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        return Picture(buf.tobytes(), camera.width, camera.height, note)

    def _draw_outlines(self, img: np.ndarray, cam: str, frame: int) -> None:
        import cv2

        o = self._outline_index(cam)
        if o is None or int(frame) not in o[0]:
            return
        at, strip0, pt0, lengths, points, colors = o
        i = at[int(frame)]
        for s in range(strip0[i], strip0[i + 1]):
            pts = np.round(points[pt0[s]:pt0[s + 1]]).astype(np.int32)
            if len(pts) >= 2:
                c = tuple(int(v) for v in colors[s][::-1])  # RGB -> BGR
                cv2.polylines(img, [pts], True, c, 1, cv2.LINE_AA)

    def _draw_track(self, img, camera, t: TrackColumns, frame: int, selected: bool) -> None:
        import cv2

        rows = np.flatnonzero(t.frame == int(frame))
        if not len(rows):
            return
        r = rows[:1]
        paths, idx = C.projected_paths(camera, t.xyz[r], t.heading[r], t.size[r])
        if not len(idx):
            return
        source = str(t.source[r[0]])
        rgb = SELECTED_COLOR if selected else L.class_colors(np.array([t.cls]), self.scene.classes)[0]
        if source == "occluded":
            rgb = tuple(int(v * OCCLUDED_SHADE) for v in rgb)
        bgr = tuple(int(v) for v in rgb[::-1])
        pts = np.round(paths[0]).astype(np.int32)
        cv2.polylines(img, [pts], False, bgr, THICKNESS.get(source, 1) + (1 if selected else 0),
                      cv2.LINE_AA)
        top = pts[pts[:, 1].argmin()]
        # "car 10", never "c10" (which reads like a camera's name); "?": an unchecked estimate
        label = f"{t.cls} {t.track_id}" + LABEL_MARK.get(source, "")
        cv2.putText(img, label, (int(top[0]) + 4, max(12, int(top[1]) - 4)),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.5, bgr, 1, cv2.LINE_AA)

    def close(self) -> None:
        for r in self._readers.values():
            if r is not None:
                r.close()
        self._readers.clear()
