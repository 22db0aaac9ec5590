"""Pixels read from a scene for review and export: video frames (a file or a folder of images)
and mask frames (MOTS) decoded into label images. Shared by the Rerun recording and the MCAP
export, so both read, check and cadence the images the same way.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from s2p_review import columns as C
from seg2pose.core.errors import InputError
from seg2pose.io.mots import MaskTable
from seg2pose.io.scene import Scene
from seg2pose.io.video import camera_reader


def video_frames(scene: Scene, cam: str, first: int, last: int, every: int = 1
                 ) -> Iterator[tuple[int, np.ndarray]]:
    """(frame, BGR image (H, W, 3) uint8) of the camera's video file or image folder for scene
    frames first..last, every k-th counted from ``first``; nothing when the camera has no video;
    stops early where the video ends. Frames carry the scene's numbering
    (``seg2pose.io.video.camera_reader``: ``extra.video_frames`` of a video file, the number in
    each image's name), so a recording whose frames start elsewhere than 0 or step by more
    than 1 is shown under the right masks."""
    if scene.video_path(cam) is None:
        return
    reader = camera_reader(scene, cam)
    for f, img in reader.frames(first, last):
        if (f - first) % every == 0:
            yield f, img


def encode_jpeg(img: np.ndarray, quality: int = 75, max_width: int | None = None) -> bytes:
    """JPEG bytes of a BGR image (H, W, 3), shrunk to ``max_width`` pixels wide when wider
    (keeps sample files small; viewers scale the image back onto the camera)."""
    import cv2

    if max_width is not None and img.shape[1] > max_width:
        h = max(1, int(round(img.shape[0] * max_width / img.shape[1])))
        img = cv2.resize(img, (max_width, h), interpolation=cv2.INTER_AREA)
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError("JPEG encoding failed")
    return buf.tobytes()


def mask_frames(scene: Scene, cam: str, first: int, last: int, every: int = 1
                ) -> Iterator[tuple[int, MaskTable]]:
    """(frame, detections) for every frame first..last on the cadence (every k-th counted from
    ``first``), an empty table where the frame has no masks; nothing when the camera has no
    mask file. Masks of another image size than the camera are an InputError."""
    path = scene.masks_path(cam)
    if not path.exists():
        return
    h, w = scene.cameras[cam].height, scene.cameras[cam].width
    # the runs are checked once per batch when painted (see ``paint``), not here per line
    stream = iter(scene.iter_masks(cam, (first, last), check_rles=False))  # checks the size
    pending = next(stream, None)
    for f in range(first, last + 1, every):
        while pending is not None and pending[0] < f:
            pending = next(stream, None)
        if pending is not None and pending[0] == f:
            t = pending[1]
            if t.height != h or t.width != w:
                raise InputError(f"masks are {t.width}x{t.height} but camera {cam} is {w}x{h}",
                                 file=path)
            yield f, t
        else:
            yield f, MaskTable.empty(h, w)


def paint(tables: list[MaskTable], values: list[np.ndarray], path: Path, dtype=np.uint8
          ) -> np.ndarray:
    """Label images (len(tables), H, W): table k's masks painted with ``values[k]`` (one value
    per mask, e.g. class ids or track ids + 1; 0 = background); later masks over earlier ones.
    A mask whose RLE does not cover H*W pixels is an InputError naming ``path``, its frame and
    track."""
    h, w = tables[0].height, tables[0].width
    rles = [r for t in tables for r in t.rles]
    slots = np.concatenate([np.full(len(t), k, np.int64) for k, t in enumerate(tables)])
    try:
        return C.paint_masks(rles, np.concatenate(values), slots, h, w, len(tables), dtype=dtype,
                             check=True)
    except C.BadMask as e:
        where = [(int(f), int(k)) for t in tables for f, k in zip(t.frame, t.track_id)]
        f, k = where[e.index]
        raise InputError(f"frame {f}, track {k}: {e}", file=path) from None
    except InputError as e:  # an RLE string that does not parse
        fr = [int(f) for t in tables for f in t.frame[:1]]
        raise InputError(f"frames {min(fr, default='?')}..{max(fr, default='?')}: {e}",
                         file=path) from None


OUTLINE_TOLERANCE = 0.8  # pixels: outlines are simplified to within this of the mask's edge


def outlines(table: MaskTable, path: Path) -> tuple[list[np.ndarray], np.ndarray]:
    """Outlines of one frame's masks: closed polylines (each (K, 2) float32, image pixels x
    right, y down, on pixel centres) and for each polyline the row of ``table`` it outlines
    (P,). Later masks cover earlier ones, as when painted; outer edges only."""
    import cv2
    from scipy import ndimage

    n = len(table)
    if n == 0:
        return [], np.zeros(0, np.int64)
    labels = paint([table], [np.arange(1, n + 1)], path, dtype=np.uint16)[0]
    polys, owner = [], []
    for k, sl in enumerate(ndimage.find_objects(labels, max_label=n)):
        if sl is None:
            continue  # wholly covered by later masks
        crop = (labels[sl] == k + 1).astype(np.uint8)
        contours, _ = cv2.findContours(crop, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        for c in contours:
            c = cv2.approxPolyDP(c, OUTLINE_TOLERANCE, True)[:, 0, :]
            pts = np.vstack([c, c[:1]]).astype(np.float32) + [sl[1].start + 0.5, sl[0].start + 0.5]
            polys.append(pts)
            owner.append(k)
    return polys, np.asarray(owner, np.int64)
