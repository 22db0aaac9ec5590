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

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from seg2pose.core.errors import InputError
from seg2pose.geometry.camera import Camera, Rig
from seg2pose.geometry.ground import GroundSurface
from seg2pose.io.atomic import atomic_write_text, outputs
from seg2pose.io.mots import MaskTable, iter_mots
from seg2pose.io.nofollow import write_new_text
from seg2pose.io.scene_schema import (  # noqa: F401 (re-exported: the scene folder's names)
    CLASS_SIZES,
    DEFAULT_CLASSES,
    MAX_CLASS_ID,
    MAX_DEFAULT_HEIGHT,
    MAX_START_NS,
    SCENE_FILE,
    SCENE_VERSION,
    check_ground_points,
    ground_points_from_text,
    ground_points_text,
    parse_start_time,
    scene_fields,
    writable_scene,
)
from seg2pose.io.schema import check
from seg2pose.io.text import load_json, read_text

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
        if not self.classes:  # as scene.json's reader reads no classes: the written scene reads back equal
            self.classes = [ClassSpec(**c) for c in DEFAULT_CLASSES]

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
        own = check(self.extra.get("class_sizes") or {}, CLASS_SIZES, file=self.root / SCENE_FILE,
                    field="extra.class_sizes")
        sizes.update({str(k): v for k, v in own.items()})
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
                         for c in self.classes or [ClassSpec(**c) for c in DEFAULT_CLASSES]],
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

    def check(self, root: str | Path | None = None) -> tuple[str, str]:
        """The texts of scene.json and of the ground points file that ``save`` would write into
        ``root`` (default: the scene's folder), checked first with the reader's schema
        (``scene_schema``): what ``load_scene`` would refuse (fps 0 or nan, a camera named
        '../x', two ground points, ...) is refused in one line naming the file and the field."""
        root = Path(root) if root is not None else self.root
        d = self.to_dict()
        try:  # NaN passes here: the schema refuses it naming its field (fps, cameras[c0].K, ...)
            writable_scene(json.loads(json.dumps(d)), root, root / SCENE_FILE)
            text = json.dumps(d, indent=1, allow_nan=False) + "\n"
        except TypeError as e:
            raise InputError(f"cannot write a value that is not JSON ({e})", file=root / SCENE_FILE) from None
        except ValueError as e:  # (not InputError: the schema passed) NaN or inf where it is free-form
            if isinstance(e, InputError):
                raise
            raise InputError(f"cannot write a number that is not finite ({e})", file=root / SCENE_FILE,
                             field="extra") from None
        try:
            ground = ground_points_text(self.ground_points, file=root / self.ground_file)
        except InputError as e:
            raise InputError(f"these ground points would not be readable: {e.message}", file=e.file,
                             field=e.field) from None
        return text, ground

    def save(self, root: str | Path | None = None) -> None:
        """Write scene.json and the ground points into ``root`` as one set (``atomic.outputs``),
        checked first (``check``): what the reader would refuse is refused with the reader's
        message, and nothing is written."""
        root = Path(root) if root is not None else self.root
        text, ground = self.check(root)
        with outputs([root / SCENE_FILE, root / self.ground_file], force=True) as out:
            write_new_text(sj := out.file(root / SCENE_FILE), text)
            g = sj.parent / self.ground_file
            g.parent.mkdir(parents=True, exist_ok=True)
            write_new_text(g, ground)
            out.adopt(root / self.ground_file, g)


def read_ground_points(path: str | Path) -> np.ndarray:
    """Ground points CSV: ``x,y,z`` per line (metres), an optional header line; checked as
    ``scene_schema.check_ground_points`` declares."""
    path = Path(path)
    return ground_points_from_text(read_text(path, "ground points file"), file=path)


def write_ground_points(path: str | Path, points: np.ndarray) -> None:
    """The ground points file, refused (nothing written) where the reader would refuse it."""
    atomic_write_text(path, ground_points_text(points, file=path))


def load_scene(root: str | Path) -> Scene:
    """Read and validate a scene folder (or a path to its scene.json): scene.json and the ground
    points checked against their schema (``io/scene_schema.py``), which every writer of them
    checks too."""
    root = Path(root)
    if root.name == SCENE_FILE:
        root = root.parent
    path = root / SCENE_FILE
    if not path.exists():
        raise InputError(f"no {SCENE_FILE} here (is this a scene folder?)", file=path)
    f = scene_fields(load_json(path), root, path)
    pts = read_ground_points(root / f.ground_file)
    return Scene(root=root, name=root.name if f.name is None else f.name, fps=f.fps, rig=f.rig,
                 ground_points=pts, classes=[ClassSpec(*c) for c in f.classes], splits=f.splits,
                 extra=f.extra, ground_file=f.ground_file, start_time=f.start_time, videos=f.videos)
