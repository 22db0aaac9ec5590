"""The cues of an error bar (``r90_m``, ``seg2pose.method.uncertainty``) as feature matrices:
per view (VIEW_FEATURES, from views.csv's cues and boxes and the scene's cameras and class
sizes) and per fused pose (POSE_FEATURES). The fitting and applying of the quantile models is
``seg2pose.method.uncertainty``; the cues themselves are described there."""

from __future__ import annotations

import numpy as np

from seg2pose.core.errors import InputError

VIEW_FEATURES = ["one", "log_grazing", "cut", "cut_edge", "crowd", "far", "log_spread", "log_residual",
                 "log_foot"]
POSE_FEATURES = ["one", "log_r_views", "log_n_views", "log_disagreement"]
FLOOR_M = 0.02         # errors below this count as this (log of a near-zero error is noise)
FOOT_FLOOR_M = 0.05    # log_foot = log(|foot offset| + this): a box bottom within a few cm of
                       # the typical one is as good as on it (pixel rounding, not size)


# ----------------------------------------------------------------------------------------------
# cues -> feature matrices


def crowding(frame: np.ndarray, camera: np.ndarray, uv: np.ndarray, rng: np.ndarray,
             size_px: np.ndarray) -> np.ndarray:
    """(N,) how far each view's mask may be hidden behind another road user's, 0 (no one
    near) to 1 (centres coincide): per frame and camera, the largest 1 - |uv_i - uv_j| / s_j
    over the views j nearer the camera (rng_j < rng_i) whose apparent size s_j (pixels) the
    centre uv_i lies within. frame, camera (N,), uv (N, 2) pixels, rng (N,) metres from the
    camera, size_px (N,) pixels."""
    n = len(frame)
    out = np.zeros(n)
    if n < 2:
        return out
    cam_id = np.unique(camera, return_inverse=True)[1].reshape(-1)
    order = np.lexsort((cam_id, frame))
    f_s, c_s = frame[order], cam_id[order]
    cut = np.flatnonzero((f_s[1:] != f_s[:-1]) | (c_s[1:] != c_s[:-1])) + 1
    for idx in np.split(order, cut):
        if len(idx) < 2:
            continue
        D = np.linalg.norm(uv[idx, None, :] - uv[None, idx, :], axis=2)
        with np.errstate(invalid="ignore", divide="ignore"):
            ov = 1.0 - D / size_px[idx][None, :]
        r = rng[idx]
        ov[~(r[None, :] < r[:, None])] = 0.0
        out[idx] = np.clip(np.nan_to_num(ov, nan=0.0), 0.0, 1.0).max(axis=1)
    return out


def cuboid_box(camera, ground, xy: np.ndarray, heading: np.ndarray, lwh: np.ndarray) -> np.ndarray:
    """(N, 4) x0, y0, x1, y1, pixels, the image box of a cuboid of size lwh (N, 3) l, w, h
    metres standing on the ground at xy (N, 2) metres, its length along ``heading`` (N,)
    radians (NaN: the mean of the boxes at headings 0, 45, 90 and 135 degrees, for a road
    user whose heading is not known yet). NaN where a corner is behind the camera or xy is
    NaN."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    n = len(xy)
    lwh = np.broadcast_to(np.asarray(lwh, float), (n, 3))
    heading = np.broadcast_to(np.asarray(heading, float), (n,))
    z = ground.height(np.nan_to_num(xy)) if n else np.zeros(0)

    def box_at(th: np.ndarray) -> np.ndarray:
        c, s = np.cos(th), np.sin(th)
        corners = []
        for a in (-0.5, 0.5):
            for b in (-0.5, 0.5):
                dx = a * lwh[:, 0] * c - b * lwh[:, 1] * s
                dy = a * lwh[:, 0] * s + b * lwh[:, 1] * c
                for h in (0.0, 1.0):
                    corners.append(np.column_stack([xy[:, 0] + dx, xy[:, 1] + dy, z + h * lwh[:, 2]]))
        P = np.stack(corners, axis=1)  # (N, 8, 3)
        uv, _, front = camera.project_points(P.reshape(-1, 3))
        uv = uv.reshape(n, 8, 2)
        box = np.concatenate([uv.min(axis=1), uv.max(axis=1)], axis=1)
        box[~front.reshape(n, 8).all(axis=1)] = np.nan
        return box

    known = np.isfinite(heading)
    out = box_at(np.where(known, heading, 0.0))
    if (~known).any():
        mean = np.mean([box_at(np.full(n, a)) for a in np.deg2rad([0.0, 45.0, 90.0, 135.0])], axis=0)
        out[~known] = mean[~known]
    return out


def typical_boxes(scene, views) -> np.ndarray:
    """(N, 4) per view, the image box (``cuboid_box``) of a road user of its class's typical
    size (``Scene.class_sizes``) standing at its normal position, heading from its motion in
    that camera (``headings_from_tracks``; NaN before it has moved). NaN where the class has no
    size or the ray missed the ground."""
    from seg2pose.geometry.normal import headings_from_tracks

    out = np.full((len(views), 4), np.nan)
    sizes = scene.class_sizes()
    lwh = np.array([sizes.get(str(c), (np.nan,) * 3) for c in views.cls], float).reshape(-1, 3)
    for cam in np.unique(views.camera):
        sel = np.flatnonzero(views.camera == cam)
        xy = views.normal[sel, :2]
        tid = views.track_id[sel]
        heading = np.full(len(sel), np.nan)
        tracked = tid >= 0
        heading[tracked] = headings_from_tracks(tid[tracked], views.frame[sel][tracked], xy[tracked])
        out[sel] = cuboid_box(scene.cameras[str(cam)], scene.ground, xy, heading, lwh[sel])
    return out


def foot_offset(scene, views, typical: np.ndarray) -> np.ndarray:
    """(N,) metres, signed along the camera's line of sight (away from the camera positive):
    where the ray through the bottom centre of the mask's box meets the ground, minus where
    it meets it for ``typical`` (N, 4), the box of the class's typical road user placed at the
    normal position. The box bottom is the road user's near ground contact whatever its
    height, while the normal position moves along the ray with its height: a road user taller
    or longer than typical gives a negative offset about as long as the normal position's
    error. NaN without a box or where a ray misses."""
    from seg2pose.geometry.normal import normal_positions

    out = np.full(len(views), np.nan)
    for cam in np.unique(views.camera):
        sel = np.flatnonzero(views.camera == cam)
        camera = scene.cameras[str(cam)]
        obs = np.column_stack([(views.box[sel, 0] + views.box[sel, 2]) / 2, views.box[sel, 3]])
        exp = np.column_stack([(typical[sel, 0] + typical[sel, 2]) / 2, typical[sel, 3]])
        ok = np.isfinite(obs).all(axis=1) & np.isfinite(exp).all(axis=1)
        if not ok.any():
            continue
        f_obs, _ = normal_positions(camera, scene.ground, obs[ok], 0.0)
        f_exp, _ = normal_positions(camera, scene.ground, exp[ok], 0.0)
        ray = views.normal[sel[ok], :2] - camera.center[:2]
        ray /= np.maximum(np.linalg.norm(ray, axis=1, keepdims=True), 1e-9)
        out[sel[ok]] = ((f_obs[:, :2] - f_exp[:, :2]) * ray).sum(axis=1)
    return out


def pose_features(est: np.ndarray, r_view: np.ndarray) -> np.ndarray:
    """(P, len(POSE_FEATURES)) for P fused poses from the stacks of their views: est (C, P, 2)
    view estimates and r_view (C, P) the views' r90, metres, NaN where a camera did not see
    the road user. (The angle between the heading and the line of sight was tried as a cue
    for cars seen end-on: it did not rank their errors better and made bicyclists' bars
    worse on the tuning scene, docs/RESULTS.md.)"""
    seen = np.isfinite(est).all(axis=2) & np.isfinite(r_view)
    n = np.maximum(seen.sum(axis=0), 1)
    r_comb = np.sqrt(np.where(seen, r_view ** 2, 0.0).sum(axis=0)) / n
    mean = np.where(seen[..., None], est, 0.0).sum(axis=0) / n[:, None]
    dev = np.where(seen, np.linalg.norm(np.nan_to_num(est) - mean[None], axis=2), 0.0)
    disagree = np.sqrt((dev ** 2).sum(axis=0) / n)
    return np.column_stack([np.ones(len(n)), np.log(np.maximum(r_comb, FLOOR_M)), np.log(n),
                            np.log(disagree + 0.05)])


def camera_centers(scene, cameras: np.ndarray) -> np.ndarray:
    """(N, 3) centre of each row's camera, metres."""
    out = np.full((len(cameras), 3), np.nan)
    for c in np.unique(cameras):
        out[cameras == c] = scene.cameras[str(c)].center
    return out


def view_columns(scene, views) -> dict[str, np.ndarray]:
    """The view features of a ViewTable with cues and boxes, by name (VIEW_FEATURES and
    ``log_distance``, which was tried): grazing = ground distance / the camera's height above
    the normal position; cut_edge = cut x log(1 + pixels from the box centre to the nearest
    image border); crowd (``crowding``) with each road user's apparent size CROWD_SCALE x f x
    the larger of its class's length and height / its range; log_foot = log(|``foot_offset``|
    + FOOT_FLOOR_M) (0 offset where it is unknown). Views without a box (a views.csv of an
    older s2p) are refused."""
    if views.box is None:
        raise InputError("views.csv has no box_x0,box_y0,box_x1,box_y1 columns (made by an older "
                         "s2p): run it again to use or fit error bars")
    cc = camera_centers(scene, views.camera)
    normal = views.normal
    d = np.linalg.norm(normal[:, :2] - cc[:, :2], axis=1)
    above = np.maximum(cc[:, 2] - normal[:, 2], 0.5)
    rng = np.linalg.norm(normal - cc, axis=1)
    focal = np.array([scene.cameras[str(c)].K[0, 0] for c in views.camera]) if len(views) else np.zeros(0)
    sizes = scene.class_sizes()
    ext = np.array([max(sizes.get(str(c), (1.0, 1.0, 1.0))[0], sizes.get(str(c), (1.0, 1.0, 1.0))[2])
                    for c in views.cls]) if len(views) else np.zeros(0)
    size_px = CROWD_SCALE * focal * ext / np.maximum(rng, 1.0)
    res = np.linalg.norm(views.residual, axis=1)
    cues = views.cues
    wh = np.array([(scene.cameras[str(c)].width, scene.cameras[str(c)].height) for c in views.camera],
                  float).reshape(-1, 2)
    u, v = views.uv[:, 0], views.uv[:, 1]
    edge = np.minimum(np.minimum(u, wh[:, 0] - u), np.minimum(v, wh[:, 1] - v))
    foot = foot_offset(scene, views, typical_boxes(scene, views))
    return {"log_foot": np.log(np.abs(np.nan_to_num(foot, nan=0.0)) + FOOT_FLOOR_M),
            "cut_edge": cues[:, 0] * np.log1p(np.maximum(np.nan_to_num(edge, nan=0.0), 0.0)),
            "one": np.ones(len(d)), "log_distance": np.log(np.maximum(d, 1.0)),
            "log_grazing": np.log(np.maximum(d / above, 0.05)), "cut": cues[:, 0],
            "crowd": crowding(views.frame, views.camera, views.uv, rng, size_px),
            "far": cues[:, 1], "log_spread": np.log(cues[:, 2] + 0.02),
            "log_residual": np.log(res + 0.05)}


CROWD_SCALE = 1.0  # the whole apparent size (not tuned)


def views_matrix(scene, views) -> np.ndarray:
    """VIEW_FEATURES of a ViewTable with cues."""
    cols = view_columns(scene, views)
    return np.column_stack([cols[k] for k in VIEW_FEATURES]) if len(views) else np.zeros((0, len(VIEW_FEATURES)))
