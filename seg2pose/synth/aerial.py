"""A top-down aerial image of the synthetic junction (what a user would get from a map
service), with its world file's affine map: carriageway, lane lines, crosswalks, sidewalks,
grass, at ``res`` metres per pixel, north up.

Units: metres; image pixels in the corner convention (camera.py); the map A (2, 3) takes
pixel (u, v) to world x, y (io/calib_files.py).
"""

from __future__ import annotations

import numpy as np

from seg2pose.synth import junction as J

ROAD, MARK, WALK, GRASS = (70, 70, 72), (235, 235, 235), (170, 172, 175), (70, 130, 80)  # BGR


def arm_coords(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(a, b) (M,) of each point in the arm it lies along most: ``a`` outwards from the centre,
    ``b`` across (junction.to_world's inverse)."""
    x, y = xy[:, 0], xy[:, 1]
    along_x = np.abs(x) >= np.abs(y)
    a = np.where(along_x, np.abs(x), np.abs(y))
    b = np.where(along_x, y * np.sign(x + 1e-12), -x * np.sign(y + 1e-12))
    return a, b


def render_aerial(lo: tuple[float, float] = (-40.0, -40.0), hi: tuple[float, float] = (40.0, 40.0),
                  res: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """(image (H, W, 3) BGR uint8, A (2, 3)) of the area lo..hi (x, y metres)."""
    w = int(round((hi[0] - lo[0]) / res))
    h = int(round((hi[1] - lo[1]) / res))
    A = np.array([[res, 0.0, lo[0]], [0.0, -res, hi[1]]])
    u = np.arange(w) + 0.5
    img = np.empty((h, w, 3), np.uint8)
    for r0 in range(0, h, 256):  # row blocks bound the memory
        v = np.arange(r0, min(h, r0 + 256)) + 0.5
        U, V = np.meshgrid(u, v)
        xy = np.column_stack([U.ravel(), V.ravel()]) @ A[:, :2].T + A[:, 2]
        d = J.curb_distance(xy)
        a, b = arm_coords(xy)
        out = np.empty((len(xy), 3), np.uint8)
        out[:] = GRASS
        out[d <= J.SIDEWALK] = WALK
        road = d <= 0
        out[road] = ROAD
        beyond = a > J.ROAD_HALF + J.CORNER_R
        lanes = road & beyond & ((np.abs(b) < 0.08)
                                 | ((np.abs(np.abs(b) - J.LANE) < 0.06) & ((a % 6.0) < 3.0)))
        c0, c1 = J.ROAD_HALF + J.CROSSWALK[0], J.ROAD_HALF + J.CROSSWALK[1]
        zebra = road & (a > c0) & (a < c1) & ((np.floor((b + 20) / 0.5) % 2) == 0)
        out[lanes | zebra] = MARK
        img[r0:r0 + len(v)] = out.reshape(len(v), w, 3)
    return img, A


def camera_view(aerial: np.ndarray, A: np.ndarray, cam, sky=(200, 180, 150)) -> np.ndarray:
    """The aerial image seen through a camera (H, W, 3) BGR: each pixel's ray met with the
    junction's true surface and the aerial image sampled there (sky where a ray does not
    meet the ground or leaves the aerial image)."""
    import cv2

    U, V = np.meshgrid(np.arange(cam.width) + 0.5, np.arange(cam.height) + 0.5)
    uv = np.column_stack([U.ravel(), V.ravel()])
    X = J.ray_ground_points(cam.center, cam.unproject(uv))
    p = np.linalg.solve(A[:, :2], (X[:, :2] - A[:, 2]).T).T - 0.5  # aerial pixel centres
    mx = np.nan_to_num(p[:, 0], nan=-1e6).reshape(cam.height, cam.width).astype(np.float32)
    my = np.nan_to_num(p[:, 1], nan=-1e6).reshape(cam.height, cam.width).astype(np.float32)
    return cv2.remap(aerial, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=sky)
