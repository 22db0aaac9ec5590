"""Log a scene and its runs to a Rerun recording stream (the layout of ``s2p_review.layout``),
one function per entity family, column-wise: every temporal entity is sent with
``rr.send_columns`` over whole frame ranges; images (the bulk of the data) go in batches of
frames to bound memory (``recording_images``); each road user of a run is an entity of its own
(``road_users``). Where the recording goes (file, viewers) is ``s2p_review.session``.
"""

from __future__ import annotations

import numpy as np

from s2p_review import columns as C
from s2p_review import layout as L
from s2p_review import road_users as RU
from s2p_review.association import association_cameras, log_association, log_masks_by_id
from s2p_review.log_context import VIDEO_FORMATS, LogContext, LogStats, LogStyle
from s2p_review.recording_images import log_masks, log_video, outline_table
from s2p_review.runs import Run
from s2p_review.selection import Selection
from s2p_review.timebase import Timebase
from seg2pose.io.poses import PoseTable, read_poses
from seg2pose.io.scene import Scene

# the names other modules import from here
__all__ = ["VIDEO_FORMATS", "LogContext", "LogStats", "LogStyle", "log_all", "log_static",
           "outline_table", "error_series"]


def _rr():
    import rerun as rr

    return rr


# --- static parts ------------------------------------------------------------------------------
def log_static(ctx: LogContext, cameras: list[str]) -> None:
    """Class colours, the ground (points and eq. (1) surface) and the cameras."""
    rr = _rr()
    scene = ctx.scene
    ctx.static("/", L.annotation_context(scene.classes))
    ctx.static("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP)
    g = scene.ground_points
    ctx.static("world/ground/points", rr.Points3D(g, radii=0.08, colors=(150, 150, 150)))
    extent = float(max(np.ptp(g[:, 0]), np.ptp(g[:, 1])))
    verts, tris = scene.ground.mesh(n=48, margin=max(2.0, 0.15 * extent))
    ctx.static("world/ground/mesh", rr.Mesh3D(vertex_positions=verts, triangle_indices=tris,
                                              albedo_factor=(90, 90, 90, 255)))
    for name in cameras:
        cam = scene.cameras[name]
        p = L.cam_path(name)
        ctx.static(p, rr.Transform3D(translation=cam.center, mat3x3=cam.R.T))
        ctx.static(p, rr.Pinhole(image_from_camera=cam.K, resolution=[cam.width, cam.height],
                                 camera_xyz=rr.ViewCoordinates.RDF,
                                 image_plane_distance=ctx.style.image_plane_distance))


# --- road users over frames ----------------------------------------------------------------------
def log_gt_boxes(ctx: LogContext, table: PoseTable, sizes: np.ndarray) -> None:
    """The truth's boxes (``world/gt``) over the range in grey, one row per frame: a reference
    to compare with, not something to select one by one (the runs' road users are that)."""
    rr = _rr()
    order = np.argsort(table.frame, kind="stable")
    t, sz = table.take(order), sizes[order]
    ctx.static("world/gt", rr.Boxes3D.from_fields(show_labels=False, fill_mode="majorwireframe"))
    ctx.send_range("world/gt", rr.Boxes3D.columns(
        **C.box_columns(t.xyz, t.heading, sz), colors=np.tile(np.array(L.GT_COLOR, np.uint8), (len(t), 1)))
        .partition(C.frame_lengths(t.frame, ctx.first, ctx.last)))


def log_projected(ctx: LogContext, ent: str, camera, table: PoseTable, sizes: np.ndarray,
                  color=None, look: str = "model") -> None:
    """The boxes of ``table`` projected into ``camera`` as LineStrips2D, per frame, in the
    ``look`` of the run (a model's lines bold, the baseline's thin and pale)."""
    rr = _rr()
    order = np.argsort(table.frame, kind="stable")
    t, sz = table.take(order), sizes[order]
    segs, idx = C.projected_paths(camera, t.xyz, t.heading, sz)
    lengths = C.frame_lengths(t.frame[idx], ctx.first, ctx.last)
    # constant look (width, draw order, and the colour of truth) once, statically
    ctx.static(ent, rr.LineStrips2D.from_fields(draw_order=2.0, radii=L.RUN_LOOKS[look]["line"],
                                                colors=color if color is not None else None))
    extra = {} if color is not None else {"colors": L.run_colors(t.cls[idx], ctx.scene.classes, look)}
    ctx.send_range(ent, rr.LineStrips2D.columns(
        strips=C.segments_arrow(segs, rr.components.LineStrip2DBatch), **extra).partition(lengths))


def log_views(ctx: LogContext, run: Run, cameras: list[str]) -> None:
    """Per view: mask centres (2D), normal positions (3D) and residual arrows."""
    rr = _rr()
    v = run.views
    if v is None or len(v) == 0:
        return
    first, last = ctx.first, ctx.last
    v = v.take((v.frame >= first) & (v.frame <= last))
    for cam in cameras:
        sel = np.flatnonzero(v.camera == cam)
        if not len(sel):
            continue
        vv = v.take(sel[np.argsort(v.frame[sel], kind="stable")])
        lengths = C.frame_lengths(vv.frame, first, last)
        cols = L.class_colors(vv.cls, ctx.scene.classes)
        ent2 = f"{L.cam_path(cam)}/normal/{L.entity_part(run.name)}"
        ctx.send_range(ent2, rr.Points2D.columns(positions=vv.uv, colors=cols,
                                                 radii=[2.5] * len(vv)).partition(lengths))
        ctx.static(ent2, rr.Points2D.from_fields(draw_order=6.0))
        base = f"world/estimates/{L.entity_part(run.name)}/{L.entity_part(cam)}"
        # a ray that missed the ground has no normal position: no 3D point, no arrow
        ok = np.isfinite(vv.normal).all(axis=1) & np.isfinite(vv.residual).all(axis=1)
        v3 = vv.take(ok)
        len3 = C.frame_lengths(v3.frame, first, last)
        ctx.static(base, rr.Points3D.from_fields(radii=0.12))
        ctx.send_range(base, rr.Points3D.columns(positions=v3.normal, colors=cols[ok]).partition(len3))
        if np.any(v3.residual != 0):
            vec = np.c_[v3.residual, np.zeros(len(v3))]
            ctx.static(base + "/residuals", rr.Arrows3D.from_fields(radii=0.03))
            ctx.send_range(base + "/residuals", rr.Arrows3D.columns(
                origins=v3.normal, vectors=vec, colors=cols[ok]).partition(len3))


def error_series(run: Run, gt: PoseTable, scene: Scene, first: int, last: int
                 ) -> dict[str, tuple[np.ndarray, np.ndarray, tuple[int, int, int]]]:
    """name -> (frames (F,), error (F,) metres, colour) of the per-frame mean error ("mean")
    and of each class (seg2pose.eval.evaluate.per_frame_errors); frames without a value left out."""
    from seg2pose.eval.evaluate import per_frame_errors

    frames, mean, per_class = per_frame_errors(run.poses.in_frames((first, last)),
                                               gt.in_frames((first, last)))
    by_name = {c.name: c for c in scene.classes}
    series = {"mean": (mean, (255, 255, 255))}
    for name, err in per_class.items():
        series[name] = (err, L.class_color(name, by_name[name].id if name in by_name else 0))
    out = {}
    for key, (err, color) in series.items():
        ok = np.isfinite(err)
        if ok.any():
            out[key] = (np.asarray(frames)[ok], np.asarray(err, float)[ok], color)
    return out


def log_errors(ctx: LogContext, run: Run, gt: PoseTable) -> bool:
    """The run's error series (``error_series``) under metrics/error/<run>: one plot per run.
    Returns whether anything was plotted."""
    rr = _rr()
    series = error_series(run, gt, ctx.scene, ctx.first, ctx.last)
    for key, (frames, err, color) in series.items():
        ent = f"metrics/error/{L.entity_part(run.name)}/{L.entity_part(key)}"
        ctx.static(ent, rr.SeriesLines(colors=[color], names=[key]))
        ctx.send(ent, frames, rr.Scalars.columns(scalars=err))
    return bool(series)


# --- the whole recording ------------------------------------------------------------------------
def log_all(rec, scene: Scene, sel: Selection, tb: Timebase, style: LogStyle = LogStyle(),
            users: dict[str, RU.RoadUsers] | None = None) -> LogStats:
    """Log everything ``sel`` selects to ``rec``; returns what was logged. users: the runs'
    road users (``road_users.prepare``) when the caller has them already."""
    first, last, cameras = sel.first, sel.last, sel.cameras
    ctx = LogContext(rec, scene, tb, first, last, style)
    log_static(ctx, cameras)
    mask_rows = video_rows = 0
    # a kind shown on every frame anyway is not reduced: video as an asset, masks as outlines
    reduced = [k for k in sel.cadence.reduced
               if not (k == "video" and style.video_format != "jpeg")
               and not (k == "masks" and style.mask_outlines and not style.mask_fills)]
    notes = [n for k, n in zip(sel.cadence.reduced, sel.cadence.notes()) if k in reduced]
    video_frames = {}
    for cam in cameras:
        if style.video:
            every = sel.cadence.video if style.video_format == "jpeg" else 1
            got = log_video(ctx, cam, every)
            video_frames[cam] = got
            want = len(range(first, last + 1, every))
            if scene.video_path(cam) is not None and len(got) < want:
                notes.append(f"video of {cam} ({scene.video_path(cam)}) has only {len(got)} of "
                             f"the {want} frames asked for; the rest is shown without video")
            video_rows += len(got)
        if style.masks:
            mask_rows += log_masks(ctx, cam, sel.cadence.masks)
    gt = None
    if style.gt and scene.gt_path.exists():
        gt = read_poses(scene.gt_path).in_frames((first, last))
        gsz = C.sizes_of(gt, scene)
        log_gt_boxes(ctx, gt, gsz)
        for cam in cameras:
            log_projected(ctx, f"{L.cam_path(cam)}/gt", scene.cameras[cam], gt, gsz,
                          color=L.GT_COLOR)
    metrics = False
    if style.masks:
        by_id = {c for run in sel.runs for c in association_cameras(run, cameras)}
        log_masks_by_id(rec, scene, tb, [c for c in cameras if c in by_id], first, last,
                        sel.cadence.masks)
    tracks, series = {}, {}
    users = users if users is not None else RU.prepare(scene, sel, gt)
    for run in sel.runs:
        look = L.run_look(run.meta)
        poses = run.poses.in_frames((first, last))
        sz = C.sizes_of(poses, scene)
        tracks[run.name] = RU.log_road_users(ctx, run.name, users[run.name], look,
                                             source=str(run.meta.get("method") or "run"),
                                             trail=style.trail)
        series[run.name] = RU.series_present(users[run.name])
        run_cams = [c for c in cameras if c in (run.cameras or cameras)]
        for cam in run_cams:
            log_projected(ctx, f"{L.cam_path(cam)}/poses/{L.entity_part(run.name)}",
                          scene.cameras[cam], poses, sz, look=look)
        log_views(ctx, run, run_cams)
        log_association(rec, run, tb, run_cams, first, last)
        if gt is not None:
            metrics |= log_errors(ctx, run, gt)
    return LogStats(last - first + 1, mask_rows, video_rows, metrics, tuple(notes), video_frames,
                    tracks, series)
