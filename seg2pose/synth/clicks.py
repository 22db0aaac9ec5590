"""A scripted user who clicks calibration pairs on a synthetic scene: points spread over the
road in a camera's view (farthest-point sampling in the image among the pixels whose ray meets
the carriageway or a sidewalk within ``max_dist`` metres), their exact pixels and world
points, and the same with click noise: pixels with ``pixel_sigma`` (clipped to the image),
world x, y with ``world_sigma`` (an aerial image clicked within a few of its pixels), and the
elevations read off the scene's surveyed ground (eq. (1) over its ground points) when given.

Units: pixels (corner convention), metres.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from seg2pose.geometry.camera import Camera
from seg2pose.synth import junction as J

STEP = 8  # pixels between the candidate pixels


def road_pixels(cam: Camera, max_dist: float = 50.0, margin: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Candidate pixels (M, 2) on the road (carriageway or sidewalk) within ``max_dist`` metres
    of the camera, ``margin`` pixels inside the image, and their true ground points (M, 3)."""
    u = np.arange(margin, cam.width - margin, STEP) + 0.5
    v = np.arange(margin, cam.height - margin, STEP) + 0.5
    U, V = np.meshgrid(u, v)
    uv = np.column_stack([U.ravel(), V.ravel()])
    X = J.ray_ground_points(cam.center, cam.unproject(uv))
    ok = np.isfinite(X).all(1)
    ok[ok] = (np.linalg.norm(X[ok] - cam.center, axis=1) <= max_dist) \
        & (J.curb_distance(X[ok, :2]) <= J.SIDEWALK)
    return uv[ok], X[ok]


def spread_clicks(cam: Camera, n: int, rng: np.random.Generator, max_dist: float = 50.0,
                  margin: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """n exact pairs spread over the road in view (``margin`` pixels inside the image): pixels
    (n, 2), world points (n, 3). The first is drawn at random, each next one is the candidate
    farthest (in the image) from those chosen, jittered by up to half a step."""
    uv, X = road_pixels(cam, max_dist, margin)
    if len(uv) < n:
        raise ValueError(f"camera {cam.name} sees only {len(uv)} road pixels within {max_dist} m")
    chosen = [int(rng.integers(len(uv)))]
    d = np.linalg.norm(uv - uv[chosen[0]], axis=1)
    for _ in range(n - 1):
        k = int(np.argmax(d + rng.uniform(0, STEP, len(d))))
        chosen.append(k)
        d = np.minimum(d, np.linalg.norm(uv - uv[k], axis=1))
    p = uv[chosen] + rng.uniform(-STEP / 2, STEP / 2, (n, 2))
    Xp = J.ray_ground_points(cam.center, cam.unproject(p))
    return p, Xp


def noisy_clicks(uv: np.ndarray, X: np.ndarray, cam: Camera, rng: np.random.Generator,
                 pixel_sigma: float = 1.5, world_sigma: float = 0.1,
                 height: Callable[[np.ndarray], np.ndarray] | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The user's clicks of exact pairs: noisy pixels (clipped into the image), noisy world
    x, y, and z from ``height`` at the noisy x, y (the surveyed ground) or the true z."""
    uvn = uv + rng.normal(0, pixel_sigma, uv.shape)
    uvn = np.clip(uvn, 0.0, [cam.width - 1e-6, cam.height - 1e-6])
    Xn = X.copy()
    Xn[:, :2] += rng.normal(0, world_sigma, (len(X), 2))
    if height is not None:
        Xn[:, 2] = height(Xn[:, :2])
    return uvn, Xn
