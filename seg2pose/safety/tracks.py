"""Road-user tracks for safety analysis: read from a run folder, a ``poses.csv`` or a T-Analyst
CSV, with every road user's footprint size filled in and the rows ordered track by track.

``Tracks`` holds N rows sorted by (track_id, frame): t = frame / fps seconds, position on the
ground (x, y metres), heading (radians, counter-clockwise from +x; NaN = unknown), footprint
length and width (metres) and, where the poses carry one, ``r90_m``: the radius (metres) within
which the true position lies with 90 % probability.

Input validation is the readers' (``seg2pose.io``): a bad row is one line naming the file and
line. ``poses.csv`` may carry an extra last column ``r90_m`` (the reader of
``seg2pose.io.poses`` knows the columns without it; this module takes it off and checks it).
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seg2pose.core.errors import InputError
from seg2pose.core.validate import FPS_RANGE
from seg2pose.io.poses import PoseTable, parse_poses
from seg2pose.io.tanalyst import TYPE_TO_CLASS, read_tanalyst, times_to_frames
from seg2pose.io.text import read_text

R90_COLUMN = "r90_m"
# typical footprints (length, width, metres) where a row gives none: a mid-size car, an adult
# walking (shoulders and stride), a bicycle with rider, a rigid truck, a city bus
CLASS_SIZES = {"car": (4.4, 1.8), "pedestrian": (0.6, 0.6), "bicyclist": (1.8, 0.6),
               "truck": (8.0, 2.5), "bus": (12.0, 2.55), "motorcycle": (2.2, 0.8),
               "moped": (1.8, 0.7)}
UNKNOWN_SIZE = (4.4, 1.8)  # a class not in CLASS_SIZES: treated as a car (said in a note)


@dataclass
class Tracks:
    """N rows of road-user poses sorted by (track_id, frame). frame, track_id: (N,) int64;
    cls: (N,) str; t: (N,) seconds (frame / fps); xy: (N, 2) metres; heading: (N,) radians
    (NaN = unknown); size: (N, 2) footprint length, width in metres; r90: (N,) metres or None;
    fps: frames per second."""

    frame: np.ndarray
    track_id: np.ndarray
    cls: np.ndarray
    xy: np.ndarray
    heading: np.ndarray
    size: np.ndarray
    fps: float
    r90: np.ndarray | None = None

    def __post_init__(self) -> None:
        order = np.lexsort((self.frame, self.track_id))
        self.frame = np.asarray(self.frame, np.int64)[order]
        self.track_id = np.asarray(self.track_id, np.int64)[order]
        self.cls = np.asarray(self.cls, object)[order]
        self.xy = np.asarray(self.xy, np.float64).reshape(-1, 2)[order]
        self.heading = np.asarray(self.heading, np.float64)[order]
        self.size = np.asarray(self.size, np.float64).reshape(-1, 2)[order]
        if self.r90 is not None:
            self.r90 = np.asarray(self.r90, np.float64)[order]
        dup = (np.diff(self.track_id) == 0) & (np.diff(self.frame) == 0)
        if dup.any():
            i = int(np.flatnonzero(dup)[0])
            raise InputError(f"track {self.track_id[i]} appears twice in frame {self.frame[i]}")

    @property
    def t(self) -> np.ndarray:
        return self.frame / self.fps

    def __len__(self) -> int:
        return len(self.frame)

    def starts(self) -> np.ndarray:
        """(N,) index of the first row of each row's track (kept once computed: chunked
        searches ask for it once per chunk; treat it as read-only)."""
        c = self.__dict__.get("_starts")
        if c is None or len(c) != len(self):
            new = np.r_[True, self.track_id[1:] != self.track_id[:-1]]
            c = self.__dict__["_starts"] = np.maximum.accumulate(np.where(new, np.arange(len(self)), 0))
        return c

    def ends(self) -> np.ndarray:
        """(N,) index of the last row of each row's track (kept, as ``starts``)."""
        c = self.__dict__.get("_ends")
        if c is None or len(c) != len(self):
            n = len(self)
            last = np.r_[self.track_id[1:] != self.track_id[:-1], True]
            c = self.__dict__["_ends"] = np.minimum.accumulate(np.where(last, np.arange(n), n)[::-1])[::-1]
        return c

    def take(self, idx) -> "Tracks":
        return Tracks(self.frame[idx], self.track_id[idx], self.cls[idx], self.xy[idx],
                      self.heading[idx], self.size[idx], self.fps,
                      None if self.r90 is None else self.r90[idx])

    def with_xy(self, xy: np.ndarray) -> "Tracks":
        """The same rows at other positions (``xy`` (N, 2), in this table's row order)."""
        out = self.take(slice(None))
        out.xy = np.asarray(xy, np.float64).reshape(-1, 2)
        return out


def class_sizes(cls: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """(N,) class names -> (N, 2) typical length, width; and the classes not known (sized as
    cars)."""
    names = np.unique(cls.astype(str)) if len(cls) else np.zeros(0, str)
    table = {n: CLASS_SIZES.get(n.lower(), UNKNOWN_SIZE) for n in names}
    unknown = [n for n in names if n.lower() not in CLASS_SIZES]
    out = np.array([table[str(c)] for c in cls], np.float64).reshape(-1, 2)
    return out, unknown


def from_poses(poses: PoseTable, fps: float, r90: np.ndarray | None = None) -> tuple[Tracks, list[str]]:
    """A pose table -> Tracks (sizes from the rows, else the class's typical size) and notes."""
    notes = []
    size, unknown = class_sizes(poses.cls)
    if poses.size is not None:
        lw = poses.size[:, :2]
        have = np.isfinite(lw).all(axis=1)
        size[have] = lw[have]
    if unknown:
        notes.append(f"classes {', '.join(unknown)} have no typical size; rows without l, w are "
                     f"sized as cars ({UNKNOWN_SIZE[0]} x {UNKNOWN_SIZE[1]} m)")
    keep = poses.track_id >= 0  # negative ids: untracked detections
    if not keep.all():
        notes.append(f"{int((~keep).sum())} rows with a negative track id (untracked) left out")
    return Tracks(poses.frame[keep], poses.track_id[keep], poses.cls[keep], poses.xyz[keep, :2],
                  poses.heading[keep], size[keep], check_fps(fps),
                  None if r90 is None else r90[keep]), notes


def check_fps(fps) -> float:
    if fps is None or not (isinstance(fps, (int, float)) and math.isfinite(fps)
                           and FPS_RANGE[0] <= fps <= FPS_RANGE[1]):
        raise InputError(f"expected frames per second in [{FPS_RANGE[0]:g}, {FPS_RANGE[1]:g}], "
                         f"got {fps!r}", field="fps")
    return float(fps)


def read_poses_r90(path: Path) -> tuple[PoseTable, np.ndarray | None]:
    """A pose CSV with an optional last column ``r90_m`` (metres, >= 0, or nan for unknown)."""
    text = read_text(path, "pose file")
    rows = list(csv.reader(io.StringIO(text)))
    header = [h.strip() for h in rows[0]] if rows else []
    if header[-1:] != [R90_COLUMN]:
        r = csv.reader(io.StringIO(text))
        try:
            return parse_poses(r, path, None), None
        except csv.Error as e:
            raise InputError(f"malformed CSV: {e}", file=path, line=r.line_num) from None
    r90 = []
    for lineno, row in enumerate(rows[1:], start=2):
        if not row:
            continue
        if len(row) != len(header):
            raise InputError(f"expected {len(header)} fields, got {len(row)}", file=path, line=lineno)
        try:
            v = float(row[-1])
        except ValueError:
            v = -1.0
        if not (math.isnan(v) or 0 <= v <= 1000):
            raise InputError(f"r90_m must be metres in [0, 1000] (or nan), got {row[-1]!r}",
                             file=path, line=lineno, field=R90_COLUMN)
        r90.append(v)
    rest = io.StringIO()
    csv.writer(rest, lineterminator="\n").writerows([r[:-1] for r in rows if r])
    # line numbers stay right: blank lines were dropped only where the reader skips them anyway
    return parse_poses(csv.reader(io.StringIO(rest.getvalue())), path, None), np.array(r90, float)


def _scene_fps(scene_dir: Path) -> float | None:
    p = scene_dir / "scene.json"
    if not p.exists():
        return None
    try:
        return float(json.loads(p.read_text(encoding="utf-8"))["fps"])
    except (ValueError, KeyError, TypeError):
        raise InputError("expected a JSON object with a number 'fps'", file=p) from None


def find_fps(path: Path) -> float | None:
    """The frame rate of the scene a pose file or run folder belongs to, when it can be found:
    RUN/run.json's scene, or the scene folder around SCENE/gt/poses.csv."""
    run_dir = path if path.is_dir() else path.parent
    meta = run_dir / "run.json"
    if meta.exists():
        try:
            scene = json.loads(meta.read_text(encoding="utf-8")).get("scene")
        except (ValueError, AttributeError):
            raise InputError("invalid JSON", file=meta) from None
        if isinstance(scene, str):
            return _scene_fps((run_dir / scene).resolve())
    if path.is_file() and path.parent.name == "gt":
        return _scene_fps(path.parent.parent)
    return None


def is_tanalyst(path: Path) -> bool:
    if not path.is_file():
        return False
    with open(path, "rb") as f:
        head = f.readline().decode("utf-8", "replace").lstrip("\ufeff")
    return head.startswith("Detection ID;")


def load_tracks(path: str | Path, fps: float | None = None, start_ms: int = 0) -> tuple[Tracks, list[str]]:
    """Tracks from ``path``: a run folder (RUN/poses.csv), a pose CSV (optionally with r90_m)
    or a T-Analyst tracks CSV (positions only: headings from motion, sizes by class). ``fps``:
    needed where no scene says it (a pose CSV outside a run or scene, a T-Analyst file);
    ``start_ms``: a T-Analyst file's time of frame 0. Returns the tracks and notes."""
    path = Path(path)
    if not path.exists():
        raise InputError("tracks not found (expected a run folder, a poses.csv or a T-Analyst CSV)",
                         file=path)
    if is_tanalyst(path):
        if fps is None:
            raise InputError("a T-Analyst file has times, not frames: pass --fps", file=path)
        ta = read_tanalyst(path)
        frames = times_to_frames(ta, check_fps(fps), start_ms, file=path)
        cls = np.array([TYPE_TO_CLASS.get(str(x).lower(), str(x).lower())
                        for x in ta.road_user_type], object)
        poses = PoseTable(frames, ta.road_user_id, cls, np.c_[ta.xy, np.zeros(len(ta))],
                          np.full(len(ta), np.nan))
        return from_poses(poses, fps)
    pose_file = path / "poses.csv" if path.is_dir() else path
    if path.is_dir() and not pose_file.exists():
        raise InputError("no poses.csv in this folder (expected a run folder made by `s2p run`)",
                         file=path)
    found = find_fps(path)
    if fps is None:
        fps = found
    if fps is None:
        raise InputError("no scene gives the frame rate of these poses: pass --fps", file=pose_file)
    poses, r90 = read_poses_r90(pose_file)
    return from_poses(poses, fps, r90)
