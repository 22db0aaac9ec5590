"""Calibrated cameras and rigs of named cameras.

Conventions (DESIGN.md):
- World: metres, right-handed, z up. A camera maps a world point X to camera coordinates
  ``x_c = R @ X + t`` (OpenCV extrinsics: x right, y down, z forward) and to pixels with K.
- Pixels: x right, y down, origin at the top-left *corner* of the top-left pixel, so the centre
  of pixel (row, col) is at (col + 0.5, row + 0.5). K's principal point is in this convention.
- Distortion acts on normalised image coordinates (x_c / z_c, y_c / z_c) before K. The model is
  pluggable (``Distortion``): OpenCV's (k1, k2, p1, p2, k3) and Tsai's (one radial term defined
  on the distorted point, as in T-Analyst's ``.tacal`` files) implement the same two methods.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import scipy.linalg

from seg2pose.core.errors import InputError
from seg2pose.core.validate import MAX_COORD, MAX_IMAGE_SIDE, MAX_PIXEL_COORD, integer, number, safe_name


class Distortion(Protocol):
    """A lens distortion model on normalised image coordinates, shape (N, 2)."""

    @property
    def model(self) -> str: ...  # read-only: the models are frozen dataclasses
    def distort(self, xy: np.ndarray) -> np.ndarray: ...
    def undistort(self, xy_d: np.ndarray) -> np.ndarray: ...
    def to_dict(self) -> dict: ...


@dataclass(frozen=True)
class OpenCVDistortion:
    """OpenCV's radial-tangential model (k1, k2, p1, p2, k3) on normalised coordinates."""

    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0
    model: str = "opencv"

    def distort(self, xy: np.ndarray) -> np.ndarray:
        """(N, 2) undistorted normalised coordinates -> (N, 2) distorted ones."""
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        radial = 1 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        xd = x * radial + 2 * self.p1 * x * y + self.p2 * (r2 + 2 * x * x)
        yd = y * radial + self.p1 * (r2 + 2 * y * y) + 2 * self.p2 * x * y
        return np.stack([xd, yd], axis=1)

    def undistort(self, xy_d: np.ndarray, iterations: int = 40) -> np.ndarray:
        """(N, 2) distorted -> undistorted normalised coordinates.

        Damped Newton on distort(x) = x_d with the analytic 2x2 Jacobian, started at x_d: a
        step is halved until the residual shrinks (OpenCV's fixed-point iteration stalls for
        strong lenses near the image corners, and plain Newton can run away where the model
        folds over). Converges to ~1e-12 wherever the model is invertible."""
        xy_d = np.asarray(xy_d, dtype=np.float64).reshape(-1, 2)
        xy = xy_d.copy()
        k1, k2, k3, p1, p2 = self.k1, self.k2, self.k3, self.p1, self.p2
        with np.errstate(all="ignore"):
            res = self.distort(xy) - xy_d
            err = np.einsum("nk,nk->n", res, res)
            for _ in range(iterations):
                x, y = xy[:, 0], xy[:, 1]
                r2 = x * x + y * y
                rad = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
                drad = k1 + r2 * (2 * k2 + 3 * k3 * r2)  # d rad / d r2
                a = rad + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x
                b = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y  # = d yd / dx as well
                d = rad + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x
                det = a * d - b * b
                step = np.stack([(d * res[:, 0] - b * res[:, 1]) / det,
                                 (-b * res[:, 0] + a * res[:, 1]) / det], axis=1)
                step[~np.isfinite(step)] = 0.0
                lam = np.ones(len(xy))
                for _ in range(30):  # backtracking: halve where the residual grew
                    cand = xy - lam[:, None] * step
                    r_c = self.distort(cand) - xy_d
                    e_c = np.einsum("nk,nk->n", r_c, r_c)
                    worse = ~(e_c <= err)
                    if not worse.any():
                        break
                    lam = np.where(worse, lam * 0.5, lam)
                keep = e_c <= err
                xy = np.where(keep[:, None], cand, xy)
                res = np.where(keep[:, None], r_c, res)
                err = np.where(keep, e_c, err)
                if np.all(~keep | (np.abs(lam[:, None] * step) < 1e-15).all(axis=1)):
                    break
        return xy

    def to_dict(self) -> dict:
        return {"model": "opencv", "k1": self.k1, "k2": self.k2, "p1": self.p1,
                "p2": self.p2, "k3": self.k3}

    @property
    def is_identity(self) -> bool:
        return not any((self.k1, self.k2, self.p1, self.p2, self.k3))


@dataclass(frozen=True)
class TsaiDistortion:
    """Tsai's one-coefficient radial model, as T-Analyst's ``.tacal`` calibrations use it.

    Defined from the *distorted* sensor point: Xu = Xd (1 + k (Xd² + Yd²)), with sensor
    coordinates in the units of the focal length f (e.g. mm; k in 1/mm²). On normalised
    coordinates (sensor / f) this is x_u = x_d (1 + κ |x_d|²) with κ = k f², so undistortion is
    closed form and distortion solves the cubic by Newton's method. k > 0 is barrel (image
    points pulled towards the centre)."""

    k: float
    f: float
    model: str = "tsai"

    def __post_init__(self) -> None:
        if not (np.isfinite(self.f) and self.f > 0):
            raise InputError(f"Tsai's focal length f must be positive, got {self.f!r}",
                             field="distortion.f")

    @property
    def kappa(self) -> float:
        """The coefficient on normalised coordinates, κ = k f² (dimensionless)."""
        return self.k * self.f * self.f

    def distort(self, xy: np.ndarray, iterations: int = 60) -> np.ndarray:
        """(N, 2) undistorted normalised coordinates -> (N, 2) distorted ones.

        The distorted point is s * xy with s (1 + κ r² s²) = 1, r = |xy|. Newton from s = 1
        converges monotonically (the cubic is convex for κ > 0, concave for κ < 0, and s = 1
        lies on the far side of the root). Where a pincushion lens (κ < 0) folds over,
        r² > -4 / (27 κ), no image point exists: NaN."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        c = self.kappa * np.einsum("nk,nk->n", xy, xy)  # κ r²
        s = np.ones(len(xy))
        with np.errstate(all="ignore"):
            for _ in range(iterations):
                step = (c * s ** 3 + s - 1) / (3 * c * s * s + 1)
                s = s - step
                if not np.any(np.abs(step) > 1e-15):
                    break
        s[c < -4.0 / 27.0] = np.nan
        return xy * s[:, None]

    def undistort(self, xy_d: np.ndarray) -> np.ndarray:
        """(N, 2) distorted -> undistorted normalised coordinates (closed form)."""
        xy_d = np.asarray(xy_d, dtype=np.float64).reshape(-1, 2)
        return xy_d * (1 + self.kappa * np.einsum("nk,nk->n", xy_d, xy_d))[:, None]

    def to_dict(self) -> dict:
        return {"model": "tsai", "k": self.k, "f": self.f}

    # no ``is_identity``: with k = 0 the model is kept, since f is the sensor's scale that a
    # written-back .tacal needs


DISTORTION_MODELS: dict[str, type] = {"opencv": OpenCVDistortion, "tsai": TsaiDistortion}


MAX_DISTORTION = 1e6  # |parameter|: real lenses stay far below (fisheye k1 ~ -0.5; Tsai f in mm or px)


def distortion_from_dict(d: dict | None, *, file=None, where: str = "") -> Distortion | None:
    """A distortion model from its JSON object; ``where`` (e.g. ``cameras[c0].``) prefixes
    the field names of errors so that they name the camera."""
    if d is None:
        return None
    if not isinstance(d, dict):
        raise InputError("expected an object {\"model\": ..., parameters}", file=file,
                         field=f"{where}distortion")
    model = d.get("model", "opencv")
    if not isinstance(model, str) or model not in DISTORTION_MODELS:
        raise InputError(f"unknown distortion model {model!r}; known: {sorted(DISTORTION_MODELS)}",
                         file=file, field=f"{where}distortion.model")
    kwargs = {}
    for k, v in d.items():
        if k == "model":
            continue
        kwargs[k] = number(v, file=file, field=f"{where}distortion.{k}", lo=-MAX_DISTORTION,
                           hi=MAX_DISTORTION)
    try:
        dist = DISTORTION_MODELS[model](**kwargs)
    except TypeError as e:
        raise InputError(f"bad distortion parameters: {e}", file=file,
                         field=f"{where}distortion") from None
    except InputError as e:  # the model's own validation, located in this file
        raise InputError(e.message, file=file, field=f"{where}{e.field}") from None
    return dist


def _check_finite(name: str, a: np.ndarray, file=None) -> None:
    if not np.all(np.isfinite(a)):
        raise InputError(f"{name} has NaN or inf entries", file=file, field=name)


@dataclass
class Camera:
    """A calibrated pinhole camera, optionally with lens distortion.

    K: (3, 3) intrinsics (pixels); R: (3, 3) world-to-camera rotation, det +1;
    t: (3,) translation (metres), so that x_cam = R @ X + t; width, height: image size (pixels).
    """

    name: str
    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    width: int
    height: int
    distortion: Distortion | None = None

    def __post_init__(self) -> None:
        self.K = np.asarray(self.K, dtype=np.float64).reshape(3, 3)
        self.R = np.asarray(self.R, dtype=np.float64).reshape(3, 3)
        self.t = np.asarray(self.t, dtype=np.float64).reshape(3)
        for n, a in (("K", self.K), ("R", self.R), ("t", self.t)):
            _check_finite(n, a)
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise InputError(f"image size must be positive, got {self.width}x{self.height}",
                             field="width/height")
        self.width, self.height = int(self.width), int(self.height)
        if not np.allclose(self.R @ self.R.T, np.eye(3), atol=1e-6) or np.linalg.det(self.R) < 0:
            raise InputError("R must be a rotation matrix (orthonormal, det +1)", field="R")
        if self.K[0, 0] <= 0 or self.K[1, 1] <= 0:
            raise InputError("focal lengths in K must be positive", field="K")
        if not np.allclose(self.K[2], [0.0, 0.0, 1.0], rtol=0, atol=1e-9):
            raise InputError(f"the last row of K must be [0, 0, 1], got {self.K[2].tolist()}",
                             field="K")

        if np.abs(self.K).max() > MAX_PIXEL_COORD:
            raise InputError(f"K entries must be within +-{MAX_PIXEL_COORD:g} pixels, got "
                             f"{np.abs(self.K).max():g}", field="K")
        if np.abs(self.center).max() > MAX_COORD:
            raise InputError(f"the camera centre must be within +-{MAX_COORD:g} m of the origin, "
                             f"got {self.center.tolist()}", field="t")
        if self.distortion is not None and getattr(self.distortion, "is_identity", False):
            self.distortion = None

    # --- construction ------------------------------------------------------------------------
    @classmethod
    def from_P(cls, name: str, P: np.ndarray, width: int, height: int,
               distortion: Distortion | None = None) -> Camera:
        """K, R, t from a 3x4 projection matrix by RQ decomposition, signs fixed so that the
        focal lengths are positive and det R = +1 (P is defined up to scale, sign included)."""
        P = np.asarray(P, dtype=np.float64)
        if P.shape != (3, 4):
            raise InputError(f"P must be 3x4, got shape {P.shape}", field="P")
        _check_finite("P", P)
        M = P[:, :3]
        if np.linalg.matrix_rank(M) < 3:
            raise InputError("P has rank < 3 (its left 3x3 block is singular)", field="P")
        if np.linalg.det(M) < 0:
            P = -P
            M = P[:, :3]
        K, R = scipy.linalg.rq(M)
        D = np.diag(np.sign(np.diag(K)))
        K, R = K @ D, D @ R
        scale = K[2, 2]
        K = K / scale
        t = np.linalg.solve(K, P[:, 3] / scale)
        return cls(name=name, K=K, R=R, t=t, width=width, height=height, distortion=distortion)

    @classmethod
    def look_at(cls, name: str, center: np.ndarray, target: np.ndarray, f: float,
                width: int, height: int, up=(0.0, 0.0, 1.0),
                distortion: Distortion | None = None) -> Camera:
        """A camera at ``center`` (3,) metres looking at ``target`` (3,), focal length f pixels,
        principal point at the image centre."""
        center = np.asarray(center, float)
        z = np.asarray(target, float) - center
        if not np.linalg.norm(z) > 0:
            raise InputError("look_at: target equals the camera centre", field="target")
        z /= np.linalg.norm(z)
        x = np.cross(z, np.asarray(up, float))
        if np.linalg.norm(x) < 1e-9:  # looking straight along 'up': any image x-axis will do
            x = np.cross(z, [0.0, 1.0, 0.0] if abs(z[1]) < 0.9 else [1.0, 0.0, 0.0])
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R = np.stack([x, y, z])
        K = np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]])
        return cls(name=name, K=K, R=R, t=-R @ center, width=width, height=height,
                   distortion=distortion)

    # --- properties --------------------------------------------------------------------------
    @property
    def P(self) -> np.ndarray:
        """(3, 4) projection matrix K [R | t] (ignores distortion)."""
        return self.K @ np.hstack([self.R, self.t[:, None]])

    @property
    def center(self) -> np.ndarray:
        """(3,) camera centre in world coordinates, metres."""
        return -self.R.T @ self.t

    # --- projection ----------------------------------------------------------------------------
    def project_points(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World points (N, 3) metres -> pixels (N, 2), depth (N,) metres along the optical
        axis, in_front (N,) bool (depth > 0). Points behind the camera still get pixels
        (mirrored); check ``in_front``."""
        X = np.asarray(X, dtype=np.float64).reshape(-1, 3)
        xc = X @ self.R.T + self.t
        depth = xc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xn = xc[:, :2] / depth[:, None]
        if self.distortion is not None:
            xn = self.distortion.distort(xn)
        uv = xn @ self.K[:2, :2].T + self.K[:2, 2]
        return uv, depth, depth > 0

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        """Pixels (N, 2) -> unit ray directions (N, 3) in world coordinates; rays start at
        ``center``. Undistorts first when the camera has distortion."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        xn = np.linalg.solve(self.K[:2, :2], (uv - self.K[:2, 2]).T).T
        if self.distortion is not None:
            xn = self.distortion.undistort(xn)
        d_cam = np.hstack([xn, np.ones((len(xn), 1))])
        d = d_cam @ self.R  # R^T @ d_cam for each row
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def in_image(self, uv: np.ndarray) -> np.ndarray:
        """(N, 2) pixels -> (N,) bool, inside the image rectangle."""
        uv = np.asarray(uv).reshape(-1, 2)
        return (uv[:, 0] >= 0) & (uv[:, 0] < self.width) & (uv[:, 1] >= 0) & (uv[:, 1] < self.height)

    # --- serialisation -------------------------------------------------------------------------
    def to_dict(self) -> dict:
        d = {"name": self.name, "width": self.width, "height": self.height,
             "K": self.K.tolist(), "R": self.R.tolist(), "t": self.t.tolist()}
        if self.distortion is not None:
            d["distortion"] = self.distortion.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: dict, *, file=None, where: str = "camera") -> Camera:
        def get(key):
            if key not in d:
                raise InputError(f"missing field '{key}'", file=file, field=f"{where}.{key}")
            return d[key]

        name = safe_name(get("name"), file=file, field=f"{where}.name", what="camera name")
        where = f"cameras[{name}]"
        width, height = (integer(get(k), file=file, field=f"{where}.{k}", lo=1, hi=MAX_IMAGE_SIDE)
                         for k in ("width", "height"))
        dist = distortion_from_dict(d.get("distortion"), file=file, where=f"{where}.")

        def arr(key, shape):
            v = get(key)  # outside the try: InputError is a ValueError too
            try:
                a = np.asarray(v, dtype=np.float64)
            except (TypeError, ValueError, OverflowError):
                raise InputError(f"expected a numeric array of shape {shape}", file=file,
                                 field=f"{where}.{key}") from None
            if a.shape != shape:
                raise InputError(f"expected shape {shape}, got {a.shape}", file=file,
                                 field=f"{where}.{key}")
            if not np.all(np.isfinite(a)):
                raise InputError("NaN or inf entries", file=file, field=f"{where}.{key}")
            return a

        try:
            if "P" in d:
                return cls.from_P(name, arr("P", (3, 4)), width, height, dist)
            return cls(name=name, K=arr("K", (3, 3)), R=arr("R", (3, 3)), t=arr("t", (3,)),
                       width=width, height=height, distortion=dist)
        except InputError as e:
            if e.file is not None:
                raise
            raise InputError(e.message, file=file, field=f"{where}.{e.field or 'P'}") from None


@dataclass
class Rig:
    """Named cameras plus named configurations (lists of camera names), e.g. the paper's
    monocular 1-3, stereo 10/30/40 cm and trinocular I/L/T (Figure 5)."""

    cameras: dict[str, Camera]
    configs: dict[str, list[str]] = field(default_factory=dict)
    name: str = "rig"

    def __post_init__(self) -> None:
        for cfg, names in self.configs.items():
            unknown = [n for n in names if n not in self.cameras]
            if unknown:
                raise InputError(f"configuration {cfg!r} names unknown cameras {unknown}",
                                 field=f"configs.{cfg}")
            if not names:
                raise InputError(f"configuration {cfg!r} has no cameras", field=f"configs.{cfg}")

    def select(self, config: str | None) -> list[Camera]:
        """The cameras of a named configuration (all cameras when ``config`` is None)."""
        if config is None:
            return list(self.cameras.values())
        if config not in self.configs:
            raise InputError(f"unknown configuration {config!r}; known: {', '.join(self.configs)}",
                             field="config")
        return [self.cameras[n] for n in self.configs[config]]

    @property
    def center(self) -> np.ndarray:
        """(3,) mean of the camera centres, metres: the 'distance from the cameras' origin."""
        return np.mean([c.center for c in self.cameras.values()], axis=0)
