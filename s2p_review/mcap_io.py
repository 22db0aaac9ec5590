"""MCAP export and import.

``export_mcap`` writes a scene and one run with Foxglove's well-known protobuf schemas, so that
Foxglove and Rerun's MCAP loader both open it, plus lossless channels of the project's own
records (JSON) and the scene files as attachments, so that ``import_mcap`` restores them exactly.

Topics (log time = frame / fps, in nanoseconds)::

    /cameras/<cam>/calibration   foxglove.CameraCalibration (K, P, distortion), first frame
    /cameras/<cam>/transform     foxglove.FrameTransform world -> <cam> (optical frame: x right,
                                 y down, z forward), first frame
    /cameras/<cam>/masks         foxglove.RawImage mono16: pixel = track_id + 1 (0 = background)
    /cameras/<cam>/image         foxglove.CompressedImage (jpeg), when the scene has video
    /cameras/<cam>/annotations   foxglove.ImageAnnotations: projected boxes, mask outlines
    /road_users/poses            foxglove.PosesInFrame (world): fused road users per frame
    /road_users/scene            foxglove.SceneUpdate: cubes (size, class colour) and labels
    /gt/scene                    foxglove.SceneUpdate: ground-truth cubes (grey), when known
    /world/ground                foxglove.SceneUpdate: the ground surface mesh, first frame
    /s2p/poses                   JSON: {"frame", "rows": [{frame, track_id, class, x, y, z,
                                 heading, l, w, h}]} per frame, every field, floats exact
    /s2p/views                   JSON: the run's views.csv rows per frame, each with its row
                                 number in the file (the import restores the file's order)
Attachments: scene.json, the ground points file, run.json (bytes as on disk).
"""

from __future__ import annotations

import json
import math
import os
import shutil
from pathlib import Path

import numpy as np

from seg2pose.errors import InputError, S2PError
from seg2pose.io.atomic import atomic_path, check_writable, temp_sibling_dir
from seg2pose.io.mots import iter_mots
from seg2pose.io.poses import PoseTable, read_poses
from seg2pose.io.scene import SCENE_FILE, Scene
from s2p_review import columns as C
from s2p_review import layout as L
from seg2pose.io.run import VIEW_COLUMNS, ViewTable, write_run_folder
from s2p_review.runs import load_run, scene_last_frame

POSE_SCHEMA = {
    "title": "s2p.PoseFrame", "type": "object",
    "properties": {
        "frame": {"type": "integer"},
        "rows": {"type": "array", "items": {"type": "object", "properties": {
            "frame": {"type": "integer"}, "track_id": {"type": "integer"},
            "class": {"type": "string"}, "x": {"type": "number"}, "y": {"type": "number"},
            "z": {"type": "number"}, "heading": {"type": ["number", "null"]},
            "l": {"type": ["number", "null"]}, "w": {"type": ["number", "null"]},
            "h": {"type": ["number", "null"]}}}}}}
VIEW_SCHEMA = {"title": "s2p.ViewFrame", "type": "object",
               "properties": {"frame": {"type": "integer"},
                              "columns": {"type": "array", "items": {"type": "string"}},
                              "rows": {"type": "array", "items": {"type": "array"}}}}
MEDIA_JSON = "application/json"


def _num(v: float):
    """JSON has no NaN: null stands for it (and comes back as NaN)."""
    v = float(v)
    return v if math.isfinite(v) else None


def _unnum(v) -> float:
    return float("nan") if v is None else float(v)


def _ns(frame: int, fps: float) -> int:
    return int(round(frame * 1e9 / fps))


def _ts(ns: int):
    from google.protobuf.timestamp_pb2 import Timestamp

    t = Timestamp()
    t.FromNanoseconds(int(ns))
    return t


def _quat_from_matrix(M: np.ndarray) -> tuple[float, float, float, float]:
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(M).as_quat()
    return float(x), float(y), float(z), float(w)


def _color(rgb, a: float = 1.0):
    from foxglove_schemas_protobuf.Color_pb2 import Color

    return Color(r=rgb[0] / 255, g=rgb[1] / 255, b=rgb[2] / 255, a=a)


class _Out:
    """A protobuf writer plus raw JSON channels on the same MCAP file."""

    def __init__(self, f):
        from mcap_protobuf.writer import Writer

        self.pb = Writer(f)
        self.raw = self.pb._writer  # the underlying mcap.writer.Writer, for JSON channels
        self.json_channels: dict[str, int] = {}

    def write(self, topic: str, msg, ns: int) -> None:
        self.pb.write_message(topic, msg, log_time=ns, publish_time=ns)

    def write_json(self, topic: str, schema: dict, obj: dict, ns: int) -> None:
        if topic not in self.json_channels:
            sid = self.raw.register_schema(name=schema["title"], encoding="jsonschema",
                                           data=json.dumps(schema).encode())
            self.json_channels[topic] = self.raw.register_channel(topic=topic, message_encoding="json",
                                                                  schema_id=sid)
        self.raw.add_message(channel_id=self.json_channels[topic], log_time=ns, publish_time=ns,
                             data=json.dumps(obj, allow_nan=False).encode())


def _write_cameras(out: _Out, scene: Scene, cams: list[str], ns: int) -> None:
    from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
    from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform

    for name in cams:
        cam = scene.cameras[name]
        d = cam.distortion.to_dict() if cam.distortion is not None else {}
        D = [float(d.get(k, 0.0)) for k in ("k1", "k2", "p1", "p2", "k3")]
        P = np.hstack([cam.K, np.zeros((3, 1))])
        out.write(f"/cameras/{name}/calibration",
                  CameraCalibration(timestamp=_ts(ns), frame_id=name, width=cam.width,
                                    height=cam.height, distortion_model="plumb_bob", D=D,
                                    K=cam.K.ravel().tolist(), R=np.eye(3).ravel().tolist(),
                                    P=P.ravel().tolist()), ns)
        tf = FrameTransform(timestamp=_ts(ns), parent_frame_id="world", child_frame_id=name)
        c = cam.center
        tf.translation.x, tf.translation.y, tf.translation.z = (float(v) for v in c)
        q = _quat_from_matrix(cam.R.T)
        tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w = q
        out.write(f"/cameras/{name}/transform", tf, ns)


def _write_ground(out: _Out, scene: Scene, ns: int) -> None:
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    verts, tris = scene.ground.mesh(n=32)
    su = SceneUpdate()
    e = su.entities.add(timestamp=_ts(ns), frame_id="world", id="ground", frame_locked=True)
    tri = e.triangles.add()
    tri.pose.orientation.w = 1.0
    for v in verts:
        p = tri.points.add()
        p.x, p.y, p.z = (float(a) for a in v)
    tri.indices.extend(int(i) for i in tris.ravel())
    tri.color.CopyFrom(_color((90, 90, 90)))
    out.write("/world/ground", su, ns)


def _scene_update(table: PoseTable, sizes: np.ndarray, scene: Scene, ns: int, lifetime_ns: int,
                  color=None, prefix: str = ""):
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    su = SceneUpdate()
    fields = C.box_columns(table.xyz, table.heading, sizes)
    cols = L.class_colors(table.cls, scene.classes) if color is None else [color] * len(table)
    labels = L.labels(table.cls, table.track_id)
    for i in range(len(table)):
        if not np.isfinite(table.xyz[i]).all():
            continue
        e = su.entities.add(timestamp=_ts(ns), frame_id="world", id=f"{prefix}{int(table.track_id[i])}")
        e.lifetime.FromNanoseconds(lifetime_ns)
        cube = e.cubes.add()
        cx, cy, cz = (float(v) for v in fields["centers"][i])
        cube.pose.position.x, cube.pose.position.y, cube.pose.position.z = cx, cy, cz
        qx, qy, qz, qw = (float(v) for v in fields["quaternions"][i])
        cube.pose.orientation.x, cube.pose.orientation.y = qx, qy
        cube.pose.orientation.z, cube.pose.orientation.w = qz, qw
        cube.size.x, cube.size.y, cube.size.z = (float(v) for v in sizes[i])
        cube.color.CopyFrom(_color(cols[i], 0.5 if color is None else 0.25))
        if color is None:
            t = e.texts.add(billboard=True, font_size=14.0, scale_invariant=True, text=labels[i])
            t.pose.position.x, t.pose.position.y = cx, cy
            t.pose.position.z = cz + float(sizes[i, 2]) / 2 + 0.3
            t.pose.orientation.w = 1.0
            t.color.CopyFrom(_color((255, 255, 255)))
    return su


def _poses_in_frame(table: PoseTable, ns: int):
    from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame

    msg = PosesInFrame(timestamp=_ts(ns), frame_id="world")
    h = np.nan_to_num(table.heading)
    for i in range(len(table)):
        if not np.isfinite(table.xyz[i]).all():
            continue
        p = msg.poses.add()
        p.position.x, p.position.y, p.position.z = (float(v) for v in table.xyz[i])
        p.orientation.z, p.orientation.w = float(np.sin(h[i] / 2)), float(np.cos(h[i] / 2))
    return msg


def _outlines(inst: np.ndarray, ids: np.ndarray, boxes: np.ndarray) -> list[np.ndarray | None]:
    """Outer contour (K, 2) pixels (pixel centres) of each id's region in an instance image
    (H, W), searched only inside the mask's bounding box (N, 4: x0, y0, x1, y1 exclusive) and
    simplified to within half a pixel; None for a mask hidden by others."""
    import cv2

    out: list = []
    for i, b in zip(ids, boxes):
        if not np.isfinite(b).all():
            out.append(None)
            continue
        x0, y0, x1, y1 = (int(v) for v in b)
        m = (inst[y0:y1, x0:x1] == i).astype(np.uint8)
        cs, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        if not cs:
            out.append(None)
            continue
        c = cv2.approxPolyDP(max(cs, key=len), 0.5, True)[:, 0, :].astype(float)
        out.append(c + [x0 + 0.5, y0 + 0.5])
    return out


def _image_annotations(camera, table: PoseTable, sizes, scene: Scene, inst: np.ndarray | None,
                       inst_ids: np.ndarray, inst_cls: list[str], ns: int,
                       boxes: np.ndarray | None = None, centres: list | None = None):
    """Projected boxes (LINE_LIST, class colours), mask outlines (LINE_LOOP) and the views'
    mask centres (POINTS) of one camera and frame, pixels."""
    from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
    from foxglove_schemas_protobuf.PointsAnnotation_pb2 import PointsAnnotation

    msg = ImageAnnotations()
    segs, idx = C.projected_edges(camera, table.xyz, table.heading, sizes)
    cols = L.class_colors(table.cls[idx], scene.classes)
    from foxglove_schemas_protobuf.Point2_pb2 import Point2

    for k in range(len(idx)):
        pa = msg.points.add(timestamp=_ts(ns), type=PointsAnnotation.LINE_LIST, thickness=2.0)
        pa.outline_color.CopyFrom(_color(cols[k]))
        pa.points.extend(Point2(x=x, y=y) for x, y in segs[k * 12:(k + 1) * 12].reshape(-1, 2).tolist())
    by_name = {c.name: c for c in scene.classes}
    for uv, name in centres or []:
        pa = msg.points.add(timestamp=_ts(ns), type=PointsAnnotation.POINTS, thickness=6.0)
        pa.outline_color.CopyFrom(_color(L.class_color(name, by_name[name].id if name in by_name else 0)))
        pa.points.add(x=float(uv[0]), y=float(uv[1]))
    if inst is not None:
        for name, c in zip(inst_cls, _outlines(inst, inst_ids, boxes)):
            if c is None:
                continue
            pa = msg.points.add(timestamp=_ts(ns), type=PointsAnnotation.LINE_LOOP, thickness=1.0)
            pa.outline_color.CopyFrom(_color(L.class_color(name, by_name[name].id if name in by_name else 0)))
            pa.points.extend(Point2(x=x, y=y) for x, y in c.tolist())
    return msg


def export_mcap(scene: Scene, run_dir: Path, out_path: Path, force: bool = False, *,
                frames: tuple[int, int] | None = None, mask_every: int | None = None,
                video_every: int | None = None, cameras: list[str] | None = None,
                notes: list | None = None) -> Path:
    """Write ``scene`` and the run in ``run_dir`` to ``out_path`` (.mcap), atomically.
    frames: (first, last) inclusive (default: the run's frames); mask_every / video_every:
    export masks / video every k-th frame only (None: automatic, as for recordings, see
    s2p_review.recording.RecordOptions); notes: gets what was decided. Returns out_path."""
    import cv2
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
    from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

    from s2p_review.recording import RecordOptions, _video_frames, _with_size, resolve_frames

    out_path = check_writable(Path(out_path), force)
    run = load_run(Path(run_dir), scene, scene_last_frame(scene))
    first, last = resolve_frames(scene, [run], frames)
    cams = list(cameras) if cameras else (run.cameras or list(scene.cameras))
    ro = RecordOptions(mask_every=mask_every, video_every=video_every)
    mask_every, video_every = ro.resolve(scene, first, last, cams)
    if notes is not None:
        notes.extend(ro.notes)
    fps = scene.fps
    dt = _ns(1, fps)
    poses = run.poses.in_frames((first, last))
    psz = _with_size(poses, scene)
    gt = read_poses(scene.gt_path).in_frames((first, last)) if scene.gt_path.exists() else None
    by_id = {c.id: c.name for c in scene.classes}
    scene_json = (scene.root / SCENE_FILE).read_bytes()
    with atomic_path(out_path) as tmp, open(tmp, "wb") as f:
        out = _Out(f)
        t0 = _ns(first, fps)
        out.pb.add_attachment(create_time=0, log_time=t0, name=SCENE_FILE, media_type=MEDIA_JSON,
                              data=scene_json)
        out.pb.add_attachment(create_time=0, log_time=t0, name=scene.ground_file,
                              media_type="text/csv", data=(scene.root / scene.ground_file).read_bytes())
        out.pb.add_attachment(create_time=0, log_time=t0, name="run.json", media_type=MEDIA_JSON,
                              data=json.dumps(run.meta, indent=1).encode())
        out.pb.add_metadata("s2p", {"scene": scene.name, "run": run.path.name, "fps": repr(fps),
                                    "first_frame": str(first), "last_frame": str(last),
                                    "has_views": str(run.views is not None).lower(),
                                    "poses_with_size": str(run.poses.size is not None).lower(),
                                    "mask_pixel": "track_id + 1 (0 = background)"})
        _write_cameras(out, scene, cams, t0)
        _write_ground(out, scene, t0)

        # own lossless records first: one JSON message per frame, rows in file order
        ptab = run.poses.in_frames((first, last))
        pf = ptab.frame
        cuts = np.flatnonzero(np.diff(pf)) + 1
        for idx in np.split(np.arange(len(pf)), cuts) if len(pf) else []:
            f = int(pf[idx[0]])
            rows = []
            for i in idx:
                r = {"frame": f, "track_id": int(ptab.track_id[i]), "class": str(ptab.cls[i]),
                     "x": float(ptab.xyz[i, 0]), "y": float(ptab.xyz[i, 1]),
                     "z": float(ptab.xyz[i, 2]), "heading": _num(ptab.heading[i])}
                if ptab.size is not None:
                    r.update(l=_num(ptab.size[i, 0]), w=_num(ptab.size[i, 1]), h=_num(ptab.size[i, 2]))
                rows.append(r)
            out.write_json("/s2p/poses", POSE_SCHEMA, {"frame": f, "rows": rows}, _ns(f, fps))
        if run.views is not None:
            v = run.views
            sel = np.flatnonzero((v.frame >= first) & (v.frame <= last))
            sel = sel[np.argsort(v.frame[sel], kind="stable")]  # by frame; "row" keeps file order
            vf = v.frame[sel]
            for idx in np.split(sel, np.flatnonzero(np.diff(vf)) + 1) if len(sel) else []:
                f = int(v.frame[idx[0]])
                rows = [[int(i), int(v.frame[i]), int(v.track_id[i]), str(v.camera[i]), str(v.cls[i]),
                         *[_num(x) for x in (*v.uv[i], *v.normal[i], *v.residual[i])]] for i in idx]
                out.write_json("/s2p/views", VIEW_SCHEMA, {"frame": f, "columns": ["row"] + VIEW_COLUMNS,
                                                          "rows": rows}, _ns(f, fps))

        # Foxglove views of the road users, per frame
        def per_frame(t: PoseTable):
            if not len(t):
                return {}
            order = np.argsort(t.frame, kind="stable")
            fr = t.frame[order]
            return {int(fr[s[0]]): order[s] for s in np.split(np.arange(len(fr)), np.flatnonzero(np.diff(fr)) + 1)}

        pidx = per_frame(poses)
        gidx = per_frame(gt) if gt is not None else {}
        gsz = _with_size(gt, scene) if gt is not None else None
        for f in range(first, last + 1):
            ns = _ns(f, fps)
            if f in pidx:
                t = poses.take(pidx[f])
                out.write("/road_users/poses", _poses_in_frame(t, ns), ns)
                out.write("/road_users/scene", _scene_update(t, psz[pidx[f]], scene, ns, dt), ns)
            if f in gidx:
                out.write("/gt/scene", _scene_update(gt.take(gidx[f]), gsz[gidx[f]], scene, ns, dt,
                                                     color=L.GT_COLOR, prefix="gt"), ns)

        # per camera: masks (instance ids), video, annotations
        for name in cams:
            cam = scene.cameras[name]
            h, w = cam.height, cam.width
            masks = {}
            mp = scene.masks_path(name)
            if mp.exists():
                for f, t in iter_mots(mp, frame_range=(first, last)):
                    if (f - first) % max(1, mask_every) == 0:
                        masks[f] = t
            centres = {}
            if run.views is not None:
                v = run.views
                for i in np.flatnonzero(v.camera == name):
                    centres.setdefault(int(v.frame[i]), []).append((v.uv[i], str(v.cls[i])))
            for f in range(first, last + 1):
                ns = _ns(f, fps)
                on = (f - first) % max(1, mask_every) == 0
                t = masks.get(f) if on else None
                inst, ids, cls, boxes = None, np.zeros(0, np.int64), [], None
                if t is not None:
                    from seg2pose.masks import rle_stats

                    ids = t.track_id + 1
                    boxes = rle_stats(t.rles, h, w)[2]
                    inst = C.paint_masks(t.rles, ids, np.zeros(len(t), np.int64), h, w, 1,
                                         dtype=np.uint16)[0]
                    cls = [by_id.get(int(c), "unknown") for c in t.class_id]
                if on and mp.exists():  # an empty image too: no stale masks in a viewer
                    img = inst if inst is not None else np.zeros((h, w), np.uint16)
                    out.write(f"/cameras/{name}/masks",
                              RawImage(timestamp=_ts(ns), frame_id=name, width=w, height=h,
                                       encoding="mono16", step=2 * w,
                                       data=img.astype("<u2").tobytes()), ns)
                sel = pidx.get(f, np.zeros(0, np.int64))
                ann = _image_annotations(cam, poses.take(sel), psz[sel], scene, inst, ids, cls, ns,
                                         boxes, centres.get(f, []))
                out.write(f"/cameras/{name}/annotations", ann, ns)
            vp = scene.video_path(name)
            if vp is not None:
                for f, img in _video_frames(vp, first, last, max(1, video_every)):
                    ns = _ns(f, fps)
                    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 75])
                    out.write(f"/cameras/{name}/image",
                              CompressedImage(timestamp=_ts(ns), frame_id=name, data=buf.tobytes(),
                                              format="jpeg"), ns)
        out.pb.finish()
    return out_path


# --- import ----------------------------------------------------------------------------------------
def read_mcap_records(path: Path) -> dict:
    """The s2p content of an export: attachments (name -> bytes), metadata, pose rows and view
    rows (JSON channels), in log-time order."""
    from mcap.reader import make_reader

    path = Path(path)
    if not path.exists():
        raise InputError("MCAP file not found", file=path)
    res = {"attachments": {}, "metadata": {}, "poses": [], "views": []}
    try:
        with open(path, "rb") as f:
            reader = make_reader(f)
            for a in reader.iter_attachments():
                res["attachments"][a.name] = a.data
            for m in reader.iter_metadata():
                res["metadata"][m.name] = dict(m.metadata)
            for _schema, channel, msg in reader.iter_messages(topics=["/s2p/poses", "/s2p/views"],
                                                              log_time_order=True):
                d = json.loads(msg.data)
                res["poses" if channel.topic == "/s2p/poses" else "views"].append(d)
    except InputError:
        raise
    except Exception as e:  # noqa: BLE001 - mcap raises many kinds on a damaged file
        raise InputError(f"not a readable MCAP file ({type(e).__name__}: {e})", file=path) from None
    if SCENE_FILE not in res["attachments"]:
        raise InputError("no scene.json attachment: not an `s2p export` file", file=path)
    return res


def _pose_table(frames_msgs: list[dict], with_size: bool) -> PoseTable:
    rows = [r for m in frames_msgs for r in m["rows"]]
    if not rows:
        return PoseTable.empty(with_size)
    size = (np.array([[_unnum(r.get("l")), _unnum(r.get("w")), _unnum(r.get("h"))] for r in rows])
            if with_size else None)
    return PoseTable([r["frame"] for r in rows], [r["track_id"] for r in rows],
                     np.array([r["class"] for r in rows], dtype=object),
                     [[r["x"], r["y"], r["z"]] for r in rows], [_unnum(r["heading"]) for r in rows],
                     size)


def _view_table(frames_msgs: list[dict]) -> ViewTable:
    rows = sorted((r for m in frames_msgs for r in m["rows"]), key=lambda r: r[0])  # file order
    if not rows:
        return ViewTable.empty()
    nums = np.array([[_unnum(x) for x in r[5:]] for r in rows], float).reshape(-1, 7)
    return ViewTable([r[1] for r in rows], [r[2] for r in rows], [r[3] for r in rows],
                     [r[4] for r in rows], nums[:, 0:2], nums[:, 2:5], nums[:, 5:7])


def import_mcap(path: Path, out_dir: Path, force: bool = False) -> Path:
    """Restore an ``s2p export`` file as a scene folder: OUT/scene.json and the ground points
    (bytes as exported), OUT/out/<run>/run.json, poses.csv (the exact pose table) and
    views.csv. Returns the run folder."""
    path, out_dir = Path(path), Path(out_dir)
    if out_dir.exists() and any(out_dir.iterdir()) and not force:
        raise S2PError(f"{out_dir} exists and is not empty; pass --force to write into it")
    rec = read_mcap_records(path)
    meta = rec["metadata"].get("s2p", {})
    att = rec["attachments"]
    try:
        scene_d = json.loads(att[SCENE_FILE])
    except json.JSONDecodeError as e:
        raise InputError(f"the scene.json attachment is not JSON: {e.msg}", file=path) from None
    gfile = str(scene_d.get("ground_points", "ground_points.csv"))
    if gfile not in att:
        raise InputError(f"no {gfile} attachment", file=path)
    run_name = meta.get("run") or "run"
    if os.sep in run_name or run_name in ("", ".", ".."):
        run_name = "run"
    with_size = meta.get("poses_with_size", "true") == "true"
    table = _pose_table(rec["poses"], with_size)

    # build in a temporary sibling folder, then move into place: nothing half-written
    tmp = temp_sibling_dir(out_dir)
    try:
        (tmp / SCENE_FILE).write_bytes(att[SCENE_FILE])
        (tmp / gfile).parent.mkdir(parents=True, exist_ok=True)
        (tmp / gfile).write_bytes(att[gfile])
        run_meta = json.loads(att["run.json"]) if "run.json" in att else {}
        views = _view_table(rec["views"]) if meta.get("has_views") == "true" or rec["views"] else None
        write_run_folder(tmp / "out" / run_name, table, views, run_meta)
        if not out_dir.exists() or not any(out_dir.iterdir()):
            if out_dir.exists():
                out_dir.rmdir()
            os.replace(tmp, out_dir)
        else:  # --force into an existing folder: move file by file (each rename is atomic)
            for p in sorted(tmp.rglob("*")):
                if p.is_file():
                    dst = out_dir / p.relative_to(tmp)
                    dst.parent.mkdir(parents=True, exist_ok=True)
                    os.replace(p, dst)
            shutil.rmtree(tmp)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out_dir / "out" / run_name
