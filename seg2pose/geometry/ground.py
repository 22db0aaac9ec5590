"""The ground surface of paper section 3.1, equation (1), and ray/surface intersection.

    z(x, y) = sum_i z_i exp(-alpha d_i^2) / sum_i exp(-alpha d_i^2),   d_i^2 = (x_i-x)^2 + (y_i-y)^2

with alpha = 0.3 (per square metre). The weights are computed with the exponents shifted by
their per-query minimum, so a query far from every ground point still gets the height of the
nearest points instead of 0/0.
"""

from __future__ import annotations

from typing import Literal, overload

import numpy as np

from seg2pose.core.errors import InputError
from seg2pose.core.validate import MAX_COORD

ALPHA = 0.3

# Reasons a ray yields NaN instead of a point (status codes of ``intersect_rays``).
HIT, POINTS_UP, BELOW_SURFACE, NO_CONVERGENCE, INVALID, TOO_FAR = 0, 1, 2, 3, 4, 5
MISS_REASONS = {
    HIT: "hit",
    POINTS_UP: "ray points up or runs parallel to the ground",
    BELOW_SURFACE: "ray starts below the raised surface (behind the camera)",
    NO_CONVERGENCE: "no convergence",
    INVALID: "NaN or inf in the ray origin, direction or height",
    # a ray almost parallel to the ground: no position file could hold it (io.schemas.METRES)
    TOO_FAR: f"the ray meets the ground more than {MAX_COORD:g} m from the origin",
}



def miss_reasons(status: np.ndarray) -> list[str]:
    """Human-readable reasons (N,) for status codes of ``intersect_rays``."""
    return [MISS_REASONS.get(int(c), f"status {int(c)}") for c in np.asarray(status).reshape(-1)]


TABLE_STEP = 0.25  # metres between the nodes of the scan's height table
TABLE_MARGIN = 10.0  # metres around the ground points covered by the table
TABLE_CELLS = 1_000_000  # table size cap (the step grows for very large areas)
SCAN_STEP = 0.25  # metres along the ground between samples that bracket the first crossing
MAX_SCAN = 256  # samples per ray at most (grazing rays)
_CHUNK = 8192  # queries per block: bounds memory at CHUNK x n_points floats


class GroundSurface:
    """Eq. (1) over ground points (n, 3) metres, vectorised over many queries."""

    def __init__(self, points: np.ndarray, alpha: float = ALPHA, *, file=None):
        pts = np.asarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise InputError(f"ground points must be (n, 3), got {pts.shape}", file=file)
        if len(pts) < 3:
            raise InputError(f"need at least 3 ground points, got {len(pts)}", file=file)
        if not np.all(np.isfinite(pts)):
            bad = int(np.argwhere(~np.isfinite(pts).all(axis=1))[0, 0])
            raise InputError(f"ground point {bad} has NaN or inf", file=file, line=bad + 1)
        _, idx, counts = np.unique(pts, axis=0, return_index=True, return_counts=True)
        if np.any(counts > 1):
            dup = int(idx[np.argmax(counts > 1)])
            raise InputError(f"duplicate ground point {pts[dup].tolist()}", file=file, line=dup + 1)
        if alpha <= 0:
            raise InputError(f"alpha must be positive, got {alpha}", field="alpha")
        self.points = pts
        self.alpha = float(alpha)
        self.z_min, self.z_max = float(pts[:, 2].min()), float(pts[:, 2].max())
        self.z_mean = float(pts[:, 2].mean())
        # precomputed for eq. (1): centred xy, alpha |x_i|^2, and the moments for the gradient
        self._origin = pts[:, :2].mean(axis=0)
        self._pxy = pts[:, :2] - self._origin
        self._alpha_sq = self.alpha * np.einsum("nk,nk->n", self._pxy, self._pxy)
        zc = pts[:, 2]
        self._moments = np.column_stack([zc, self._pxy, zc[:, None] * self._pxy])
        # height table for ray scans, built on first use: origin (2,), spacing, heights (ny, nx)
        self._tab: tuple[np.ndarray, float, np.ndarray] | None = None

    def _weights(self, xy: np.ndarray) -> np.ndarray:
        """Normalised weights (M, n) of the ground points for queries xy (M, 2) metres.

        -alpha d_i^2 = alpha (2 x.x_i - |x_i|^2) - alpha |x|^2; the last term is the same for
        every point of a query and cancels in the normalisation, so it is dropped, and the
        exponents are shifted by their per-query maximum (the largest weight is exp(0) = 1):
        no 0/0 far from all points, no overflow for huge queries, and one BLAS product instead
        of an (M, n, 2) difference array. Coordinates are taken relative to the points' mean
        so that survey coordinates (e.g. 6e6 m northings) keep full precision."""
        q = xy - self._origin
        e = q @ (2 * self.alpha * self._pxy.T)
        e -= self._alpha_sq
        e -= e.max(axis=1, keepdims=True)
        np.exp(e, out=e)
        e /= e.sum(axis=1, keepdims=True)
        return e

    def height(self, xy: np.ndarray) -> np.ndarray:
        """Ground height z (M,) metres at top-down positions xy (M, 2) metres."""
        return self.height_and_gradient(xy, gradient=False)[0]

    @overload
    def height_and_gradient(self, xy: np.ndarray, gradient: Literal[True] = ...
                            ) -> tuple[np.ndarray, np.ndarray]: ...

    @overload
    def height_and_gradient(self, xy: np.ndarray, gradient: bool
                            ) -> tuple[np.ndarray, np.ndarray | None]: ...

    def height_and_gradient(self, xy: np.ndarray, gradient: bool = True
                            ) -> tuple[np.ndarray, np.ndarray | None]:
        """z (M,) and dz/d(x, y) (M, 2) at xy (M, 2).

        dz/dx = 2 alpha sum_i w_i (z_i - z)(x_i - x) = 2 alpha (sum_i w_i z_i x_i - z sum_i w_i x_i)
        (the x terms cancel since the weights sum to 1), with w the normalised weights."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        z = np.empty(len(xy))
        g = np.empty((len(xy), 2)) if gradient else None
        for s in range(0, len(xy), _CHUNK):
            w = self._weights(xy[s:s + _CHUNK])
            if g is not None:  # gradient asked for
                m = w @ self._moments  # (M, 5): z, x, y, z*x, z*y
                zc = m[:, 0]
                g[s:s + _CHUNK] = 2 * self.alpha * (m[:, 3:5] - zc[:, None] * m[:, 1:3])
            else:
                zc = w @ self.points[:, 2]
            z[s:s + _CHUNK] = zc
        return z, g

    def _table(self) -> tuple[np.ndarray, float, np.ndarray]:
        """A lazily built table of eq. (1) on a regular grid over the points' extent plus
        ``TABLE_MARGIN`` metres (at most ~1e6 cells): origin (2,), spacing, heights (ny, nx)."""
        if self._tab is None:
            lo = self.points[:, :2].min(axis=0) - TABLE_MARGIN
            hi = self.points[:, :2].max(axis=0) + TABLE_MARGIN
            res = max(TABLE_STEP, float(np.sqrt(np.prod(hi - lo) / TABLE_CELLS)))
            nx, ny = (np.ceil((hi - lo) / res).astype(int) + 1)
            gx, gy = np.meshgrid(lo[0] + res * np.arange(nx), lo[1] + res * np.arange(ny))
            zt = self.height(np.column_stack([gx.ravel(), gy.ravel()])).reshape(ny, nx)
            self._tab = (lo, res, zt)
        return self._tab

    def height_lookup(self, xy: np.ndarray) -> np.ndarray:
        """Approximate z (M,) at xy (M, 2) metres: bilinear interpolation in a table of eq. (1)
        (errors of a few millimetres on kerbs); exact eq. (1) outside the table. For scans."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        lo, res, zt = self._table()
        ny, nx = zt.shape
        g = (xy - lo) / res
        inside = (g[:, 0] >= 0) & (g[:, 0] < nx - 1) & (g[:, 1] >= 0) & (g[:, 1] < ny - 1)
        z = np.empty(len(xy))
        if not inside.all():
            z[~inside] = self.height(xy[~inside])
        gi = g[inside]
        i0 = np.floor(gi).astype(np.int64)
        fx, fy = gi[:, 0] - i0[:, 0], gi[:, 1] - i0[:, 1]
        c, r = i0[:, 0], i0[:, 1]
        z[inside] = ((zt[r, c] * (1 - fx) + zt[r, c + 1] * fx) * (1 - fy)
                     + (zt[r + 1, c] * (1 - fx) + zt[r + 1, c + 1] * fx) * fy)
        return z

    def intersect_rays(self, origins: np.ndarray, dirs: np.ndarray, h: np.ndarray | float = 0.0,
                       tol: float = 1e-7, max_iter: int = 60, step: float = SCAN_STEP
                       ) -> tuple[np.ndarray, np.ndarray]:
        """Intersect rays with the surface raised by ``h``: the first point X along each ray
        (nearest its origin) with X_z = z(X_xy) + h.

        origins: (M, 3) or (3,) metres; dirs: (M, 3) (need not be unit); h: (M,) or scalar metres.
        Returns X (M, 3) metres (NaN rows for misses) and status (M,) int8, see MISS_REASONS.

        The surface lies between the points' lowest and highest z, so a crossing can only
        happen on the part of the ray between those heights (+ h). That part is scanned in
        steps of at most ``step`` metres top-down (eq. (1) varies on the scale of metres) to
        bracket the first crossing; then Newton steps along the ray, started at the crossing of
        the plane at the points' mean height + h (the paper's plane start) when it lies in the
        bracket, safeguarded by bisection. Every downward ray from above the surface converges.
        """
        dirs = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
        M = len(dirs)
        o = np.broadcast_to(np.asarray(origins, dtype=np.float64).reshape(-1, 3), (M, 3))
        h = np.broadcast_to(np.asarray(h, dtype=np.float64), (M,))
        status = np.zeros(M, dtype=np.int8)
        X = np.full((M, 3), np.nan)

        finite = np.isfinite(dirs).all(axis=1) & np.isfinite(o).all(axis=1) & np.isfinite(h)
        down = finite & (dirs[:, 2] < -1e-12)
        status[~down] = POINTS_UP
        status[~finite] = INVALID
        f0 = np.full(M, np.nan)
        f0[finite] = o[finite, 2] - self.height(o[finite, :2]) - h[finite]
        above = f0 > 0
        status[down & ~above] = BELOW_SURFACE
        ok = down & above
        if not ok.any():
            return X, status
        o, d, hh = o[ok], dirs[ok], h[ok]
        dz = d[:, 2]
        n = len(o)

        def f_at(s: np.ndarray, rows: np.ndarray, exact: bool = True) -> np.ndarray:
            p = o[rows] + s[:, None] * d[rows]
            z = self.height(p[:, :2]) if exact else self.height_lookup(p[:, :2])
            return p[:, 2] - z - hh[rows]

        # f(s) = o_z + s d_z - z(o_xy + s d_xy) - h: > 0 for s < s_a (above the highest point),
        # < 0 at s_b (1 mm below the lowest point).
        s_a = np.maximum((self.z_max + hh - o[:, 2]) / dz, 0.0)
        s_b = (self.z_min + hh - 1e-3 - o[:, 2]) / dz
        horiz = (s_b - s_a) * np.linalg.norm(d[:, :2], axis=1)
        k = np.clip(np.ceil(horiz / step).astype(np.int64), 1, MAX_SCAN)
        rows = np.repeat(np.arange(n), k)
        j = np.arange(k.sum()) - np.repeat(np.cumsum(k) - k, k) + 1  # 1..k per ray
        s_samp = s_a[rows] + (s_b - s_a)[rows] * j / k[rows]
        f_samp = f_at(s_samp, rows, exact=False)  # tabulated surface: cheap, mm-accurate
        f_samp[j == k[rows]] = -1.0  # s_b is below the surface by construction
        # first sample per ray at or below the surface
        below = np.flatnonzero(f_samp <= 0)
        first = below[np.r_[True, rows[below][1:] != rows[below][:-1]]]
        hi = s_samp[first]
        jf = j[first]
        lo = np.where(jf > 1, s_samp[np.maximum(first - 1, 0)], s_a)
        # the table is approximate: make the bracket exact (f(lo) > 0 >= f(hi)), widening it to
        # the safe ends s_a / s_b where the table was off by its few millimetres
        all_rows = np.arange(n)
        f_hi = f_at(hi, all_rows)
        hi = np.where(f_hi <= 0, hi, s_b)
        f_lo = f_at(lo, all_rows)
        lo, hi = np.where(f_lo > 0, lo, s_a), np.where(f_lo > 0, hi, lo)
        s_plane = (self.z_mean + hh - o[:, 2]) / dz  # the plane at the mean height
        s = np.where((s_plane > lo) & (s_plane < hi), s_plane, 0.5 * (lo + hi))
        done = np.zeros(n, dtype=bool)
        for _ in range(max_iter):
            act = np.flatnonzero(~done)
            if not len(act):
                break
            sa = s[act]
            p = o[act] + sa[:, None] * d[act]
            z, g = self.height_and_gradient(p[:, :2])
            f = p[:, 2] - z - hh[act]
            fp = dz[act] - np.einsum("mk,mk->m", g, d[act, :2])
            # keep the bracket: f > 0 above the surface (lo side), f <= 0 on/below (hi side)
            lo_a = np.where(f > 0, sa, lo[act])
            hi_a = np.where(f <= 0, sa, hi[act])
            with np.errstate(divide="ignore", invalid="ignore"):
                s_new = sa - f / fp
            bad = ~np.isfinite(s_new) | (s_new <= lo_a) | (s_new >= hi_a)
            s_new = np.where(bad, 0.5 * (lo_a + hi_a), s_new)
            hit = np.abs(f) < tol
            s_new = np.where(hit, sa, s_new)  # converged: keep the point where f was measured
            conv = hit | (hi_a - lo_a < tol * 1e-2)
            lo[act], hi[act], s[act] = lo_a, hi_a, s_new
            done[act[conv]] = True
        Xok = o + s[:, None] * d
        idx = np.flatnonzero(ok)
        X[idx] = Xok
        status[idx[~done]] = NO_CONVERGENCE
        far = done & ~(np.abs(Xok) <= MAX_COORD).all(axis=1)
        status[idx[far]] = TOO_FAR
        X[idx[~done | far]] = np.nan
        return X, status

    def mesh(self, n: int = 64, margin: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
        """A triangle mesh of the surface over the points' bounding box (plus ``margin`` m):
        vertices (n*n, 3) metres, triangles (2*(n-1)^2, 3) vertex indices."""
        lo = self.points[:, :2].min(axis=0) - margin
        hi = self.points[:, :2].max(axis=0) + margin
        gx, gy = np.meshgrid(np.linspace(lo[0], hi[0], n), np.linspace(lo[1], hi[1], n))
        xy = np.stack([gx.ravel(), gy.ravel()], axis=1)
        verts = np.hstack([xy, self.height(xy)[:, None]])
        i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
        a = (i * n + j).ravel()
        tris = np.concatenate([np.stack([a, a + 1, a + n], 1), np.stack([a + 1, a + n + 1, a + n], 1)])
        return verts, tris
