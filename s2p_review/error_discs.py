"""The error bar of each estimated pose in review: a disc on the ground under the road user
with radius r90_m (the radius that holds the true position with 90 % probability,
``seg2pose.method.uncertainty``), outlined in a colour by size -- green for a tight bar, through
yellow, to red at ``R90_RED_M`` and beyond -- so that the poses to distrust stand out.

Each disc is drawn on its road user's own entity (``road_users``), so that hiding the road
user hides its disc. Runs without r90_m (older runs, runs without a calibration) draw nothing.
"""

from __future__ import annotations

import numpy as np

R90_RED_M = 3.0        # metres: the radius drawn fully red
DISC_POINTS = 25       # points per outline (24 segments, closed)
LIFT_M = 0.03          # drawn this far above the ground point, over the road's texture


def disc_outlines(xyz: np.ndarray, r90: np.ndarray, n: int = DISC_POINTS) -> np.ndarray:
    """(N, n, 3) closed circles of radius r90 (N,) metres around xyz (N, 3) in the ground's
    horizontal plane, lifted by LIFT_M."""
    a = np.linspace(0.0, 2.0 * np.pi, n)
    ring = np.stack([np.cos(a), np.sin(a), np.zeros(n)], axis=1)
    return xyz[:, None, :] + r90[:, None, None] * ring[None] + [0.0, 0.0, LIFT_M]


def r90_colors(r90: np.ndarray, red_m: float = R90_RED_M) -> np.ndarray:
    """(N, 4) uint8 RGBA: green (0 m) -> yellow (red_m / 2) -> red (>= red_m)."""
    s = np.clip(np.asarray(r90, float) / red_m, 0.0, 1.0)
    r = np.clip(2.0 * s, 0.0, 1.0)
    g = np.clip(2.0 * (1.0 - s), 0.0, 1.0)
    out = np.column_stack([r * 255, g * 200, np.full(len(s), 40.0), np.full(len(s), 230.0)])
    return np.round(out).astype(np.uint8)
