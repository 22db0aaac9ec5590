"""The images of a review recording: masks (filled on the mask cadence, outlines on every
frame, cached) and camera video (one H.264 asset per camera, or JPEG frames), each camera's
under ``world/cameras/<cam>`` (``layout``), sent in batches of frames to bound memory.
"""

from __future__ import annotations

import numpy as np

from s2p_review import imagery
from s2p_review import layout as L
from s2p_review.log_context import IMAGE_BATCH, LogContext, batched
from seg2pose.core.errors import S2PError
from seg2pose.io.atomic import atomic_open
from seg2pose.io.scene import Scene


def _rr():
    import rerun as rr

    return rr


def _clear_frames(ctx: LogContext, ent: str, frames) -> None:
    """Empty ``ent`` at ``frames`` (nothing to show there: no stale image from before)."""
    frames = np.asarray(sorted(frames), np.int64)
    if len(frames):
        ctx.send(ent, frames, _rr().Clear.columns(is_recursive=np.zeros(len(frames), bool)))


def log_masks(ctx: LogContext, cam: str, every: int) -> int:
    """SegmentationImage per frame on the cadence (pixel = class id), blank between; with
    ``style.mask_outlines`` every frame's masks as outlines too. Returns filled rows sent."""
    rr = _rr()
    scene = ctx.scene
    camera = scene.cameras[cam]
    ent = L.cam_path(cam) + "/masks"
    path = scene.masks_path(cam)
    if not path.exists():
        return 0
    sent = 0
    if ctx.style.mask_fills:
        ctx.static(ent, rr.SegmentationImage.from_fields(
            format=rr.components.ImageFormat(width=camera.width, height=camera.height,
                                             channel_datatype="U8"), opacity=0.6, draw_order=5.0))

        def send(batch):
            imgs = imagery.paint([t for _, t in batch], [t.class_id for _, t in batch], path)
            ctx.send(ent, [f for f, _ in batch],
                     rr.SegmentationImage.columns(buffer=imgs.reshape(len(batch), -1)))

        sent = batched(imagery.mask_frames(scene, cam, ctx.first, ctx.last, every), send)
        if every > 1:
            _clear_frames(ctx, ent, [f for f in ctx.frames if (f - ctx.first) % every])
    if ctx.style.mask_outlines:
        log_mask_outlines(ctx, cam)
    return sent


def log_mask_outlines(ctx: LogContext, cam: str) -> int:
    """Every frame's masks as class-coloured outlines (LineStrips2D, imagery.outlines) under
    the camera: a few bytes per mask, so every frame fits. Computed once per masks file and
    range, then cached (``outline_table``). Returns frames sent."""
    rr = _rr()
    ent = L.cam_path(cam) + "/masks/outlines"
    ctx.static(ent, rr.LineStrips2D.from_fields(draw_order=4.0, radii=1.0))
    frames, per_frame, lengths, points, colors = outline_table(ctx.scene, cam, ctx.first, ctx.last)
    strips = np.split(points, np.cumsum(lengths)[:-1]) if len(lengths) else []
    for a in range(0, len(frames), IMAGE_BATCH):
        fr = frames[a:a + IMAGE_BATCH]
        s0, s1 = int(per_frame[:a].sum()), int(per_frame[:a + len(fr)].sum())
        ctx.send(ent, fr, rr.LineStrips2D.columns(strips=strips[s0:s1], colors=colors[s0:s1])
                 .partition(per_frame[a:a + len(fr)]))
    return len(frames)


def outline_table(scene: Scene, cam: str, first: int, last: int):
    """(frames (F,), strips per frame (F,), points per strip (S,), points (P, 2) float32,
    colours (S, 3) uint8) of the mask outlines of frames first..last, from the cache
    (video_asset.cache_dir) or computed and cached."""
    import hashlib
    import json

    from s2p_review.video_asset import cache_dir

    path = scene.masks_path(cam)
    st = path.stat()
    key = hashlib.sha256(json.dumps([str(path.resolve()), st.st_size, st.st_mtime_ns, first,
                                     last, imagery.OUTLINE_TOLERANCE, 1]).encode()).hexdigest()[:20]
    cached = cache_dir() / f"outlines-{cam}-{key}.npz"
    try:
        with np.load(cached) as z:
            return z["frames"], z["per_frame"], z["lengths"], z["points"], z["colors"]
    except (OSError, ValueError, KeyError):
        pass
    by_id = scene.class_by_id()
    frames, per_frame, lengths, points, colors = [], [], [], [], []
    for f, t in imagery.mask_frames(scene, cam, first, last, 1):
        polys, owner = imagery.outlines(t, path)
        names = np.array([by_id[int(c)].name if int(c) in by_id else "" for c in t.class_id])
        frames.append(f)
        per_frame.append(len(polys))
        lengths += [len(q) for q in polys]
        points += polys
        if len(owner):
            colors.append(L.class_colors(names, scene.classes)[owner])
    out = (np.asarray(frames, np.int64), np.asarray(per_frame, np.int64),
           np.asarray(lengths, np.int64),
           np.concatenate(points).astype(np.float32) if points else np.zeros((0, 2), np.float32),
           np.concatenate(colors).astype(np.uint8) if colors else np.zeros((0, 3), np.uint8))
    try:
        with atomic_open(cached, "wb") as f:
            np.savez(f, frames=out[0], per_frame=out[1], lengths=out[2], points=out[3],
                     colors=out[4])
    except (OSError, S2PError):
        pass  # a cache we cannot write only costs time
    return out


def log_video(ctx: LogContext, cam: str, every: int) -> np.ndarray:
    """The camera's video under the camera, as ``style.video_format`` says; frames without
    video are left blank. Returns the scene frames that have video."""
    if ctx.scene.video_path(cam) is None:
        return np.zeros(0, np.int64)
    if ctx.style.video_format == "asset":
        return _log_video_asset(ctx, cam)
    return _log_video_jpeg(ctx, cam, every)


def _log_video_asset(ctx: LogContext, cam: str) -> np.ndarray:
    from s2p_review.video_asset import video_asset

    rr = _rr()
    ent = L.cam_path(cam) + "/image"
    asset = video_asset(ctx.scene, cam, ctx.first, ctx.last, ctx.style.image_scale)
    if asset is None:
        return np.zeros(0, np.int64)
    camera = ctx.scene.cameras[cam]
    if (asset.width, asset.height) != (camera.width, camera.height):  # shown at the camera's size
        ctx.static(ent, rr.Transform3D(scale=[camera.width / asset.width,
                                              camera.height / asset.height, 1.0]))
    ctx.static(ent, rr.AssetVideo(contents=asset.path.read_bytes(), media_type="video/mp4"))
    ctx.send(ent, asset.frames, rr.VideoFrameReference.columns_nanos(asset.timestamps_ns))
    _clear_frames(ctx, ent, sorted(set(ctx.frames.tolist()) - set(asset.frames.tolist())))
    return asset.frames


def _log_video_jpeg(ctx: LogContext, cam: str, every: int) -> np.ndarray:
    rr = _rr()
    ent = L.cam_path(cam) + "/image"
    camera = ctx.scene.cameras[cam]
    width = max(1, int(round(camera.width * ctx.style.image_scale)))
    if width < camera.width:  # stored small, shown at the camera's size
        h = max(1, int(round(camera.height * width / camera.width)))
        ctx.static(ent, rr.Transform3D(scale=[camera.width / width, camera.height / h, 1.0]))
    done: list[int] = []

    def send(batch):
        frames = [f for f, _ in batch]
        blobs = [imagery.encode_jpeg(img, ctx.style.jpeg_quality, width) for _, img in batch]
        ctx.send(ent, frames, rr.EncodedImage.columns(blob=blobs,
                                                      media_type=["image/jpeg"] * len(blobs)))
        done.extend(frames)

    batched(imagery.video_frames(ctx.scene, cam, ctx.first, ctx.last, every), send)
    return np.asarray(done, np.int64)
