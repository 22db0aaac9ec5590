"""Road-user tracks for safety analysis: read from a run folder, a ``poses.csv`` or a T-Analyst
CSV, with every road user's footprint size filled in and the rows ordered track by track.

``Tracks`` holds N rows sorted by (track_id, frame): t = frame / fps seconds, position on the
ground (x, y metres), heading (radians, counter-clockwise from +x; NaN = unknown), footprint
length and width (metres) and, where the poses carry one, ``r90_m``: the radius (metres) within
which the true position lies with 90 % probability.

Input validation is the readers' (``seg2pose.io``): a bad row is one line naming the file and
line. ``poses.csv`` may carry an extra last column ``r90_m`` (read by ``seg2pose.io.poses``).
"""

from __future__ import annotations

import io
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seg2pose.core.errors import InputError
from seg2pose.core.validate import FPS_RANGE, MAX_COORD
from seg2pose.io.poses import BASE_COLUMNS, SIZE_COLUMNS, PoseTable, read_poses
from seg2pose.io.poses import R90_COLUMN as POSE_R90
from seg2pose.io.scene import DEFAULT_CLASS_SIZES, UNKNOWN_CLASS, road_user_sizes
from seg2pose.io.tanalyst import TYPE_TO_CLASS, read_tanalyst, times_to_frames
from seg2pose.safety.workers import map_chunks

R90_COLUMN = "r90_m"
# the typical footprints (length, width, metres) of rows that give none: the scene's class
# sizes where the tracks belong to a scene, else these (``seg2pose.io.scene``: one source)
CLASS_SIZES = {k: (v[0], v[1]) for k, v in DEFAULT_CLASS_SIZES.items()}


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

    def take(self, idx) -> Tracks:
        return Tracks(self.frame[idx], self.track_id[idx], self.cls[idx], self.xy[idx],
                      self.heading[idx], self.size[idx], self.fps,
                      None if self.r90 is None else self.r90[idx])

    def with_xy(self, xy: np.ndarray) -> Tracks:
        """The same rows at other positions (``xy`` (N, 2), in this table's row order)."""
        out = self.take(slice(None))
        out.xy = np.asarray(xy, np.float64).reshape(-1, 2)
        return out


def class_sizes(cls: np.ndarray, sizes: dict | None = None) -> tuple[np.ndarray, list[str]]:
    """(N,) class names -> (N, 2) typical length, width (``sizes``: a scene's class sizes,
    default ``seg2pose.io.scene.DEFAULT_CLASS_SIZES``); and the classes not known (sized as
    UNKNOWN_CLASS)."""
    out, unknown = road_user_sizes(cls, None, sizes)
    return out[:, :2], unknown


def from_poses(poses: PoseTable, fps: float, r90: np.ndarray | None = None,
               sizes: dict | None = None) -> tuple[Tracks, list[str]]:
    """A pose table -> Tracks (sizes from the rows, else the class's typical size: ``sizes``,
    a scene's ``Scene.class_sizes()``, default the defaults) and notes."""
    notes = []
    own = None if poses.size is None else poses.size[:, :2]
    if own is not None:
        own = np.where(np.isfinite(own).all(axis=1)[:, None], own, np.nan)  # l and w, or neither
    full, unknown = road_user_sizes(poses.cls, own, sizes)
    size = full[:, :2]
    if unknown:
        notes.append(f"classes {', '.join(unknown)} have no typical size; rows without l, w are "
                     f"sized as a {UNKNOWN_CLASS}")
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


def read_poses_r90(path: Path, workers: int = 1) -> tuple[PoseTable, np.ndarray | None]:
    """A pose CSV (``seg2pose.io.poses``, with an optional last column ``r90_m``): the table
    and its r90_m (None: no such column). Read by ``read_poses_fast`` (in ``workers``
    processes) where it can vouch for the file, else (and for every error message) by
    ``seg2pose.io.poses.read_poses``."""
    poses = read_poses_fast(path, workers)
    if poses is None:
        poses = read_poses(path)
    return poses, poses.r90


FAST_LINES = 1 << 18  # lines of a pose file parsed at once by read_poses_fast
_HEADERS = {tuple(BASE_COLUMNS + s + r): (bool(s), bool(r))
            for s in ([], SIZE_COLUMNS) for r in ([], [POSE_R90])}


def read_poses_fast(path: Path, workers: int = 1) -> PoseTable | None:
    """The pose table of ``path`` as ``seg2pose.io.poses.read_poses`` gives it, parsed by
    numpy's C reader in blocks of about ``FAST_LINES`` lines, in ``workers`` processes (an
    hour of traffic has millions of rows: the per-row reader takes minutes and gigabytes);
    None where this reader cannot vouch for the result (a ``source`` column, quoting, a value
    or a row the file checks would reject, ...): the caller then reads it with
    ``read_poses``, which gives the table or the error naming the line. Every check of
    ``read_poses`` is made here too, on whole columns."""
    path = Path(path)
    if not path.is_file():
        return None
    size = path.stat().st_size
    with open(path, "rb") as f:
        head = f.readline()
        try:
            header = tuple(h.strip() for h in head.decode("utf-8").rstrip("\r\n").split(","))
        except UnicodeDecodeError:
            return None
        if header not in _HEADERS:
            return None
        # the blocks: byte ranges of whole lines
        bounds = [f.tell()]
        while True:
            nxt = bounds[-1] + FAST_LINES * 64
            if nxt >= size:
                if bounds[-1] < size:
                    bounds.append(size)
                break
            f.seek(nxt)
            f.readline()  # to the end of the line holding byte nxt
            bounds.append(f.tell())
    with_size, with_r90 = _HEADERS[header]
    nnum = len(header) - 3

    def block(i: int):
        with open(path, "rb") as g:
            g.seek(bounds[i])
            data = g.read(bounds[i + 1] - bounds[i])
        if b'"' in data or b"\r" in data:
            return None  # quoting, old line ends: the csv module's business
        return _parse_block(data, nnum)

    parts = map_chunks(block, range(len(bounds) - 1), workers)
    if not parts or any(p is None for p in parts):
        return None  # (no rows: let the reader say what it says of that)
    frame, tid, cls, num = (np.concatenate([p[k] for p in parts]) for k in range(4))
    del parts
    if not _rows_valid(frame, tid, num, with_size, with_r90):
        return None
    return PoseTable(frame, tid, cls, num[:, :3], num[:, 3],
                     num[:, 4:7] if with_size else None, None,
                     num[:, -1] if with_r90 else None)


def _parse_block(block: bytes, nnum: int):
    """(frame, track id, class, numbers (n, nnum)) of the rows of ``block`` (whole lines), or
    None. The two integers must be plain digits with an optional sign (1-19 digits: the
    pattern read_poses takes, without its surrounding spaces), checked on the bytes; the rest
    is numpy's C parser (numbers correctly rounded, as Python's float)."""
    if not block.endswith(b"\n"):
        block += b"\n"
    arr = np.frombuffer(block, np.uint8)
    if (arr == 0).any():
        return None  # NUL bytes: the fixed-width class names below would drop them
    ends = np.flatnonzero(arr == 10)
    starts = np.r_[0, ends[:-1] + 1]
    if (ends == starts).any():
        return None  # a blank line
    commas = np.flatnonzero(arr == 44)
    k = np.searchsorted(commas, starts)
    if (k + 2 >= len(commas)).any():
        return None
    c1, c2, c3 = commas[k], commas[k + 1], commas[k + 2]  # after frame, track id, class
    if (c3 > ends).any():
        return None
    digit = np.r_[0, np.cumsum((arr >= 48) & (arr <= 57), dtype=np.int32)]
    for lo, hi in ((starts, c1), (c1 + 1, c2)):
        n = digit[hi] - digit[lo]
        signed = np.isin(arr[np.minimum(lo, len(arr) - 1)], (43, 45)) & (hi > lo)
        if not ((n >= 1) & (n <= 19) & (n == hi - lo - signed)).all():
            return None
    # the class names: the bytes between the two commas, as fixed-width byte strings (few
    # distinct ones, each decoded once)
    width = int((c3 - c2 - 1).max())
    if width == 0 or width > 255:
        return None
    j = c2[:, None] + 1 + np.arange(width)[None, :]
    raw = np.where(j < c3[:, None], arr[np.minimum(j, len(arr) - 1)], 0).astype(np.uint8)
    names, inv = np.unique(raw.view(f"S{width}").reshape(-1), return_inverse=True)
    try:
        cls = np.array([x.decode("utf-8").strip() for x in names], object)[inv.reshape(-1)]
    except UnicodeDecodeError:
        return None
    dtype = [("frame", np.int64), ("tid", np.int64)] + [(f"v{i}", np.float64) for i in range(nnum)]
    try:
        rec = np.loadtxt(io.StringIO(block.decode("utf-8")), delimiter=",", dtype=dtype,
                         comments=None, ndmin=1, quotechar=None, usecols=[0, 1] + list(range(3, 3 + nnum)))
    except (ValueError, OverflowError, UnicodeDecodeError):
        return None
    if len(rec) != len(starts):
        return None
    nums = np.stack([rec[f"v{i}"] for i in range(nnum)], axis=1)
    return rec["frame"], rec["tid"], cls, nums


def _rows_valid(frame, tid, num, with_size: bool, with_r90: bool) -> bool:
    """Whether every row passes read_poses' checks (ranges, order, no duplicate rows)."""
    if not ((frame >= 0).all() and (frame < 2**62).all() and (tid > -2**62).all()
            and (tid < 2**62).all() and (np.diff(frame) >= 0).all()):
        return False
    xyz = num[:, :3]
    if not (np.isfinite(xyz).all() and (np.abs(xyz) <= MAX_COORD).all()) or np.isinf(num[:, 3]).any():
        return False
    if with_size:
        sz = num[:, 4:7]
        if not (np.isnan(sz) | ((sz > 0) & (sz <= 1000))).all():
            return False
    if with_r90:
        r = num[:, -1]
        if not (np.isnan(r) | ((r >= 0) & (r <= MAX_COORD))).all():
            return False
    tracked = tid >= 0  # frames are in order: a duplicate is a repeat within a frame
    f, t = frame[tracked], tid[tracked]
    o = np.lexsort((t, f))
    return not ((np.diff(f[o]) == 0) & (np.diff(t[o]) == 0)).any()


def scene_of(path: Path) -> Path | None:
    """The scene folder a pose file or run folder belongs to, where it can be found: RUN's
    run.json's scene, or the scene around SCENE/gt/poses.csv."""
    run_dir = path if path.is_dir() else path.parent
    meta = run_dir / "run.json"
    if meta.exists():
        try:
            scene = json.loads(meta.read_text(encoding="utf-8")).get("scene")
        except (ValueError, AttributeError):
            raise InputError("invalid JSON", file=meta) from None
        if isinstance(scene, str) and ((run_dir / scene) / "scene.json").exists():
            return (run_dir / scene).resolve()
    if path.is_file() and path.parent.name == "gt" and (path.parent.parent / "scene.json").exists():
        return path.parent.parent
    return None


def scene_class_sizes(path: Path) -> dict | None:
    """The class sizes of the scene ``path`` belongs to (``scene_of``), or None."""
    scene = scene_of(Path(path))
    if scene is None:
        return None
    from seg2pose.io.scene import load_scene

    return load_scene(scene).class_sizes()


def _scene_fps(scene_dir: Path) -> float | None:
    p = scene_dir / "scene.json"
    if not p.exists():
        return None
    try:
        return float(json.loads(p.read_text(encoding="utf-8"))["fps"])
    except (ValueError, KeyError, TypeError):
        raise InputError("expected a JSON object with a number 'fps'", file=p) from None


def find_fps(path: Path) -> float | None:
    """The frame rate of the scene a pose file or run folder belongs to (``scene_of``), when
    it can be found."""
    scene = scene_of(Path(path))
    return None if scene is None else _scene_fps(scene)


def is_tanalyst(path: Path) -> bool:
    if not path.is_file():
        return False
    with open(path, "rb") as f:
        head = f.readline().decode("utf-8", "replace").lstrip("\ufeff")
    return head.startswith("Detection ID;")


def load_tracks(path: str | Path, fps: float | None = None, start_ms: int = 0,
                workers: int = 1) -> tuple[Tracks, list[str]]:
    """Tracks from ``path``: a run folder (RUN/poses.csv), a pose CSV (optionally with r90_m)
    or a T-Analyst tracks CSV (positions only: headings from motion, sizes by class: the
    scene's class sizes where the poses belong to a scene, ``scene_of``). ``fps``:
    needed where no scene says it (a pose CSV outside a run or scene, a T-Analyst file);
    ``start_ms``: a T-Analyst file's time of frame 0; ``workers``: processes a long pose CSV
    is parsed in. Returns the tracks and notes."""
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
    poses, r90 = read_poses_r90(pose_file, workers)
    return from_poses(poses, fps, r90, scene_class_sizes(path))
