"""The ground of a new site from the elevations a user knows: clicked points with an elevation
and surveyed points, a least-squares plane through them with its residuals, and ground points
for eq. (1) (geometry/ground.py): the measured points themselves (they carry kerbs and local
slopes) plus points of the fitted plane on a grid where no measured point is near, so that
eq. (1) stays on the plane away from them. With fewer than three elevations (or all on one
line) nothing is known about the slope: the ground is flat, at the mean known elevation (0 m
when none is known), and the summary says so.

Units: metres, world z up.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

GRID_STEP = 5.0  # metres between the plane's grid points
NEAR = 3.0  # metres: no plane point this close to a measured point
MARGIN = 20.0  # metres of plane around the points' extent


@dataclass
class GroundFit:
    """coef (a, b, c) of z = a x + b y + c (None: flat at ``c``), residuals (n,) metres of the
    measured points against it, ``points`` (m, 3) the ground points to write, ``summary``."""

    coef: tuple[float, float, float] | None
    level: float
    residuals: np.ndarray
    points: np.ndarray
    summary: str

    def height(self, xy: np.ndarray) -> np.ndarray:
        """The fitted plane's (or the flat ground's) z (M,) at xy (M, 2)."""
        xy = np.asarray(xy, float).reshape(-1, 2)
        if self.coef is None:
            return np.full(len(xy), self.level)
        a, b, c = self.coef
        return a * xy[:, 0] + b * xy[:, 1] + c


def fit_plane(P: np.ndarray) -> tuple[float, float, float] | None:
    """Least-squares z = a x + b y + c through P (n, 3); None when n < 3 or the points'
    xy lie on one line (the slope across it is unknown)."""
    P = np.asarray(P, float).reshape(-1, 3)
    if len(P) < 3:
        return None
    xy = P[:, :2] - P[:, :2].mean(0)
    sv = np.linalg.svd(xy, compute_uv=False)
    if sv[1] / np.sqrt(len(P)) < 0.5:  # spread under ~0.5 m across: no slope across it
        return None
    A = np.column_stack([P[:, :2], np.ones(len(P))])
    coef = np.linalg.lstsq(A, P[:, 2], rcond=None)[0]
    return float(coef[0]), float(coef[1]), float(coef[2])


def ground_from_elevations(known: np.ndarray, extent_xy: np.ndarray, step: float = GRID_STEP
                           ) -> GroundFit:
    """Ground points from known elevations ``known`` (n, 3) over the area ``extent_xy`` (m, 2)
    (e.g. every clicked point's xy), see the module doc."""
    known = np.asarray(known, float).reshape(-1, 3)
    if len(known):  # the same spot measured twice: one point, the mean elevation
        _, inv = np.unique(np.round(known[:, :2], 3), axis=0, return_inverse=True)
        inv = inv.ravel()
        known = np.array([known[inv == k].mean(0) for k in range(inv.max() + 1)])
    ext = np.vstack([np.asarray(extent_xy, float).reshape(-1, 2), known[:, :2]])
    coef = fit_plane(known)
    level = float(known[:, 2].mean()) if len(known) else 0.0
    if coef is None:
        residuals = known[:, 2] - level
        why = ("no elevation known" if not len(known) else
               f"{len(known)} elevation(s), too few or on one line for a slope")
        summary = f"flat ground at z = {level:.2f} m ({why}; the slope is not known)"
    else:
        a, b, c = coef
        residuals = known[:, 2] - (a * known[:, 0] + b * known[:, 1] + c)
        slope = float(np.hypot(a, b))
        summary = (f"plane through {len(known)} elevations: slope {100 * slope:.1f} % towards "
                   f"{np.degrees(np.arctan2(b, a)):.0f} deg, residuals rms "
                   f"{np.sqrt(np.mean(residuals ** 2)):.3f} m, max {np.abs(residuals).max():.3f} m")
    lo, hi = ext.min(0) - MARGIN, ext.max(0) + MARGIN
    gx, gy = np.meshgrid(np.arange(lo[0], hi[0] + step / 2, step), np.arange(lo[1], hi[1] + step / 2, step))
    grid = np.column_stack([gx.ravel(), gy.ravel()])
    if len(known):
        d = np.min(np.linalg.norm(grid[:, None, :] - known[None, :, :2], axis=2), axis=1)
        grid = grid[d > NEAR]
    fit = GroundFit(coef, level, residuals, np.empty((0, 3)), summary)
    fit.points = np.vstack([known, np.column_stack([grid, fit.height(grid)])])
    return fit
