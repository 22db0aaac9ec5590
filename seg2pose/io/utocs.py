"""Import of UTOCS (CARLA traffic-surveillance data) into a scene folder.

UTOCS layout (one recording)::

    cameras.json        {"instrinsics": {"f", "Cx", "Cy"},            # sic: "instrinsics"
                         "cams": [{"id", "x", "y", "z", "pitch", "roll", "yaw"}, ...]}  # m, deg
    ground_points.txt   x,y,z per line (metres)
    positions/NNNNNN.json   per frame: [{"type", "id", "x", "y", "z", "l", "w", "h",
                                         "forward_x", "forward_y", ...}, ...]
    images/cam<id>/NNNNNN.jpg   optional frames (or a video file cam<id>.mp4 / videos/cam<id>.mp4,
                        or, with one camera, the folder's only *.mp4|*.avi|*.mkv, e.g. vid.mp4)

A video's k-th frame is the k-th positions file (``extra.video_frames`` in scene.json records
the first number and the step).

CARLA's world is Unreal's: left-handed, z up. This project's world is right-handed, z up, so the
import mirrors y: a CARLA point (x, y, z) becomes (x, -y, z), everywhere (cameras, ground
points, road users, forward vectors). A mirror flips handedness, so the camera rotation becomes
a proper rotation again (see ``carla_camera``); headings are atan2(-forward_y, forward_x).

Positions are the bottom centre of each road user's box; l, w, h are taken as full box sizes
(``size_scale=2`` doubles them when a recording stores CARLA's half extents).
"""

from __future__ import annotations

import math
import re
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seg2pose.core.errors import InputError
from seg2pose.core.say import say
from seg2pose.core.validate import FPS_RANGE, MAX_COORD, number, safe_name
from seg2pose.geometry.camera import Camera, Rig
from seg2pose.io.atomic import check_writable, replacing
from seg2pose.io.poses import PoseTable, write_poses
from seg2pose.io.scene import DEFAULT_CLASSES, ClassSpec, Scene, parse_start_time, read_ground_points
from seg2pose.io.text import load_json

MIRROR = np.diag([1.0, -1.0, 1.0])  # CARLA (left-handed) <-> this project (right-handed)
# camera axes: OpenCV (x right, y down, z forward) from CARLA's local (x forward, y right, z up)
CARLA_TO_OPENCV = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
CARLA_FRAME_TIME = 0.075  # s, the paper's recording interval (4.1)

TYPE_ALIASES = {
    "pedestrian": "pedestrian", "walker": "pedestrian", "person": "pedestrian",
    "bicyclist": "bicyclist", "bicycle": "bicyclist", "cyclist": "bicyclist", "bike": "bicyclist",
    "car": "car", "vehicle": "car",
}
EXTRA_HEIGHTS = {"truck": 1.5, "bus": 1.6, "motorbike": 0.8, "motorcyclist": 0.8, "van": 1.1}
_NUM = re.compile(r"^(\d{1,15})\.json$")


def carla_rotation(pitch: float, roll: float, yaw: float) -> np.ndarray:
    """CARLA's camera-to-world rotation (3, 3) in Unreal's left-handed world; angles degrees."""
    p, r, y = (math.radians(a) for a in (pitch, roll, yaw))
    cp, sp, cr, sr, cy, sy = math.cos(p), math.sin(p), math.cos(r), math.sin(r), math.cos(y), math.sin(y)
    return np.array([[cp * cy, cy * sp * sr - sy * cr, -cy * sp * cr - sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, -sy * sp * cr + cy * sr],
                     [sp, -cp * sr, cp * cr]])


def carla_camera(name: str, f: float, cx: float, cy: float, x: float, y: float, z: float,
                 pitch: float, roll: float, yaw: float, width: int, height: int) -> Camera:
    """A camera of this project's (right-handed, y-mirrored) world from a CARLA transform.

    CARLA: X_ue = R_cw @ x_local + p, the camera looks along local +x, image right = local +y,
    image down = local -z. With X_ue = M X (M the y mirror) and x_cv = C x_local,
    x_cv = C R_cw^T M (X - M p): R = C R_cw^T M (det = (-1)(+1)(-1) = +1), centre = M p."""
    R = CARLA_TO_OPENCV @ carla_rotation(pitch, roll, yaw).T @ MIRROR
    center = MIRROR @ np.array([x, y, z], dtype=np.float64)
    K = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
    return Camera(name=name, K=K, R=R, t=-R @ center, width=width, height=height)


def _num(d: dict, key: str, file: Path, where: str) -> float:
    v = d.get(key) if isinstance(d, dict) else None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise InputError(f"expected a finite number, got {v!r}", file=file, field=f"{where}{key}")
    return float(v)


@dataclass
class UtocsCamera:
    id: str
    x: float
    y: float
    z: float
    pitch: float
    roll: float
    yaw: float


def read_cameras_json(path: Path) -> tuple[tuple[float, float, float], list[UtocsCamera]]:
    """(f, Cx, Cy) and the cameras of a UTOCS cameras.json."""
    if not path.exists():
        raise InputError("cameras.json not found (is this a UTOCS folder?)", file=path)
    d = load_json(path)
    if not isinstance(d, dict):
        raise InputError("expected a JSON object", file=path)
    intr = d.get("instrinsics", d.get("intrinsics"))
    if not isinstance(intr, dict):
        raise InputError("missing object 'instrinsics' {f, Cx, Cy}", file=path, field="instrinsics")
    f, cx, cy = (_num(intr, k, path, "instrinsics.") for k in ("f", "Cx", "Cy"))
    if f <= 0:
        raise InputError(f"focal length must be positive, got {f}", file=path, field="instrinsics.f")
    cams_d = d.get("cams")
    if not isinstance(cams_d, list) or not cams_d:
        raise InputError("expected a non-empty list of cameras", file=path, field="cams")
    cams = []
    for i, c in enumerate(cams_d):
        if not isinstance(c, dict) or "id" not in c or isinstance(c["id"], (dict, list)):
            raise InputError("expected an object with an 'id'", file=path, field=f"cams[{i}]")
        vals = [_num(c, k, path, f"cams[{i}].") for k in ("x", "y", "z", "pitch", "roll", "yaw")]
        # the id names files (images/cam<id>/, video/cam<id>.mp4): no way out of the folder
        cid = safe_name(str(c["id"]), file=path, field=f"cams[{i}].id", what="camera id")
        cams.append(UtocsCamera(cid, *vals))
    if len({c.id for c in cams}) != len(cams):
        raise InputError("duplicate camera ids", file=path, field="cams")
    return (f, cx, cy), cams


def read_utocs_ground(path: Path) -> np.ndarray:
    """UTOCS ground points (n, 3) in CARLA coordinates (validated like a scene's)."""
    return read_ground_points(path)


def read_positions(folder: Path) -> tuple[PoseTable, list[str], int]:
    """All positions/NNNNNN.json as a PoseTable in CARLA coordinates with type names as classes
    (heading from forward_x/y, still left-handed). Returns the table, types in first-seen
    order, and the number of frame files."""
    if not folder.is_dir():
        raise InputError("positions/ folder not found", file=folder)
    files = sorted((int(m.group(1)), p) for p in folder.iterdir() if (m := _NUM.match(p.name)))
    if not files:
        raise InputError("no NNNNNN.json files", file=folder)
    frames, tids, types, nums = [], [], [], []
    seen: list[str] = []
    for frame, p in files:
        recs = load_json(p)
        if not isinstance(recs, list):
            raise InputError("expected a JSON list of road users", file=p)
        for i, r in enumerate(recs):
            if not isinstance(r, dict):
                raise InputError("expected an object", file=p, field=f"[{i}]")
            t = r.get("type")
            if not isinstance(t, str) or not t.strip():
                raise InputError(f"expected a type name, got {t!r}", file=p, field=f"[{i}].type")
            rid = r.get("id")
            if isinstance(rid, bool) or not isinstance(rid, int) or not abs(rid) < 2**62:
                raise InputError(f"expected an integer id, got {rid!r}", file=p, field=f"[{i}].id")
            v = [_num(r, k, p, f"[{i}].") for k in ("x", "y", "z", "l", "w", "h",
                                                    "forward_x", "forward_y")]
            for k, x in zip(("l", "w", "h"), v[3:6]):
                if not 0 <= x <= 1000:
                    raise InputError(f"expected a size in [0, 1000] metres, got {x!r}", file=p,
                                     field=f"[{i}].{k}")
            if v[6] == 0 and v[7] == 0:
                raise InputError("forward vector (forward_x, forward_y) is zero: the heading is "
                                 "undefined", file=p, field=f"[{i}].forward_x")
            if max(abs(x) for x in v[:3]) > MAX_COORD:
                raise InputError(f"position more than {MAX_COORD:g} m from the origin: {v[:3]}",
                                 file=p, field=f"[{i}].x")
            name = safe_name(t.strip().lower(), file=p, field=f"[{i}].type", what="type name")
            if name not in seen:
                seen.append(name)
            frames.append(frame)
            tids.append(rid)
            types.append(name)
            nums.append(v)
    a = np.array(nums, dtype=np.float64).reshape(-1, 8)
    heading = np.arctan2(a[:, 7], a[:, 6])
    return (PoseTable(np.array(frames, np.int64), np.array(tids, np.int64), np.array(types, object),
                      a[:, :3], heading, a[:, 3:6]), seen, len(files))


def _class_specs(types: list[str]) -> tuple[list[ClassSpec], dict[str, str]]:
    """This project's classes (defaults + one per extra type) and type -> class name."""
    specs = [ClassSpec(c["id"], c["name"], c["default_height"]) for c in DEFAULT_CLASSES]
    mapping = {}
    for t in types:
        if t in TYPE_ALIASES:
            mapping[t] = TYPE_ALIASES[t]
            continue
        if t not in {s.name for s in specs}:
            specs.append(ClassSpec(max(s.id for s in specs) + 1, t, EXTRA_HEIGHTS.get(t, 1.0)))
        mapping[t] = t
    return specs, mapping


def _find_video(src: Path, cam_id: str, only_camera: bool = False) -> Path | None:
    """cam<id>.<ext> (also under videos/ or video/); with one camera, else the only video."""
    for sub in ("", "videos", "video"):
        for ext in (".mp4", ".avi", ".mkv", ".mov"):
            for stem in (f"cam{cam_id}", f"{cam_id}"):
                p = src / sub / f"{stem}{ext}" if sub else src / f"{stem}{ext}"
                if p.is_file():
                    return p
    if only_camera:
        found = sorted(p for p in src.iterdir() if p.is_file() and p.suffix.lower() in (".mp4", ".avi", ".mkv"))
        if len(found) > 1:
            raise InputError(f"several videos ({', '.join(p.name for p in found)}) and one camera: "
                             "name the camera's video cam<id>.mp4", file=src)
        return found[0] if found else None
    return None


def _frame_numbering(folder: Path) -> dict:
    """{"first", "step"} of the positions files' numbers (the video's k-th frame is the k-th
    file); uneven numbering cannot be mapped and is an error."""
    nums = sorted(int(m.group(1)) for p in folder.iterdir() if (m := _NUM.match(p.name)))
    steps = np.unique(np.diff(nums)) if len(nums) > 1 else np.array([1])
    if len(steps) != 1 or steps[0] < 1:
        raise InputError("positions files are not evenly numbered, so video frames cannot be "
                         "matched to them", file=folder)
    return {"first": nums[0], "step": int(steps[0])}


def _copy(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    if dst.exists():
        dst.unlink()
    try:
        dst.hardlink_to(src)  # frames are large; a hard link costs nothing when possible
    except OSError:
        shutil.copy2(src, dst)


def default_splits(frames: np.ndarray, gap: int = 150) -> dict[str, tuple[int, int]]:
    """Train/val/test as consecutive thirds of the frame range with ``gap`` frames dropped
    between them (the paper's protocol, 4.1); no gap when the recording is too short."""
    lo, hi = int(frames.min()), int(frames.max())
    n = hi - lo + 1
    if n < 3:
        return {}
    g = gap if n >= 3 * 10 + 2 * gap else 0
    k = (n - 2 * g) // 3
    a = lo
    out = {}
    for name in ("train", "val", "test"):
        out[name] = (a, a + k - 1)
        a += k + g
    out["test"] = (out["test"][0], hi)
    return out


def import_utocs(src: str | Path, out: str | Path, force: bool = False,
                 fps: float | None = None, size_scale: float = 1.0, copy_frames: bool = True,
                 log=say, start_time: str | None = None) -> Scene:
    """Convert a UTOCS recording ``src`` into a scene folder ``out`` (see module docstring):
    scene.json, ground_points.csv, gt/poses.csv, masks/ (empty), video/ (when frames exist).
    start_time: the recording's time of frame 0 (ISO 8601 with a zone; UTOCS files do not
    carry it), kept as the scene's start_time."""
    src, out = Path(src), Path(out)
    if start_time is not None:
        parse_start_time(start_time, field="start_time")
    if not src.is_dir():
        raise InputError("UTOCS source folder not found", file=src)
    if fps is not None:
        fps = number(fps, field="fps", lo=FPS_RANGE[0], hi=FPS_RANGE[1])
    size_scale = number(size_scale, field="size_scale", lo=0, lo_open=True, hi=100)
    check_writable(out, force)
    (f, cx, cy), ucams = read_cameras_json(src / "cameras.json")
    gp = src / "ground_points.txt"
    if not gp.exists():
        gp = src / "ground_points.csv"
    ground = read_utocs_ground(gp) @ MIRROR
    poses, types, n_files = read_positions(src / "positions")
    specs, mapping = _class_specs(types)

    cameras: dict[str, Camera] = {}
    frame_sources: dict[str, tuple[str, Path]] = {}
    for uc in ucams:
        name = f"cam{uc.id}"
        img_dir = src / "images" / name
        imgs = sorted(img_dir.glob("*.jpg")) + sorted(img_dir.glob("*.png")) if img_dir.is_dir() else []
        width, height = int(round(2 * cx)), int(round(2 * cy))
        if imgs:
            import cv2

            im = cv2.imread(str(imgs[0]), cv2.IMREAD_UNCHANGED)
            if im is not None:
                height, width = im.shape[:2]
            frame_sources[name] = ("images", img_dir)
        elif (v := _find_video(src, uc.id, only_camera=len(ucams) == 1)) is not None:
            frame_sources[name] = ("video", v)
        if width <= 0 or height <= 0:
            raise InputError(f"cannot infer the image size from Cx={cx}, Cy={cy}",
                             file=src / "cameras.json", field="instrinsics")
        cameras[name] = carla_camera(name, f, cx, cy, uc.x, uc.y, uc.z, uc.pitch, uc.roll, uc.yaw,
                                     width, height)
    configs = {f"mono-{n[3:]}": [n] for n in cameras}
    if len(cameras) > 1:
        configs["all"] = list(cameras)

    # ground truth in the right-handed world
    heading = np.arctan2(-np.sin(poses.heading), np.cos(poses.heading))
    cls = np.array([mapping[t] for t in poses.cls], object)
    size = poses.size  # (every pose read has its l, w, h)
    assert size is not None
    size = size * size_scale
    gt = PoseTable(poses.frame, poses.track_id, cls, poses.xyz @ MIRROR, heading, size).sorted()
    cars = size[cls == "car", 0]
    if len(cars) and np.median(cars) < 3.0 and size_scale == 1.0:
        log(f"note: median car length {np.median(cars):.2f} m looks like CARLA half extents; "
            "import it with a size scale of 2 if so")

    video_frames = {n: _frame_numbering(src / "positions") for n, (k, _) in frame_sources.items()
                    if k == "video"}
    scene = Scene(root=out, name=src.name, fps=float(fps or 1.0 / CARLA_FRAME_TIME),
                  rig=Rig(cameras=cameras, configs=configs, name="utocs"), ground_points=ground,
                  classes=specs, splits=default_splits(gt.frame) if len(gt) else {},
                  start_time=start_time,
                  extra={"source": {"format": "utocs", "path": str(src.resolve()),
                                    "world": "CARLA y mirrored: (x, y, z) -> (x, -y, z)",
                                    "frames": n_files, "size_scale": size_scale,
                                    "types": {t: mapping[t] for t in types}},
                                    **({"video_frames": video_frames} if video_frames else {})})
    scene.check()  # as load_scene reads it, before anything is written
    # built beside OUT and swapped in as a unit: --force replaces the old scene entirely (its
    # masks, frames and cameras do not survive), and a killed import leaves OUT as it was
    with replacing(out, force) as tmp:
        (tmp / "masks").mkdir()
        write_poses(tmp / "gt" / "poses.csv", gt)
        if copy_frames:
            for name, (kind, p) in frame_sources.items():
                if kind == "images":
                    for im in sorted(p.iterdir()):
                        if im.suffix.lower() in (".jpg", ".jpeg", ".png"):
                            _copy(im, tmp / "video" / name / im.name)
                else:
                    _copy(p, tmp / "video" / f"{name}{p.suffix.lower()}")
        scene.save(tmp)
    log(f"imported {len(cameras)} cameras, {len(ground)} ground points, {n_files} frames, "
        f"{len(gt)} ground-truth poses of {len(np.unique(gt.track_id))} road users -> {out}")
    if frame_sources:
        log(f"frames: {', '.join(f'{n} ({k})' for n, (k, _) in frame_sources.items())} -> {out / 'video'}")
    return scene
