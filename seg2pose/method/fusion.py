"""Late fusion (paper 3.3): the views of one road user in one frame -- one per camera, joined by
track id -- averaged into a pose, headings from motion (3.4), optional smoothing along the
tracks, the confirmation rule for associated ids (a pose is kept when enough of the cameras that
see its place report it) and the fused poses' error bars."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seg2pose.geometry.normal import fuse_views, headings_from_tracks
from seg2pose.geometry.smoothing import smooth_along_tracks
from seg2pose.io.poses import PoseTable
from seg2pose.io.run import ViewTable
from seg2pose.io.scene import Scene


@dataclass
class ViewGroups:
    """Views grouped into fused poses (one per frame and track id; an untracked view, id -1,
    is a pose of its own). keep: (N,) the views that take part (finite estimate, a class);
    keys: (P, 2) frame and grouping id, in np.unique order; first: (P,) a kept view of each
    pose; inv: (K,) pose of each kept view; cam_idx: (K,) its camera; n_cams."""

    keep: np.ndarray
    keys: np.ndarray
    first: np.ndarray
    inv: np.ndarray
    cam_idx: np.ndarray
    n_cams: int

    @classmethod
    def of(cls, views: ViewTable) -> ViewGroups:
        est = views.normal[:, :2] + views.residual
        keep = np.isfinite(est).all(axis=1) & (views.cls != "")
        key_tid = views.track_id[keep].copy()
        lone = key_tid < 0  # untracked detections get unique negative keys: they stay alone
        key_tid[lone] = -1 - np.arange(int(lone.sum()))
        keys = np.stack([views.frame[keep], key_tid], axis=1)
        ukeys, first, inv = np.unique(keys, axis=0, return_index=True, return_inverse=True)
        cams, cam_idx = np.unique(views.camera[keep], return_inverse=True)
        return cls(keep, ukeys, first, inv.reshape(-1), cam_idx, len(cams))

    def stack(self, values: np.ndarray) -> np.ndarray:
        """(n_cams, P, ...) the kept views' ``values`` (K, ...) by camera and pose; NaN where a
        camera did not see the pose's road user."""
        out = np.full((self.n_cams, len(self.keys)) + values.shape[1:], np.nan)
        out[self.cam_idx, self.inv] = values  # one detection per (camera, road user, frame)
        return out

    @property
    def track_id(self) -> np.ndarray:
        return np.where(self.keys[:, 1] < 0, -1, self.keys[:, 1])


def fuse(views: ViewTable, scene: Scene, smooth: int = 0, confirm: float = 0.0,
         config_cameras: list[str] | None = None, r90=None) -> PoseTable:
    """Late fusion: per (frame, track_id), the mean over views of normal position + residual;
    z from the ground surface at the fused (x, y); headings from the fused tracks (eq. 2);
    sizes from the class. Detections without a track id (-1) are not fused with anything.

    ``confirm`` > 0 (several cameras ``config_cameras`` with associated ids): a pose is kept only when
    at least this share of the cameras whose image holds its place reported it
    (``seen_share``): a blob one lens reports where the others see nothing is a false
    detection more often than not (docs/RESULTS.md, "Multi-camera association").

    ``smooth`` > 0: each tracked road user's fused (x, y) replaced by a line fitted to its
    positions within ``smooth`` frames either side (``seg2pose.geometry.smoothing``; centred, so no lag
    on steady motion), before z and the headings.

    ``r90``: a ``seg2pose.method.uncertainty.Calibration``; with it (and views that carry their r90),
    each pose gets its error bar (PoseTable.r90)."""
    g = ViewGroups.of(views)
    if not g.keep.any():
        return PoseTable.empty(with_size=True)
    ukeys, first = g.keys, g.first
    stack = g.stack((views.normal[:, :2] + views.residual)[g.keep])
    cls = views.cls[g.keep]
    xy = fuse_views(stack)
    out_cls = cls[first]
    kept = np.ones(len(ukeys), bool)
    if confirm > 0 and config_cameras and len(config_cameras) > 1:
        n_views = np.bincount(g.inv, minlength=len(ukeys))
        kept = n_views >= confirm * seen_by(scene, config_cameras, xy, out_cls)
        ukeys, xy, out_cls = ukeys[kept], xy[kept], out_cls[kept]
    out_tid = np.where(ukeys[:, 1] < 0, -1, ukeys[:, 1])
    if smooth > 0:
        xy = smooth_along_tracks(out_tid, ukeys[:, 0], xy, smooth, degree=1)
    z = scene.ground.height(xy)
    heading = np.full(len(ukeys), np.nan)
    tracked = out_tid >= 0
    heading[tracked] = headings_from_tracks(out_tid[tracked], ukeys[tracked, 0], xy[tracked])
    sizes = scene.class_sizes()
    size = np.array([sizes.get(str(c), (np.nan, np.nan, np.nan)) for c in out_cls], float)
    pose_r90 = None
    if r90 is not None and views.r90 is not None:
        from seg2pose.method.r90_features import pose_features

        pose_r90 = r90.pose.predict(out_cls, pose_features(stack[:, kept],
                                                           g.stack(views.r90[g.keep])[:, kept]))
    table = PoseTable(ukeys[:, 0], out_tid, out_cls, np.column_stack([xy, z]), heading, size,
                      r90=pose_r90)
    return table.sorted()


def seen_by(scene: Scene, cams: list[str], xy: np.ndarray, cls: np.ndarray,
            margin: float = 0.02) -> np.ndarray:
    """(N,) how many of ``cams`` have the place xy (N, 2) metres of a road user of class
    ``cls`` (N,) in their image: its centre (the class's default height above the ground)
    in front of the camera and at least ``margin`` of the image size inside the border."""
    h = scene.default_heights()
    X = np.column_stack([xy, scene.ground.height(xy) + np.array([h.get(str(c), 0.8) for c in cls])])
    n = np.zeros(len(xy), np.int64)
    for c in cams:
        cam = scene.cameras[c]
        uv, _, front = cam.project_points(X)
        mx, my = margin * cam.width, margin * cam.height
        with np.errstate(invalid="ignore"):
            n += front & (uv[:, 0] >= mx) & (uv[:, 0] < cam.width - mx) & (uv[:, 1] >= my) \
                & (uv[:, 1] < cam.height - my)
    return n
