"""Column builders: whole tracks and whole frame ranges turned into arrays for
``rr.send_columns`` (one call per entity and batch instead of one ``rr.log`` per frame).

All builders are vectorised over rows; a frame range [a, b] always produces one row per frame
(frames without data get an empty batch, so nothing from an earlier frame lingers).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from seg2pose.structures.masks import foreground_runs

if TYPE_CHECKING:
    from seg2pose.io.poses import PoseTable
    from seg2pose.io.scene import Scene

# corner order of a box: bottom 0-3, top 4-7; edges as index pairs
_SX = np.array([1, 1, -1, -1, 1, 1, -1, -1]) * 0.5
_SY = np.array([1, -1, -1, 1, 1, -1, -1, 1]) * 0.5
_SZ = np.array([0, 0, 0, 0, 1, 1, 1, 1], dtype=float)
EDGES = np.array([[0, 1], [1, 2], [2, 3], [3, 0], [4, 5], [5, 6], [6, 7], [7, 4],
                  [0, 4], [1, 5], [2, 6], [3, 7]])
# one polyline over all 12 edges (three are drawn twice): 16 points instead of 12 segments
PATH = np.array([0, 1, 2, 3, 0, 4, 5, 1, 5, 6, 2, 6, 7, 3, 7, 4])


def send_scalars(rec, entity: str, tb, frames: np.ndarray, values: np.ndarray) -> bool:
    """One ``send_columns`` of a scalar series: ``values`` (N,) at ``frames`` (N,) on the
    scene's timelines (``tb``: a ``Timebase``). Frames whose value is not finite (no value
    there) are left out, so the plot shows a gap; nothing is sent when none is. Returns
    whether anything was sent."""
    import rerun as rr

    values = np.asarray(values, float)
    ok = np.isfinite(values)
    if not ok.any():
        return False
    rec.send_columns(entity, indexes=tb.rerun_columns(np.asarray(frames)[ok]),
                     columns=rr.Scalars.columns(scalars=values[ok]))
    return True


def frame_lengths(frame: np.ndarray, first: int, last: int) -> np.ndarray:
    """Rows per frame (last - first + 1,) for rows already sorted by frame within [first, last]."""
    return np.bincount(np.asarray(frame, np.int64) - first, minlength=last - first + 1)


def sizes_of(table: PoseTable, scene: Scene) -> np.ndarray:
    """(N, 3) l, w, h metres of each row: the table's own sizes where given, else the scene's
    class sizes (``Scene.road_user_sizes``: the one source that conflicts and export use too)."""
    return scene.road_user_sizes(table.cls, table.size)[0]


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


def _project_boxes(camera, xyz: np.ndarray, heading: np.ndarray, size: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Corners (M, 8, 2) pixels of the boxes fully in front of ``camera`` with at least one
    corner in the image and none far outside it (half an image beyond the border: a box beside
    the camera would draw lines across the whole view); also their (M,) indices."""
    n = len(xyz)
    if n == 0:
        return np.zeros((0, 8, 2)), np.zeros(0, np.int64)
    corners = box_corners(xyz, heading, size).reshape(-1, 3)
    uv, _, front = camera.project_points(corners)
    uv = uv.reshape(n, 8, 2)
    w, h = camera.width, camera.height
    near = ((uv[..., 0] > -0.5 * w) & (uv[..., 0] < 1.5 * w) &
            (uv[..., 1] > -0.5 * h) & (uv[..., 1] < 1.5 * h)).all(axis=1)
    keep = (front.reshape(n, 8).all(axis=1) & near &
            camera.in_image(uv.reshape(-1, 2)).reshape(n, 8).any(axis=1))
    idx = np.flatnonzero(keep)
    return uv[idx], idx


def projected_edges(camera, xyz: np.ndarray, heading: np.ndarray, size: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Box edges as 2D segments (M*12, 2, 2) pixels of the boxes ``camera`` sees (see
    ``_project_boxes``); also the (M,) indices of those boxes."""
    uv, idx = _project_boxes(camera, xyz, heading, size)
    return uv[:, EDGES].reshape(-1, 2, 2), idx


def projected_paths(camera, xyz: np.ndarray, heading: np.ndarray, size: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Each seen box as one 16-point polyline (M, 16, 2) pixels over its 12 edges; also the
    (M,) indices of those boxes. A third of the data of ``projected_edges``."""
    uv, idx = _project_boxes(camera, xyz, heading, size)
    return uv[:, PATH], idx


def strips_arrow(points: np.ndarray, offsets: np.ndarray, batch_cls):
    """Many line strips as one Arrow list array of the type of ``batch_cls`` (e.g.
    rr.components.LineStrip2DBatch), built from all points (P, dim) and strip offsets (S+1,)
    without a Python loop over strips (rerun's own conversion walks the strips one by one).
    Rerun takes an Arrow array of the right type as it is."""
    import pyarrow as pa

    dim = points.shape[1]
    inner = pa.FixedSizeListArray.from_arrays(
        pa.array(np.ascontiguousarray(points, dtype=np.float32).ravel()), dim)
    arr = pa.ListArray.from_arrays(pa.array(np.asarray(offsets, np.int32)), inner)
    return arr.cast(batch_cls._ARROW_DATATYPE)


def segments_arrow(segs: np.ndarray, batch_cls):
    """(S, K, dim) strips of K points each as an Arrow array (see ``strips_arrow``)."""
    s, k = segs.shape[:2]
    return strips_arrow(segs.reshape(s * k, -1), np.arange(s + 1) * k, batch_cls)


def trail_points(track_id: np.ndarray, frame: np.ndarray, xyz: np.ndarray, length: int
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Trails of all rows at once: for row i, the track's positions over its last ``length``
    rows up to and including row i (rows of a track taken in frame order). Returns points
    (P, 3) and offsets (N+1,) so that row i's trail is points[offsets[i]:offsets[i+1]]."""
    n = len(track_id)
    if n == 0:
        return np.zeros((0, 3)), np.zeros(1, np.int64)
    order = np.lexsort((frame, track_id))
    tid = track_id[order]
    start = np.flatnonzero(np.r_[True, tid[1:] != tid[:-1]])
    first_of = np.repeat(start, np.diff(np.r_[start, n]))
    i = np.arange(n)
    lo_sorted = np.maximum(first_of, i - length + 1)
    lo = np.empty(n, np.int64)
    hi = np.empty(n, np.int64)
    lo[order], hi[order] = lo_sorted, i  # in the caller's row order, as positions in ``order``
    cnt = hi - lo + 1
    offsets = np.r_[0, np.cumsum(cnt)]
    pos = np.arange(offsets[-1]) - np.repeat(offsets[:-1], cnt) + np.repeat(lo, cnt)
    return xyz[order][pos], offsets


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


class BadMask(ValueError):
    """A mask whose runs do not cover height*width pixels; ``index`` is its position."""

    def __init__(self, index: int, total: int, expected: int):
        super().__init__(f"RLE covers {total} pixels but height*width = {expected}")
        self.index = index


def paint_masks(rles: Sequence[bytes], values: np.ndarray, slot: np.ndarray, height: int,
                width: int, n_slots: int, dtype=np.uint8, check: bool = False) -> np.ndarray:
    """Paint many masks into a stack of label images straight from their RLE runs.

    rles: N compressed COCO RLE strings; values: (N,) label of each mask (class id or instance
    id); slot: (N,) index of the image each mask goes to. Returns (n_slots, height, width)
    images, 0 = background; a mask later in the list is painted over earlier ones. Pixels:
    row-major, (row, col) as in the image. check: raise BadMask when a mask's runs do not add
    up to height*width."""
    hw = height * width
    # paint into column-major images (slot, col, row): an RLE run is then one contiguous range
    out = np.zeros(n_slots * hw, dtype=dtype)
    if len(rles) == 0:
        return out.reshape(n_slots, height, width)
    own, st, ln, total = foreground_runs(rles)
    if check:
        bad = np.flatnonzero(total != hw)
        if len(bad):
            raise BadMask(int(bad[0]), int(total[bad[0]]), hw)
    ln_cs = np.cumsum(ln)
    # flat index of each foreground pixel = its run's start (in its slot) + position in the run
    shift = st + np.asarray(slot, np.int64)[own] * hw - (ln_cs - ln)
    it = np.int32 if n_slots * hw < 2**31 else np.int64  # int32 halves the memory traffic
    idx: np.ndarray = np.arange(int(ln_cs[-1]) if len(ln) else 0, dtype=it)
    idx += np.repeat(shift.astype(it), ln)
    out[idx] = np.repeat(np.asarray(values).astype(dtype)[own], ln)
    # back to row-major (slot, row, col); cv2's transpose is ~3x faster than numpy's here
    import cv2

    cm = out.reshape(n_slots, width, height)
    rm = np.empty((n_slots, height, width), dtype=dtype)
    for j in range(n_slots):
        cv2.transpose(cm[j], dst=rm[j])
    return rm
