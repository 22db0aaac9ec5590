"""Rough 3D models (paper 3.5, Figure 4): crude car, pedestrian and bicyclist meshes placed at
random positions and headings on a scene's ground and rasterised into one camera.

Training uses these for every fourth example and for training without any annotations. They
are deliberately cruder than the benchmark's road users (``shapes.py``): a car is two plain
boxes (no wheels, no sloped windscreen), a pedestrian a block with a head, a bicyclist a thin
slab with a block on it. Positions use the scene's ground *points* (eq. (1) through
``GroundSurface``), since that is all the training side knows about the ground.

Pixels: x right, y down, origin at the top-left corner of the top-left pixel.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from seg2pose.core.errors import InputError
from seg2pose.geometry.camera import Camera
from seg2pose.geometry.ground import GroundSurface
from seg2pose.synth.raster import fill_parts, project_parts, rle_from_crop_t
from seg2pose.synth.shapes import hexa

MAX_DISTANCE = 60.0  # m: default region = ground the camera sees up to this far away
# randomised rough models (``--rough-random``): length, width, height ranges per class, metres,
# drawn independently per example -- a prior of how road users of a class vary, not one box
RANDOM_SIZES = {
    "car": ((3.5, 6.0), (1.6, 2.1), (1.35, 2.4)),
    "pedestrian": ((0.22, 0.45), (0.36, 0.6), (1.1, 2.0)),
    "bicyclist": ((1.5, 2.3), (0.4, 0.8), (1.3, 1.95)),
}
BASE_SIZES = {"car": (4.5, 1.8, 1.5), "pedestrian": (0.3, 0.44, 1.75), "bicyclist": (1.8, 0.4, 1.75)}


def rough_model(cls: str, scale: float = 1.0) -> np.ndarray:
    """The rough model of a class: parts (P, 8, 3) in the local frame (x forward, y left,
    z up, origin at the ground contact point), metres."""
    s = scale
    if cls == "car":
        l, w, h = 4.5 * s, 1.8 * s, 1.5 * s
        return np.stack([hexa(-l / 2, l / 2, -w / 2, w / 2, 0.0, 0.55 * h),
                         hexa(-0.3 * l, 0.15 * l, -0.45 * w, 0.45 * w, 0.55 * h, h)])
    if cls == "pedestrian":
        h = 1.75 * s
        return np.stack([hexa(-0.15 * s, 0.15 * s, -0.22 * s, 0.22 * s, 0.0, 0.87 * h),
                         hexa(-0.1 * s, 0.1 * s, -0.1 * s, 0.1 * s, 0.87 * h, h)])
    if cls == "bicyclist":
        l, h = 1.8 * s, 1.75 * s
        return np.stack([hexa(-l / 2, l / 2, -0.07 * s, 0.07 * s, 0.0, 0.95 * s),
                         hexa(-0.25 * s, 0.15 * s, -0.2 * s, 0.2 * s, 0.6 * s, h)])
    raise InputError(f"no rough model for class {cls!r}; known: car, pedestrian, bicyclist",
                     field="cls")


_REGION_CACHE: dict[bytes, tuple[float, float, float, float]] = {}


def visible_region(camera: Camera, ground: GroundSurface, max_distance: float = MAX_DISTANCE
                   ) -> tuple[float, float, float, float]:
    """(xmin, xmax, ymin, ymax) metres of the ground the camera sees (up to ``max_distance``).
    Cached per calibration and ground (training asks for a few examples at a time)."""
    import hashlib

    h = hashlib.sha1()
    for a in (camera.K, camera.R, camera.t, ground.points):
        h.update(np.ascontiguousarray(a, np.float64).tobytes())
    h.update(repr((camera.width, camera.height, ground.alpha, float(max_distance),
                   camera.distortion.to_dict() if camera.distortion else None)).encode())
    key = h.digest()
    if key not in _REGION_CACHE:
        if len(_REGION_CACHE) > 64:
            _REGION_CACHE.clear()
        _REGION_CACHE[key] = _visible_region(camera, ground, max_distance)
    return _REGION_CACHE[key]


def _visible_region(camera: Camera, ground: GroundSurface, max_distance: float
                    ) -> tuple[float, float, float, float]:
    u, v = np.meshgrid(np.linspace(0, camera.width, 41), np.linspace(0, camera.height, 25))
    uv = np.column_stack([u.ravel(), v.ravel()])
    X, _ = ground.intersect_rays(camera.center, camera.unproject(uv), 0.0)
    ok = np.isfinite(X[:, 0]) & (np.linalg.norm(X - camera.center, axis=1) <= max_distance)
    if not ok.any():
        raise InputError(f"camera {camera.name!r} sees no ground within {max_distance:g} m",
                         field="region_xy")
    x, y = X[ok, 0], X[ok, 1]
    return float(x.min()), float(x.max()), float(y.min()), float(y.max())


def place(local: np.ndarray, heading: ArrayLike, xyz: ArrayLike) -> np.ndarray:
    """Model parts (..., P, 8, 3) in the local frame -> world metres: turned by ``heading``
    (...,) radians about z, then moved to the ground contact points ``xyz`` (..., 3)."""
    h = np.asarray(heading, float)[..., None, None]
    c, s = np.cos(h), np.sin(h)
    wx = c * local[..., 0] - s * local[..., 1]
    wy = s * local[..., 0] + c * local[..., 1]
    return np.stack([wx, wy, local[..., 2]], -1) + np.asarray(xyz, float)[..., None, None, :]


def occluder_parts(camera: Camera, ground: GroundSurface, target_xy: np.ndarray,
                   rng: np.random.Generator) -> np.ndarray:
    """A rough car (70 %) or pedestrian standing 1.5-5 m in front of ``target_xy`` (towards
    the camera, up to 1.2 m aside), random heading: its parts (P, 8, 3) in world metres."""
    to_cam = camera.center[:2] - target_xy
    u = to_cam / max(float(np.linalg.norm(to_cam)), 1e-9)
    side = np.array([-u[1], u[0]])
    xy = target_xy + rng.uniform(1.5, 5.0) * u + rng.uniform(-1.2, 1.2) * side
    model = rough_model("car" if rng.random() < 0.7 else "pedestrian")
    h = rng.uniform(-np.pi, np.pi)
    return place(model, h, [xy[0], xy[1], float(ground.height(xy[None])[0])])


def render_rough_examples(camera: Camera, ground: GroundSurface, cls: str, n: int,
                          rng: np.random.Generator, region_xy=None, scale_jitter: float = 0.08,
                          max_distance: float = MAX_DISTANCE, occlusion: float = 0.0,
                          random_sizes: bool = False
                          ) -> tuple[list[bytes], np.ndarray, np.ndarray]:
    """``n`` rough-model examples of class ``cls`` seen by ``camera``.

    region_xy: (xmin, xmax, ymin, ymax) metres to draw positions from (default: the ground the
    camera sees). Headings are uniform; sizes vary by ``scale_jitter`` (relative).
    Returns the masks as compressed RLE (n), their ground-contact positions xyz (n, 3) metres
    on ``ground``, and headings (n,) radians. Every mask is non-empty and its box centre lies
    inside the image. Each example is drawn alone, except that with probability ``occlusion``
    a rough car or pedestrian in front of it (``occluder_parts``) hides part of it, as road
    users hide each other at a junction (the truth stays the hidden road user's position).
    ``random_sizes``: each example's length, width and height drawn from the class's
    RANDOM_SIZES (independently) instead of the one box times ``scale_jitter``.
    """
    if n < 0:
        raise InputError(f"n must be >= 0, got {n}", field="n")
    base = rough_model(cls)
    if n == 0:
        return [], np.zeros((0, 3)), np.zeros(0)
    if region_xy is None:
        region_xy = visible_region(camera, ground, max_distance)
    x0r, x1r, y0r, y1r = map(float, region_xy)
    if not (x1r > x0r and y1r > y0r):
        raise InputError(f"region_xy must be (xmin, xmax, ymin, ymax) with min < max, got {region_xy}",
                         field="region_xy")
    W, H = camera.width, camera.height
    P = len(base)
    # occluders draw from their own stream, so the road users' poses do not depend on them
    occ_rng = rng.spawn(1)[0] if occlusion > 0 else None
    rles: list[bytes] = []
    xyz_out, hd_out = [], []
    tries = 0
    while len(rles) < n:
        tries += 1
        if tries > 200:
            raise InputError(f"could not place {n} {cls} examples in view inside region {region_xy}",
                             field="region_xy")
        m = max(2 * (n - len(rles)), 16)
        xy = np.column_stack([rng.uniform(x0r, x1r, m), rng.uniform(y0r, y1r, m)])
        hd = rng.uniform(-np.pi, np.pi, m)
        if random_sizes:  # per-axis scales (m, 3): l, w, h drawn from the class's ranges
            lo, hi = np.array(RANDOM_SIZES[cls]).T
            sc = rng.uniform(lo, hi, (m, 3)) / np.array(BASE_SIZES[cls])
        else:
            sc = np.repeat((1.0 + rng.uniform(-scale_jitter, scale_jitter, m))[:, None], 3, axis=1)
        z = ground.height(xy)
        xyz = np.column_stack([xy, z])
        # cheap reject first: the contact point must project into (a margin around) the image
        uv0, d0, front = camera.project_points(xyz)
        near = front & (np.linalg.norm(xyz - camera.center, axis=1) <= max_distance) \
            & (uv0[:, 0] > -0.25 * W) & (uv0[:, 0] < 1.25 * W) & (uv0[:, 1] > -0.25 * H) \
            & (uv0[:, 1] < 1.25 * H)
        idx = np.flatnonzero(near)
        if len(idx) == 0:
            continue
        k = len(idx)
        world = place(base[None] * sc[idx, None, None, :], hd[idx], xyz[idx])  # (k, P, 8, 3)
        uv, ok = project_parts(camera, world.reshape(k * P, 8, 3))
        uv = uv.reshape(k, P, 8, 2)
        ok = np.all(ok.reshape(k, P), axis=1)  # (k,) every part drawable
        for j in range(k):
            if len(rles) >= n:
                break
            if not ok[j]:
                continue
            pts = uv[j].reshape(-1, 2)
            bx0 = max(int(np.floor(pts[:, 0].min())) - 1, 0)
            by0 = max(int(np.floor(pts[:, 1].min())) - 1, 0)
            bx1 = min(int(np.ceil(pts[:, 0].max())) + 1, W)
            by1 = min(int(np.ceil(pts[:, 1].max())) + 1, H)
            if bx1 <= bx0 or by1 <= by0:
                continue
            crop = np.zeros((bx1 - bx0, by1 - by0), np.uint8)
            fill_parts(crop, uv[j] - np.array([bx0, by0]), np.ones(P, np.int64))
            if occ_rng is not None and occ_rng.random() < occlusion:  # set iff occlusion > 0
                ouv, ook = project_parts(camera, occluder_parts(camera, ground, xyz[idx[j], :2], occ_rng))
                if ook.all():
                    hidden = np.zeros_like(crop)
                    fill_parts(hidden, ouv - np.array([bx0, by0]), np.ones(len(ouv), np.int64))
                    crop[hidden > 0] = 0
            cols = np.flatnonzero(crop.any(axis=1))
            if len(cols) == 0:
                continue
            rows = np.flatnonzero(crop.any(axis=0))
            cx = bx0 + 0.5 * (cols[0] + cols[-1] + 1)
            cy = by0 + 0.5 * (rows[0] + rows[-1] + 1)
            if not (0 <= cx < W and 0 <= cy < H):
                continue
            rles.append(rle_from_crop_t(crop.astype(bool), bx0, by0, H, W))
            xyz_out.append(xyz[idx[j]])
            hd_out.append(hd[idx[j]])
    return rles, np.asarray(xyz_out, float).reshape(-1, 3), np.asarray(hd_out, float)
