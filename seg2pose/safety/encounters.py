"""The spatial pre-filter: which road users are near each other, found for all frames at once.

A long recording has millions of rows; comparing every pair in every frame would be most of
the work and almost all of it useless. One k-d tree over (x, y, time) finds, in a single
query, every pair of rows that lie within a box of half-side ``r`` in x and y and within
``dt`` in time: the time axis is scaled so that ``dt`` seconds equal ``r`` metres, and the
query uses the maximum-coordinate (Chebyshev) distance. With ``dt`` = 0 this is the same-frame
pairs (frames are scaled far apart). The query runs over time chunks to bound memory.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from seg2pose.safety.tracks import Tracks

CHUNK_S = 120.0  # seconds of recording per k-d tree (memory: pairs of one chunk at a time)


def _box_pairs(xy: np.ndarray, t: np.ndarray, r: float, dt: float,
               xy2: np.ndarray | None = None, t2: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i, j), (P,) each, with |dx|, |dy| <= r and |t_i - t_j| <= dt: i < j within
    one set of points, or i of the first set and j of the second (``xy2``, ``t2``)."""
    scale = r / dt if dt > 0 else 1e6 * (r + 1.0)  # dt = 0: one frame apart is far beyond r
    e = np.zeros(0, np.int64)
    if xy2 is None:
        if len(xy) < 2:
            return e, e
        tree = cKDTree(np.c_[xy, t * scale], balanced_tree=False, compact_nodes=False)
        m = tree.query_pairs(r, p=np.inf, output_type="ndarray")
        return m[:, 0].astype(np.int64), m[:, 1].astype(np.int64)
    if len(xy) == 0 or len(xy2) == 0:
        return e, e
    assert t2 is not None  # given with xy2
    t1 = cKDTree(np.c_[xy, t * scale], balanced_tree=False, compact_nodes=False)
    t2_ = cKDTree(np.c_[xy2, t2 * scale], balanced_tree=False, compact_nodes=False)
    m = t1.sparse_distance_matrix(t2_, r, p=np.inf, output_type="ndarray")
    return m["i"].astype(np.int64), m["j"].astype(np.int64)


def near_pairs(tracks: Tracks, rows: np.ndarray, r: float, dt: float = 0.0,
               chunk_s: float = CHUNK_S, other: np.ndarray | None = None,
               apart: np.ndarray | None = None) -> np.ndarray:
    """(P, 2) pairs of indices into ``tracks`` (taken from ``rows``; or one from ``rows`` and
    one from ``other``), of different road users, within ``r`` metres in x and y (a box:
    callers filter by distance as they need) and ``dt`` seconds; each pair once, first index
    the lower track id. ``apart``: (N,) bool, rows never paired with each other (pairs of two
    pedestrians where the table leaves them out): the pairs are those of the other rows
    among themselves and with them (the same pairs, in another order, as without ``apart``
    and then dropping the pairs of two ``apart`` rows)."""
    rows = np.asarray(rows, np.int64)
    if apart is not None:
        a1, o1 = rows[~apart[rows]], rows[apart[rows]]
        if other is None:
            parts = [near_pairs(tracks, a1, r, dt, chunk_s), near_pairs(tracks, a1, r, dt, chunk_s, o1)]
        else:
            other = np.asarray(other, np.int64)
            a2 = other[~apart[other]]  # apart x apart pairs are left out
            parts = [near_pairs(tracks, a1, r, dt, chunk_s, other),
                     near_pairs(tracks, o1, r, dt, chunk_s, a2)]
        return np.concatenate(parts)
    t = tracks.frame[rows] / tracks.fps  # tracks.t of these rows (not of all)
    out_a, out_b = [], []
    if other is not None:
        other = np.asarray(other, np.int64)
        t2 = tracks.frame[other] / tracks.fps
    if len(rows) and (other is None or len(other)):
        t0 = float(min(t.min(), t2.min())) if other is not None else float(t.min())
        k = np.floor((t - t0) / chunk_s).astype(np.int64)
        k2 = None if other is None else np.floor((t2 - t0) / chunk_s).astype(np.int64)
        for c in np.unique(k if other is None else np.r_[k, k2]):
            # a chunk and dt seconds of the next one: pairs across the border are found once
            sel = np.flatnonzero((k == c) | ((k == c + 1) & (t - t0 - (c + 1) * chunk_s <= dt)))
            if other is None:
                i, j = _box_pairs(tracks.xy[rows[sel]], t[sel], r, dt)
                i, j = sel[i], sel[j]
                keep = (k[i] == c) | (k[j] == c)  # not both in the next chunk
                out_a.append(rows[i[keep]])
                out_b.append(rows[j[keep]])
            else:
                sel2 = np.flatnonzero((k2 == c) | ((k2 == c + 1) & (t2 - t0 - (c + 1) * chunk_s <= dt)))
                i, j = _box_pairs(tracks.xy[rows[sel]], t[sel], r, dt, tracks.xy[other[sel2]], t2[sel2])
                i, j = sel[i], sel2[j]
                assert k2 is not None  # other is given
                keep = (k[i] == c) | (k2[j] == c)
                out_a.append(rows[i[keep]])
                out_b.append(other[j[keep]])
    return _ordered(tracks, out_a, out_b)


def _ordered(tracks: Tracks, out_a: list, out_b: list) -> np.ndarray:
    """(P, 2) the pairs of rows (a, b) of different road users, the lower track id first."""
    if not out_a:
        return np.zeros((0, 2), np.int64)
    a, b = np.concatenate(out_a), np.concatenate(out_b)
    tid = tracks.track_id
    ta, tb = tid[a], tid[b]
    diff = ta != tb
    if not diff.all():
        a, b, ta, tb = a[diff], b[diff], ta[diff], tb[diff]
    swap = ta > tb
    return np.c_[np.where(swap, b, a), np.where(swap, a, b)]


# same-frame pairs are enumerated frame by frame (all pairs of the road users in view, then
# the box) while that is at most this many pairs per row; denser scenes use the k-d tree
ENUMERATE_PER_ROW = 100


def frame_pairs(tracks: Tracks, rows: np.ndarray, r: float,
                apart: np.ndarray | None = None) -> np.ndarray:
    """``near_pairs(tracks, rows, r, 0.0, apart=apart)``: the pairs of rows in the same frame
    within the box of half-side ``r`` (the same set; in another order). With a few dozen road
    users in view, listing every pair of a frame and keeping those in the box costs less than
    the k-d tree; with many more (over ``ENUMERATE_PER_ROW`` pairs per row), the k-d tree."""
    rows = np.asarray(rows, np.int64)
    f = tracks.frame[rows]
    o = np.argsort(f, kind="stable")  # rows of a frame keep their order: by track id
    rs, fs = rows[o], f[o]
    n = len(rs)
    if n < 2:
        return np.zeros((0, 2), np.int64)
    st = np.flatnonzero(np.r_[True, fs[1:] != fs[:-1]])
    cnt = np.diff(np.r_[st, n])
    if float((cnt * (cnt - 1) // 2).sum()) > ENUMERATE_PER_ROW * n:
        return near_pairs(tracks, rows, r, 0.0, apart=apart)
    pos = np.arange(n) - np.repeat(st, cnt)
    later = np.repeat(cnt, cnt) - 1 - pos  # rows after this one in its frame
    i = np.repeat(np.arange(n), later)
    first = np.cumsum(later) - later
    j = i + 1 + (np.arange(len(i)) - np.repeat(first, later))
    a, b = rs[i], rs[j]  # a's track id is the lower (same frame, track order)
    x, y = tracks.xy[:, 0], tracks.xy[:, 1]
    keep = (np.abs(x[a] - x[b]) <= r) & (np.abs(y[a] - y[b]) <= r)
    if apart is not None:
        keep &= ~(apart[a] & apart[b])
    return np.c_[a[keep], b[keep]]


def class_rows(cls: np.ndarray, name: str) -> np.ndarray:
    """(N,) bool: rows whose class is ``name`` (case-insensitive); the class names are
    compared once per run of equal names (rows come track by track)."""
    n = len(cls)
    if n == 0:
        return np.zeros(0, bool)
    heads = np.flatnonzero(np.r_[True, cls[1:] != cls[:-1]])
    hit = np.array([str(c).lower() == name for c in cls[heads]], bool)
    return np.repeat(hit, np.diff(np.r_[heads, n]))


def pair_codes(track_a: np.ndarray, track_b: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """(M,) int64 codes of pairs of track ids (one code per pair, ordered as (a, b));
    ``ids``: the sorted unique track ids (faster than ``np.unique(axis=0)`` on pairs)."""
    n = np.int64(len(ids))
    return np.searchsorted(ids, track_a) * n + np.searchsorted(ids, track_b)
