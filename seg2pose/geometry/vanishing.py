"""A camera from the traffic itself: vanishing points of the road users' motion, the focal
length and rotation they imply, and the camera's height from the road users' typical heights.

After Dubská, Herout, Juránek & Sochor 2014 (fully automatic roadside camera calibration):
straight stretches of tracked road users are lines through the vanishing point of their
direction of motion. At a junction the two roads give two such points, v1 and v2, for two
orthogonal ground directions (where the roads cross at right angles; Dubská et al. take the
second from the vehicles' edges across the motion, which a single straight road needs). With
the principal point p at the image centre, orthogonality gives f^2 = -(v1 - p).(v2 - p)
(Caprile & Torre 1990), the rotation's columns are K^-1 v1, K^-1 v2 and their cross product
(the vertical). The scale comes from the size classes (Dubská et al. use the vehicles' 3D
boxes): a road user of known height standing on the ground, its foot and head pixels and the
rotation give its height in units of the camera's height (Criminisi, Reid & Zisserman 2000,
single view metrology), so the camera's height is the typical height over that ratio (median
over many road users).

The world frame of such a camera is its own: origin on the ground below the camera, x along
the first road, z up. Units: pixels, metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seg2pose.core.errors import InputError


@dataclass
class Segments:
    """Straight stretches of motion: lines (M, 3) homogeneous, unit normal part; mid (M, 2) and
    direction (M, 2) unit; weight (M,) their length in pixels."""

    lines: np.ndarray
    mid: np.ndarray
    direction: np.ndarray
    weight: np.ndarray

    def take(self, idx) -> Segments:
        return Segments(self.lines[idx], self.mid[idx], self.direction[idx], self.weight[idx])


def track_segments(tracks: list[np.ndarray], chunk: int = 8, min_len: float = 30.0,
                   max_rms: float = 1.0) -> Segments:
    """Lines through chunks of ``chunk`` consecutive points of each track (points (n, 2)
    pixels in time order) that moved at least ``min_len`` pixels and deviate from their line
    by at most ``max_rms`` pixels rms (turning road users are left out)."""
    L, M, D, W = [], [], [], []
    for P in tracks:
        P = np.asarray(P, float).reshape(-1, 2)
        for s in range(0, len(P) - chunk + 1, chunk // 2):
            Q = P[s:s + chunk]
            c = Q.mean(0)
            _, sv, vt = np.linalg.svd(Q - c, full_matrices=False)
            d = vt[0]
            span = np.ptp((Q - c) @ d)
            if span < min_len or sv[1] / np.sqrt(len(Q)) > max_rms:
                continue
            n = np.array([-d[1], d[0]])
            L.append([n[0], n[1], -n @ c])
            M.append(c)
            D.append(d)
            W.append(span)
    if not L:
        return Segments(np.zeros((0, 3)), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))
    return Segments(np.array(L), np.array(M), np.array(D), np.array(W))


def _agree(seg: Segments, vp: np.ndarray, tol: float) -> np.ndarray:
    """(M,) bool: segments whose direction points at vp (homogeneous) within ``tol`` radians."""
    to = vp[:2][None, :] - seg.mid * vp[2]  # direction towards vp (works for vp at infinity)
    norm = np.linalg.norm(to, axis=1)
    sin = np.abs(seg.direction[:, 0] * to[:, 1] - seg.direction[:, 1] * to[:, 0]) / np.maximum(norm, 1e-12)
    return sin < np.sin(tol)


def vanishing_point(seg: Segments, rng: np.random.Generator, tol_deg: float = 1.5,
                    iterations: int = 3000) -> tuple[np.ndarray, np.ndarray]:
    """(vp (3,) homogeneous, unit; inliers (M,) bool): RANSAC over pairs of segments (their
    lines' intersection), scored by the length of the segments pointing at it, refined as the
    least-squares point of the inliers' lines (smallest singular vector)."""
    m = len(seg.lines)
    if m < 2:
        raise InputError(f"{m} straight stretches of motion: too few for a vanishing point")
    tol = np.radians(tol_deg)
    best, best_score = None, -1.0
    for _ in range(iterations):
        i, j = rng.choice(m, 2, replace=False)
        vp = np.cross(seg.lines[i], seg.lines[j])
        if not np.any(vp):
            continue
        vp = vp / np.linalg.norm(vp)
        score = float(seg.weight[_agree(seg, vp, tol)].sum())
        if score > best_score:
            best, best_score = vp, score
    if best is None:
        raise InputError("the straight stretches of motion are all parallel in the image")
    inl = _agree(seg, best, tol)
    A = seg.lines[inl] * np.sqrt(seg.weight[inl])[:, None]
    vp = np.linalg.svd(A)[2][-1]
    return vp / np.linalg.norm(vp), _agree(seg, vp, tol)


def orthogonal_vps(seg: Segments, width: int, height: int, rng: np.random.Generator
                   ) -> tuple[np.ndarray, np.ndarray, float]:
    """(v1, v2, f): the strongest direction of motion, then the strongest among the rest that
    is orthogonal to it for some focal length (f^2 > 0); f from the pair."""
    v1, in1 = vanishing_point(seg, rng)
    rest = seg.take(np.flatnonzero(~in1))
    p = np.array([width / 2, height / 2])
    for _ in range(4):  # the second direction: retried without directions that give f^2 <= 0
        v2, in2 = vanishing_point(rest, rng)
        f = focal_from_vps(v1, v2, p)
        if f is not None:
            return v1, v2, f
        rest = rest.take(np.flatnonzero(~in2))
        if len(rest.lines) < 2:
            break
    raise InputError("the road users' motion shows no two orthogonal directions (a junction's two "
                     "roads); click a few points instead")


def focal_from_vps(v1: np.ndarray, v2: np.ndarray, p: np.ndarray) -> float | None:
    """f (pixels) from two vanishing points of orthogonal directions and the principal point:
    f^2 = -(v1 - p).(v2 - p); None when either is at infinity or f^2 <= 0."""
    if abs(v1[2]) < 1e-12 or abs(v2[2]) < 1e-12:
        return None
    f2 = -float((v1[:2] / v1[2] - p) @ (v2[:2] / v2[2] - p))
    return float(np.sqrt(f2)) if f2 > 0 else None


def rotation_from_vps(v1: np.ndarray, v2: np.ndarray, K: np.ndarray) -> np.ndarray:
    """World-to-camera R (3, 3) whose world x points at v1, y at v2 (made orthogonal), z up
    (the camera's image y axis points down, so z has a negative camera-y part)."""
    Kinv = np.linalg.inv(K)
    r1 = Kinv @ v1
    r1 /= np.linalg.norm(r1)
    if r1[2] < 0:  # x along the road away from the camera
        r1 = -r1
    r2 = Kinv @ v2
    r2 -= (r2 @ r1) * r1
    r2 /= np.linalg.norm(r2)
    r3 = np.cross(r1, r2)
    if r3[1] > 0:  # z up: flip y (and so z)
        r2, r3 = -r2, -r3
    return np.column_stack([r1, r2, r3])


def height_ratios(K: np.ndarray, R: np.ndarray, feet: np.ndarray, heads: np.ndarray,
                  foot_offset: np.ndarray | float = 0.0) -> np.ndarray:
    """Each road user's height (N,) in units of the camera's height above the ground: feet and
    heads (N, 2) pixels, the head straight above the feet. With the camera at height 1 the
    foot ray meets z = 0 at X_f; the head lies at X_f + h e_z on its own ray: least squares
    for (s, h) in C + s d = X_f + h e_z.

    foot_offset (N,) or scalar, in units of the camera's height: how far the head's vertical
    lies beyond the lowest foot pixel's ground point, away from the camera (the lowest pixel of
    a standing person is the near edge of their footprint; taking it as below the head puts
    the head on a nearer vertical, higher up its ray: heights too large by (H - h) delta / D)."""
    Kinv = np.linalg.inv(K)

    def rays(uv):
        d = np.column_stack([np.asarray(uv, float), np.ones(len(uv))]) @ Kinv.T @ R  # R^T (K^-1 x)
        return d

    df, dh = rays(feet), rays(heads)
    C = np.array([0.0, 0.0, 1.0])
    out = np.full(len(df), np.nan)
    down = df[:, 2] < -1e-9
    with np.errstate(divide="ignore", invalid="ignore"):
        Xf = C + (-1.0 / df[:, 2:3]) * df
        away = Xf[:, :2] / np.maximum(np.linalg.norm(Xf[:, :2], axis=1, keepdims=True), 1e-12)
        Xf[:, :2] += np.broadcast_to(np.asarray(foot_offset, float), (len(df),))[:, None] * away
        # least squares of [d_h, -e_z] (s, h) = X_f - C, by its 2x2 normal equations
        b = Xf - C
        a11 = np.einsum("nk,nk->n", dh, dh)
        a12 = -dh[:, 2]
        r1 = np.einsum("nk,nk->n", dh, b)
        r2 = -b[:, 2]
        det = a11 - a12 * a12  # a22 = 1
        s = (r1 - a12 * r2) / det
        h = (a11 * r2 - a12 * r1) / det
    ok = down & (s > 0) & np.isfinite(h)
    out[ok] = h[ok]
    return out
