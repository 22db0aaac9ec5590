"""The scene folder (DESIGN.md): ``scene.json`` + ground points + masks + video + ground truth.

scene.json, version 1::

    {
      "version": 1,
      "name": "junction",
      "fps": 13.333,
      "ground_points": "ground_points.csv",
      "classes": [{"id": 1, "name": "pedestrian", "default_height": 0.9}, ...],
      "rig": "device",
      "cameras": [{"name": "c0", "width": 1280, "height": 720,
                   "K": [[...]], "R": [[...]], "t": [...],          # or "P": 3x4
                   "distortion": {"model": "opencv", "k1": 0, ...}}], # optional
      "configs": {"mono-1": ["c0"], "stereo-10": ["c0", "c1"]},
      "splits": {"train": [0, 6999], "val": [7150, 14149], "test": [14300, 21299]},  # optional
      "start_time": "2021-06-14T08:00:00.000Z",   # optional: UTC time of frame 0 (ISO 8601)
      "extra": {...}   # free-form provenance (generator settings etc.)
    }
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from seg2pose.core.errors import InputError
from seg2pose.core.validate import FPS_RANGE, MAX_COORD, MAX_ID, inside, integer, number, safe_name
from seg2pose.geometry.camera import Camera, Rig
from seg2pose.geometry.ground import GroundSurface
from seg2pose.io.atomic import atomic_write_text, outputs
from seg2pose.io.mots import MaskTable, iter_mots
from seg2pose.io.nofollow import write_new_text
from seg2pose.io.text import load_json, read_text

SCENE_VERSION = 1
MAX_CLASS_ID = 65535
MAX_DEFAULT_HEIGHT = 20.0  # metres above the ground
SCENE_FILE = "scene.json"
DEFAULT_CLASSES: list[dict] = [
    {"id": 1, "name": "pedestrian", "default_height": 0.9},
    {"id": 2, "name": "bicyclist", "default_height": 0.9},
    {"id": 3, "name": "car", "default_height": 0.75},
]


# l, w, h metres, used when scene.json gives no extra["class_sizes"]: a mid-size car, an adult
# walking (shoulders and stride), a bicycle with rider, a rigid truck, a city bus, a motorcycle
# and a moped with their riders
DEFAULT_CLASS_SIZES = {"pedestrian": (0.6, 0.6, 1.75), "bicyclist": (1.8, 0.6, 1.7),
                       "car": (4.5, 1.8, 1.5), "truck": (8.0, 2.5, 3.2), "bus": (12.0, 2.55, 3.2),
                       "motorcycle": (2.2, 0.8, 1.5), "moped": (1.8, 0.7, 1.5)}
UNKNOWN_CLASS = "car"  # a class without a typical size is sized as this one (callers say so)


def road_user_sizes(cls, own: np.ndarray | None = None,
                    sizes: dict[str, tuple[float, float, float]] | None = None
                    ) -> tuple[np.ndarray, list[str]]:
    """The one source of road-user sizes (review, MCAP export, conflicts): (N, 3) l, w, h
    metres per row and the class names that have no typical size (sized as UNKNOWN_CLASS).

    cls: (N,) class names; own: (N, 3) or (N, 2) sizes the rows carry (NaN = none; a finite
    value is kept, a missing one is taken from the class); sizes: class name -> (l, w, h), a
    scene's ``Scene.class_sizes()`` (default: DEFAULT_CLASS_SIZES). Names are matched as given,
    then in lower case. Looked up once per run of equal names (millions of rows, few classes)."""
    table = DEFAULT_CLASS_SIZES if sizes is None else sizes
    lower = {str(k).lower(): v for k, v in table.items()}
    cls = np.asarray(cls, object).reshape(-1)
    n = len(cls)
    out = np.zeros((n, 3), np.float64)
    unknown: list[str] = []
    if n:
        heads = np.flatnonzero(np.r_[True, cls[1:] != cls[:-1]])
        looked: dict[str, tuple[float, float, float]] = {}
        for name in {str(c) for c in cls[heads]}:
            size = table.get(name, lower.get(name.lower()))
            if size is None:
                unknown.append(name)
                size = table.get(UNKNOWN_CLASS, DEFAULT_CLASS_SIZES[UNKNOWN_CLASS])
            looked[name] = (float(size[0]), float(size[1]), float(size[2]))
        run = np.array([looked[str(c)] for c in cls[heads]], np.float64).reshape(-1, 3)
        out = np.repeat(run, np.diff(np.r_[heads, n]), axis=0)
    if own is not None and n:
        own = np.asarray(own, np.float64).reshape(n, -1)
        k = min(3, own.shape[1])
        have = np.isfinite(own[:, :k])
        out[:, :k][have] = own[:, :k][have]
    return out, sorted(unknown)


@dataclass
class ClassSpec:
    id: int
    name: str
    default_height: float  # metres: the height of the normal position above the ground (3.2)


@dataclass
class Scene:
    """A scene folder in memory (masks and truth stay on disk and are streamed)."""

    root: Path
    name: str
    fps: float
    rig: Rig
    ground_points: np.ndarray  # (n, 3) metres
    classes: list[ClassSpec]
    splits: dict[str, tuple[int, int]] = field(default_factory=dict)
    extra: dict = field(default_factory=dict)
    ground_file: str = "ground_points.csv"
    start_time: str | None = None  # ISO 8601 time of frame 0 with its zone (see parse_start_time)
    videos: dict = field(default_factory=dict)  # camera -> its video file or image folder, relative

    def __post_init__(self) -> None:
        self.ground = GroundSurface(self.ground_points, file=self.root / self.ground_file)

    # --- lookups --------------------------------------------------------------------------------
    @property
    def cameras(self) -> dict[str, Camera]:
        return self.rig.cameras

    def class_by_id(self) -> dict[int, ClassSpec]:
        return {c.id: c for c in self.classes}

    @property
    def class_names(self) -> list[str]:
        return [c.name for c in self.classes]

    def class_names_by_id(self) -> dict[int, str]:
        return {c.id: c.name for c in self.classes}

    def default_heights(self) -> dict[str, float]:
        """Class name -> default height, metres (paper 3.2)."""
        return {c.name: c.default_height for c in self.classes}

    def class_sizes(self) -> dict[str, tuple[float, float, float]]:
        """Class name -> typical (l, w, h) metres: extra['class_sizes'] over the defaults."""
        sizes = dict(DEFAULT_CLASS_SIZES)
        extra = self.extra.get("class_sizes") or {}
        if not isinstance(extra, dict):
            raise InputError("expected an object of class name -> [l, w, h]",
                             file=self.root / SCENE_FILE, field="extra.class_sizes")
        for k, v in extra.items():
            f = f"extra.class_sizes.{k}"
            if not isinstance(v, list) or len(v) != 3:
                raise InputError("expected [l, w, h] numbers (metres)", file=self.root / SCENE_FILE, field=f)
            l, w, h = (number(x, file=self.root / SCENE_FILE, field=f, lo=0, lo_open=True, hi=1000.0) for x in v)
            sizes[str(k)] = (l, w, h)
        return sizes

    def road_user_sizes(self, cls, own: np.ndarray | None = None) -> tuple[np.ndarray, list[str]]:
        """(N, 3) l, w, h metres of rows of classes ``cls`` (N,) and the classes without a typical
        size: the rows' ``own`` sizes where finite, else this scene's class sizes
        (module function ``road_user_sizes``)."""
        return road_user_sizes(cls, own, self.class_sizes())

    def masks_path(self, camera: str) -> Path:
        return self.root / "masks" / f"{camera}.txt"

    def iter_masks(self, camera: str, frame_range: tuple[int, int] | None = None,
                   check_rles: bool = True):
        """Stream a camera's masks (``masks/<camera>.txt``) frame by frame, checked against the
        scene's class ids and the camera's image size: (frame, MaskTable) pairs."""
        cam = self.cameras[camera]
        return iter_mots(self.masks_path(camera), [c.id for c in self.classes], frame_range,
                         check_rles=check_rles, image_size=(cam.height, cam.width))

    def read_masks(self, camera: str, frame_range: tuple[int, int] | None = None):
        """A camera's masks as one MaskTable (checked like ``iter_masks``; an empty table of
        the camera's size when the file has no detections)."""
        tables = [t for _, t in self.iter_masks(camera, frame_range)]
        if not tables:
            cam = self.cameras[camera]
            return MaskTable.empty(cam.height, cam.width)
        return MaskTable.concat(tables)

    def video_path(self, camera: str) -> Path | None:
        """The camera's video file or image folder, when present: the one scene.json names
        (``videos``), else (older scenes) video/<camera>.mp4, an image folder video/<camera>,
        .avi, .mkv, .mov in that order."""
        if camera in self.videos:
            p = self.root / self.videos[camera]
            return p if p.exists() else None
        for cand in (self.root / "video" / f"{camera}.mp4", self.root / "video" / camera,
                     *(self.root / "video" / f"{camera}{e}" for e in (".avi", ".mkv", ".mov"))):
            if cand.exists():
                return cand
        return None

    @property
    def start_time_ns(self) -> int | None:
        """UTC time of frame 0, nanoseconds since the Unix epoch (None: unknown)."""
        return None if self.start_time is None else parse_start_time(self.start_time)

    @property
    def gt_path(self) -> Path:
        return self.root / "gt" / "poses.csv"

    def split_range(self, split: str | None) -> tuple[int, int] | None:
        """(first, last) frame, inclusive, of a named split; None = all frames."""
        if split is None or split == "all":
            return None
        if split not in self.splits:
            raise InputError(f"scene has no split {split!r}; known: {sorted(self.splits)}",
                             file=self.root / SCENE_FILE, field="splits")
        return self.splits[split]

    def fingerprint(self) -> str:
        """A short hash of the calibration and ground points: checkpoints record it so that
        a model trained on another scene is noticed."""
        d = {"cameras": [c.to_dict() for c in self.cameras.values()],
             "ground": np.round(self.ground_points, 6).tolist()}
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]

    def cameras_fingerprint(self) -> str:
        """A short hash of the calibration alone: what a model made for a camera device rather
        than for one scene (the demo's shipped models) records, so that another device's
        cameras are noticed while another scene of the same device is not."""
        d = {"cameras": [c.to_dict() for c in self.cameras.values()]}
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]

    # --- serialisation ---------------------------------------------------------------------------
    def to_dict(self) -> dict:
        d = {"version": SCENE_VERSION, "name": self.name, "fps": self.fps,
             "ground_points": self.ground_file,
             "classes": [{"id": c.id, "name": c.name, "default_height": c.default_height}
                         for c in self.classes],
             "rig": self.rig.name,
             "cameras": [c.to_dict() for c in self.cameras.values()],
             "configs": self.rig.configs}
        if self.splits:
            d["splits"] = {k: list(v) for k, v in self.splits.items()}
        if self.start_time is not None:
            d["start_time"] = self.start_time
        if self.videos:
            d["videos"] = dict(self.videos)
        if self.extra:
            d["extra"] = self.extra
        return d

    def save(self, root: str | Path | None = None) -> None:
        """Write scene.json and the ground points into ``root`` as one set (``atomic.outputs``),
        read back by ``load_scene`` first: what the reader would refuse (fps 0 or nan, two
        ground points, ...) is refused with the reader's message, and nothing is written."""
        root = Path(root) if root is not None else self.root
        try:
            text = json.dumps(self.to_dict(), indent=1, allow_nan=False) + "\n"
        except ValueError:
            raise InputError(f"cannot write a scene with fps {self.fps!r} or another value that is "
                             "not a finite number", file=root / SCENE_FILE) from None
        with outputs([root / SCENE_FILE, root / self.ground_file], force=True) as out:
            write_new_text(sj := out.file(root / SCENE_FILE), text)
            g = sj.parent / self.ground_file
            g.parent.mkdir(parents=True, exist_ok=True)
            write_new_text(g, ground_points_text(self.ground_points))
            out.adopt(root / self.ground_file, g)
            try:
                load_scene(sj.parent)
            except InputError as e:
                f = SCENE_FILE if e.file is None or Path(e.file).name == SCENE_FILE else self.ground_file
                raise InputError(f"this scene would not be readable: {e.message}", file=root / f,
                                 field=e.field, line=e.line) from None


def read_ground_points(path: str | Path) -> np.ndarray:
    """Ground points CSV: ``x,y,z`` per line (metres), an optional header line."""
    path = Path(path)
    text = read_text(path, "ground points file")
    reader = csv.reader(io.StringIO(text))
    try:
        pts, lines = _parse_ground_points(reader, path)
    except csv.Error as e:
        raise InputError(f"malformed CSV: {e}", file=path, line=reader.line_num) from None
    try:
        GroundSurface(pts, file=path)  # validates count and duplicates
    except InputError as e:
        if e.line is None or not lines:
            raise
        # GroundSurface numbers points from 1; report the file's line instead
        raise InputError(e.message, file=path, line=lines[e.line - 1]) from None
    return pts


def _parse_ground_points(reader, path: Path) -> tuple[np.ndarray, list[int]]:
    """Rows (n, 3) metres and their line numbers (n,)."""
    rows: list[list[float]] = []
    lines: list[int] = []
    for row in reader:
        i = reader.line_num
        if not row or all(not c.strip() for c in row):
            continue
        if not rows and row[0].strip().lower() in ("x", "#x"):
            continue  # header
        if len(row) != 3:
            raise InputError(f"expected 3 fields x,y,z, got {len(row)}", file=path, line=i)
        try:
            v = [float(c) for c in row]
        except ValueError:
            raise InputError(f"expected numbers x,y,z, got {row}", file=path, line=i) from None
        if not np.all(np.isfinite(v)):
            raise InputError("NaN or inf in ground point", file=path, line=i)
        if max(abs(x) for x in v) > MAX_COORD:
            raise InputError(f"ground point {v} is more than {MAX_COORD:g} m from the origin; "
                             "expected metres within +-1e6", file=path, line=i)
        rows.append(v)
        lines.append(i)
    return np.array(rows, dtype=np.float64).reshape(-1, 3), lines


def ground_points_text(points: np.ndarray) -> str:
    buf = io.StringIO()
    buf.write("x,y,z\n")
    for x, y, z in np.asarray(points, float).tolist():  # Python floats: repr is a plain number
        buf.write(f"{x!r},{y!r},{z!r}\n")
    return buf.getvalue()


def write_ground_points(path: str | Path, points: np.ndarray) -> None:
    atomic_write_text(path, ground_points_text(points))


def _req(d: dict, key: str, file: Path, where: str = ""):
    if not isinstance(d, dict) or key not in d:
        raise InputError(f"missing field '{where}{key}'", file=file, field=f"{where}{key}")
    return d[key]


def load_scene(root: str | Path) -> Scene:
    """Read and validate a scene folder (or a path to its scene.json)."""
    root = Path(root)
    if root.name == SCENE_FILE:
        root = root.parent
    path = root / SCENE_FILE
    if not path.exists():
        raise InputError(f"no {SCENE_FILE} here (is this a scene folder?)", file=path)
    d = load_json(path)
    if not isinstance(d, dict):
        raise InputError("expected a JSON object", file=path)
    version = _req(d, "version", path)
    if version != SCENE_VERSION:
        raise InputError(f"unsupported version {version!r}; this s2p reads version {SCENE_VERSION}",
                         file=path, field="version")
    fps = number(_req(d, "fps", path), file=path, field="fps", lo=FPS_RANGE[0], hi=FPS_RANGE[1])
    cams_d = _req(d, "cameras", path)
    if not isinstance(cams_d, list) or not cams_d:
        raise InputError("expected a non-empty list of cameras", file=path, field="cameras")
    cameras: dict[str, Camera] = {}
    for i, cd in enumerate(cams_d):
        if not isinstance(cd, dict):
            raise InputError("expected an object", file=path, field=f"cameras[{i}]")
        cam = Camera.from_dict(cd, file=path, where=f"cameras[{i}]")
        if cam.name in cameras:
            raise InputError(f"duplicate camera name {cam.name!r}", file=path, field=f"cameras[{i}].name")
        cameras[cam.name] = cam
    configs = d.get("configs") or {}
    if not isinstance(configs, dict) or not all(isinstance(v, list) for v in configs.values()):
        raise InputError("expected an object of name -> list of camera names", file=path, field="configs")
    for k, v in configs.items():
        safe_name(k, file=path, field=f"configs.{k}", what="configuration name")
        for j, n in enumerate(v):
            if not isinstance(n, str):
                raise InputError(f"expected a camera name, got {n!r}", file=path,
                                 field=f"configs.{k}[{j}]")
    try:
        rig = Rig(cameras=cameras, configs={k: [str(n) for n in v] for k, v in configs.items()},
                  name=str(d.get("rig", "rig")))
    except InputError as e:
        raise InputError(e.message, file=path, field=e.field) from None
    classes = []
    classes_d = d.get("classes") or DEFAULT_CLASSES
    if not isinstance(classes_d, list):
        raise InputError("expected a list of {id, name, default_height}", file=path, field="classes")
    for i, c in enumerate(classes_d):
        if not isinstance(c, dict):
            raise InputError("expected an object {id, name, default_height}", file=path,
                             field=f"classes[{i}]")
        cs = ClassSpec(id=integer(_req(c, "id", path, f"classes[{i}]."), file=path,
                                  field=f"classes[{i}].id", lo=1, hi=MAX_CLASS_ID),
                       name=safe_name(_req(c, "name", path, f"classes[{i}]."), file=path,
                                      field=f"classes[{i}].name", what="class name"),
                       default_height=number(c.get("default_height", 0.9), file=path,
                                             field=f"classes[{i}].default_height", lo=0,
                                             hi=MAX_DEFAULT_HEIGHT))
        classes.append(cs)
    if len({c.id for c in classes}) != len(classes) or len({c.name for c in classes}) != len(classes):
        raise InputError("class ids and names must be unique", file=path, field="classes")
    splits = {}
    splits_d = d.get("splits") or {}
    if not isinstance(splits_d, dict):
        raise InputError("expected an object of name -> [first, last]", file=path, field="splits")
    for k, v in splits_d.items():
        if not (isinstance(v, list) and len(v) == 2
                and all(isinstance(x, int) and not isinstance(x, bool) and 0 <= x < MAX_ID for x in v)
                and v[0] <= v[1]):
            raise InputError("expected [first, last] frame numbers, 0 <= first <= last", file=path,
                             field=f"splits.{k}")
        splits[k] = (v[0], v[1])
    gfile = d.get("ground_points", "ground_points.csv")
    gpath = inside(root, gfile, file=path, field="ground_points", what="ground points file")
    if gpath == path:
        raise InputError(f"the ground points cannot be in {SCENE_FILE}", file=path, field="ground_points")
    extra = d.get("extra") or {}
    if not isinstance(extra, dict):
        raise InputError("expected an object", file=path, field="extra")
    start = d.get("start_time")
    if start is not None:
        parse_start_time(start, file=path, field="start_time")
    videos = d.get("videos") or {}
    if not isinstance(videos, dict):
        raise InputError("expected an object of camera name -> video file", file=path, field="videos")
    for k, v in videos.items():
        if k not in cameras:
            raise InputError(f"no camera {k!r} in the scene", file=path, field=f"videos.{k}")
        inside(root, v, file=path, field=f"videos.{k}", what="video file")
    pts = read_ground_points(gpath)
    return Scene(root=root, name=str(d.get("name", root.name)), fps=float(fps), rig=rig,
                 ground_points=pts, classes=classes, splits=splits,
                 extra=extra, ground_file=gfile, start_time=start, videos=dict(videos))


def parse_start_time(text, file: str | Path | None = None, field: str | None = None) -> int:
    """An ISO 8601 time with its zone (``2021-06-14T08:00:00Z``, ``...+02:00``) -> UTC
    nanoseconds since the Unix epoch. A time without a zone is refused: it would be read
    differently on another machine."""
    import datetime as dt

    want = "expected an ISO 8601 time with a zone, e.g. 2021-06-14T08:00:00Z"
    if not isinstance(text, str):
        raise InputError(f"{want}, got {text!r}", file=file, field=field)
    try:
        t = dt.datetime.fromisoformat(text.strip())
    except ValueError:
        raise InputError(f"{want}, got {text!r}", file=file, field=field) from None
    if t.tzinfo is None:
        raise InputError(f"{want} (no zone in {text!r})", file=file, field=field)
    delta = t - dt.datetime(1970, 1, 1, tzinfo=dt.UTC)
    ns = (delta.days * 86400 + delta.seconds) * 10**9 + delta.microseconds * 1000
    if not 0 <= ns < MAX_START_NS:
        raise InputError(f"expected a time from 1970 to 2199 (MCAP and Rerun count unsigned / "
                         f"signed 64-bit ns from 1970), got {text!r}", file=file, field=field)
    return ns


MAX_START_NS = 7_258_118_400 * 10**9  # 2200-01-01Z: 62 years below Rerun's end (2262-04-11)
