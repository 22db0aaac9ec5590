"""MCAP export of a scene and one run: Foxglove's well-known protobuf schemas (Foxglove opens
it; Rerun's MCAP loader shows cameras, images and poses), lossless s2p records (JSON, see
``mcap_records``) and the scene files as attachments, so that ``mcap_import`` restores them.

Topics (log time = the frame's time, ns; see ``timebase``)::

    /cameras/<cam>/calibration   foxglove.CameraCalibration (K, P, distortion) of the images as
                                 shown (``image_scale`` times the camera's size), first frame
    /cameras/<cam>/transform     foxglove.FrameTransform world -> <cam> (optical frame), first frame
    /cameras/<cam>/display       the masks for people: class colours blended over the video
                                 (foxglove.CompressedImage, jpeg), or on black without video
                                 (foxglove.RawImage rgb8); every mask frame
    /cameras/<cam>/masks         foxglove.RawImage mono16, full size, lossless: pixel =
                                 track_id + 1 (0 = background); every mask frame
    /cameras/<cam>/image         foxglove.CompressedImage (jpeg), video frames, when asked for
    /cameras/<cam>/annotations   foxglove.ImageAnnotations per frame: projected boxes, the views'
                                 mask centres, and the outlines of the latest mask frame
    /road_users/poses            foxglove.PosesInFrame (world): road users of known heading
    /road_users/scene            foxglove.SceneUpdate: a cube per road user (an upright cylinder
                                 where the heading is unknown), label; entity id = track id,
                                 metadata track_id, class, heading
    /gt/scene                    foxglove.SceneUpdate: ground-truth cubes (grey), when known
    /world/ground                foxglove.SceneUpdate: the ground surface mesh, first frame
    /s2p/errors                  JSON per frame: {"frame", "mean", <class>: ...} ground-plane
                                 error (metres) against the ground truth, when known
    /s2p/poses, /s2p/views       JSON: the run's poses and views, exact (``mcap_records``); a
                                 road user is followed in Foxglove with the message path
                                 ``/s2p/poses.rows[:]{track_id==12}.x``

Log time: the frame's wall-clock time when the scene's start time is known (``timebase``), else
frame / fps since 0; the frame number is in every JSON message and follows from the metadata
record ``s2p`` (start_ns, fps). Messages are written in log-time order over the whole file (the
per-topic streams are merged), so a front-to-back reader sees them in time order. Attachments:
scene.json, the ground points file, run.json (bytes as on disk). Beside the file: a Foxglove
layout, ``<name>.layout.json`` (``foxglove_layout``).
"""

from __future__ import annotations

import heapq
import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from s2p_review import columns as C
from s2p_review import foxglove as F
from s2p_review import foxglove_layout as FL
from s2p_review import imagery
from s2p_review import layout as L
from s2p_review import mcap_records as R
from s2p_review.runs import Run
from s2p_review.selection import Selection, select
from s2p_review.timebase import Timebase, scene_timebase
from seg2pose.core.errors import InputError
from seg2pose.io.atomic import check_writable, outputs
from seg2pose.io.nofollow import fdopen_nofollow, write_new_text
from seg2pose.io.poses import PoseTable, read_poses
from seg2pose.io.scene import SCENE_FILE, Scene

MEDIA_JSON = "application/json"
ERRORS_TOPIC = "/s2p/errors"
ERROR_SCHEMA = {"title": "s2p.FrameErrors", "type": "object",
                "properties": {"frame": {"type": "integer"}, "mean": {"type": ["number", "null"]}},
                "additionalProperties": {"type": ["number", "null"]}}
MASK_PIXEL = "track_id + 1 (0 = background)"


@dataclass(frozen=True)
class ExportOptions:
    """What to export. frames: (first, last) inclusive (None: the run's frames); cameras: None =
    the run's cameras; mask_every / video_every: every k-th frame only (None: automatic, as
    for recordings); start_ns: UTC time of frame 0, ns (None: the scene's, when it has one);
    video: also the plain video frames (the display images already show the video under the
    masks); image_scale: the size images are shown at, relative to the camera's (calibration
    and annotations follow; the mono16 masks stay full size); jpeg_quality: of video and
    display images; layout: write the Foxglove layout beside the file; attachments: more files
    to carry, name -> bytes (e.g. an annotation journal, see ``annotated_mcap``); conflicts:
    a conflicts.csv (``s2p conflicts``) exported as events (``s2p_review.conflicts``); gt: the
    ground truth to show (None: the scene's gt/poses.csv when it has one), e.g. the gt that
    an annotation export writes in the same set (the file on disk is the one it replaces)."""

    frames: tuple[int, int] | None = None
    cameras: list[str] | None = None
    mask_every: int | None = None
    video_every: int | None = None
    start_ns: int | None = None
    video: bool = True
    image_scale: float = 1.0
    jpeg_quality: int = 75
    layout: bool = True
    attachments: dict[str, bytes] | None = None
    conflicts: Path | None = None  # a conflicts.csv: its rows as events on /s2p/conflicts
    gt: PoseTable | None = None
    # more message streams, each made from the selection and the timebase and yielding Items in
    # log-time order (e.g. the annotated set's video, ``annotated_mcap``)
    extra_streams: tuple = ()


@dataclass(frozen=True)
class ExportResult:
    """The file written (and its layout, or None), what it holds and notes for the user."""

    path: Path
    layout: Path | None
    selection: Selection
    messages: int
    notes: tuple[str, ...]


# A message waiting to be written: (log time ns, stream rank, topic, payload). The payload is a
# protobuf message, or (schema, dict) for a JSON channel.
Item = tuple[int, int, str, object]


class _Writer:
    """A protobuf writer plus raw JSON channels on the same MCAP file."""

    def __init__(self, f):
        from mcap_protobuf.writer import Writer

        self.pb = Writer(f)
        self.raw = self.pb._writer  # the underlying mcap.writer.Writer, for JSON channels
        self.json_channels: dict[str, int] = {}
        self.count = 0

    def write(self, ns: int, topic: str, payload) -> None:
        self.count += 1
        if not isinstance(payload, tuple):
            self.pb.write_message(topic, payload, log_time=ns, publish_time=ns)
            return
        schema, obj = payload
        if topic not in self.json_channels:
            sid = self.raw.register_schema(name=schema["title"], encoding="jsonschema",
                                           data=json.dumps(schema).encode())
            self.json_channels[topic] = self.raw.register_channel(topic=topic, message_encoding="json",
                                                                  schema_id=sid)
        self.raw.add_message(channel_id=self.json_channels[topic], log_time=ns, publish_time=ns,
                             data=json.dumps(obj, allow_nan=False).encode())


def _rows_by_frame(t: PoseTable) -> dict[int, np.ndarray]:
    return {int(t.frame[idx[0]]): idx for idx in R.split_by_frame(t.frame)}


# --- streams: each yields its messages in log-time order -------------------------------------------
def _static_stream(scene: Scene, cams: list[str], ns: int, scale: float) -> Iterator[Item]:
    for name in cams:
        yield ns, 0, f"/cameras/{name}/calibration", F.camera_calibration(scene, name, ns, scale)
        yield ns, 0, f"/cameras/{name}/transform", F.camera_transform(scene, name, ns)
    yield ns, 0, "/world/ground", F.ground(scene, ns)


def _record_stream(run: Run, sel: Selection, tb: Timebase) -> Iterator[Item]:
    """The lossless s2p channels, one message per frame per channel."""
    poses = run.poses.in_frames((sel.first, sel.last))
    msgs = [(f, R.POSES_TOPIC, (R.POSE_SCHEMA, m)) for f, m in R.pose_messages(poses)]
    if run.views is not None:
        v = run.views.take((run.views.frame >= sel.first) & (run.views.frame <= sel.last))
        msgs += [(f, R.VIEWS_TOPIC, (R.VIEW_SCHEMA, m)) for f, m in R.view_messages(v)]
    for f, topic, payload in sorted(msgs, key=lambda m: m[0]):
        yield tb.ns1(f), 1, topic, payload


def _road_user_stream(scene: Scene, sel: Selection, tb: Timebase, poses: PoseTable,
                      psz: np.ndarray, gt: PoseTable | None) -> Iterator[Item]:
    """Fused road users (PosesInFrame, SceneUpdate) and ground truth per frame."""
    dt = tb.ns1(1) - tb.ns1(0)
    pidx = _rows_by_frame(poses)
    gidx = _rows_by_frame(gt) if gt is not None else {}
    gsz = C.sizes_of(gt, scene) if gt is not None else None
    for f in range(sel.first, sel.last + 1):
        ns = tb.ns1(f)
        if f in pidx:
            t = poses.take(pidx[f])
            yield ns, 2, "/road_users/poses", F.poses_in_frame(t, ns)
            yield ns, 2, "/road_users/scene", F.scene_update(t, psz[pidx[f]], scene, ns, dt)
        if f in gidx:
            assert gt is not None and gsz is not None  # gidx is empty without truth
            yield ns, 2, "/gt/scene", F.scene_update(gt.take(gidx[f]), gsz[gidx[f]], scene, ns, dt,
                                                     rgb=L.GT_COLOR, prefix="gt")


def _error_stream(tb: Timebase, poses: PoseTable, gt: PoseTable | None) -> Iterator[Item]:
    """Per-frame ground-plane errors against the truth (for the layout's plot)."""
    if gt is None:
        return
    from seg2pose.eval.evaluate import per_frame_errors

    frames, mean, per_class = per_frame_errors(poses, gt)
    for k, f in enumerate(frames.tolist()):
        msg = {"frame": f, "mean": R.num(mean[k])}
        msg.update({c: R.num(e[k]) for c, e in per_class.items()})
        yield tb.ns1(f), 1, ERRORS_TOPIC, (ERROR_SCHEMA, msg)


def _camera_stream(scene: Scene, name: str, rank: int, sel: Selection, tb: Timebase,
                   poses: PoseTable, psz: np.ndarray, run: Run, opts: ExportOptions
                   ) -> Iterator[Item]:
    """One camera's images and annotations, frame by frame. The outlines of the latest mask
    frame stay on the annotations until the next one (viewers keep showing that mask)."""
    from seg2pose.structures.masks import rle_stats

    cam = scene.cameras[name]
    s = opts.image_scale
    size = F.scaled_size(cam, s)
    rgb_of = {c.id: L.class_color(c.name, c.id) for c in scene.classes}
    names = {c.id: c.name for c in scene.classes}
    masks = imagery.mask_frames(scene, name, sel.first, sel.last, sel.cadence.masks)
    pending_mask = next(masks, None)
    # every frame is decoded: the display images need the video at the mask frames too
    video = imagery.video_frames(scene, name, sel.first, sel.last)
    pending_video = next(video, None)
    centres: dict[int, list] = {}
    if run.views is not None:
        v = run.views
        for i in np.flatnonzero(v.camera == name):
            centres.setdefault(int(v.frame[i]), []).append((v.uv[i], str(v.cls[i])))
    pidx = _rows_by_frame(poses)
    loops: list = []
    for f in range(sel.first, sel.last + 1):
        ns = tb.ns1(f)
        frame_bgr = None
        if pending_video is not None and pending_video[0] == f:
            frame_bgr = pending_video[1]
            pending_video = next(video, None)
            if opts.video and (f - sel.first) % sel.cadence.video == 0:
                jpeg = imagery.encode_jpeg(frame_bgr, opts.jpeg_quality, size[0])
                yield ns, rank, f"/cameras/{name}/image", F.compressed_image(jpeg, name, ns)
        if pending_mask is not None and pending_mask[0] == f:
            t = pending_mask[1]
            ids = t.track_id + 1
            path = scene.masks_path(name)
            inst = imagery.paint([t], [ids], path, dtype=np.uint16)[0]
            cls_img = imagery.paint([t], [t.class_id], path)[0]
            boxes = rle_stats(t.rles, cam.height, cam.width)[2]
            loops = [(names.get(int(c), "unknown"), o)
                     for c, o in zip(t.class_id, F.outlines(inst, ids, boxes)) if o is not None]
            disp = F.overlay(cls_img, rgb_of, frame_bgr, size)
            if frame_bgr is not None:
                jpeg = imagery.encode_jpeg(disp[..., ::-1], opts.jpeg_quality)
                yield ns, rank, f"/cameras/{name}/display", F.compressed_image(jpeg, name, ns)
            else:
                yield ns, rank, f"/cameras/{name}/display", F.raw_image(disp, name, ns)
            # an empty image too: no stale masks in a viewer
            yield ns, rank, f"/cameras/{name}/masks", F.raw_image(inst, name, ns)
            pending_mask = next(masks, None)
        sel_rows = pidx.get(f, np.zeros(0, np.int64))
        yield ns, rank, f"/cameras/{name}/annotations", F.image_annotations(
            cam, poses.take(sel_rows), psz[sel_rows], scene, ns, loops, centres.get(f, []), s)


def _layout(scene: Scene, sel: Selection, gt: PoseTable | None) -> dict:
    """The Foxglove layout for this export: display images where a camera has masks."""
    image_topic = {c: FL.camera_topics(c)["display" if scene.masks_path(c).exists() else "image"]
                   for c in sel.cameras}
    return FL.layout(sel.cameras, [c.name for c in scene.classes], image_topic,
                     with_gt=gt is not None, with_errors=gt is not None)


def export_mcap(scene: Scene, run_dir: Path, out_path: Path, options: ExportOptions | None = None,
                force: bool = False) -> ExportResult:
    """Write ``scene`` and the run in ``run_dir`` to ``out_path`` (.mcap), atomically (an
    existing file is kept unless ``force``)."""
    opts = options or ExportOptions()
    out_path = check_writable(Path(out_path), force)
    lay_path = FL.layout_path(out_path) if opts.layout else None
    if lay_path is not None:
        check_writable(lay_path, force)
    if not 0 < opts.image_scale <= 1:
        raise InputError(f"image scale must be in (0, 1], got {opts.image_scale}", field="image_scale")
    sel = select(scene, [Path(run_dir)], opts.frames, opts.cameras, opts.mask_every,
                 opts.video_every, video=opts.video)
    run = sel.runs[0]
    # Foxglove's calibrations know plumb_bob only: other lens models are fitted, or refused
    # here, before anything is written, when no fit is within F.PLUMB_BOB_TOLERANCE_PX
    fits = {name: F.plumb_bob(scene.cameras[name]) for name in sel.cameras}
    fit_notes = [f"camera {name}: its {getattr(scene.cameras[name].distortion, 'model', '?')} distortion is "
                 f"written as plumb_bob k1..k3 fitted over the image (max {fit.max_px:.3f} px, "
                 f"mean {fit.mean_px:.3f} px off)" for name, fit in fits.items() if fit.fitted]
    tb = scene_timebase(scene, opts.start_ns)
    poses = run.poses.in_frames((sel.first, sel.last))
    psz = C.sizes_of(poses, scene)
    gt = opts.gt if opts.gt is not None else read_poses(scene.gt_path) if scene.gt_path.exists() else None
    gt = gt.in_frames((sel.first, sel.last)) if gt is not None else None
    t0 = tb.ns1(sel.first)
    events = []
    if opts.conflicts is not None:
        from s2p_review import conflicts as CF

        events = CF.mcap_items(CF.read_conflicts(opts.conflicts), tb, sel.first, sel.last)
    # the MCAP and its layout: one set of outputs, swapped in together (a kill between two
    # separate swaps left a new MCAP beside the old layout)
    finals = [out_path] + ([lay_path] if lay_path is not None else [])
    with outputs(finals, force) as files, fdopen_nofollow(files.file(out_path), "xb") as f:
        out = _Writer(f)
        out.pb.add_attachment(create_time=0, log_time=t0, name=SCENE_FILE, media_type=MEDIA_JSON,
                              data=(scene.root / SCENE_FILE).read_bytes())
        out.pb.add_attachment(create_time=0, log_time=t0, name=scene.ground_file,
                              media_type="text/csv", data=(scene.root / scene.ground_file).read_bytes())
        out.pb.add_attachment(create_time=0, log_time=t0, name="run.json", media_type=MEDIA_JSON,
                              data=json.dumps(run.meta, indent=1).encode())
        for name, data in (opts.attachments or {}).items():
            out.pb.add_attachment(create_time=0, log_time=t0, name=name,
                                  media_type="application/octet-stream", data=data)
        out.pb.add_metadata("s2p", {
            "scene": scene.name, "run": run.path.name, "fps": repr(scene.fps),
            "first_frame": str(sel.first), "last_frame": str(sel.last),
            "start_ns": str(tb.start_ns or 0), "start_time": scene.start_time or "",
            "frame_of_log_time": "round((log_time - start_ns) * fps / 1e9)",
            "image_scale": repr(opts.image_scale),
            "has_views": str(run.views is not None).lower(),
            "poses_with_size": str(run.poses.size is not None).lower(), "mask_pixel": MASK_PIXEL})
        streams = [_static_stream(scene, sel.cameras, t0, opts.image_scale),
                   _record_stream(run, sel, tb), _error_stream(tb, poses, gt),
                   _road_user_stream(scene, sel, tb, poses, psz, gt), iter(events)]
        streams += [_camera_stream(scene, name, 3 + k, sel, tb, poses, psz, run, opts)
                    for k, name in enumerate(sel.cameras)]
        streams += [make(sel, tb) for make in opts.extra_streams]
        for ns, _rank, topic, payload in heapq.merge(*streams, key=lambda m: (m[0], m[1])):
            out.write(ns, topic, payload)
        out.pb.finish()
        if lay_path is not None:
            write_new_text(files.file(lay_path), FL.layout_text(_layout(scene, sel, gt)))
    return ExportResult(out_path, lay_path, sel, out.count, tuple(sel.cadence.notes() + fit_notes))
