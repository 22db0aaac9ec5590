"""Footprints: each road user an oriented rectangle (length l along its heading, width w) on
the ground, and the separating-axis tests on them, vectorised over M pairs.

Two convex polygons are apart exactly when their projections on one of their edge normals
are apart; for two rectangles those are the 4 axes of their two headings. When B moves at a
constant velocity relative to A (neither turning), the projections on each axis overlap over
one interval of time; the rectangles overlap over the intersection of the 4 intervals. That
gives TTC (the start of that interval) and the exact times a footprint enters or leaves
another one, with no time stepping.
"""

from __future__ import annotations

import numpy as np


def directions(heading: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(M,) radians -> unit vectors along (M, 2) and across (M, 2) the heading."""
    c, s = np.cos(heading), np.sin(heading)
    return np.stack([c, s], -1), np.stack([-s, c], -1)


def corners(xy: np.ndarray, heading: np.ndarray, size: np.ndarray) -> np.ndarray:
    """(M, 4, 2) corners, front left first, counter-clockwise, of footprints at ``xy`` (M, 2)
    with ``heading`` (M,) and ``size`` (M, 2) length, width in metres."""
    d, n = directions(heading)
    hl, hw = size[:, :1] / 2, size[:, 1:2] / 2
    return np.stack([xy + d * hl + n * hw, xy - d * hl + n * hw, xy - d * hl - n * hw,
                     xy + d * hl - n * hw], axis=1)


def _half_extent(u: np.ndarray, d: np.ndarray, n: np.ndarray, size: np.ndarray) -> np.ndarray:
    """(M,) half the length of the projection of a rectangle (along d, across n) on axis u."""
    return (size[:, 0] / 2 * np.abs(_dot(d, u)) + size[:, 1] / 2 * np.abs(_dot(n, u)))


def _dot(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """(M,) row-wise dot products of (M, 2) arrays (faster than (p * q).sum(-1))."""
    return p[:, 0] * q[:, 0] + p[:, 1] * q[:, 1]


def overlap_interval(xy_a, heading_a, size_a, xy_b, heading_b, size_b, v_rel):
    """Times (enter, leave), (M,) each in seconds from now, between which footprint B, moving
    at ``v_rel`` (M, 2) m/s relative to A, overlaps footprint A. enter > leave: never (at this
    relative velocity); -inf / inf: the overlap started before / lasts for ever (no relative
    motion along some axis)."""
    da, na = directions(heading_a)
    db, nb = directions(heading_b)
    rel = xy_b - xy_a
    M = len(rel)
    enter = np.full(M, -np.inf)
    leave = np.full(M, np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        for u in (da, na, db, nb):
            s0 = _dot(rel, u)
            rate = _dot(v_rel, u)
            R = _half_extent(u, da, na, size_a) + _half_extent(u, db, nb, size_b)
            still = np.abs(rate) < 1e-12
            t1 = (-R - s0) / rate
            t2 = (R - s0) / rate
            lo = np.where(still, np.where(np.abs(s0) <= R, -np.inf, np.inf), np.minimum(t1, t2))
            hi = np.where(still, np.where(np.abs(s0) <= R, np.inf, -np.inf), np.maximum(t1, t2))
            enter = np.maximum(enter, lo)
            leave = np.minimum(leave, hi)
    return enter, leave


def overlaps(xy_a, heading_a, size_a, xy_b, heading_b, size_b) -> np.ndarray:
    """(M,) bool: footprints A and B overlap (touching counts)."""
    enter, leave = overlap_interval(xy_a, heading_a, size_a, xy_b, heading_b, size_b,
                                    np.zeros_like(xy_a))
    return enter <= leave


def reach(size: np.ndarray) -> np.ndarray:
    """(M,) half diagonals, metres: two footprints whose centres are farther apart than the sum
    of theirs cannot overlap."""
    return 0.5 * np.hypot(size[:, 0], size[:, 1])
