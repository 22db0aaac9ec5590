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
               xy2: np.ndarray | None = None, t2: np.ndarray | None = None) -> np.ndarray:
    """(P, 2) index pairs with |dx|, |dy| <= r and |t_i - t_j| <= dt: i < j within one set of
    points, or i of the first set and j of the second (``xy2``, ``t2``)."""
    scale = r / dt if dt > 0 else 1e6 * (r + 1.0)  # dt = 0: one frame apart is far beyond r
    if xy2 is None:
        if len(xy) < 2:
            return np.zeros((0, 2), np.int64)
        tree = cKDTree(np.c_[xy, t * scale], balanced_tree=False, compact_nodes=False)
        return tree.query_pairs(r, p=np.inf, output_type="ndarray").astype(np.int64)
    if len(xy) == 0 or len(xy2) == 0:
        return np.zeros((0, 2), np.int64)
    t1 = cKDTree(np.c_[xy, t * scale], balanced_tree=False, compact_nodes=False)
    t2_ = cKDTree(np.c_[xy2, t2 * scale], balanced_tree=False, compact_nodes=False)
    m = t1.sparse_distance_matrix(t2_, r, p=np.inf, output_type="ndarray")
    return np.c_[m["i"], m["j"]].astype(np.int64)


def near_pairs(tracks: Tracks, rows: np.ndarray, r: float, dt: float = 0.0,
               chunk_s: float = CHUNK_S, other: np.ndarray | None = None) -> np.ndarray:
    """(P, 2) pairs of indices into ``tracks`` (taken from ``rows``; or one from ``rows`` and
    one from ``other``), of different road users, within ``r`` metres in x and y (a box:
    callers filter by distance as they need) and ``dt`` seconds; each pair once, first index
    the lower track id."""
    rows = np.asarray(rows, np.int64)
    t = tracks.t[rows]
    out = []
    if other is not None:
        other = np.asarray(other, np.int64)
        t2 = tracks.t[other]
    if len(rows) and (other is None or len(other)):
        t0 = float(min(t.min(), t2.min())) if other is not None else float(t.min())
        k = np.floor((t - t0) / chunk_s).astype(np.int64)
        k2 = None if other is None else np.floor((t2 - t0) / chunk_s).astype(np.int64)
        for c in np.unique(k if other is None else np.r_[k, k2]):
            # a chunk and dt seconds of the next one: pairs across the border are found once
            sel = np.flatnonzero((k == c) | ((k == c + 1) & (t - t0 - (c + 1) * chunk_s <= dt)))
            if other is None:
                p = sel[_box_pairs(tracks.xy[rows[sel]], t[sel], r, dt)]
                keep = (k[p[:, 0]] == c) | (k[p[:, 1]] == c)  # not both in the next chunk
                out.append(rows[p[keep]])
            else:
                sel2 = np.flatnonzero((k2 == c) | ((k2 == c + 1) & (t2 - t0 - (c + 1) * chunk_s <= dt)))
                p = _box_pairs(tracks.xy[rows[sel]], t[sel], r, dt, tracks.xy[other[sel2]], t2[sel2])
                i, j = sel[p[:, 0]], sel2[p[:, 1]]
                keep = (k[i] == c) | (k2[j] == c)
                out.append(np.c_[rows[i[keep]], other[j[keep]]])
    pairs = np.concatenate(out) if out else np.zeros((0, 2), np.int64)
    tid = tracks.track_id
    pairs = pairs[tid[pairs[:, 0]] != tid[pairs[:, 1]]]
    swap = tid[pairs[:, 0]] > tid[pairs[:, 1]]
    pairs[swap] = pairs[swap][:, ::-1]
    return pairs


def pair_codes(track_a: np.ndarray, track_b: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """(M,) int64 codes of pairs of track ids (one code per pair, ordered as (a, b));
    ``ids``: the sorted unique track ids (faster than ``np.unique(axis=0)`` on pairs)."""
    n = np.int64(len(ids))
    return np.searchsorted(ids, track_a) * n + np.searchsorted(ids, track_b)
