"""Headings along the motion: keyframes placed without a heading take the direction of motion
from their neighbouring keyframes, and follow it as those neighbours change, until the
annotator sets the heading (rotates the keyframe or gives one).

Such keyframes carry the flag ``AUTO`` ("auto_heading"). After every edit the project asks
``auto_heading_op`` for the operation that brings their headings up to date, and journals it
with the edit (one undoable step; replay needs no geometry).

The direction at keyframe k is that of the chord from its previous to its next keyframe
(central difference: the tangent at the middle of a circular arc through three equally spaced
keyframes); at the ends, the one chord there. A road user that moved less than ``MIN_STEP``
metres over that chord stands still: it keeps the previous keyframe's heading (or its own).
"""

from __future__ import annotations

import math

import numpy as np

from annotate.model import Track

AUTO = "auto_heading"
MIN_STEP = 0.3  # metres over the neighbouring chord: less is standing still


def motion_headings(xy: np.ndarray, heading: np.ndarray, auto: np.ndarray,
                    min_step: float = MIN_STEP) -> np.ndarray:
    """Headings (K,) radians for keyframes at xy (K, 2) metres, sorted by frame: ``heading``
    where ``auto`` (K,) bool is False, else the direction of motion (module docstring)."""
    xy = np.asarray(xy, dtype=np.float64)
    h = np.asarray(heading, dtype=np.float64).copy()
    n = len(h)
    for k in np.flatnonzero(np.asarray(auto, bool)):
        a, b = max(int(k) - 1, 0), min(int(k) + 1, n - 1)
        d = xy[b] - xy[a]
        if math.hypot(d[0], d[1]) > min_step:
            h[k] = math.atan2(d[1], d[0])
        elif k > 0:
            h[k] = h[k - 1]  # standing still: the last heading (already resolved, k-1 < k)
    return h


def auto_heading_op(track: Track) -> dict | None:
    """The ``set_keyframes`` operation that brings ``track``'s auto headings up to date (None
    when they are)."""
    frames = track.frames
    kfs = [track.keyframes[f] for f in frames]
    auto = np.array([AUTO in k.flags for k in kfs], bool)
    if not auto.any():
        return None
    xy = np.array([[k.x, k.y] for k in kfs])
    new = motion_headings(xy, np.array([k.heading for k in kfs]), auto)
    new = (new + math.pi) % (2 * math.pi) - math.pi
    rows = [[f, k.x, k.y, float(h), list(k.flags)]
            for f, k, h, a in zip(frames, kfs, new, auto)
            if a and abs(math.remainder(h - k.heading, 2 * math.pi)) > 1e-12]
    return {"op": "set_keyframes", "id": track.id, "set": rows} if rows else None
