"""The schema of a scene folder's own files, in the language of ``io/schema.py``: scene.json
(``scene_schema``, checked whole by ``scene_fields``) and the ground points file
(``GROUND_POINT``, ``check_ground_points``, read by ``ground_points_from_text``).

``io.scene.load_scene`` reads a folder through these, and every writer of the files checks what
it is about to write against the same declarations first (``writable_scene``,
``check_ground_points``), so that no writer produces what the reader refuses: ``Scene.save``
(s2p new-scene, import-tacal, import-utocs, synth, heights --write), ``ground_points_text``
(calibrate-camera's ground points, ``write_ground_points``), ``calib_files.write_scene_version`` (calibrate-camera's
new scene version) and import-mcap's restore (its attachments and the restored videos).

scene.json, version 1 (``io/scene.py`` shows one): ``version`` 1; ``fps`` in [0.001, 1e6];
``cameras`` a non-empty list, each as ``Camera.from_dict`` reads it (a name safe in a file
name, width and height integers in [1, 2^20] pixels, K/R/t or P finite, R a rotation, K's
focal lengths positive, distortion parameters within +-1e6), names unique; ``configs`` name ->
camera names of the scene; ``classes`` (default: pedestrian, bicyclist, car) with ids in [1,
65535], names safe in a file name, default heights in [0, 20] metres (default 0.9), ids and
names unique (an empty list or none: the defaults; ``Scene`` holds them then too);
``splits`` name -> [first, last] frames, 0 <= first <= last < 2^62; ``ground_points`` a file
inside the folder, not scene.json; ``start_time`` an ISO 8601 time with its zone from 1970 to
2199 (what MCAP and Rerun can time); ``videos`` camera -> a path inside the folder;
``extra.class_sizes`` class name -> [l, w, h] metres in (0, 1000]. Other keys pass.

The ground points file: ``x,y,z`` per line (metres, an optional header line), at least 3
points, each finite and within +-1e6 m, no point twice.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

from seg2pose.core.errors import InputError
from seg2pose.core.validate import FPS_RANGE, MAX_COORD, MAX_ID, inside, integer, number
from seg2pose.geometry.camera import Camera, Rig
from seg2pose.io.schema import DictOf, Fn, ListOf, Name, Num, Opt, Record, Text, check

SCENE_FILE = "scene.json"
SCENE_VERSION = 1
MAX_CLASS_ID = 65535
MAX_DEFAULT_HEIGHT = 20.0  # metres above the ground
MAX_CLASS_SIZE = 1000.0  # metres: a class's typical l, w, h
MIN_GROUND_POINTS = 3
DEFAULT_GROUND_FILE = "ground_points.csv"
DEFAULT_HEIGHT = 0.9  # metres: a class without its own default height
DEFAULT_CLASSES: list[dict] = [
    {"id": 1, "name": "pedestrian", "default_height": 0.9},
    {"id": 2, "name": "bicyclist", "default_height": 0.9},
    {"id": 3, "name": "car", "default_height": 0.75},
]
GROUND_POINT = Num(-MAX_COORD, MAX_COORD, unit="metres")  # x, y, z of a ground point
MAX_START_NS = 7_258_118_400 * 10**9  # 2200-01-01Z: 62 years below Rerun's end (2262-04-11)


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


# --- scene.json ------------------------------------------------------------------------------------
def _version(v, *, file=None, field=None) -> int:
    if v != SCENE_VERSION or isinstance(v, bool):
        raise InputError(f"unsupported version {v!r}; this s2p reads version {SCENE_VERSION}",
                         file=file, field=field)
    return v


def _camera(v, *, file=None, field=None) -> Camera:
    if not isinstance(v, dict):
        raise InputError("expected an object", file=file, field=field)
    return Camera.from_dict(v, file=file, where=field or "camera")


def _split(v, *, file=None, field=None) -> tuple[int, int]:
    if not (isinstance(v, list) and len(v) == 2
            and all(isinstance(x, int) and not isinstance(x, bool) and 0 <= x < MAX_ID for x in v)
            and v[0] <= v[1]):
        raise InputError("expected [first, last] frame numbers, 0 <= first <= last", file=file,
                         field=field)
    return v[0], v[1]


def _size(v, *, file=None, field=None) -> tuple[float, float, float]:
    """A class's typical [l, w, h], metres (the whole list named by ``field``)."""
    if not isinstance(v, list) or len(v) != 3:
        raise InputError("expected [l, w, h] numbers (metres)", file=file, field=field)
    l, w, h = (number(x, file=file, field=field, lo=0, lo_open=True, hi=MAX_CLASS_SIZE) for x in v)
    return l, w, h


def _path_in(root: Path, what: str):
    """A path relative to ``root`` that stays inside it (``core.validate.inside``), kept as written."""
    def fn(v, *, file=None, field=None) -> str:
        inside(root, v, file=file, field=field, what=what)
        return v
    return Fn(fn)


CLASS = Record({"id": Fn(partial(integer, lo=1, hi=MAX_CLASS_ID)),
                "name": Name("class name"),
                "default_height": Opt(Fn(partial(number, lo=0, hi=MAX_DEFAULT_HEIGHT)))},
               what="an object {id, name, default_height}")
CLASSES = ListOf(CLASS, what="a list of {id, name, default_height}")
CLASS_SIZES = DictOf(Fn(_size), what="an object of class name -> [l, w, h]")
SPLITS = DictOf(Fn(_split), what="an object of name -> [first, last]")
CONFIGS = DictOf(ListOf(Name("camera name"), what="a list of camera names"), key=Name("configuration name"),
                 what="an object of name -> list of camera names")


def scene_schema(root: str | Path) -> Record:
    """scene.json's declaration for the scene folder ``root`` (its paths must stay inside it)."""
    root = Path(root)
    return Record({
        "version": Fn(_version),
        "fps": Fn(partial(number, lo=FPS_RANGE[0], hi=FPS_RANGE[1])),
        "cameras": ListOf(Fn(_camera), min_len=1, what="a non-empty list of cameras"),
        "configs": Opt(CONFIGS),
        "classes": Opt(CLASSES),
        "splits": Opt(SPLITS),
        "ground_points": Opt(_path_in(root, "ground points file")),
        "extra": Opt(Record({"class_sizes": Opt(CLASS_SIZES)})),
        "start_time": Opt(Fn(parse_start_time)),
        "videos": Opt(DictOf(_path_in(root, "video file"),
                             what="an object of camera name -> video file")),
        "name": Opt(Text()), "rig": Opt(Text()),
    })


@dataclass
class SceneFields:
    """scene.json's fields as read (``scene_fields``)."""

    name: str | None
    fps: float
    rig: Rig
    classes: list[tuple[int, str, float]]  # id, name, default height (metres)
    splits: dict[str, tuple[int, int]]
    ground_file: str
    start_time: str | None
    videos: dict[str, str]
    extra: dict  # as the file holds it


def scene_fields(d, root: str | Path, file: str | Path | None = None) -> SceneFields:
    """scene.json's parsed object ``d`` of the scene folder ``root`` checked against
    ``scene_schema`` and the rules between its fields (camera names, class ids and names unique;
    configurations and videos name cameras of the scene; the ground points not scene.json):
    the reader's check and every writer's. Refused with one line naming ``file`` and the field."""
    root = Path(root)
    if not isinstance(d, dict):
        raise InputError("expected a JSON object", file=file)
    v = check(d, scene_schema(root), file=file)
    cameras: dict[str, Camera] = {}
    for i, cam in enumerate(v["cameras"]):
        if cam.name in cameras:
            raise InputError(f"duplicate camera name {cam.name!r}", file=file, field=f"cameras[{i}].name")
        cameras[cam.name] = cam
    try:
        rig = Rig(cameras=cameras, configs=v["configs"] or {}, name="rig" if v["rig"] is None else v["rig"])
    except InputError as e:
        raise InputError(e.message, file=file, field=e.field) from None
    classes = [(c["id"], c["name"], DEFAULT_HEIGHT if c["default_height"] is None else c["default_height"])
               for c in v["classes"] or DEFAULT_CLASSES]
    if len({c[0] for c in classes}) != len(classes) or len({c[1] for c in classes}) != len(classes):
        raise InputError("class ids and names must be unique", file=file, field="classes")
    gfile = DEFAULT_GROUND_FILE if v["ground_points"] is None else v["ground_points"]
    if inside(root, gfile) == root / SCENE_FILE:
        raise InputError(f"the ground points cannot be in {SCENE_FILE}", file=file, field="ground_points")
    videos = v["videos"] or {}
    for k in videos:
        if k not in cameras:
            raise InputError(f"no camera {k!r} in the scene", file=file, field=f"videos.{k}")
    return SceneFields(name=v["name"], fps=float(v["fps"]), rig=rig, classes=classes,
                       splits=v["splits"] or {}, ground_file=gfile, start_time=d.get("start_time"),
                       videos=dict(videos), extra=d.get("extra") or {})


def writable_scene(d: dict, root: str | Path, file: str | Path) -> None:
    """What a writer checks before it writes scene.json ``d`` into ``root``: ``scene_fields``,
    the reader's check, its refusal said as the writer's (one line naming ``file`` and the
    field; nothing is written)."""
    try:
        scene_fields(d, root, file)
    except InputError as e:
        raise InputError(f"this scene would not be readable: {e.message}", file=file,
                         field=e.field, line=e.line) from None


# --- the ground points file ---------------------------------------------------------------------
def check_ground_points(points, *, file=None, lines=None) -> np.ndarray:
    """Ground points (n, 3) metres checked as the file's reader checks them (the writers before
    writing): at least MIN_GROUND_POINTS, each finite and within +-MAX_COORD, no point twice.
    ``lines``: (n,) the file's line of each point (else a point is named by its number, from 1).
    Returns the points as an (n, 3) float array."""
    def where(i: int) -> dict:
        return {"line": int(lines[i])} if lines is not None else {"field": f"point {i + 1}"}

    try:
        pts = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError("expected ground points x,y,z (numbers, metres)", file=file) from None
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InputError(f"ground points must be (n, 3), got {pts.shape}", file=file)
    good = GROUND_POINT.ok(pts)
    if not good.all():
        i = int(np.argmin(good))
        _refuse_point(pts[i], file, where(i))
    if len(pts) < MIN_GROUND_POINTS:
        raise InputError(f"need at least {MIN_GROUND_POINTS} ground points, got {len(pts)}", file=file)
    _, idx, counts = np.unique(pts, axis=0, return_index=True, return_counts=True)
    if np.any(counts > 1):
        i = int(idx[np.argmax(counts > 1)])
        raise InputError(f"duplicate ground point {pts[i].tolist()}", file=file, **where(i))
    return pts


def _refuse_point(p: np.ndarray, file, where: dict) -> None:
    """The one-line refusal of a ground point outside ``GROUND_POINT``."""
    if not np.isfinite(p).all():
        raise InputError("NaN or inf in ground point", file=file, **where)
    raise InputError(f"ground point {p.tolist()} is more than {MAX_COORD:g} m from the origin; "
                     f"expected metres within +-{MAX_COORD:g}", file=file, **where)


def ground_points_from_text(text: str, file=None) -> np.ndarray:
    """The ground points file's text -> (n, 3) metres, checked (``check_ground_points``)."""
    reader = csv.reader(io.StringIO(text))
    rows: list[list[float]] = []
    lines: list[int] = []
    try:
        for row in reader:
            i = reader.line_num
            if not row or all(not c.strip() for c in row):
                continue
            if not rows and row[0].strip().lower() in ("x", "#x"):
                continue  # header
            if len(row) != 3:
                raise InputError(f"expected 3 fields x,y,z, got {len(row)}", file=file, line=i)
            try:
                v = [float(c) for c in row]
            except ValueError:
                raise InputError(f"expected numbers x,y,z, got {row}", file=file, line=i) from None
            if not GROUND_POINT.ok(np.array([v]))[0]:  # refused at its line, before a later bad row
                _refuse_point(np.array(v), file, {"line": i})
            rows.append(v)
            lines.append(i)
    except csv.Error as e:
        raise InputError(f"malformed CSV: {e}", file=file, line=reader.line_num) from None
    return check_ground_points(np.array(rows, dtype=np.float64).reshape(-1, 3), file=file, lines=lines)


def ground_points_text(points, file=None) -> str:
    """The ground points file's text (a header, then ``x,y,z`` per point, each number as Python
    writes it: read back exactly), refused as the reader would refuse it (``check_ground_points``)."""
    pts = check_ground_points(points, file=file)
    buf = io.StringIO()
    buf.write("x,y,z\n")
    for x, y, z in pts.tolist():  # Python floats: repr is a plain number
        buf.write(f"{x!r},{y!r},{z!r}\n")
    return buf.getvalue()
