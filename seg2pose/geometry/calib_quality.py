"""What a solved calibration's error costs in metres, and where it is extrapolating.

- per pair: the reprojection error (pixels) and the ground error (metres): the clicked pixel's
  ray through the solved camera, met with the pair's elevation, against the pair's world point;
- per pixel of the frame: how far one pixel of error moves a normal position there (metres
  per pixel at the pedestrians' default height, 0.9 m above the ground: the footprint of a
  pixel) and how far the calibration's own uncertainty moves it (its covariance carried to
  the ground, first order);
- extrapolation: outside the convex hull of the pairs kept (grown by ``HULL_MARGIN`` of the
  image diagonal) the calibration rests on no point;
- the suggested next point: of the road's pixels, the one whose pair would shrink the mean
  position variance over the road the most (expected variance reduction, an A-optimal design:
  Sigma' = Sigma - Sigma J^T (J Sigma J^T + C)^-1 J Sigma, J the pair's pixel Jacobian and C
  its noise; Chaloner & Verdinelli 1995).

Units: pixels, metres; a height function maps xy (M, 2) to ground z (M,).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from seg2pose.geometry.calibrate import Solution, SolveOptions, pair_covariances, project, rodrigues

NORMAL_HEIGHT = 0.9  # m: a normal position's height above the ground (pedestrians, paper 3.2)
HULL_MARGIN = 0.05  # of the image diagonal around the pairs' convex hull
MAX_RANGE = 80.0  # m: farther ground is not "the road in view"
DISAGREE = 3.0  # Mahalanobis sigmas: a kept pair above this is named in a warning

HeightFn = Callable[[np.ndarray], np.ndarray]


def flat(xy: np.ndarray) -> np.ndarray:
    return np.zeros(len(np.asarray(xy).reshape(-1, 2)))


# --- parameters <-> camera -------------------------------------------------------------------------
def params_of(sol: Solution) -> np.ndarray:
    """The camera's parameter vector in ``sol.param_names`` order."""
    cam = sol.camera
    p = [np.log(cam.K[0, 0])]
    if "cx" in sol.param_names:
        p += [cam.K[0, 2], cam.K[1, 2]]
    if "k1" in sol.param_names:
        p += [getattr(cam.distortion, "k1", 0.0) if cam.distortion is not None else 0.0]
    from seg2pose.geometry.calibrate import rotation_vector

    return np.concatenate([p, rotation_vector(cam.R), cam.t])


def _unpack(sol: Solution, p: np.ndarray) -> tuple[float, np.ndarray, float, np.ndarray, np.ndarray]:
    names = sol.param_names
    f = float(np.exp(p[0]))
    c = p[1:3] if "cx" in names else np.array([sol.camera.width / 2, sol.camera.height / 2])
    k1 = float(p[names.index("k1")]) if "k1" in names else 0.0
    return f, c, k1, rodrigues(p[-6:-3]), p[-3:]


def ground_hits(f, c, k1, R, t, uv: np.ndarray, height: HeightFn, h: float = 0.0,
                iterations: int = 6) -> np.ndarray:
    """World points (M, 3) where the rays through pixels uv (M, 2) meet the ground raised by h
    (fixed-point iteration on the height function; NaN where a ray does not point down)."""
    xd = (np.asarray(uv, float).reshape(-1, 2) - c) / f
    xn = xd.copy()
    for _ in range(20 if k1 else 0):  # undistort x_d = x (1 + k1 |x|^2)
        xn = xd / (1 + k1 * np.einsum("nk,nk->n", xn, xn))[:, None]
    d = np.column_stack([xn, np.ones(len(xn))]) @ R  # world directions
    o = -R.T @ t
    z = np.full(len(d), float(np.median(height(np.array([o[:2]]))) + h))
    with np.errstate(divide="ignore", invalid="ignore"):
        for _ in range(iterations):
            s = (z - o[2]) / d[:, 2]
            X = o + s[:, None] * d
            z = height(X[:, :2]) + h
        bad = ~(s > 0) | ~(d[:, 2] < 0)
    X[bad] = np.nan
    return X


def pair_ground_errors(sol: Solution) -> np.ndarray:
    """(N,) metres: the clicked pixel's ray, met at the pair's own elevation, from its world
    point (horizontal distance)."""
    f, c, k1, R, t = _unpack(sol, params_of(sol))
    out = np.empty(len(sol.pairs.uv))
    for i, (uv, X) in enumerate(zip(sol.pairs.uv, sol.pairs.X, strict=True)):
        def level(xy: np.ndarray, z: float = float(X[2])) -> np.ndarray:
            return np.full(len(xy), z)

        hit = ground_hits(f, c, k1, R, t, uv[None], level)
        out[i] = float(np.linalg.norm(hit[0, :2] - X[:2]))
    return out


# --- maps over the frame ----------------------------------------------------------------------------
@dataclass
class CostMaps:
    """On a grid of pixels ``u`` (nx,), ``v`` (ny,): metres per pixel at a normal position
    (ny, nx), the calibration's own position uncertainty (ny, nx) metres (one sd, horizontal),
    ``road`` (ny, nx) bool (the ground in view within MAX_RANGE), ``extrapolating`` (ny, nx)."""

    u: np.ndarray
    v: np.ndarray
    m_per_px: np.ndarray
    sd_m: np.ndarray
    road: np.ndarray
    extrapolating: np.ndarray


def _jac(fn, p: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """Numeric Jacobian (M, k, P) of fn(p) -> (M, k) by central differences."""
    cols = []
    for j in range(len(p)):
        dp = np.zeros_like(p)
        dp[j] = eps * max(1.0, abs(p[j]))
        cols.append((fn(p + dp) - fn(p - dp)) / (2 * dp[j]))
    return np.stack(cols, axis=-1)


def hull_mask(points_uv: np.ndarray, u: np.ndarray, v: np.ndarray, margin_px: float) -> np.ndarray:
    """(ny, nx) bool: grid pixels within ``margin_px`` of the convex hull of points_uv."""
    import cv2

    pts = np.asarray(points_uv, np.float32).reshape(-1, 2)
    hull = cv2.convexHull(pts).reshape(-1, 2)
    U, V = np.meshgrid(u, v)
    out = np.empty(U.size, bool)
    for i, (a, b) in enumerate(zip(U.ravel(), V.ravel(), strict=True)):
        out[i] = cv2.pointPolygonTest(hull.reshape(-1, 1, 2), (float(a), float(b)), True) >= -margin_px
    return out.reshape(U.shape)


def _pixel_grid(width: int, height: int, step: int
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Pixel centres every ``step`` pixels: u (nu,), v (nv,), the grid's U (nv, nu) and its
    points uv (nv*nu, 2), row by row."""
    u = np.arange(step / 2, width, step)
    v = np.arange(step / 2, height, step)
    U, V = np.meshgrid(u, v)
    return u, v, U, np.column_stack([U.ravel(), V.ravel()])


def cost_maps(sol: Solution, height: HeightFn = flat, step: int = 16) -> CostMaps:
    """The maps of ``CostMaps`` on a grid every ``step`` pixels."""
    cam = sol.camera
    u, v, U, uv = _pixel_grid(cam.width, cam.height, step)
    p0 = params_of(sol)
    f, c, k1, R, t = _unpack(sol, p0)
    X = ground_hits(f, c, k1, R, t, uv, height, NORMAL_HEIGHT)
    Xu = ground_hits(f, c, k1, R, t, uv + [1.0, 0.0], height, NORMAL_HEIGHT)
    Xv = ground_hits(f, c, k1, R, t, uv + [0.0, 1.0], height, NORMAL_HEIGHT)
    mpp = np.maximum(np.linalg.norm(Xu - X, axis=1), np.linalg.norm(Xv - X, axis=1))
    G = _jac(lambda p: ground_hits(*_unpack(sol, p), uv, height, NORMAL_HEIGHT)[:, :2], p0)
    G = np.nan_to_num(G)
    var = np.einsum("mkp,pq,mkq->m", G, sol.cov, G)
    dist = np.linalg.norm(X[:, :2] - cam.center[:2], axis=1)
    road = np.isfinite(X).all(1) & (dist <= MAX_RANGE)
    used = sol.pairs.uv[sol.used]
    ext = ~hull_mask(used, u, v, HULL_MARGIN * float(np.hypot(cam.width, cam.height)))
    shape = U.shape
    return CostMaps(u, v, np.where(road, mpp, np.nan).reshape(shape),
                    np.where(road, np.sqrt(np.maximum(var, 0)), np.nan).reshape(shape),
                    road.reshape(shape), ext)


def suggest_next(sol: Solution, opts: SolveOptions, height: HeightFn = flat, step: int = 32
                 ) -> tuple[np.ndarray, np.ndarray, float] | None:
    """(pixel (2,), world point (3,), share of the road's mean position variance it removes)
    of the best next pair (module doc), or None when no road is in view."""
    cam = sol.camera
    u, v, U, uv = _pixel_grid(cam.width, cam.height, step)
    p0 = params_of(sol)
    f, c, k1, R, t = _unpack(sol, p0)
    X = ground_hits(f, c, k1, R, t, uv, height)
    ok = np.isfinite(X).all(1) & (np.linalg.norm(X[:, :2] - cam.center[:2], axis=1) <= MAX_RANGE)
    if ok.sum() < 2:
        return None
    uv, X = uv[ok], X[ok]
    Xn = ground_hits(f, c, k1, R, t, uv, height, NORMAL_HEIGHT)
    good = np.isfinite(Xn).all(1)
    G = np.nan_to_num(_jac(lambda p: ground_hits(*_unpack(sol, p), uv[good], height,
                                                 NORMAL_HEIGHT)[:, :2], p0))  # (M, 2, P)
    Jp = _jac(lambda p: project(*_unpack(sol, p), X)[0], p0)  # (N, 2, P): a pair at X
    _, xc = project(f, c, k1, R, t, X)
    C = pair_covariances(f, R, xc, opts) * sol.scale ** 2
    S = sol.cov
    SG = np.einsum("pq,mkq->pmk", S, G).reshape(len(p0), -1)  # Sigma G^T (P, 2M)
    total = float(np.einsum("mkp,pq,mkq->", G, S, G))
    if total <= 0:
        return None
    gains = np.empty(len(X))
    for i in range(len(X)):
        J = Jp[i]  # (2, P)
        Sinv = np.linalg.inv(J @ S @ J.T + C[i])
        B = J @ SG  # (2, 2M): J Sigma G^T
        gains[i] = float(np.einsum("ka,kl,la->", B, Sinv, B))
    i = int(np.argmax(gains))
    return uv[i], X[i], gains[i] / total


def disagreeing(sol: Solution, ground_err: np.ndarray) -> list[str]:
    """Warnings naming the pairs that disagree with the others (dropped, or kept beyond
    DISAGREE sigmas), and a noise scale far above the stated noise."""
    out = []
    for i, name in enumerate(sol.pairs.names):
        err = float(np.linalg.norm(sol.residual_px[i]))
        if not sol.used[i]:
            out.append(f"{sol.camera.name}: {name} disagrees with the others ({err:.1f} px, "
                       f"{ground_err[i]:.2f} m on the ground) and was left out; is it mistyped "
                       "or paired with the wrong point?")
        elif sol.mahalanobis[i] * sol.scale > DISAGREE:
            out.append(f"{sol.camera.name}: {name} fits worse than its stated noise allows "
                       f"({err:.1f} px, {ground_err[i]:.2f} m on the ground); check it")
    if sol.scale > 2.0:
        out.append(f"{sol.camera.name}: the pairs disagree {sol.scale:.1f}x more than the stated "
                   "click noise; check the world coordinates' units and axes, or the noise options")
    return out
