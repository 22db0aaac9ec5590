"""Log a scene and its runs to a Rerun recording stream (the layout of ``s2p_review.layout``),
one function per entity family, column-wise: every temporal entity is sent with
``rr.send_columns`` over whole frame ranges; images (the bulk of the data) go in batches of
frames to bound memory. Where the recording goes (file, viewers) is ``s2p_review.session``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seg2pose.io.poses import PoseTable, read_poses
from seg2pose.io.scene import Scene
from s2p_review import columns as C
from s2p_review.error_discs import log_error_discs
from s2p_review import imagery
from s2p_review import layout as L
from s2p_review.runs import Run
from s2p_review.selection import Selection
from s2p_review.timebase import Timebase

IMAGE_BATCH = 64  # frames per send_columns call for images (bounds memory)


@dataclass(frozen=True)
class LogStyle:
    """How things look. trail: frames of trail behind each road user (<= 1: none);
    image_plane_distance: metres from a camera to its image in the 3D view; jpeg_quality and
    image_scale: how video frames are stored (shrunk to image_scale of the camera's size and
    shown at full size again)."""

    masks: bool = True
    video: bool = True
    gt: bool = True  # ground truth, when the scene has it (off in the annotation app)
    trail: int = L.TRAIL_FRAMES
    image_plane_distance: float = 2.0
    jpeg_quality: int = 75
    image_scale: float = 1.0


@dataclass(frozen=True)
class LogStats:
    """What was logged: frames in the range, mask and video rows, whether errors were plotted,
    and notes for the user (e.g. a video shorter than the range)."""

    frames: int
    mask_rows: int
    video_rows: int
    metrics: bool
    notes: tuple[str, ...] = ()


def _rr():
    import rerun as rr

    return rr


# --- static parts ------------------------------------------------------------------------------
def log_static(rec, scene: Scene, cameras: list[str], style: LogStyle = LogStyle()) -> None:
    """Class colours, the ground (points and eq. (1) surface) and the cameras."""
    rr = _rr()
    rec.log("/", L.annotation_context(scene.classes), static=True)
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    g = scene.ground_points
    rec.log("world/ground/points", rr.Points3D(g, radii=0.08, colors=(150, 150, 150)), static=True)
    extent = float(max(np.ptp(g[:, 0]), np.ptp(g[:, 1])))
    verts, tris = scene.ground.mesh(n=48, margin=max(2.0, 0.15 * extent))
    rec.log("world/ground/mesh", rr.Mesh3D(vertex_positions=verts, triangle_indices=tris,
                                           albedo_factor=(90, 90, 90, 255)), static=True)
    for name in cameras:
        cam = scene.cameras[name]
        p = L.cam_path(name)
        rec.log(p, rr.Transform3D(translation=cam.center, mat3x3=cam.R.T), static=True)
        rec.log(p, rr.Pinhole(image_from_camera=cam.K, resolution=[cam.width, cam.height],
                              camera_xyz=rr.ViewCoordinates.RDF,
                              image_plane_distance=style.image_plane_distance), static=True)


# --- images ------------------------------------------------------------------------------------
def log_masks(rec, scene: Scene, tb: Timebase, cam: str, first: int, last: int, every: int) -> int:
    """SegmentationImage per frame on the cadence (pixel = class id). Returns rows sent."""
    rr = _rr()
    camera = scene.cameras[cam]
    h, w = camera.height, camera.width
    ent = L.cam_path(cam) + "/masks"
    path = scene.masks_path(cam)
    sent = 0
    batch: list = []

    def flush():
        imgs = imagery.paint([t for _, t in batch], [t.class_id for _, t in batch], path)
        rec.send_columns(ent, indexes=tb.rerun_columns([f for f, _ in batch]),
                         columns=rr.SegmentationImage.columns(buffer=imgs.reshape(len(batch), -1)))

    for item in imagery.mask_frames(scene, cam, first, last, every):
        if not sent and not batch:
            rec.log(ent, rr.SegmentationImage.from_fields(
                format=rr.components.ImageFormat(width=w, height=h, channel_datatype="U8"),
                opacity=0.6, draw_order=5.0), static=True)
        batch.append(item)
        if len(batch) == IMAGE_BATCH:
            flush()
            sent += len(batch)
            batch = []
    if batch:
        flush()
        sent += len(batch)
    return sent


def log_video(rec, scene: Scene, tb: Timebase, cam: str, first: int, last: int, every: int,
              style: LogStyle = LogStyle()) -> int:
    """Video frames as JPEG EncodedImage under the camera. Returns frames sent."""
    rr = _rr()
    path = scene.video_path(cam)
    if path is None:
        return 0
    ent = L.cam_path(cam) + "/image"
    camera = scene.cameras[cam]
    width = max(1, int(round(camera.width * style.image_scale)))
    sent = 0
    frames, blobs = [], []

    def flush():
        rec.send_columns(ent, indexes=tb.rerun_columns(frames),
                         columns=rr.EncodedImage.columns(blob=blobs, media_type=["image/jpeg"] * len(blobs)))

    for f, img in imagery.video_frames(scene, cam, first, last, every):
        if not sent and not frames and img.shape[1] > width:  # shown at the camera's size
            h = max(1, int(round(img.shape[0] * width / img.shape[1])))
            rec.log(ent, rr.Transform3D(scale=[img.shape[1] / width, img.shape[0] / h, 1.0]),
                    static=True)
        frames.append(f)
        blobs.append(imagery.encode_jpeg(img, style.jpeg_quality, width))
        if len(frames) == IMAGE_BATCH:
            flush()
            sent += len(frames)
            frames, blobs = [], []
    if frames:
        flush()
        sent += len(frames)
    return sent


# --- road users over frames ----------------------------------------------------------------------
def log_boxes(rec, ent: str, table: PoseTable, sizes: np.ndarray, scene: Scene, tb: Timebase,
              first: int, last: int, color=None, with_labels: bool = True,
              look: str = "model") -> None:
    """Boxes3D over [first, last], one row per frame; class colours unless ``color``, in the
    ``look`` of the run (``layout.RUN_LOOKS``: a model's boxes solid, the baseline's hollow
    and pale). Labels are data, shown on hover and selection, not drawn (crowds overlap)."""
    rr = _rr()
    order = np.argsort(table.frame, kind="stable")
    t, sz = table.take(order), sizes[order]
    fields = C.box_columns(t.xyz, t.heading, sz)
    cols = (np.tile(np.array(color, np.uint8), (len(t), 1)) if color is not None
            else L.run_colors(t.cls, scene.classes, look, solid=True))
    extra = {"labels": L.labels(t.cls, t.track_id)} if with_labels else {}
    rec.log(ent, rr.Boxes3D.from_fields(show_labels=False,
                                        fill_mode="solid" if L.RUN_LOOKS[look]["solid"] and color is None
                                        else "majorwireframe"), static=True)
    rec.send_columns(ent, indexes=tb.rerun_columns(np.arange(first, last + 1)),
                     columns=rr.Boxes3D.columns(**fields, colors=cols, **extra)
                     .partition(C.frame_lengths(t.frame, first, last)))


def log_trails(rec, ent: str, table: PoseTable, scene: Scene, tb: Timebase, first: int,
               last: int, length: int) -> None:
    """Each road user's last ``length`` positions as a line, per frame."""
    rr = _rr()
    t = table.take(np.argsort(table.frame, kind="stable"))
    t = t.take(np.isfinite(t.xyz).all(axis=1))
    pts, offs = C.trail_points(t.track_id, t.frame, t.xyz + [0, 0, 0.05], length)
    strips = C.strips_arrow(pts, offs, rr.components.LineStrip3DBatch)
    rec.log(ent, rr.LineStrips3D.from_fields(radii=0.04), static=True)
    rec.send_columns(ent, indexes=tb.rerun_columns(np.arange(first, last + 1)),
                     columns=rr.LineStrips3D.columns(strips=strips,
                                                     colors=L.class_colors(t.cls, scene.classes))
                     .partition(C.frame_lengths(t.frame, first, last)))


def log_projected(rec, ent: str, camera, table: PoseTable, sizes: np.ndarray, scene: Scene,
                  tb: Timebase, first: int, last: int, color=None, look: str = "model") -> None:
    """The boxes of ``table`` projected into ``camera`` as LineStrips2D, per frame, in the
    ``look`` of the run (a model's lines bold, the baseline's thin and pale)."""
    rr = _rr()
    order = np.argsort(table.frame, kind="stable")
    t, sz = table.take(order), sizes[order]
    segs, idx = C.projected_paths(camera, t.xyz, t.heading, sz)
    lengths = C.frame_lengths(t.frame[idx], first, last)
    # constant look (width, draw order, and the colour of truth) once, statically
    rec.log(ent, rr.LineStrips2D.from_fields(draw_order=2.0, radii=L.RUN_LOOKS[look]["line"],
                                             colors=color if color is not None else None), static=True)
    extra = {} if color is not None else {"colors": L.run_colors(t.cls[idx], scene.classes, look)}
    rec.send_columns(ent, indexes=tb.rerun_columns(np.arange(first, last + 1)),
                     columns=rr.LineStrips2D.columns(
                         strips=C.segments_arrow(segs, rr.components.LineStrip2DBatch), **extra)
                     .partition(lengths))


def log_views(rec, run: Run, scene: Scene, tb: Timebase, cameras: list[str], first: int,
              last: int) -> None:
    """Per view: mask centres (2D), normal positions (3D) and residual arrows."""
    rr = _rr()
    v = run.views
    if v is None or len(v) == 0:
        return
    v = v.take((v.frame >= first) & (v.frame <= last))
    idx_t = tb.rerun_columns(np.arange(first, last + 1))
    for cam in cameras:
        sel = np.flatnonzero(v.camera == cam)
        if not len(sel):
            continue
        vv = v.take(sel[np.argsort(v.frame[sel], kind="stable")])
        lengths = C.frame_lengths(vv.frame, first, last)
        cols = L.class_colors(vv.cls, scene.classes)
        ent2 = f"{L.cam_path(cam)}/normal/{run.name}"
        rec.send_columns(ent2, indexes=idx_t,
                         columns=rr.Points2D.columns(positions=vv.uv, colors=cols,
                                                     radii=[2.5] * len(vv)).partition(lengths))
        rec.log(ent2, rr.Points2D.from_fields(draw_order=6.0), static=True)
        base = f"world/estimates/{run.name}/{L.safe_name(cam)}"
        # a ray that missed the ground has no normal position: no 3D point, no arrow
        ok = np.isfinite(vv.normal).all(axis=1) & np.isfinite(vv.residual).all(axis=1)
        v3 = vv.take(ok)
        len3 = C.frame_lengths(v3.frame, first, last)
        rec.log(base, rr.Points3D.from_fields(radii=0.12), static=True)
        rec.send_columns(base, indexes=idx_t,
                         columns=rr.Points3D.columns(positions=v3.normal, colors=cols[ok]).partition(len3))
        if np.any(v3.residual != 0):
            vec = np.c_[v3.residual, np.zeros(len(v3))]
            rec.log(base + "/residuals", rr.Arrows3D.from_fields(radii=0.03), static=True)
            rec.send_columns(base + "/residuals", indexes=idx_t,
                             columns=rr.Arrows3D.columns(origins=v3.normal, vectors=vec, colors=cols[ok])
                             .partition(len3))


def error_series(run: Run, gt: PoseTable, scene: Scene, first: int, last: int
                 ) -> dict[str, tuple[np.ndarray, np.ndarray, tuple[int, int, int]]]:
    """name -> (frames (F,), error (F,) metres, colour) of the per-frame mean error ("mean")
    and of each class (seg2pose.evaluate.per_frame_errors); frames without a value left out."""
    from seg2pose.evaluate import per_frame_errors

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


def log_errors(rec, run: Run, gt: PoseTable, scene: Scene, tb: Timebase, first: int,
               last: int) -> bool:
    """The run's error series (``error_series``) under metrics/error/<run>: one plot per run.
    Returns whether anything was plotted."""
    rr = _rr()
    series = error_series(run, gt, scene, first, last)
    for key, (frames, err, color) in series.items():
        ent = f"metrics/error/{run.name}/{L.safe_name(key)}"
        rec.log(ent, rr.SeriesLines(colors=[color], names=[key]), static=True)
        rec.send_columns(ent, indexes=tb.rerun_columns(frames),
                         columns=rr.Scalars.columns(scalars=err))
    return bool(series)


# --- the whole recording ------------------------------------------------------------------------
def log_all(rec, scene: Scene, sel: Selection, tb: Timebase, style: LogStyle = LogStyle()
            ) -> LogStats:
    """Log everything ``sel`` selects to ``rec``; returns what was logged."""
    first, last, cameras = sel.first, sel.last, sel.cameras
    log_static(rec, scene, cameras, style)
    mask_rows = video_rows = 0
    notes = list(sel.cadence.notes())
    for cam in cameras:
        if style.video:
            n = log_video(rec, scene, tb, cam, first, last, sel.cadence.video, style)
            want = len(range(first, last + 1, sel.cadence.video))
            if scene.video_path(cam) is not None and n < want:
                notes.append(f"video of {cam} ({scene.video_path(cam)}) has only {n} of the "
                             f"{want} frames asked for; the rest is shown without video")
            video_rows += n
        if style.masks:
            mask_rows += log_masks(rec, scene, tb, cam, first, last, sel.cadence.masks)
    gt = None
    if style.gt and scene.gt_path.exists():
        gt = read_poses(scene.gt_path).in_frames((first, last))
        gsz = C.sizes_of(gt, scene)
        log_boxes(rec, "world/gt", gt, gsz, scene, tb, first, last, color=L.GT_COLOR,
                  with_labels=False)
        for cam in cameras:
            log_projected(rec, f"{L.cam_path(cam)}/gt", scene.cameras[cam], gt, gsz, scene, tb,
                          first, last, color=L.GT_COLOR)
    metrics = False
    for run in sel.runs:
        look = L.run_look(run.meta)
        poses = run.poses.in_frames((first, last))
        sz = C.sizes_of(poses, scene)
        log_boxes(rec, f"world/road_users/{run.name}", poses, sz, scene, tb, first, last, look=look)
        if style.trail > 1:
            log_trails(rec, f"world/road_users/{run.name}/trails", poses, scene, tb, first, last,
                       style.trail)
        log_error_discs(rec, f"world/road_users/{run.name}/r90", poses, tb, first, last)
        run_cams = [c for c in cameras if c in (run.cameras or cameras)]
        for cam in run_cams:
            log_projected(rec, f"{L.cam_path(cam)}/poses/{run.name}", scene.cameras[cam], poses,
                          sz, scene, tb, first, last, look=look)
        log_views(rec, run, scene, tb, run_cams, first, last)
        if gt is not None:
            metrics |= log_errors(rec, run, gt, scene, tb, first, last)
    return LogStats(last - first + 1, mask_rows, video_rows, metrics, tuple(notes))
