"""Log a scene and its runs to a Rerun recording stream (the layout of ``s2p_review.layout``),
one function per entity family, column-wise: every temporal entity is sent with
``rr.send_columns`` over whole frame ranges; images (the bulk of the data) go in batches of
frames to bound memory. Where the recording goes (file, viewers) is ``s2p_review.session``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from s2p_review import columns as C
from s2p_review import imagery
from s2p_review import layout as L
from s2p_review.association import association_cameras, log_association, log_masks_by_id
from s2p_review.error_discs import log_error_discs
from s2p_review.runs import Run
from s2p_review.selection import Selection
from s2p_review.timebase import Timebase
from seg2pose.io.poses import PoseTable, read_poses
from seg2pose.io.scene import Scene

IMAGE_BATCH = 64  # frames per send_columns call for images (bounds memory)
VIDEO_FORMATS = ("asset", "jpeg")


@dataclass(frozen=True)
class LogStyle:
    """How things look. trail: frames of trail behind each road user (<= 1: none);
    image_plane_distance: metres from a camera to its image in the 3D view; video_format:
    "asset" (every frame, one H.264 video per camera decoded by the viewer: video_asset.py) or
    "jpeg" (JPEG images on the video cadence); jpeg_quality and image_scale: how video frames
    are stored (shrunk to image_scale of the camera's size and shown at full size again);
    mask_outlines: every frame's masks as outlines; mask_fills: the filled masks on the mask
    cadence, blank on the frames between (off in the annotation app: a 1280x720 fill is 0.9 MB
    a frame, outlines a few kB)."""

    masks: bool = True
    video: bool = True
    gt: bool = True  # ground truth, when the scene has it (off in the annotation app)
    trail: int = L.TRAIL_FRAMES
    image_plane_distance: float = 2.0
    video_format: str = "asset"
    jpeg_quality: int = 75
    image_scale: float = 1.0
    mask_outlines: bool = True
    mask_fills: bool = True  # the filled masks on the cadence (the annotation app: outlines only)


@dataclass(frozen=True)
class LogStats:
    """What was logged: frames in the range, mask and video rows, whether errors were plotted,
    notes for the user (e.g. a video shorter than the range), and per camera the frames that
    have video (``video_frames``)."""

    frames: int
    mask_rows: int
    video_rows: int
    metrics: bool
    notes: tuple[str, ...] = ()
    video_frames: dict = field(default_factory=dict)


@dataclass(frozen=True)
class LogContext:
    """Where and what every ``log_*`` function logs: ``rec`` (a RecordingStream or anything
    with ``log``/``send_columns``), the scene, its timebase ``tb``, frames first..last, style."""

    rec: object
    scene: Scene
    tb: Timebase
    first: int
    last: int
    style: LogStyle = LogStyle()

    @property
    def frames(self) -> np.ndarray:
        return np.arange(self.first, self.last + 1)

    def static(self, ent: str, archetype) -> None:
        self.rec.log(ent, archetype, static=True)

    def send(self, ent: str, frames, columns) -> None:
        """Rows of ``columns`` at scene ``frames``."""
        self.rec.send_columns(ent, indexes=self.tb.rerun_columns(frames), columns=columns)

    def send_range(self, ent: str, columns) -> None:
        """One (partitioned) row per frame of the range."""
        self.send(ent, self.frames, columns)


def _rr():
    import rerun as rr

    return rr


def _batched(items, send, size: int = IMAGE_BATCH) -> int:
    """Call ``send(batch)`` on lists of up to ``size`` items of an iterator (bounds memory);
    returns how many items were sent."""
    n, batch = 0, []
    for item in items:
        batch.append(item)
        if len(batch) == size:
            send(batch)
            n, batch = n + len(batch), []
    if batch:
        send(batch)
        n += len(batch)
    return n


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


# --- images ------------------------------------------------------------------------------------
def _clear_frames(ctx: LogContext, ent: str, frames) -> None:
    """Empty ``ent`` at ``frames`` (nothing to show there: no stale image from before)."""
    frames = np.asarray(sorted(frames), np.int64)
    if len(frames):
        ctx.send(ent, frames, _rr().Clear.columns(is_recursive=np.zeros(len(frames), bool)))


def log_masks(ctx: LogContext, cam: str, every: int) -> int:
    """SegmentationImage per frame on the cadence (pixel = class id), blank between; with
    ``style.mask_outlines`` every frame's masks as outlines too. Returns filled rows sent."""
    rr = _rr()
    scene = ctx.scene
    camera = scene.cameras[cam]
    ent = L.cam_path(cam) + "/masks"
    path = scene.masks_path(cam)
    if not path.exists():
        return 0
    sent = 0
    if ctx.style.mask_fills:
        ctx.static(ent, rr.SegmentationImage.from_fields(
            format=rr.components.ImageFormat(width=camera.width, height=camera.height,
                                             channel_datatype="U8"), opacity=0.6, draw_order=5.0))

        def send(batch):
            imgs = imagery.paint([t for _, t in batch], [t.class_id for _, t in batch], path)
            ctx.send(ent, [f for f, _ in batch],
                     rr.SegmentationImage.columns(buffer=imgs.reshape(len(batch), -1)))

        sent = _batched(imagery.mask_frames(scene, cam, ctx.first, ctx.last, every), send)
        if every > 1:
            _clear_frames(ctx, ent, [f for f in ctx.frames if (f - ctx.first) % every])
    if ctx.style.mask_outlines:
        log_mask_outlines(ctx, cam)
    return sent


def log_mask_outlines(ctx: LogContext, cam: str) -> int:
    """Every frame's masks as class-coloured outlines (LineStrips2D, imagery.outlines) under
    the camera: a few bytes per mask, so every frame fits. Computed once per masks file and
    range, then cached (``outline_table``). Returns frames sent."""
    rr = _rr()
    ent = L.cam_path(cam) + "/masks/outlines"
    ctx.static(ent, rr.LineStrips2D.from_fields(draw_order=4.0, radii=1.0))
    frames, per_frame, lengths, points, colors = outline_table(ctx.scene, cam, ctx.first, ctx.last)
    strips = np.split(points, np.cumsum(lengths)[:-1]) if len(lengths) else []
    for a in range(0, len(frames), IMAGE_BATCH):
        fr = frames[a:a + IMAGE_BATCH]
        s0, s1 = int(per_frame[:a].sum()), int(per_frame[:a + len(fr)].sum())
        ctx.send(ent, fr, rr.LineStrips2D.columns(strips=strips[s0:s1], colors=colors[s0:s1])
                 .partition(per_frame[a:a + len(fr)]))
    return len(frames)


def outline_table(scene: Scene, cam: str, first: int, last: int):
    """(frames (F,), strips per frame (F,), points per strip (S,), points (P, 2) float32,
    colours (S, 3) uint8) of the mask outlines of frames first..last, from the cache
    (video_asset.cache_dir) or computed and cached."""
    import hashlib
    import json

    from s2p_review.video_asset import cache_dir

    path = scene.masks_path(cam)
    st = path.stat()
    key = hashlib.sha256(json.dumps([str(path.resolve()), st.st_size, st.st_mtime_ns, first,
                                     last, imagery.OUTLINE_TOLERANCE, 1]).encode()).hexdigest()[:20]
    cached = cache_dir() / f"outlines-{cam}-{key}.npz"
    try:
        with np.load(cached) as z:
            return z["frames"], z["per_frame"], z["lengths"], z["points"], z["colors"]
    except (OSError, ValueError, KeyError):
        pass
    by_id = scene.class_by_id()
    frames, per_frame, lengths, points, colors = [], [], [], [], []
    for f, t in imagery.mask_frames(scene, cam, first, last, 1):
        polys, owner = imagery.outlines(t, path)
        names = np.array([by_id[int(c)].name if int(c) in by_id else "" for c in t.class_id])
        frames.append(f)
        per_frame.append(len(polys))
        lengths += [len(q) for q in polys]
        points += polys
        if len(owner):
            colors.append(L.class_colors(names, scene.classes)[owner])
    out = (np.asarray(frames, np.int64), np.asarray(per_frame, np.int64),
           np.asarray(lengths, np.int64),
           np.concatenate(points).astype(np.float32) if points else np.zeros((0, 2), np.float32),
           np.concatenate(colors).astype(np.uint8) if colors else np.zeros((0, 3), np.uint8))
    try:
        cached.parent.mkdir(parents=True, exist_ok=True)
        tmp = cached.with_name(cached.name + ".tmp.npz")
        np.savez(tmp, frames=out[0], per_frame=out[1], lengths=out[2], points=out[3],
                 colors=out[4])
        tmp.replace(cached)
    except OSError:
        pass  # a cache we cannot write only costs time
    return out


def log_video(ctx: LogContext, cam: str, every: int) -> np.ndarray:
    """The camera's video under the camera, as ``style.video_format`` says; frames without
    video are left blank. Returns the scene frames that have video."""
    if ctx.scene.video_path(cam) is None:
        return np.zeros(0, np.int64)
    if ctx.style.video_format == "asset":
        return _log_video_asset(ctx, cam)
    return _log_video_jpeg(ctx, cam, every)


def _log_video_asset(ctx: LogContext, cam: str) -> np.ndarray:
    from s2p_review.video_asset import video_asset

    rr = _rr()
    ent = L.cam_path(cam) + "/image"
    asset = video_asset(ctx.scene, cam, ctx.first, ctx.last, ctx.style.image_scale)
    if asset is None:
        return np.zeros(0, np.int64)
    camera = ctx.scene.cameras[cam]
    if (asset.width, asset.height) != (camera.width, camera.height):  # shown at the camera's size
        ctx.static(ent, rr.Transform3D(scale=[camera.width / asset.width,
                                              camera.height / asset.height, 1.0]))
    ctx.static(ent, rr.AssetVideo(contents=asset.path.read_bytes(), media_type="video/mp4"))
    ctx.send(ent, asset.frames, rr.VideoFrameReference.columns_nanos(asset.timestamps_ns))
    _clear_frames(ctx, ent, sorted(set(ctx.frames.tolist()) - set(asset.frames.tolist())))
    return asset.frames


def _log_video_jpeg(ctx: LogContext, cam: str, every: int) -> np.ndarray:
    rr = _rr()
    ent = L.cam_path(cam) + "/image"
    camera = ctx.scene.cameras[cam]
    width = max(1, int(round(camera.width * ctx.style.image_scale)))
    if width < camera.width:  # stored small, shown at the camera's size
        h = max(1, int(round(camera.height * width / camera.width)))
        ctx.static(ent, rr.Transform3D(scale=[camera.width / width, camera.height / h, 1.0]))
    done: list[int] = []

    def send(batch):
        frames = [f for f, _ in batch]
        blobs = [imagery.encode_jpeg(img, ctx.style.jpeg_quality, width) for _, img in batch]
        ctx.send(ent, frames, rr.EncodedImage.columns(blob=blobs,
                                                      media_type=["image/jpeg"] * len(blobs)))
        done.extend(frames)

    _batched(imagery.video_frames(ctx.scene, cam, ctx.first, ctx.last, every), send)
    return np.asarray(done, np.int64)


# --- road users over frames ----------------------------------------------------------------------
def log_boxes(ctx: LogContext, ent: str, table: PoseTable, sizes: np.ndarray, color=None,
              with_labels: bool = True, look: str = "model") -> None:
    """Boxes3D over the range, one row per frame; class colours unless ``color``, in the
    ``look`` of the run (``layout.RUN_LOOKS``: a model's boxes solid, the baseline's hollow
    and pale). Labels are data, shown on hover and selection, not drawn (crowds overlap)."""
    rr = _rr()
    order = np.argsort(table.frame, kind="stable")
    t, sz = table.take(order), sizes[order]
    fields = C.box_columns(t.xyz, t.heading, sz)
    cols = (np.tile(np.array(color, np.uint8), (len(t), 1)) if color is not None
            else L.run_colors(t.cls, ctx.scene.classes, look, solid=True))
    extra = {"labels": L.labels(t.cls, t.track_id)} if with_labels else {}
    ctx.static(ent, rr.Boxes3D.from_fields(show_labels=False,
                                           fill_mode="solid" if L.RUN_LOOKS[look]["solid"] and color is None
                                           else "majorwireframe"))
    ctx.send_range(ent, rr.Boxes3D.columns(**fields, colors=cols, **extra)
                   .partition(C.frame_lengths(t.frame, ctx.first, ctx.last)))


def log_trails(ctx: LogContext, ent: str, table: PoseTable, length: int) -> None:
    """Each road user's last ``length`` positions as a line, per frame."""
    rr = _rr()
    t = table.take(np.argsort(table.frame, kind="stable"))
    t = t.take(np.isfinite(t.xyz).all(axis=1))
    pts, offs = C.trail_points(t.track_id, t.frame, t.xyz + [0, 0, 0.05], length)
    strips = C.strips_arrow(pts, offs, rr.components.LineStrip3DBatch)
    ctx.static(ent, rr.LineStrips3D.from_fields(radii=0.04))
    ctx.send_range(ent, rr.LineStrips3D.columns(strips=strips,
                                                colors=L.class_colors(t.cls, ctx.scene.classes))
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
        ent2 = f"{L.cam_path(cam)}/normal/{run.name}"
        ctx.send_range(ent2, rr.Points2D.columns(positions=vv.uv, colors=cols,
                                                 radii=[2.5] * len(vv)).partition(lengths))
        ctx.static(ent2, rr.Points2D.from_fields(draw_order=6.0))
        base = f"world/estimates/{run.name}/{L.safe_name(cam)}"
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
        ent = f"metrics/error/{run.name}/{L.safe_name(key)}"
        ctx.static(ent, rr.SeriesLines(colors=[color], names=[key]))
        ctx.send(ent, frames, rr.Scalars.columns(scalars=err))
    return bool(series)


# --- the whole recording ------------------------------------------------------------------------
def log_all(rec, scene: Scene, sel: Selection, tb: Timebase, style: LogStyle = LogStyle()
            ) -> LogStats:
    """Log everything ``sel`` selects to ``rec``; returns what was logged."""
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
        log_boxes(ctx, "world/gt", gt, gsz, color=L.GT_COLOR, with_labels=False)
        for cam in cameras:
            log_projected(ctx, f"{L.cam_path(cam)}/gt", scene.cameras[cam], gt, gsz,
                          color=L.GT_COLOR)
    metrics = False
    if style.masks:
        by_id = {c for run in sel.runs for c in association_cameras(run, cameras)}
        log_masks_by_id(rec, scene, tb, [c for c in cameras if c in by_id], first, last,
                        sel.cadence.masks)
    for run in sel.runs:
        look = L.run_look(run.meta)
        poses = run.poses.in_frames((first, last))
        sz = C.sizes_of(poses, scene)
        log_boxes(ctx, f"world/road_users/{run.name}", poses, sz, look=look)
        if style.trail > 1:
            log_trails(ctx, f"world/road_users/{run.name}/trails", poses, style.trail)
        log_error_discs(ctx, f"world/road_users/{run.name}/r90", poses)
        run_cams = [c for c in cameras if c in (run.cameras or cameras)]
        for cam in run_cams:
            log_projected(ctx, f"{L.cam_path(cam)}/poses/{run.name}", scene.cameras[cam], poses,
                          sz, look=look)
        log_views(ctx, run, run_cams)
        log_association(rec, run, tb, run_cams, first, last)
        if gt is not None:
            metrics |= log_errors(ctx, run, gt)
    return LogStats(last - first + 1, mask_rows, video_rows, metrics, tuple(notes), video_frames)
