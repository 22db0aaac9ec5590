"""Normal positions (paper 3.2), per-class default heights by bisection, late fusion (3.3) and
headings from motion (3.4, eq. 2).

The normal position of a road user in one view: take the mask centre (pixels), cast the camera
ray through it, intersect it with the ground surface *raised by the class's default height*
(first approximated by a plane at the mean ground height, then refined on the real surface
until the 3D point projects onto the mask centre — it lies on the ray by construction). The
road user stands on the ground below that point: the normal position is (x, y, z_ground(x, y)).
"""

from __future__ import annotations

import numpy as np

from seg2pose.geometry.camera import Camera
from seg2pose.geometry.ground import GroundSurface

DEFAULT_HEIGHTS = {"pedestrian": 0.9, "bicyclist": 0.9, "car": 0.75}  # metres, before bisection

# Which mask centre the normal position starts from: "bbox" (centre of the mask's bounding box,
# paper section 5) or "centroid" (mean of its pixels, paper 3.2). Measured on four synthetic
# scenes with truth (docs/NORMAL_POSITIONS.md): bbox 0.309 m vs centroid 0.317 m per view,
# 0.440 vs 0.457 m fused; bbox wins for pedestrians, the centroid for cars.
DEFAULT_CENTER_METHOD = "bbox"
CENTER_METHODS = ("bbox", "centroid")


def normal_positions(camera: Camera, ground: GroundSurface, centers: np.ndarray,
                     heights: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """Normal positions for many detections of one camera.

    centers: (N, 2) mask centres in pixels; heights: (N,) or scalar default heights, metres.
    Returns positions (N, 3) metres on the ground (NaN rows where the ray misses) and the
    status codes (N,) of ``GroundSurface.intersect_rays``.
    """
    centers = np.asarray(centers, dtype=np.float64).reshape(-1, 2)
    if len(centers) == 0:
        return np.zeros((0, 3)), np.zeros(0, np.int8)
    dirs = camera.unproject(centers)
    X, status = ground.intersect_rays(camera.center, dirs, heights)
    X[:, 2] = np.where(np.isfinite(X[:, 0]), X[:, 2] - heights, np.nan)
    return X, status


def closer_share(views: list[tuple[Camera, np.ndarray, np.ndarray]], ground: GroundSurface,
                 height: float) -> tuple[float, int]:
    """Share of normal positions (at ``height``) closer to their camera, in the ground plane,
    than the true positions, and the number of detections whose ray hit the surface.

    views: per camera, (camera, centers (N, 2) pixels, truth_xy (N, 2) metres)."""
    closer = n = 0
    for cam, cen, txy in views:
        X, _ = normal_positions(cam, ground, cen, height)
        ok = np.isfinite(X[:, 0])
        c = cam.center[:2]
        closer += int(np.sum(np.linalg.norm(X[ok, :2] - c, axis=1)
                             < np.linalg.norm(np.asarray(txy)[ok] - c, axis=1)))
        n += int(ok.sum())
    return (closer / n if n else float("nan")), n


def default_height_bisection(views: list[tuple[Camera, np.ndarray, np.ndarray]],
                             ground: GroundSurface, lo: float = 0.0, hi: float = 4.0,
                             tol: float = 1e-3) -> float:
    """Paper 3.2: the default height of a class such that about half of the training set's
    normal positions are closer to the camera than the truth and half further.

    views: per camera, (camera, centers (N, 2) pixels, truth_xy (N, 2) metres). A higher
    default height moves normal positions towards the camera, so the share of 'closer' grows
    with the height and bisection applies.
    """
    def share(h: float) -> float:
        value, n = closer_share(views, ground, h)
        return value if n else 0.0

    a, b = lo, hi
    while b - a > tol:
        m = 0.5 * (a + b)
        if share(m) < 0.5:
            a = m
        else:
            b = m
    return 0.5 * (a + b)


def fuse_views(estimates: np.ndarray) -> np.ndarray:
    """Late fusion (3.3): mean over views, skipping views that did not see the road user.

    estimates: (V, N, D) with NaN rows for views without a detection -> (N, D); NaN where no
    view saw it."""
    est = np.asarray(estimates, dtype=np.float64)
    seen = np.asarray(np.isfinite(est).all(axis=2))
    n = seen.sum(axis=0)
    total = np.where(seen[..., None], est, 0.0).sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = total / n[:, None]
    out[n == 0] = np.nan
    return out


MIN_STEP = 0.02  # metres: eq. (2) updates the direction only on larger steps


def headings_from_tracks(track_id: np.ndarray, frame: np.ndarray, xy: np.ndarray,
                         min_step: float = MIN_STEP, new_weight: float = 0.1) -> np.ndarray:
    """Headings (N,) radians, counter-clockwise from +x, from motion (paper 3.4, eq. 2).

    Per track, in frame order: if the step D from the previous position (the last finite one)
    is longer than
    ``min_step``, the direction becomes normalise(0.1 * D/|D| + 0.9 * D_t); otherwise it is
    kept. The first step sets the direction. NaN until a track has moved.

    track_id, frame: (N,) ints; xy: (N, 2) metres. Rows may come in any order.
    """
    track_id = np.asarray(track_id)
    frame = np.asarray(frame)
    xy = np.asarray(xy, dtype=np.float64)
    heading = np.full(len(track_id), np.nan)
    if not len(track_id):
        return heading
    order = np.lexsort((frame, track_id))
    tid, p = track_id[order], xy[order]
    # the recursion is sequential in time; it runs over tracks in parallel, one step per frame
    starts = np.flatnonzero(np.r_[True, tid[1:] != tid[:-1]])
    lengths = np.diff(np.r_[starts, len(tid)])
    D = np.full((len(starts), 2), np.nan)
    last = p[starts].copy()
    out = np.full(len(tid), np.nan)
    for k in range(1, int(lengths.max(initial=1))):
        act = lengths > k
        idx = starts[act] + k
        cur = p[idx]
        step = cur - last[act]
        n = np.linalg.norm(step, axis=1)
        valid = np.isfinite(n)
        move = valid & (n > min_step)
        Dk = D[act]
        unit = step / np.where(move, n, 1.0)[:, None]
        first = move & ~np.isfinite(Dk[:, 0])
        upd = move & ~first
        new = new_weight * unit + (1 - new_weight) * Dk
        new /= np.linalg.norm(new, axis=1, keepdims=True)
        Dk = np.where(first[:, None], unit, np.where(upd[:, None], new, Dk))
        D[act] = Dk
        # the previous position is the last one seen (a NaN position is skipped)
        last_act = last[act]
        last_act[valid | ~np.isfinite(last_act[:, 0])] = cur[valid | ~np.isfinite(last_act[:, 0])]
        last[act] = last_act
        out[idx] = np.arctan2(Dk[:, 1], Dk[:, 0])
    heading[order] = out
    return heading
