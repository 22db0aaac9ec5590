"""Smoothing along a track: each value replaced by a local fit over the same road user's
values within ``half_window`` frames (a centred window, so no lag on steady motion).

Used on Seg2PoseNet's residuals per view (the residual of one road user seen by one camera
changes slowly with its distance and heading, while the network's per-frame noise does not),
and, for an honest comparison, on the fused positions of any run (the baseline included).

Vectorised over all rows: rows are sorted by (track, frame) and every window sum is a
difference of cumulative sums, so gaps in a track are handled exactly (the window counts
frames, not rows) and the cost is O(N log N) for N rows.
"""

from __future__ import annotations

import numpy as np


def smooth_along_tracks(track_key: np.ndarray, frame: np.ndarray, values: np.ndarray,
                        half_window: int, degree: int = 0) -> np.ndarray:
    """Values (N, D) smoothed along each track: at row i, the least-squares polynomial of
    ``degree`` (0: the mean, 1: a line) in the frame number, fitted to the rows of the same
    track whose frame is within ``half_window`` of row i's, evaluated at row i's frame.

    track_key: (N,) ints (rows with a negative key are untracked and left as they are; so are
    NaN values, which also take no part in their neighbours' fits); frame: (N,) ints;
    values: (N, D) floats. ``half_window`` 0 returns a copy. A line needs two distinct
    frames; with fewer the mean is used."""
    values = np.asarray(values, dtype=np.float64)
    out = values.copy()
    if half_window <= 0 or len(values) == 0:
        return out
    if degree not in (0, 1):
        raise ValueError(f"degree must be 0 or 1, got {degree}")
    track_key = np.asarray(track_key, dtype=np.int64)
    frame = np.asarray(frame, dtype=np.int64)
    ok = (track_key >= 0) & np.isfinite(values).all(axis=1)
    rows = np.flatnonzero(ok)
    if len(rows) == 0:
        return out
    order = rows[np.lexsort((frame[rows], track_key[rows]))]
    tk, fr, v = track_key[order], frame[order], values[order]
    # one sortable key per row: the track's rank times a stride larger than any window
    _, rank = np.unique(tk, return_inverse=True)
    t0 = np.minimum.reduceat(fr, np.flatnonzero(np.r_[True, tk[1:] != tk[:-1]]))[rank]
    t = (fr - t0).astype(np.float64)           # frames since the track's first row
    stride = int(t.max(initial=0)) + 2 * half_window + 2
    key = rank.astype(np.int64) * stride + (fr - t0)
    lo = np.searchsorted(key, key - half_window, side="left")
    hi = np.searchsorted(key, key + half_window, side="right")

    def window_sum(x: np.ndarray) -> np.ndarray:
        c = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(x, axis=0)])
        return c[hi] - c[lo]

    n = (hi - lo).astype(np.float64)[:, None]
    mean_v = window_sum(v) / n
    if degree == 1:
        st = window_sum(t[:, None])
        mean_t = st / n
        var_t = window_sum(t[:, None] ** 2) / n - mean_t ** 2
        cov = window_sum(t[:, None] * v) / n - mean_t * mean_v
        line = var_t > 1e-9
        slope = np.where(line, cov / np.where(line, var_t, 1.0), 0.0)
        mean_v = mean_v + slope * (t[:, None] - mean_t)
    out[order] = mean_v
    return out
