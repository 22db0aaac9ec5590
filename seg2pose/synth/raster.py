"""Rasterising unions of convex parts into instance masks, and masks into COCO RLE.

Pixels: x right, y down, origin at the top-left corner of the top-left pixel; the centre of
pixel (row, col) is at (col + 0.5, row + 0.5). OpenCV's drawing functions put integer
coordinates at pixel centres, so points are shifted by -0.5 before drawing.

The instance buffer is kept *transposed*, shape (W, H): its rows are image columns, so a crop
of it is already in COCO's column-major order and RLE runs come straight out of it.
"""

from __future__ import annotations

import cv2
import numpy as np
from pycocotools import mask as mask_util

SHIFT = 4  # fixed-point bits for cv2 polygon vertices (1/16 pixel)
NEAR = 0.1  # m: parts with a vertex closer than this to the image plane are not drawn


def pose_parts(verts: np.ndarray, swing: np.ndarray, owner: np.ndarray, xyz: np.ndarray,
               heading: np.ndarray, phase: np.ndarray | None = None) -> np.ndarray:
    """Local part vertices (P, 8, 3) -> world (P, 8, 3) metres.

    owner: (P,) index of each part's road user into xyz (A, 3) (ground contact, metres),
    heading (A,) radians and phase (A,) gait phase (legs swing by ``swing`` (P,) * sin(phase)).
    """
    v = verts.copy()
    if phase is not None:
        v[:, :, 0] += (swing * np.sin(phase[owner]))[:, None]
    c, s = np.cos(heading[owner])[:, None], np.sin(heading[owner])[:, None]
    x = c * v[:, :, 0] - s * v[:, :, 1]
    y = s * v[:, :, 0] + c * v[:, :, 1]
    out = np.stack([x, y, v[:, :, 2]], axis=-1)
    out += xyz[owner][:, None, :]
    return out


def project_parts(camera, world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World part vertices (P, 8, 3) -> pixels (P, 8, 2) and a (P,) bool 'drawable' (every
    vertex in front of the camera)."""
    P = len(world)
    uv, depth, _ = camera.project_points(world.reshape(-1, 3))
    return uv.reshape(P, 8, 2), (depth.reshape(P, 8) > NEAR).all(axis=1)


def fill_parts(buf_t: np.ndarray, uv: np.ndarray, values: np.ndarray) -> None:
    """Fill each part's projected convex hull into the transposed buffer (W, H) with its
    value, in the given order (painter's algorithm: pass far parts first).

    uv: (P, 8, 2) pixels; values: (P,) ints."""
    # transposed buffer: (x, y) -> (y, x); cv2 puts integer coordinates at pixel centres
    pts = np.round((uv[:, :, ::-1] - 0.5) * (1 << SHIFT))
    lim = float(1 << 28)  # keep far-off vertices inside cv2's integer range
    pts = np.clip(pts, -lim, lim).astype(np.int32)
    for p, val in zip(pts, values.tolist()):
        hull = cv2.convexHull(p)
        cv2.fillConvexPoly(buf_t, hull, int(val), lineType=cv2.LINE_8, shift=SHIFT)


def bbox_of(uv: np.ndarray, width: int, height: int, margin: int = 0
            ) -> tuple[int, int, int, int] | None:
    """Integer pixel box (x0, y0, x1, y1), exclusive ends, covering points uv (M, 2) plus
    ``margin`` pixels, clipped to the image; None when it misses the image."""
    lo = np.floor(uv.min(axis=0)).astype(np.int64) - 1 - margin
    hi = np.ceil(uv.max(axis=0)).astype(np.int64) + 1 + margin
    x0, y0 = max(int(lo[0]), 0), max(int(lo[1]), 0)
    x1, y1 = min(int(hi[0]), width), min(int(hi[1]), height)
    if x1 <= x0 or y1 <= y0:
        return None
    return x0, y0, x1, y1


def rle_from_crop_t(crop_t: np.ndarray, x0: int, y0: int, height: int, width: int) -> bytes:
    """Compressed COCO RLE of a full (height, width) image that is empty except for a crop.

    crop_t: (w_c, h_c) bool, the *transposed* crop whose top-left image pixel is (x0, y0)."""
    wc, hc = crop_t.shape
    pad = np.zeros((wc, hc + 2), bool)
    pad[:, 1:-1] = crop_t
    # transitions, column by column: every column starts and ends with background, so they
    # alternate run start, run end
    idx = np.flatnonzero(pad[:, 1:] ^ pad[:, :-1])
    col, row = np.divmod(idx, hc + 1)
    H = int(height)
    lin = (x0 + col).astype(np.int64) * H + y0 + row
    start, end = lin[0::2], lin[1::2]
    if len(start) == 0:
        counts = [H * int(width)]
    else:
        # runs that end at a column's last row and go on at the next column's first row are one
        keep = np.ones(len(start) + 1, bool)
        keep[1:-1] = end[:-1] != start[1:]
        start = start[keep[:-1]]
        end = end[keep[1:]]
        c = np.empty(2 * len(start) + 1, np.int64)
        c[0] = start[0]
        c[1:-1:2] = end - start
        c[2:-1:2] = start[1:] - end[:-1]
        c[-1] = H * int(width) - end[-1]
        counts = c.tolist() if c[-1] else c[:-1].tolist()  # pycocotools drops a last 0 run
    return mask_util.frPyObjects({"size": [H, int(width)], "counts": counts}, H, int(width))["counts"]
