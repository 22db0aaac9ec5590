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


def overlap_interval(xy_a, heading_a, size_a, xy_b, heading_b, size_b, v_rel):
    """Times (enter, leave), (M,) each in seconds from now, between which footprint B, moving
    at ``v_rel`` (M, 2) m/s relative to A, overlaps footprint A. enter > leave: never (at this
    relative velocity); -inf / inf: the overlap started before / lasts for ever (no relative
    motion along some axis).

    Written out per axis in components (no (M, 2) temporaries): on A's axis along its heading
    A projects to +-l_a / 2 and B to +-(l_b |cos| + w_b |sin|) / 2 of the angle between them,
    and so on for the other three axes."""
    xy_a, xy_b, v_rel = (np.asarray(x, np.float64) for x in (xy_a, xy_b, v_rel))
    size_a, size_b = np.asarray(size_a, np.float64), np.asarray(size_b, np.float64)
    ca, sa = np.cos(heading_a), np.sin(heading_a)
    cb, sb = np.cos(heading_b), np.sin(heading_b)
    cd = np.abs(ca * cb + sa * sb)  # |cos| and |sin| of the angle between the headings
    sd = np.abs(sa * cb - ca * sb)
    la, wa = size_a[:, 0] / 2, size_a[:, 1] / 2
    lb, wb = size_b[:, 0] / 2, size_b[:, 1] / 2
    rx, ry = xy_b[:, 0] - xy_a[:, 0], xy_b[:, 1] - xy_a[:, 1]
    vx, vy = v_rel[:, 0], v_rel[:, 1]
    M = len(rx)
    enter = np.full(M, -np.inf)
    leave = np.full(M, np.inf)
    axes = ((ca, sa, la + lb * cd + wb * sd), (-sa, ca, wa + lb * sd + wb * cd),
            (cb, sb, lb + la * cd + wa * sd), (-sb, cb, wb + la * sd + wa * cd))
    with np.errstate(divide="ignore", invalid="ignore"):
        for ux, uy, R in axes:
            s0 = rx * ux + ry * uy
            rate = vx * ux + vy * uy
            still = np.abs(rate) < 1e-12
            inside = np.abs(s0) <= R
            t1 = (-R - s0) / rate
            t2 = (R - s0) / rate
            lo = np.where(still, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2))
            hi = np.where(still, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2))
            np.maximum(enter, lo, out=enter)
            np.minimum(leave, hi, out=leave)
    return enter, leave


def overlaps(xy_a, heading_a, size_a, xy_b, heading_b, size_b) -> np.ndarray:
    """(M,) bool: footprints A and B overlap (touching counts): on none of the 4 axes are
    their projections apart (the static case of ``overlap_interval``, without its divisions)."""
    xy_a, xy_b = np.asarray(xy_a, np.float64), np.asarray(xy_b, np.float64)
    size_a, size_b = np.asarray(size_a, np.float64), np.asarray(size_b, np.float64)
    ca, sa = np.cos(heading_a), np.sin(heading_a)
    cb, sb = np.cos(heading_b), np.sin(heading_b)
    cd = np.abs(ca * cb + sa * sb)
    sd = np.abs(sa * cb - ca * sb)
    la, wa = size_a[:, 0] / 2, size_a[:, 1] / 2
    lb, wb = size_b[:, 0] / 2, size_b[:, 1] / 2
    rx, ry = xy_b[:, 0] - xy_a[:, 0], xy_b[:, 1] - xy_a[:, 1]
    out = np.abs(rx * ca + ry * sa) <= la + lb * cd + wb * sd
    out &= np.abs(ry * ca - rx * sa) <= wa + lb * sd + wb * cd
    out &= np.abs(rx * cb + ry * sb) <= lb + la * cd + wa * sd
    out &= np.abs(ry * cb - rx * sb) <= wb + la * sd + wa * cd
    return out


def reach(size: np.ndarray) -> np.ndarray:
    """(M,) half diagonals, metres: two footprints whose centres are farther apart than the sum
    of theirs cannot overlap."""
    return 0.5 * np.hypot(size[:, 0], size[:, 1])
