"""Log a scene and its runs to Rerun (the layout of ``s2p_review.layout``), column-wise.

``record`` is the public entry point: it writes an .rrd (atomically), streams to a spawned or
running viewer, or both. Every temporal entity is sent with ``rr.send_columns`` over whole frame
ranges; masks (the bulk of the data) go in batches of frames to bound memory.
"""

from __future__ import annotations

import uuid
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from seg2pose.errors import InputError, S2PError
from seg2pose.io.atomic import atomic_path, check_writable
from seg2pose.io.mots import iter_mots
from seg2pose.io.poses import PoseTable, read_poses
from seg2pose.io.scene import Scene
from s2p_review import columns as C
from s2p_review import layout as L
from s2p_review.runs import Run, load_run, scene_last_frame

MASK_BATCH = 64  # frames per send_columns call for images (bounds memory)


IMAGE_BUDGET_PX = 160e6  # pixels of masks (and of video) logged by default: a few MB of .rrd


def auto_every(n_frames: int, cams: list[str], scene: Scene, budget_px: float = IMAGE_BUDGET_PX) -> int:
    """The smallest cadence k that keeps n_frames / k images per camera within ``budget_px``."""
    px = sum(scene.cameras[c].width * scene.cameras[c].height for c in cams) * n_frames
    return max(1, int(np.ceil(px / budget_px)))


@dataclass
class RecordOptions:
    """What to log. mask_every / video_every: log masks / video frames every k-th frame only
    (a viewer shows the latest one, so a smaller file costs some lag); None = automatic: every
    frame while the images stay within IMAGE_BUDGET_PX pixels, else the smallest cadence that
    does. cameras: the cameras to show (None = the runs' cameras, or all); trail: frames of
    trail behind each road user. ``notes`` collects what was decided (for the CLI to print)."""

    mask_every: int | None = None
    video_every: int | None = None
    cameras: list[str] | None = None
    masks: bool = True
    video: bool = True
    trail: int = L.TRAIL_FRAMES
    image_plane_distance: float = 2.0
    notes: list = field(default_factory=list)
    resolved: tuple[int, int] = (1, 1)  # (mask_every, video_every) used by the last recording

    def resolve(self, scene: Scene, first: int, last: int, cams: list[str]) -> tuple[int, int]:
        """(mask_every, video_every) for this recording; automatic ones are noted."""
        n = last - first + 1
        out = []
        has_video = any(scene.video_path(c) is not None for c in cams)
        for what, k in (("masks", self.mask_every), ("video", self.video_every)):
            if k is None:
                k = auto_every(n, cams, scene)
                wanted = self.masks if what == "masks" else (self.video and has_video)
                if k > 1 and wanted:
                    self.notes.append(f"{what}: one frame in {k} (keeps the file small; "
                                      f"--{what.rstrip('s')}-every 1 for all)")
            out.append(max(1, int(k)))
        return out[0], out[1]


def _rr():
    import rerun as rr

    return rr


def _times(frames: np.ndarray, fps: float):
    rr = _rr()
    frames = np.asarray(frames, np.int64)
    return [rr.TimeColumn(L.TIMELINE, sequence=frames),
            rr.TimeColumn(L.TIME, duration=frames / float(fps))]


def _with_size(table: PoseTable, scene: Scene) -> np.ndarray:
    if table.size is not None:
        return np.nan_to_num(table.size, nan=1.0)
    sizes = scene.class_sizes()
    return np.array([sizes.get(c, (1.0, 1.0, 1.0)) for c in table.cls], float).reshape(-1, 3)


# --- static parts ------------------------------------------------------------------------------
def log_static(rec, scene: Scene, cameras: list[str], opts: RecordOptions) -> None:
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
                              image_plane_distance=opts.image_plane_distance), static=True)


# --- scene data over frames -----------------------------------------------------------------------
def log_masks(rec, scene: Scene, cam: str, first: int, last: int, every: int) -> int:
    """SegmentationImage per frame (pixel = class id). Returns the number of rows sent."""
    rr = _rr()
    path = scene.masks_path(cam)
    if not path.exists():
        return 0
    camera = scene.cameras[cam]
    h, w = camera.height, camera.width
    ent = L.cam_path(cam) + "/masks"
    rec.log(ent, rr.SegmentationImage.from_fields(
        format=rr.components.ImageFormat(width=w, height=h, channel_datatype="U8"),
        opacity=0.6, draw_order=5.0), static=True)
    frames_all = np.arange(first, last + 1, every, dtype=np.int64)
    # runs are checked per batch in paint_masks (one decode instead of one per frame)
    stream = iter(iter_mots(path, known_classes=[c.id for c in scene.classes],
                            frame_range=(first, last), check_rles=False))
    pending = next(stream, None)
    for lo in range(0, len(frames_all), MASK_BATCH):
        fr = frames_all[lo:lo + MASK_BATCH]
        rles: list[bytes] = []
        where: list[tuple[int, int]] = []  # (frame, track id) of each mask, for messages
        vals, slots = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
        while pending is not None and pending[0] <= fr[-1]:
            f, t = pending
            if t.height != h or t.width != w:
                raise InputError(f"masks are {t.width}x{t.height} but camera {cam} is {w}x{h}",
                                 file=path)
            if (f - first) % every == 0:
                rles += t.rles
                where += [(f, int(k)) for k in t.track_id]
                vals.append(t.class_id)
                slots.append(np.full(len(t), int(np.searchsorted(fr, f))))
            pending = next(stream, None)
        try:
            imgs = C.paint_masks(rles, np.concatenate(vals), np.concatenate(slots), h, w, len(fr),
                                 check=True)
        except C.BadMask as e:
            f, k = where[e.index]
            raise InputError(f"frame {f}, track {k}: {e}", file=path) from None
        except InputError as e:
            raise InputError(f"frames {fr[0]}..{fr[-1]}: {e}", file=path) from None
        rec.send_columns(ent, indexes=_times(fr, scene.fps),
                         columns=rr.SegmentationImage.columns(buffer=imgs.reshape(len(fr), -1)))
    return len(frames_all)


def _video_frames(path: Path, first: int, last: int, every: int):
    """(frame, BGR image) of a video file or image folder, frames first..last, every k-th."""
    import cv2

    if path.is_dir():
        files = sorted(p for p in path.iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg"))
        for f in range(first, min(last, len(files) - 1) + 1, every):
            img = cv2.imread(str(files[f]))
            if img is None:
                raise InputError("cannot read image", file=files[f])
            yield f, img
        return
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise InputError("cannot open video (unreadable or unsupported codec)", file=path)
    try:
        cap.set(cv2.CAP_PROP_POS_FRAMES, first)
        for f in range(first, last + 1):
            ok, img = cap.read()
            if not ok:
                break
            if (f - first) % every == 0:
                yield f, img
    finally:
        cap.release()


def log_video(rec, scene: Scene, cam: str, first: int, last: int, every: int) -> int:
    """Video frames as JPEG EncodedImage under the camera. Returns frames sent."""
    import cv2

    rr = _rr()
    path = scene.video_path(cam)
    if path is None:
        return 0
    ent = L.cam_path(cam) + "/image"
    sent = 0
    frames, blobs = [], []

    def flush():
        rec.send_columns(ent, indexes=_times(np.array(frames), scene.fps),
                         columns=rr.EncodedImage.columns(blob=blobs, media_type=["image/jpeg"] * len(blobs)))

    for f, img in _video_frames(path, first, last, every):
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 75])
        frames.append(f)
        blobs.append(buf.tobytes())
        if len(frames) == MASK_BATCH:
            flush()
            sent += len(frames)
            frames, blobs = [], []
    if frames:
        flush()
        sent += len(frames)
    return sent


def log_boxes(rec, ent: str, table: PoseTable, sizes: np.ndarray, scene: Scene, first: int,
              last: int, color=None, with_labels: bool = True) -> None:
    """Boxes3D over [first, last], one row per frame; class colours unless ``color``."""
    rr = _rr()
    order = np.argsort(table.frame, kind="stable")
    t, sz = table.take(order), sizes[order]
    fields = C.box_columns(t.xyz, t.heading, sz)
    cols = (np.tile(np.array(color, np.uint8), (len(t), 1)) if color is not None
            else L.class_colors(t.cls, scene.classes))
    extra = {"labels": L.labels(t.cls, t.track_id)} if with_labels else {}
    frames = np.arange(first, last + 1)
    rec.send_columns(ent, indexes=_times(frames, scene.fps),
                     columns=rr.Boxes3D.columns(**fields, colors=cols, **extra)
                     .partition(C.frame_lengths(t.frame, first, last)))


def log_trails(rec, ent: str, table: PoseTable, scene: Scene, first: int, last: int,
               length: int) -> None:
    rr = _rr()
    t = table.take(np.argsort(table.frame, kind="stable"))
    ok = np.isfinite(t.xyz).all(axis=1)
    t = t.take(ok)
    pts, offs = C.trail_points(t.track_id, t.frame, t.xyz + [0, 0, 0.05], length)
    strips = C.strips_arrow(pts, offs, rr.components.LineStrip3DBatch)
    rec.log(ent, rr.LineStrips3D.from_fields(radii=0.04), static=True)
    rec.send_columns(ent, indexes=_times(np.arange(first, last + 1), scene.fps),
                     columns=rr.LineStrips3D.columns(strips=strips,
                                                     colors=L.class_colors(t.cls, scene.classes))
                     .partition(C.frame_lengths(t.frame, first, last)))


def log_projected(rec, ent: str, camera, table: PoseTable, sizes: np.ndarray, scene: Scene,
                  first: int, last: int, color=None) -> None:
    """The boxes of ``table`` projected into ``camera`` as LineStrips2D segments."""
    rr = _rr()
    order = np.argsort(table.frame, kind="stable")
    t, sz = table.take(order), sizes[order]
    segs, idx = C.projected_paths(camera, t.xyz, t.heading, sz)
    lengths = C.frame_lengths(t.frame[idx], first, last)
    # constant look (width, draw order, and the colour of truth) once, statically
    rec.log(ent, rr.LineStrips2D.from_fields(draw_order=2.0, radii=0.75,
                                             colors=color if color is not None else None), static=True)
    extra = {} if color is not None else {
        "colors": L.class_colors(t.cls[idx], scene.classes)}
    rec.send_columns(ent, indexes=_times(np.arange(first, last + 1), scene.fps),
                     columns=rr.LineStrips2D.columns(
                         strips=C.segments_arrow(segs, rr.components.LineStrip2DBatch), **extra)
                     .partition(lengths))


def log_views(rec, run: Run, scene: Scene, cameras: list[str], first: int, last: int) -> None:
    """Per view: mask centres (2D), normal positions (3D) and residual arrows."""
    rr = _rr()
    v = run.views
    if v is None or len(v) == 0:
        return
    frames = np.arange(first, last + 1)
    idx_t = _times(frames, scene.fps)
    for cam in cameras:
        sel = np.flatnonzero(v.camera == cam)
        if not len(sel):
            continue
        vv = v.take(sel[np.argsort(v.frame[sel], kind="stable")])
        lengths = C.frame_lengths(vv.frame, first, last)
        cols = L.class_colors(vv.cls, scene.classes)
        rec.send_columns(f"{L.cam_path(cam)}/normal/{run.name}", indexes=idx_t,
                         columns=rr.Points2D.columns(positions=vv.uv, colors=cols,
                                                     radii=[2.5] * len(vv))
                         .partition(lengths))
        rec.log(f"{L.cam_path(cam)}/normal/{run.name}", rr.Points2D.from_fields(draw_order=6.0),
                static=True)
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


def log_errors(rec, run: Run, gt: PoseTable, scene: Scene, first: int, last: int,
               shade: float = 1.0) -> bool:
    """Per-frame mean error and per-class errors (metres) from seg2pose.evaluate; ``shade``
    (0..1] darkens the run's line colours so that runs compared in one plot stay apart."""
    rr = _rr()
    try:
        from seg2pose.evaluate import per_frame_errors
    except ImportError:  # evaluation not available in this build: no plots
        return False
    frames, mean, per_class = per_frame_errors(run.poses.in_frames((first, last)),
                                               gt.in_frames((first, last)))
    if not len(frames):
        return False
    series = {"mean": (mean, (255, 255, 255))}
    by_name = {c.name: c for c in scene.classes}
    for name, err in per_class.items():
        cid = by_name[name].id if name in by_name else 0
        series[name] = (err, L.class_color(name, cid))
    for key, (err, color) in series.items():
        color = tuple(int(round(c * shade)) for c in color)
        ent = f"metrics/error/{run.name}/{L.safe_name(key)}"
        ok = np.isfinite(err)
        if not ok.any():
            continue
        rec.log(ent, rr.SeriesLines(colors=[color], names=[f"{run.name} {key}"]), static=True)
        rec.send_columns(ent, indexes=_times(np.asarray(frames)[ok], scene.fps),
                         columns=rr.Scalars.columns(scalars=np.asarray(err, float)[ok]))
    return True


# --- the whole recording ------------------------------------------------------------------------
def resolve_frames(scene: Scene, runs: list[Run], frames: tuple[int, int] | None
                   ) -> tuple[int, int]:
    """The frame range to show: ``frames`` when given, else the runs' frames, else the scene's."""
    last_scene = scene_last_frame(scene)
    if frames is not None:
        a, b = int(frames[0]), int(frames[1])
        if a < 0 or b < a:
            raise InputError(f"bad frame range {a}:{b}; expected A:B with 0 <= A <= B", field="--frames")
        if last_scene is not None and a > last_scene:
            raise InputError(f"frame range {a}:{b} starts beyond the scene's last frame {last_scene}",
                             field="--frames")
        return a, b if last_scene is None else min(b, last_scene)
    ranges = [r.frame_range for r in runs if r.frame_range is not None]
    if ranges:
        return min(a for a, _ in ranges), max(b for _, b in ranges)
    if last_scene is None:
        raise InputError("the scene has no masks, ground truth or splits, and no run was given: "
                         "nothing to show over time", file=scene.root)
    return 0, last_scene


def log_all(rec, scene: Scene, runs: list[Run], first: int, last: int, cameras: list[str],
            opts: RecordOptions) -> dict:
    """Log everything to ``rec``; returns counts for the caller's summary."""
    stats = {"frames": last - first + 1, "mask_rows": 0, "video_rows": 0, "runs": [r.name for r in runs]}
    log_static(rec, scene, cameras, opts)
    mask_every, video_every = opts.resolve(scene, first, last, cameras)
    opts.resolved = (mask_every, video_every)
    for cam in cameras:
        if opts.video:
            n = log_video(rec, scene, cam, first, last, video_every)
            want = len(range(first, last + 1, video_every))
            if scene.video_path(cam) is not None and n < want:
                opts.notes.append(f"video of {cam} ({scene.video_path(cam)}) has only {n} of the "
                                  f"{want} frames asked for; the rest is shown without video")
            stats["video_rows"] += n
        if opts.masks:
            stats["mask_rows"] += log_masks(rec, scene, cam, first, last, mask_every)
    gt = None
    if scene.gt_path.exists():
        gt = read_poses(scene.gt_path).in_frames((first, last))
        gsz = _with_size(gt, scene)
        log_boxes(rec, "world/gt", gt, gsz, scene, first, last, color=L.GT_COLOR, with_labels=False)
        for cam in cameras:
            log_projected(rec, f"{L.cam_path(cam)}/gt", scene.cameras[cam], gt, gsz, scene,
                          first, last, color=L.GT_COLOR)
    stats["metrics"] = False
    for run in runs:
        poses = run.poses.in_frames((first, last))
        sz = _with_size(poses, scene)
        log_boxes(rec, f"world/road_users/{run.name}", poses, sz, scene, first, last)
        if opts.trail > 1:
            log_trails(rec, f"world/road_users/{run.name}/trails", poses, scene, first, last, opts.trail)
        run_cams = [c for c in cameras if c in (run.cameras or cameras)]
        for cam in run_cams:
            log_projected(rec, f"{L.cam_path(cam)}/poses/{run.name}", scene.cameras[cam], poses, sz,
                          scene, first, last)
        if run.views is not None:
            vsel = (run.views.frame >= first) & (run.views.frame <= last)
            log_views(rec, Run(run.path, run.name, run.meta, poses, run.views.take(vsel)), scene,
                      run_cams, first, last)
        if gt is not None:
            stats["metrics"] |= log_errors(rec, run, gt, scene, first, last,
                                           shade=(1.0, 0.55, 0.8, 0.4)[runs.index(run) % 4])
    return stats


def prepare(scene: Scene, runs: list[Path], frames, cameras) -> tuple[list[Run], int, int, list[str]]:
    """Load and check the runs; settle the frame range and the cameras to show."""
    last_scene = scene_last_frame(scene)
    loaded = [load_run(Path(p), scene, last_scene) for p in runs]
    names = [r.name for r in loaded]
    for i, r in enumerate(loaded):  # two runs with one folder name: keep both apart
        if names.count(r.name) > 1:
            r.name = f"{r.name}_{i}"
    first, last = resolve_frames(scene, loaded, frames)
    if cameras:
        unknown = [c for c in cameras if c not in scene.cameras]
        if unknown:
            raise InputError(f"unknown cameras {unknown}; the scene has {sorted(scene.cameras)}",
                             field="--camera")
        cams = list(cameras)
    else:
        used = {c for r in loaded for c in r.cameras}
        cams = [c for c in scene.cameras if c in used] if used else list(scene.cameras)
    return loaded, first, last, cams


def record(scene: Scene, runs: list[Path], rrd_path: Path | None = None, *, spawn: bool = False,
           connect: str | None = None, frames: tuple[int, int] | None = None, force: bool = False,
           options: RecordOptions | None = None, screenshot: Path | None = None,
           screenshot_frame: int | None = None, follow: bool = False) -> Path | None:
    """Record ``scene`` with ``runs`` (run folders) to Rerun.

    rrd_path: write an .rrd there (atomically; refuses to overwrite without ``force``);
    spawn: open the native desktop viewer; connect: stream to a running viewer at this URL
    (``rerun+http://host:port/proxy``); frames: (first, last) inclusive, default the runs'
    frames; screenshot: also run a headless viewer and save a PNG of it there;
    screenshot_frame: the time cursor for the screenshot and for a spawned or connected viewer
    (default: the middle frame for screenshots, the viewer's choice otherwise); follow: make a
    spawned or connected viewer follow the newest frame instead.
    Returns the .rrd path (or None when none was written)."""
    from s2p_review import viewer as V

    rr = _rr()
    opts = options or RecordOptions()
    if rrd_path is not None:
        rrd_path = check_writable(Path(rrd_path), force)
    if screenshot is not None:
        check_writable(Path(screenshot), force)
    if connect is not None:
        V.check_reachable(connect)
    if rrd_path is None and not spawn and connect is None and screenshot is None:
        raise S2PError("nothing to do: pass --save FILE.rrd, --spawn, --connect URL or --screenshot FILE.png")
    loaded, first, last, cams = prepare(scene, runs, frames, opts.cameras)
    bp = L.blueprint(cams, [r.name for r in loaded],
                     with_metrics=scene.gt_path.exists() and bool(loaded), eye=L.default_eye(scene),
                     fps=scene.fps)
    rec = rr.RecordingStream("s2p", recording_id=uuid.uuid4().hex)
    title = f"{scene.name}: " + (", ".join(r.name for r in loaded) if loaded else "scene")
    viewers = []
    try:
        sinks = []
        live = []  # viewers to drive after logging (time cursor / follow)
        if spawn:
            client = V.spawn_viewer(headless=False)
            live.append(client)
            sinks.append(rr.GrpcSink(client.url))
        if connect is not None:
            live.append(V.connect_viewer(connect))
            sinks.append(rr.GrpcSink(connect))
        if screenshot is not None:
            shot = V.spawn_viewer(headless=True)
            viewers.append(shot)
            sinks.append(rr.GrpcSink(shot.url))
        if rrd_path is not None:
            with atomic_path(rrd_path) as tmp:
                rec.set_sinks(rr.FileSink(tmp), *sinks)
                # active, not only default: a viewer that remembers an older s2p layout (other
                # cameras) would otherwise keep showing that one
                rec.send_blueprint(bp, make_active=True, make_default=True)
                rec.send_recording_name(title)
                log_all(rec, scene, loaded, first, last, cams, opts)
                rec.flush()
                rec.disconnect()  # closes the file before it is renamed
        else:
            rec.set_sinks(*sinks)
            rec.send_blueprint(bp, make_active=True, make_default=True)
            rec.send_recording_name(title)
            log_all(rec, scene, loaded, first, last, cams, opts)
            rec.flush()
        for client in live:
            if follow:
                V.wait_loaded(client)
                V.follow(client)
            elif screenshot_frame is not None:
                V.wait_loaded(client, min_end=screenshot_frame)
                V.set_frame(client, screenshot_frame)
        if screenshot is not None:
            k = opts.resolved[0] if opts.masks else 1  # a frame that has masks, not a stale one
            frame = (screenshot_frame if screenshot_frame is not None
                     else first + ((last - first) // 2) // k * k)
            V.screenshot_when_loaded(viewers[0], Path(screenshot), frame=frame, force=force)
    finally:
        rec.disconnect()  # before the viewers go: no "connection severed" noise
        for v in viewers:
            V.stop(v)
    return rrd_path
