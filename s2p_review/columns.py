"""Column builders: whole tracks and whole frame ranges turned into arrays for
``rr.send_columns`` (one call per entity and batch instead of one ``rr.log`` per frame).

All builders are vectorised over rows; a frame range [a, b] always produces one row per frame
(frames without data get an empty batch, so nothing from an earlier frame lingers).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from seg2pose.masks import decode_counts

# corner order of a box: bottom 0-3, top 4-7; edges as index pairs
_SX = np.array([1, 1, -1, -1, 1, 1, -1, -1]) * 0.5
_SY = np.array([1, -1, -1, 1, 1, -1, -1, 1]) * 0.5
_SZ = np.array([0, 0, 0, 0, 1, 1, 1, 1], dtype=float)
EDGES = np.array([[0, 1], [1, 2], [2, 3], [3, 0], [4, 5], [5, 6], [6, 7], [7, 4],
                  [0, 4], [1, 5], [2, 6], [3, 7]])


def frame_lengths(frame: np.ndarray, first: int, last: int) -> np.ndarray:
    """Rows per frame (last - first + 1,) for rows already sorted by frame within [first, last]."""
    return np.bincount(np.asarray(frame, np.int64) - first, minlength=last - first + 1)


def box_corners(xyz: np.ndarray, heading: np.ndarray, size: np.ndarray) -> np.ndarray:
    """(N, 8, 3) corners of boxes standing on bottom-centre points xyz (N, 3) metres, turned
    by heading (N,) radians (NaN = 0), size (N, 3) = l, w, h metres."""
    h = np.nan_to_num(np.asarray(heading, float))
    lx = _SX[None] * size[:, :1]
    ly = _SY[None] * size[:, 1:2]
    c, s = np.cos(h)[:, None], np.sin(h)[:, None]
    x = xyz[:, :1] + c * lx - s * ly
    y = xyz[:, 1:2] + s * lx + c * ly
    z = xyz[:, 2:3] + _SZ[None] * size[:, 2:3]
    return np.stack([x, y, z], axis=2)


def box_columns(xyz: np.ndarray, heading: np.ndarray, size: np.ndarray) -> dict:
    """Boxes3D fields for N boxes: centres (N, 3) metres (bottom centre raised by h/2),
    half sizes (N, 3) metres, rotation quaternions (N, 4) xyzw about +z."""
    h = np.nan_to_num(np.asarray(heading, float))
    centers = xyz + np.c_[np.zeros((len(xyz), 2)), size[:, 2] / 2]
    quats = np.stack([np.zeros_like(h), np.zeros_like(h), np.sin(h / 2), np.cos(h / 2)], axis=1)
    return {"centers": centers, "half_sizes": size / 2, "quaternions": quats}


def projected_edges(camera, xyz: np.ndarray, heading: np.ndarray, size: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Box edges as 2D segments (M*12, 2, 2) pixels for the boxes fully in front of ``camera``
    with at least one corner in the image; also the (M,) indices of those boxes."""
    n = len(xyz)
    if n == 0:
        return np.zeros((0, 2, 2)), np.zeros(0, np.int64)
    corners = box_corners(xyz, heading, size).reshape(-1, 3)
    uv, _, front = camera.project_points(corners)
    uv = uv.reshape(n, 8, 2)
    keep = front.reshape(n, 8).all(axis=1) & camera.in_image(uv.reshape(-1, 2)).reshape(n, 8).any(axis=1)
    idx = np.flatnonzero(keep)
    return uv[idx][:, EDGES].reshape(-1, 2, 2), idx


def trail_strips(track_id: np.ndarray, frame: np.ndarray, xyz: np.ndarray, length: int
                 ) -> list[np.ndarray]:
    """For each row (rows sorted by frame), the track's positions (K, 3) over its last
    ``length`` rows up to and including this one (K <= length)."""
    order = np.lexsort((frame, track_id))
    tid = track_id[order]
    start = np.flatnonzero(np.r_[True, tid[1:] != tid[:-1]])
    first_of = np.repeat(start, np.diff(np.r_[start, len(tid)]))
    pos_sorted = xyz[order]
    i = np.arange(len(order))
    lo = np.maximum(first_of, i - length + 1)
    strips_sorted = [pos_sorted[a:b + 1] for a, b in zip(lo.tolist(), i.tolist())]
    out: list = [None] * len(order)
    for k, o in enumerate(order.tolist()):
        out[o] = strips_sorted[k]
    return out


def paint_masks(rles: Sequence[bytes], values: np.ndarray, slot: np.ndarray, height: int,
                width: int, n_slots: int, dtype=np.uint8) -> np.ndarray:
    """Paint many masks into a stack of label images straight from their RLE runs.

    rles: N compressed COCO RLE strings; values: (N,) label of each mask (class id or instance
    id); slot: (N,) index of the image each mask goes to. Returns (n_slots, height, width)
    images, 0 = background; a mask later in the list is painted over earlier ones. Pixels:
    row-major, (row, col) as in the image."""
    out = np.zeros(n_slots * height * width, dtype=dtype)
    if len(rles) == 0:
        return out.reshape(n_slots, height, width)
    counts, offsets = decode_counts(rles)
    n = len(rles)
    owner = np.repeat(np.arange(n), np.diff(offsets))
    k = np.arange(len(counts)) - offsets[owner]
    cs = np.cumsum(counts)
    before = np.concatenate([[0], cs])[offsets[:-1]]
    start = cs - counts - np.repeat(before, np.diff(offsets))
    fg = (k % 2) == 1  # runs alternate background / foreground, starting with background
    own, st, ln = owner[fg], start[fg], counts[fg]
    total = int(ln.sum())
    # column-major pixel index p of every foreground pixel
    p = np.arange(total) - np.repeat(np.cumsum(ln) - ln, ln) + np.repeat(st, ln)
    col, row = np.divmod(p, height)
    m = np.repeat(own, ln)
    out[np.asarray(slot, np.int64)[m] * (height * width) + row * width + col] = np.asarray(values)[m]
    return out.reshape(n_slots, height, width)
