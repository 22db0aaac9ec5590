"""The cross-camera association of a multi-camera run, shown so that a wrong join is visible at
a glance (issue 23):

- ``world/cameras/<cam>/masks_by_id``: every camera's masks painted in the colour of their
  track id (one colour per road user, the same in every camera);
- ``world/association/<run>``: per frame, a line from each camera's estimate of a road user
  (normal position + residual) to its fused pose: one star per road user; a line across the
  junction is two road users joined by mistake.
"""

from __future__ import annotations

import colorsys

import numpy as np

from s2p_review import columns as C
from s2p_review import imagery
from s2p_review import layout as L
from s2p_review.runs import Run
from s2p_review.timebase import Timebase
from seg2pose.io.scene import Scene

N_COLORS = 255   # id colours cycle (pixel value 1..255; 0 = background)
BATCH = 64       # frames per send_columns call of images


def id_color(track_id: np.ndarray) -> np.ndarray:
    """(N, 3) uint8: one colour per id (golden-ratio hues, cycling every N_COLORS ids)."""
    k = (np.asarray(track_id, np.int64) - 1) % N_COLORS
    rgb = [colorsys.hsv_to_rgb((0.618034 * i) % 1.0, 0.75, 1.0) for i in range(N_COLORS)]
    return (np.array(rgb)[k] * 255).astype(np.uint8)


def _id_value(track_id: np.ndarray) -> np.ndarray:
    return np.where(track_id > 0, (track_id - 1) % N_COLORS + 1, 0).astype(np.uint8)


def log_masks_by_id(rec, scene: Scene, tb: Timebase, cameras: list[str], first: int, last: int,
                    every: int = 1) -> None:
    """Every camera's masks painted in the colour of their track id, on the cadence ``every``
    (see the module docstring). The masks are the scene's, not a run's: logged once per
    recording, for the cameras of its multi-camera runs."""
    import rerun as rr

    ctx = rr.AnnotationContext([rr.AnnotationInfo(id=0, label="background", color=(0, 0, 0, 0))]
                               + [rr.AnnotationInfo(id=i, label=f"id {i} (mod {N_COLORS})",
                                                    color=tuple(int(x) for x in id_color(np.array([i]))[0]))
                                  for i in range(1, N_COLORS + 1)])
    for cam in cameras:
        ent = L.cam_path(cam) + "/masks_by_id"
        cam_obj = scene.cameras[cam]
        rec.log(ent, ctx, static=True)
        rec.log(ent, rr.SegmentationImage.from_fields(
            format=rr.components.ImageFormat(width=cam_obj.width, height=cam_obj.height,
                                             channel_datatype="U8"),
            opacity=0.5, draw_order=5.5), static=True)
        batch: list = []
        for item in list(imagery.mask_frames(scene, cam, first, last, every)) + [None]:
            if item is not None:
                batch.append(item)
            if batch and (item is None or len(batch) == BATCH):
                imgs = imagery.paint([t for _, t in batch], [_id_value(t.track_id) for _, t in batch],
                                     scene.masks_path(cam))
                rec.send_columns(ent, indexes=tb.rerun_columns([f for f, _ in batch]),
                                 columns=rr.SegmentationImage.columns(buffer=imgs.reshape(len(batch), -1)))
                batch = []


def association_cameras(run: Run, cameras: list[str]) -> list[str]:
    """The cameras of ``cameras`` that ``run`` fused; empty for a one-camera run (nothing to
    associate)."""
    run_cams = [c for c in cameras if c in (run.cameras or cameras)]
    return run_cams if len(run_cams) >= 2 else []


def log_association(rec, run: Run, tb: Timebase, cameras: list[str], first: int,
                    last: int) -> None:
    """The per-camera estimates of ``run`` joined to its fused poses (see the module
    docstring). Nothing for a one-camera run."""
    import rerun as rr

    run_cams = association_cameras(run, cameras)
    if not run_cams:
        return
    frames, strips, ids = association_strips(run, run_cams, first, last)
    ent = f"world/association/{L.entity_part(run.name)}"
    rec.log(ent, rr.LineStrips3D.from_fields(radii=0.04), static=True)
    rec.send_columns(ent, indexes=tb.rerun_columns(np.arange(first, last + 1)),
                     columns=rr.LineStrips3D.columns(strips=list(strips), colors=id_color(ids))
                     .partition(C.frame_lengths(frames, first, last)))


def association_strips(run: Run, cameras: list[str], first: int, last: int
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frames (K,), segments (K, 2, 3) metres from each view's estimate (normal position +
    residual, at the fused pose's height) to the fused pose of its (frame, track id), and the
    ids (K,); in frame order. Views of untracked masks or without a fused pose are left out."""
    v, p = run.views, run.poses
    empty = (np.zeros(0, np.int64), np.zeros((0, 2, 3)), np.zeros(0, np.int64))
    if v is None or not len(v):
        return empty
    v = v.take((v.frame >= first) & (v.frame <= last) & (v.track_id >= 0) & np.isin(v.camera, cameras))
    p = p.in_frames((first, last))
    if not len(v) or not len(p):
        return empty
    key_p = p.frame * (1 << 31) + p.track_id
    order = np.argsort(key_p)
    key_v = v.frame * (1 << 31) + v.track_id
    at = np.minimum(np.searchsorted(key_p[order], key_v), len(p) - 1)
    hit = key_p[order][at] == key_v
    v = v.take(hit)
    fused = p.xyz[order[at[hit]]]
    est = np.c_[v.normal[:, :2] + v.residual, fused[:, 2]]
    ok = np.isfinite(est).all(axis=1) & np.isfinite(fused).all(axis=1)
    o = np.flatnonzero(ok)[np.argsort(v.frame[ok], kind="stable")]
    return v.frame[o], np.stack([est[o], fused[o]], axis=1), v.track_id[o]
