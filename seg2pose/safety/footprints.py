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
    return _interval(xy_b[:, 0] - xy_a[:, 0], xy_b[:, 1] - xy_a[:, 1], v_rel[:, 0], v_rel[:, 1],
                     np.cos(heading_a), np.sin(heading_a), size_a[:, 0] / 2, size_a[:, 1] / 2,
                     np.cos(heading_b), np.sin(heading_b), size_b[:, 0] / 2, size_b[:, 1] / 2)


def _interval(rx, ry, vx, vy, ca, sa, la, wa, cb, sb, lb, wb):
    """``overlap_interval`` from components: B's centre relative to A's (rx, ry), B's velocity
    relative to A's (vx, vy), the headings' cosines and sines, half lengths and widths."""
    M = len(rx)
    enter = np.full(M, -np.inf)
    leave = np.full(M, np.inf)
    axes = separating_axes(ca, sa, la, wa, cb, sb, lb, wb)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # inf: never / for ever
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
    return _overlaps(xy_b[:, 0] - xy_a[:, 0], xy_b[:, 1] - xy_a[:, 1],
                     np.cos(heading_a), np.sin(heading_a), size_a[:, 0] / 2, size_a[:, 1] / 2,
                     np.cos(heading_b), np.sin(heading_b), size_b[:, 0] / 2, size_b[:, 1] / 2)


def _overlaps(rx, ry, ca, sa, la, wa, cb, sb, lb, wb) -> np.ndarray:
    (ux0, uy0, R0), *rest = separating_axes(ca, sa, la, wa, cb, sb, lb, wb)
    out = np.abs(rx * ux0 + ry * uy0) <= R0
    for ux, uy, R in rest:
        out &= np.abs(rx * ux + ry * uy) <= R
    return out


def separating_axes(ca, sa, la, wa, cb, sb, lb, wb):
    """The 4 axes on which two rectangles are tested (A's length and width directions, then
    B's), each (ux, uy, R): the axis's direction and the half-width R of the pair's combined
    projection on it. The rectangles (headings' cosines ``ca``, ``cb`` and sines ``sa``,
    ``sb``; half lengths ``la``, ``lb`` and widths ``wa``, ``wb``) overlap where B's centre
    relative to A's projects within R on every axis. On A's axis along its heading A projects
    to +-la and B to +-(lb |cos| + wb |sin|) of the angle between them, and so on."""
    cd = np.abs(ca * cb + sa * sb)  # |cos| and |sin| of the angle between the headings
    sd = np.abs(sa * cb - ca * sb)
    return ((ca, sa, la + lb * cd + wb * sd), (-sa, ca, wa + lb * sd + wb * cd),
            (cb, sb, lb + la * cd + wa * sd), (-sb, cb, wb + la * sd + wa * cd))


class Footprints:
    """The footprints of N rows, kept per row in the form the tests use, so that testing
    many pairs of the same rows gathers them instead of recomputing them per pair: centre
    x, y; the heading's cosine and sine; half length and width; the half diagonal
    (``reach``). ``overlap`` and ``interval`` give the same answers, bit for bit, as
    ``overlaps`` and ``overlap_interval`` on the same rows."""

    def __init__(self, xy: np.ndarray, heading: np.ndarray, size: np.ndarray):
        xy, size = np.asarray(xy, np.float64), np.asarray(size, np.float64)
        self.x, self.y = xy[:, 0], xy[:, 1]  # views: gathers from them cost no more
        self.cos, self.sin = np.cos(heading), np.sin(heading)
        self.hl, self.hw = size[:, 0] / 2, size[:, 1] / 2
        self.reach = reach(size)

    def grown(self, by: np.ndarray) -> Footprints:
        """The same rows with footprints ``by`` (N,) metres longer and wider (as if made
        with size + by on both sides: the same values), sharing the centres and headings."""
        out = Footprints.__new__(Footprints)
        out.x, out.y, out.cos, out.sin = self.x, self.y, self.cos, self.sin
        size = np.c_[self.hl * 2 + by, self.hw * 2 + by]
        out.hl, out.hw = size[:, 0] / 2, size[:, 1] / 2
        out.reach = reach(size)
        return out

    def near(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """(M,) bool: rows a and b (M,) no farther apart, centre to centre, than the sum of
        their half diagonals (with a margin of 1e-9 of it for rounding): footprints overlap
        only where this holds, so it is an exact pre-filter (no trigonometry)."""
        dx = self.x[b] - self.x[a]
        dy = self.y[b] - self.y[a]
        r = (self.reach[a] + self.reach[b]) * (1.0 + 1e-9)
        return dx * dx + dy * dy <= r * r

    def overlap(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """(M,) bool: the footprints of rows a (M,) and b (M,) overlap (``overlaps``)."""
        out = self.near(a, b)
        i = np.flatnonzero(out)
        a, b = a[i], b[i]
        out[i] = _overlaps(self.x[b] - self.x[a], self.y[b] - self.y[a],
                           self.cos[a], self.sin[a], self.hl[a], self.hw[a],
                           self.cos[b], self.sin[b], self.hl[b], self.hw[b])
        return out

    def interval(self, a: np.ndarray, b: np.ndarray, vx: np.ndarray, vy: np.ndarray):
        """``overlap_interval`` of rows a (M,) and b (M,), b moving at (vx, vy) (M,) each
        relative to a."""
        return _interval(self.x[b] - self.x[a], self.y[b] - self.y[a], vx, vy,
                         self.cos[a], self.sin[a], self.hl[a], self.hw[a],
                         self.cos[b], self.sin[b], self.hl[b], self.hw[b])


def reach(size: np.ndarray) -> np.ndarray:
    """(M,) half diagonals, metres: two footprints whose centres are farther apart than the sum
    of theirs cannot overlap."""
    return 0.5 * np.hypot(size[:, 0], size[:, 1])
