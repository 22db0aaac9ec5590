"""Camera video for the Rerun viewer as one video asset per camera: every frame of the range,
re-encoded once as H.264 in MP4 (libx264 through PyAV, ultrafast, a keyframe every
``GOP`` frames so that a jump to any frame decodes at most GOP - 1 frames first) and cached.

The viewer decodes the asset on demand (``rr.AssetVideo`` + one ``rr.VideoFrameReference``
per scene frame), so every frame is there at a few MB, where JPEG images of every frame would
be hundreds (a 400-frame 1280x720 camera: docs/BENCHMARKS.md, "Annotation app").

The scene's video is read through ``imagery.video_frames`` (the scene's frame numbering), so
frame k of the asset is the k-th frame that exists in the range; ``VideoAsset.frames`` says
which scene frame that is. Cache: ``$XDG_CACHE_HOME/s2p/viewer-video`` (else
``~/.cache/s2p/viewer-video``), one file per (video file, size, mtime, range, settings),
written atomically.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np

from s2p_review import imagery
from seg2pose.core.errors import S2PError
from seg2pose.io.atomic import atomic_path
from seg2pose.io.scene import Scene

GOP = 12          # frames between keyframes: bounds the decoding work of a jump
CRF = 26          # x264 quality (lower: better, bigger); 26 keeps masks' edges readable
VERSION = 1       # of the encoding settings (part of the cache key)


@dataclass(frozen=True)
class VideoAsset:
    """An encoded camera video: ``path`` (MP4), ``frames`` (K,) the scene frame of each video
    frame, ``timestamps_ns`` (K,) their presentation times in the asset, ``width``/``height``
    the encoded size (even numbers; the camera's, rounded down)."""

    path: Path
    frames: np.ndarray
    timestamps_ns: np.ndarray
    width: int
    height: int


def cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "s2p" / "viewer-video"


def _key(src: Path, first: int, last: int, fps: float, scale: float) -> str:
    st = src.stat()
    files = [src] if src.is_file() else sorted(p for p in src.iterdir() if p.is_file())
    sig = [[p.name, p.stat().st_size, p.stat().st_mtime_ns] for p in files]
    raw = json.dumps([str(src.resolve()), st.st_mtime_ns, sig, first, last, round(fps, 6),
                      scale, GOP, CRF, VERSION])
    return hashlib.sha256(raw.encode()).hexdigest()[:20]


def video_asset(scene: Scene, cam: str, first: int, last: int, scale: float = 1.0,
                folder: Path | None = None) -> VideoAsset | None:
    """The camera's video over scene frames first..last as an MP4 asset (cached); None when
    the camera has no video or none of its frames lies in the range."""
    src = scene.video_path(cam)
    if src is None:
        return None
    folder = folder or cache_dir()
    key = _key(src, first, last, scene.fps, scale)
    mp4, meta = folder / f"{cam}-{key}.mp4", folder / f"{cam}-{key}.json"
    if mp4.exists() and meta.exists():
        try:
            d = json.loads(meta.read_text())
            return VideoAsset(mp4, np.asarray(d["frames"], np.int64),
                              np.asarray(d["timestamps_ns"], np.int64), d["width"], d["height"])
        except (OSError, ValueError, KeyError):
            pass  # a damaged cache entry is made again
    folder.mkdir(parents=True, exist_ok=True)
    made = _encode(scene, cam, first, last, scale, mp4)
    if made is None:
        return None
    from seg2pose.io.atomic import atomic_write_text

    atomic_write_text(meta, json.dumps({"frames": made.frames.tolist(),
                                        "timestamps_ns": made.timestamps_ns.tolist(),
                                        "width": made.width, "height": made.height}))
    return made


def _encode(scene: Scene, cam: str, first: int, last: int, scale: float, out: Path
            ) -> VideoAsset | None:
    try:
        import av
    except ImportError:
        raise S2PError("PyAV is not installed (pip install av): it encodes camera video for "
                       "the viewer") from None
    import cv2

    camera = scene.cameras[cam]
    w = max(2, int(round(camera.width * scale)) // 2 * 2)
    h = max(2, int(round(camera.height * scale)) // 2 * 2)
    rate = Fraction(scene.fps).limit_denominator(1001)
    frames: list[int] = []
    try:
        ts = _write_asset(out, av, cv2, scene, cam, first, last, w, h, rate, frames)
    except _NoFrames:
        return None
    return VideoAsset(out, np.asarray(frames, np.int64), np.asarray(ts, np.int64), w, h)


class _NoFrames(Exception):
    """The camera has no frames in the range: no asset (the partial file is removed)."""


def _write_asset(out: Path, av, cv2, scene: Scene, cam: str, first: int, last: int, w: int, h: int,
                 rate: Fraction, frames: list[int]):
    """Encode the asset at ``out`` (frames appended to ``frames``); its frame timestamps (ns)."""
    with atomic_path(out) as tmp:  # renamed to ``out`` when the asset checks out, else removed
        container = av.open(str(tmp), "w", format="mp4")
        try:
            stream = container.add_stream("libx264", rate=rate)
            stream.width, stream.height, stream.pix_fmt = w, h, "yuv420p"
            stream.options = {"preset": "ultrafast", "crf": str(CRF), "tune": "zerolatency"}
            stream.codec_context.gop_size = GOP
            for f, img in imagery.video_frames(scene, cam, first, last):
                if img.shape[1] != w or img.shape[0] != h:
                    img = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
                vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="bgr24")
                vf.pts = len(frames)
                container.mux(stream.encode(vf))
                frames.append(f)
            container.mux(stream.encode())
        finally:
            container.close()
        if not frames:
            raise _NoFrames
        import rerun as rr

        ts = rr.AssetVideo(path=tmp, media_type="video/mp4").read_frame_timestamps_nanos()
        if len(ts) != len(frames):
            raise S2PError(f"encoding the video of camera {cam} for the viewer gave {len(ts)} frames "
                           f"for {len(frames)} read")
    return ts
