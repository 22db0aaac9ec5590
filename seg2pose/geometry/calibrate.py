"""Cameras from clicked image-world point pairs: focal length (principal point and radial k1
if asked), R and t, with the click noise of both sides in the fit.

The steps (OpenCV names; Hartley & Zisserman 2004, ch. 7 and A6 for the estimation):

1. **Checks**: at least ``min_pairs`` pairs, every pixel inside the image, world points and
   pixels not all on one line (one clear line naming the problem otherwise).
2. **Prior-aware focal search**: for focal lengths on a log grid spanning horizontal fields of
   view of 10-140 degrees, ``cv2.solvePnPRansac`` (principal point at the image centre) gives
   a pose and its inliers; each candidate is scored by a robust (MSAC, Torr & Zisserman 2000)
   cost of its residuals whitened by the pairs' noise, plus the focal prior's penalty. A plain
   sweep of ``solvePnP`` picks the focal of least pixel error; on road scenes (nearly planar
   points seen at a slant) that error is flat over a wide range of focal lengths, and the
   near points' world noise (0.1 m is ~9 px at 10 m) decides the pick: focal misses of 10 %.
   Here the focal has a log-normal prior (``SolveOptions``: a typical traffic camera's 65
   degree horizontal field of view, sigma 0.35 in log f, i.e. fields of view of about 40-90
   degrees within one sigma; a focal from the traffic replaces it), and every pair's residual
   is weighed by its own covariance: sigma_px^2 I + J_X diag(sigma_w^2) J_X^T, where J_X
   (2x3) is how the pixel moves with the world point. Near points, whose world noise spans
   many pixels, count less.
3. **Levenberg-Marquardt refinement** (``scipy.optimize.least_squares``) of log f (cx, cy,
   k1 when asked), rvec, tvec of every camera, jointly for the cameras of one device: they
   share the intrinsics. The noise scale s (how much the stated noise is off) is estimated
   from the residuals and the fit repeated: noise-free pairs drive s to 0 and the prior's
   weight with it, so exact pairs give the exact camera.
4. **Outliers**: the pair with the largest Mahalanobis residual is dropped while it exceeds
   ``outlier_sigma`` robust standard deviations (a mistyped or swapped pair), refitting each
   time, as long as ``min_pairs`` remain.

Units: pixels (corner-origin convention of camera.py), metres, world z up.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import cast

import numpy as np

from seg2pose.core.errors import InputError
from seg2pose.geometry.camera import Camera, Distortion, OpenCVDistortion

FOV_RANGE_DEG = (10.0, 140.0)  # horizontal fields of view the focal search spans
FOCAL_GRID = 56  # focal lengths tried, log-spaced
TRUNCATE = 9.0  # MSAC: a whitened residual's square counts at most this (3 sigma)


@dataclass(frozen=True)
class SolveOptions:
    """How cameras are solved from pairs.

    pixel_sigma: click noise in the frame, pixels; world_sigma: noise of the world points'
    x and y, metres (an aerial image at 5 cm/px clicked within 2 px: 0.1 m); z_sigma: noise
    of the elevations, metres; fov_prior_deg / focal_log_sigma: the focal's log-normal prior
    (centre as a horizontal field of view, spread in log f; ``focal_prior_px`` replaces the
    centre, e.g. a focal from the traffic); principal_point: fit cx, cy (else the image
    centre); k1: fit one radial distortion term; min_pairs: pairs needed per camera;
    outlier_sigma: Mahalanobis threshold (robust sigmas) for dropping a pair; ransac_px:
    inlier threshold of the RANSAC candidates (default: 1.5 % of the image diagonal, at least
    10 px, so that near points' world noise does not make them outliers)."""

    pixel_sigma: float = 1.5
    world_sigma: float = 0.1
    z_sigma: float = 0.1
    fov_prior_deg: float = 65.0
    focal_log_sigma: float = 0.35
    focal_prior_px: float | None = None
    principal_point: bool = False
    k1: bool = False
    min_pairs: int = 6
    outlier_sigma: float = 4.0
    ransac_px: float | None = None

    def focal_prior(self, width: int) -> float:
        """The prior's centre, pixels."""
        if self.focal_prior_px is not None:
            return float(self.focal_prior_px)
        return 0.5 * width / np.tan(np.radians(self.fov_prior_deg) / 2)


@dataclass
class PairSet:
    """One camera's pairs: uv (N, 2) pixels, X (N, 3) metres, names (N,) for messages."""

    camera: str
    width: int
    height: int
    uv: np.ndarray
    X: np.ndarray
    names: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.uv = np.asarray(self.uv, np.float64).reshape(-1, 2)
        self.X = np.asarray(self.X, np.float64).reshape(-1, 3)
        if not self.names:
            self.names = [f"pair {i + 1}" for i in range(len(self.uv))]


@dataclass
class Solution:
    """One solved camera: ``camera``; ``used`` (N,) bool, the pairs kept; ``residual_px``
    (N, 2) solved projection minus clicked pixel; ``mahalanobis`` (N,) each pair's residual
    in its own noise's standard deviations (noise scale s applied); ``scale`` s; ``focal_sd``
    pixels (from the fit's covariance, the prior included); ``cov`` the covariance of this
    camera's parameters (log f, [cx, cy], [k1], rvec, tvec); ``notes``: what was done."""

    camera: Camera
    pairs: PairSet
    used: np.ndarray
    residual_px: np.ndarray
    mahalanobis: np.ndarray
    scale: float
    focal_sd: float
    cov: np.ndarray
    param_names: list[str]
    notes: list[str] = field(default_factory=list)


# --- checks ---------------------------------------------------------------------------------
def check_pairs(p: PairSet, opts: SolveOptions) -> None:
    """Refuse pairs no camera can be solved from (one line naming the camera and pair)."""
    n = len(p.uv)
    if len(p.X) != n or len(p.names) != n:
        raise InputError(f"camera {p.camera}: {n} pixels but {len(p.X)} world points")
    if n < opts.min_pairs:
        raise InputError(f"camera {p.camera}: {n} pairs, at least {opts.min_pairs} needed "
                         "(click more points spread over the road)")
    bad = ~(np.isfinite(p.uv).all(1) & np.isfinite(p.X).all(1))
    if bad.any():
        raise InputError(f"camera {p.camera}: {p.names[int(np.argmax(bad))]} has a NaN or "
                         "missing coordinate")
    out = ~((p.uv[:, 0] >= 0) & (p.uv[:, 0] <= p.width) & (p.uv[:, 1] >= 0)
            & (p.uv[:, 1] <= p.height))
    if out.any():
        i = int(np.argmax(out))
        raise InputError(f"camera {p.camera}: {p.names[i]} at pixel ({p.uv[i, 0]:g}, "
                         f"{p.uv[i, 1]:g}) is outside the {p.width}x{p.height} image")
    for what, a, tol in (("world points", p.X, 0.05), ("pixels", p.uv, 2.0)):
        sv = np.linalg.svd(a - a.mean(0), compute_uv=False)
        if sv[1] / np.sqrt(n) < tol:
            raise InputError(f"camera {p.camera}: the {what} of its {n} pairs lie on one line; "
                             "click points spread over the road, not along one edge")


# --- projection and its parameters ----------------------------------------------------------
def rodrigues(rvec: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) -> rotation matrix (3, 3) (Rodrigues' formula)."""
    th = float(np.linalg.norm(rvec))
    if th < 1e-12:
        k = np.asarray(rvec, float)
        return np.eye(3) + np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    k = np.asarray(rvec, float) / th
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(th) * Kx + (1 - np.cos(th)) * Kx @ Kx


def rotation_vector(R: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.Rodrigues(np.asarray(R, np.float64))[0].ravel()


def project(f: float, c: np.ndarray, k1: float, R: np.ndarray, t: np.ndarray, X: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (N, 2) and camera coordinates (N, 3) of world points X (N, 3)."""
    xc = X @ R.T + t
    xn = xc[:, :2] / xc[:, 2:3]
    if k1:
        xn = xn * (1 + k1 * np.einsum("nk,nk->n", xn, xn))[:, None]
    return f * xn + c, xc


def pair_covariances(f: float, R: np.ndarray, xc: np.ndarray, opts: SolveOptions) -> np.ndarray:
    """(N, 2, 2) pixel covariance of each pair: click noise plus the world point's noise
    carried into the image by J_X = d uv / d X = f / z [[1, 0, -x/z], [0, 1, -y/z]] R."""
    z = xc[:, 2]
    J = np.zeros((len(xc), 2, 3))
    J[:, 0, 0] = J[:, 1, 1] = f / z
    J[:, 0, 2] = -f * xc[:, 0] / z ** 2
    J[:, 1, 2] = -f * xc[:, 1] / z ** 2
    JX = J @ R  # (N, 2, 3) in world axes
    W = np.diag([opts.world_sigma ** 2, opts.world_sigma ** 2, opts.z_sigma ** 2])
    return opts.pixel_sigma ** 2 * np.eye(2) + JX @ W @ JX.transpose(0, 2, 1)


def whiteners(cov: np.ndarray) -> np.ndarray:
    """(N, 2, 2) L^-1 with cov = L L^T: whitened residual = L^-1 r."""
    return np.linalg.inv(np.linalg.cholesky(cov))


# --- initial guess: prior-aware focal search -------------------------------------------------
def focal_search(p: PairSet, opts: SolveOptions) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """(f, rvec, tvec, inliers (N,) bool) of the best-scored focal on the grid (module doc)."""
    import cv2

    w, h = p.width, p.height
    c = np.array([w / 2, h / 2])
    lo, hi = (0.5 * w / np.tan(np.radians(a) / 2) for a in FOV_RANGE_DEG[::-1])
    f0, s0 = opts.focal_prior(w), opts.focal_log_sigma
    thr = opts.ransac_px or max(10.0, 0.015 * float(np.hypot(w, h)))
    obj, img = p.X.astype(np.float64), p.uv.astype(np.float64)
    best = None
    for f in np.geomspace(lo, hi, FOCAL_GRID):
        K = np.array([[f, 0, c[0]], [0, f, c[1]], [0, 0, 1.0]])
        try:
            ok, rv, tv, inl = cv2.solvePnPRansac(obj, img, K, None, iterationsCount=200,
                                                 reprojectionError=thr, confidence=0.999,
                                                 flags=cv2.SOLVEPNP_EPNP)
        except cv2.error:
            continue
        n_inl = len(np.asarray(inl).reshape(-1)) if ok else 0  # inl is None when no pose was found
        if n_inl < 4:
            continue
        inliers = np.zeros(len(obj), bool)
        inliers[inl.ravel()] = True
        ok, rv, tv = cv2.solvePnP(obj[inliers], img[inliers], K, None, rv, tv,
                                  useExtrinsicGuess=True, flags=cv2.SOLVEPNP_ITERATIVE)
        R = rodrigues(rv.ravel())
        uv, xc = project(f, c, 0.0, R, tv.ravel(), obj)
        if not (xc[:, 2] > 0).all():
            continue
        r = np.einsum("nij,nj->ni", whiteners(pair_covariances(f, R, xc, opts)), uv - img)
        cost = float(np.minimum(np.einsum("nk,nk->n", r, r), TRUNCATE).sum())
        cost += (np.log(f / f0) / s0) ** 2
        if best is None or cost < best[0]:
            best = (cost, f, rv.ravel(), tv.ravel(), inliers)
    if best is None:
        raise InputError(f"camera {p.camera}: no camera pose fits the pairs at any focal length; "
                         "check that each pixel is paired with its own world point")
    _, f, rv, tv, inliers = best
    # the search's inliers used a generous pixel threshold; refinement decides outliers
    return float(f), rv, tv, inliers


def _pose_at(p: PairSet, f: float) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """(f, rvec, tvec, all True) of a camera at a known focal (``cv2.solvePnP``, SQPnP)."""
    import cv2

    K = np.array([[f, 0, p.width / 2], [0, f, p.height / 2], [0, 0, 1.0]])
    ok, rv, tv = cv2.solvePnP(p.X, p.uv, K, None, flags=cv2.SOLVEPNP_SQPNP)
    if not ok:
        raise InputError(f"camera {p.camera}: no pose fits its {len(p.uv)} pairs")
    return f, rv.ravel(), tv.ravel(), np.ones(len(p.uv), bool)


# --- joint refinement ---------------------------------------------------------------------------
@dataclass
class _Block:
    """Where one camera's parameters sit in the joint vector."""

    pairs: PairSet
    group: int
    pose: slice  # rvec (3), tvec (3)
    used: np.ndarray


def _intrinsic_names(opts: SolveOptions) -> list[str]:
    return ["log_f"] + (["cx", "cy"] if opts.principal_point else []) + (["k1"] if opts.k1 else [])


def _unpack(x: np.ndarray, g0: int, b: _Block, opts: SolveOptions):
    """(f, c (2,), k1, R, t) of block ``b`` from the joint vector."""
    i = g0
    f = float(np.exp(x[i]))
    i += 1
    if opts.principal_point:
        c = x[i:i + 2]
        i += 2
    else:
        c = np.array([b.pairs.width / 2, b.pairs.height / 2])
    k1 = float(x[i]) if opts.k1 else 0.0
    return f, c, k1, rodrigues(x[b.pose][:3]), x[b.pose][3:]


def refine(blocks: list[_Block], intr0: list[np.ndarray], poses0: list[np.ndarray],
           opts: SolveOptions, rounds: int = 12) -> tuple[np.ndarray, list[int], float, np.ndarray]:
    """Joint Levenberg-Marquardt over the blocks' shared intrinsics (one per group) and
    poses, with per-pair whitening and the noise scale re-estimated each round. Returns the
    vector, the groups' offsets, the scale s and the covariance of the vector."""
    from scipy.optimize import least_squares

    ni = len(_intrinsic_names(opts))
    goff = [k * ni for k in range(len(intr0))]
    x = np.concatenate([*intr0, *poses0])
    log_f0 = [np.log(opts.focal_prior(next(b.pairs.width for b in blocks if b.group == g)))
              for g in range(len(intr0))]
    s = 1.0
    for _ in range(rounds):
        Ls = []
        for b in blocks:
            f, c, k1, R, t = _unpack(x, goff[b.group], b, opts)
            _, xc = project(f, c, k1, R, t, b.pairs.X[b.used])
            Ls.append(whiteners(pair_covariances(f, R, xc, opts)) / s)

        def resid(v, Ls=Ls):
            out = []
            for b, L in zip(blocks, Ls, strict=True):
                f, c, k1, R, t = _unpack(v, goff[b.group], b, opts)
                uv, _ = project(f, c, k1, R, t, b.pairs.X[b.used])
                out.append(np.einsum("nij,nj->ni", L, uv - b.pairs.uv[b.used]).ravel())
            out.append((v[goff] - log_f0) / opts.focal_log_sigma)
            return np.concatenate(out)

        sol = least_squares(resid, x, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15,
                            max_nfev=4000, x_scale="jac")
        x = sol.x
        r = sol.fun[:-len(goff)] * s  # whitened by the stated noise alone
        dof = max(len(r) - len(x), 1)
        s_new = max(float(np.sqrt(np.dot(r, r) / dof)), 1e-12)
        J = sol.jac
        if abs(np.log(s_new / s)) < 1e-3:
            s = s_new
            break
        s = s_new
    cov = np.linalg.pinv(J.T @ J)
    return x, goff, s, cov


def solve_group(pairsets: list[PairSet], opts: SolveOptions = SolveOptions(),
                distortion_note: bool = True) -> list[Solution]:
    """Solve the cameras of one device together (shared intrinsics); each camera needs
    ``min_pairs`` pairs of its own. Returns one Solution per PairSet, in order."""
    if not pairsets:
        return []
    # a camera with fewer than min_pairs (but 4) pairs borrows the focal of its device's others
    full = [len(p.uv) >= opts.min_pairs for p in pairsets]
    for p, ok in zip(pairsets, full, strict=True):
        check_pairs(p, opts if ok or not any(full) else
                    SolveOptions(**{**opts.__dict__, "min_pairs": min(4, opts.min_pairs)}))
    notes: list[str] = []
    # solved about the pairs' mean: survey coordinates (1e5 m eastings) keep their precision
    originals = pairsets
    origin = np.mean(np.vstack([p.X for p in pairsets]), axis=0)
    pairsets = [PairSet(p.camera, p.width, p.height, p.uv, p.X - origin, p.names) for p in pairsets]
    starts = {k: focal_search(p, opts) for k, p in enumerate(pairsets) if full[k]}
    f_init = float(np.exp(np.median([np.log(s[0]) for s in starts.values()])))
    for k, p in enumerate(pairsets):
        if k not in starts:
            starts[k] = _pose_at(p, f_init)
            notes.append(f"{p.camera}: {len(p.uv)} pairs, solved with its device's focal length")
    starts = [starts[k] for k in range(len(pairsets))]
    intr = [np.log(f_init)]
    w0, h0 = pairsets[0].width, pairsets[0].height
    if opts.principal_point:
        intr += [w0 / 2, h0 / 2]
    if opts.k1:
        intr += [0.0]
    poses = [np.concatenate([s[1], s[2]]) for s in starts]
    blocks, off = [], 1 + 2 * opts.principal_point + opts.k1
    for k, p in enumerate(pairsets):
        floor = opts.min_pairs if len(p.uv) >= opts.min_pairs else 4
        inl = starts[k][3] if starts[k][3].sum() >= floor else np.ones(len(p.uv), bool)
        blocks.append(_Block(p, 0, slice(off + 6 * k, off + 6 * k + 6), inl.copy()))
    readmitted = False
    while True:
        x, goff, s, cov = refine(blocks, [np.array(intr, float)], poses, opts)
        intr = list(x[:off])
        poses = [x[b.pose] for b in blocks]
        worst, back = None, False
        for b in blocks:
            d = _mahalanobis(x, goff, b, opts, 1.0)
            robust = max(float(np.median(d[b.used])) / 1.1774, 0.25)  # median of a 2-dof chi
            k = int(np.argmax(np.where(b.used, d, -1)))
            floor = opts.min_pairs if len(b.used) >= opts.min_pairs else 4
            if d[k] > opts.outlier_sigma * robust and b.used.sum() > floor:
                if worst is None or d[k] / robust > worst[0]:
                    worst = (d[k] / robust, b, k)
            if worst is None and not readmitted:
                # pairs the RANSAC search left out come back where the refined camera fits them
                fits = ~b.used & (d <= opts.outlier_sigma * robust)
                if fits.any():
                    b.used |= fits
                    back = True
        if worst is None and not back:
            break
        if worst is not None:
            _, b, k = worst
            b.used[k] = False
        else:
            readmitted = True
    dropped = [f"{b.pairs.camera}: {b.pairs.names[k]}" for b in blocks for k in np.flatnonzero(~b.used)]
    if dropped:
        notes.append(f"dropped as outliers: {', '.join(dropped)}")
    names = [f"{n}" for n in _intrinsic_names(opts)]
    out = []
    for b, orig in zip(blocks, originals, strict=True):
        f, c, k1, R, t = _unpack(x, goff[b.group], b, opts)
        K = np.array([[f, 0, c[0]], [0, f, c[1]], [0, 0, 1.0]])
        # a frozen dataclass's read-only model field vs the Protocol's attribute: the same thing
        dist = cast(Distortion, OpenCVDistortion(k1=k1)) if k1 else None
        cam = Camera(b.pairs.camera, K, R, t - R @ origin, b.pairs.width, b.pairs.height, distortion=dist)
        uv, _ = project(f, c, k1, R, t, b.pairs.X)
        idx = np.r_[np.arange(off), np.arange(b.pose.start, b.pose.stop)]
        # the uncertainty of the stated noise at least: a small s from few pairs is luck
        sub = cov[np.ix_(idx, idx)] * (max(s, 1.0) / s) ** 2  # refine's cov is at noise s
        sub = _to_world(sub, x[b.pose][:3], origin, off)
        out.append(Solution(camera=cam, pairs=orig, used=b.used.copy(),
                            residual_px=uv - b.pairs.uv,
                            mahalanobis=_mahalanobis(x, goff, b, opts, s), scale=s,
                            focal_sd=f * float(np.sqrt(max(sub[0, 0], 0.0))), cov=sub,
                            param_names=names + ["rx", "ry", "rz", "tx", "ty", "tz"],
                            notes=list(notes)))
    return out


def _to_world(cov: np.ndarray, rvec: np.ndarray, origin: np.ndarray, off: int) -> np.ndarray:
    """The covariance of (intrinsics, rvec, t) carried from the solve's frame (world minus
    ``origin``) to the world: t_world = t - R(rvec) origin, its Jacobian by central differences."""
    J = np.eye(len(cov))
    for j in range(3):
        d = np.zeros(3)
        d[j] = 1e-7
        J[off + 3:off + 6, off + j] = -(rodrigues(rvec + d) - rodrigues(rvec - d)) @ origin / 2e-7
    return J @ cov @ J.T


def _mahalanobis(x, goff, b: _Block, opts: SolveOptions, s: float) -> np.ndarray:
    f, c, k1, R, t = _unpack(x, goff[b.group], b, opts)
    uv, xc = project(f, c, k1, R, t, b.pairs.X)
    r = np.einsum("nij,nj->ni", whiteners(pair_covariances(f, R, xc, opts)), uv - b.pairs.uv)
    return np.linalg.norm(r, axis=1) / max(s, 1e-12)


def solve_camera(pairs: PairSet, opts: SolveOptions = SolveOptions()) -> Solution:
    """One camera from its pairs (``solve_group`` with one camera)."""
    return solve_group([pairs], opts)[0]
