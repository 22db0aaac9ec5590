"""Time-to-collision: with both road users continuing at their current velocity (and
heading), the time until their footprints first overlap (Hayward 1972; SSAM's TTC).

Exact for the constant-velocity prediction (``footprints.overlap_interval``), vectorised over
M pair-frames. 0 when the footprints overlap already; NaN when the prediction never makes them
meet, or only after ``horizon_s``.
"""

from __future__ import annotations

import numpy as np

from seg2pose.safety.footprints import Footprints, overlap_interval


def ttc(xy_a, heading_a, size_a, vel_a, xy_b, heading_b, size_b, vel_b,
        horizon_s: float = np.inf) -> np.ndarray:
    """(M,) seconds (NaN: no collision on the current course within ``horizon_s``).
    Positions (M, 2) metres, headings (M,) radians, sizes (M, 2) length, width metres,
    velocities (M, 2) m/s."""
    enter, leave = overlap_interval(xy_a, heading_a, size_a, xy_b, heading_b, size_b,
                                    np.asarray(vel_b, float) - np.asarray(vel_a, float))
    return from_interval(enter, leave, horizon_s)


def ttc_rows(fp: Footprints, vx: np.ndarray, vy: np.ndarray, a: np.ndarray, b: np.ndarray,
             horizon_s: float = np.inf) -> np.ndarray:
    """``ttc`` of rows a (M,) and b (M,) of ``fp`` (the rows' footprints), moving at (vx, vy)
    (N,) each: the same values, bit for bit, without recomputing each row's geometry."""
    enter, leave = fp.interval(a, b, vx[b] - vx[a], vy[b] - vy[a])
    return from_interval(enter, leave, horizon_s)


def from_interval(enter: np.ndarray, leave: np.ndarray, horizon_s: float) -> np.ndarray:
    """TTC from the overlap interval of the predicted footprints."""
    hit = (enter <= leave) & (leave >= 0) & (enter <= horizon_s)
    return np.where(hit, np.maximum(enter, 0.0), np.nan)
