"""Pose tables: ground truth (``gt/poses.csv``) and estimated pose tracks (``RUN/poses.csv``).

CSV with a header: ``frame,track_id,class,x,y,z,heading[,l,w,h][,source][,r90_m]`` — metres,
heading in radians counter-clockwise from +x; x, y, z is the road user's ground contact point
(bottom centre). ``r90_m`` (estimated poses of ``s2p run``) is the pose's error bar: the radius,
metres on the ground, around x, y that holds the true position with 90 % probability
(``seg2pose.method.uncertainty``; NaN where the run had no calibration). Floats are written
with ``repr`` so that a round trip is exact. ``source`` (annotated ground truth only) says where
a row comes from (its provenance): ``keyframe`` (placed by the annotator), ``estimate-accepted``
(a Seg2Pose estimate the annotator accepted or reviewed), ``estimate-unchecked`` (an estimate,
or the interpolation next to one, that nobody has checked: exported only when asked),
``interpolated`` between checked keyframes, ``reviewed`` (interpolated, in frames the annotator
played back and passed), or ``occluded`` (inside a span marked occluded: training skips these).
Files without ``source`` or ``r90_m`` stay valid.
"""

from __future__ import annotations

import csv
import io
import re
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seg2pose.core.errors import InputError
from seg2pose.io.atomic import atomic_write_text
from seg2pose.io.schemas import FRAME, ID, POSES, pose_columns
from seg2pose.io.text import read_text

BASE_COLUMNS = ["frame", "track_id", "class", "x", "y", "z", "heading"]
SIZE_COLUMNS = ["l", "w", "h"]
_INT = re.compile(r"^[+-]?[0-9]{1,19}$")
SOURCE_COLUMN = "source"
SOURCES = ("keyframe", "estimate-accepted", "estimate-unchecked", "interpolated", "reviewed",
           "occluded")
# rows a person placed or checked one by one, and the rows between them (training's two choices)
CHECKED_KEYFRAME_SOURCES = ("keyframe", "estimate-accepted")
TRUSTED_SOURCES = CHECKED_KEYFRAME_SOURCES + ("interpolated", "reviewed")
R90_COLUMN = "r90_m"


@dataclass
class PoseTable:
    """Columns of N poses. frame, track_id: (N,) int64; cls: (N,) str; xyz: (N, 3) metres;
    heading: (N,) radians (NaN = unknown); size: (N, 3) l, w, h metres or None; source: (N,)
    str, one of SOURCES, or None (not annotated ground truth); r90: (N,) metres, the radius
    holding the true position with 90 % probability, or None (a file without the column)."""

    frame: np.ndarray
    track_id: np.ndarray
    cls: np.ndarray
    xyz: np.ndarray
    heading: np.ndarray
    size: np.ndarray | None = None
    source: np.ndarray | None = None
    r90: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.frame = np.asarray(self.frame, dtype=np.int64).reshape(-1)
        self.track_id = np.asarray(self.track_id, dtype=np.int64).reshape(-1)
        self.cls = np.asarray(self.cls, dtype=object).reshape(-1)
        self.xyz = np.asarray(self.xyz, dtype=np.float64).reshape(-1, 3)
        self.heading = np.asarray(self.heading, dtype=np.float64).reshape(-1)
        if self.size is not None:
            self.size = np.asarray(self.size, dtype=np.float64).reshape(-1, 3)
        if self.source is not None:
            self.source = np.asarray(self.source, dtype=object).reshape(-1)
        if self.r90 is not None:
            self.r90 = np.asarray(self.r90, dtype=np.float64).reshape(-1)
        n = len(self.frame)
        if not (len(self.track_id) == len(self.cls) == len(self.xyz) == len(self.heading) == n) or (
                self.size is not None and len(self.size) != n) or (
                self.source is not None and len(self.source) != n) or (
                self.r90 is not None and len(self.r90) != n):
            raise ValueError("PoseTable columns differ in length")

    def __len__(self) -> int:
        return len(self.frame)

    def take(self, idx) -> PoseTable:
        return PoseTable(self.frame[idx], self.track_id[idx], self.cls[idx], self.xyz[idx],
                         self.heading[idx], None if self.size is None else self.size[idx],
                         None if self.source is None else self.source[idx],
                         None if self.r90 is None else self.r90[idx])

    def sorted(self) -> PoseTable:
        return self.take(np.lexsort((self.track_id, self.frame)))

    def in_frames(self, frame_range: tuple[int, int] | None) -> PoseTable:
        if frame_range is None:
            return self
        return self.take((self.frame >= frame_range[0]) & (self.frame <= frame_range[1]))

    @classmethod
    def empty(cls, with_size: bool = False) -> PoseTable:
        return cls(np.zeros(0), np.zeros(0), np.zeros(0, object), np.zeros((0, 3)), np.zeros(0),
                   np.zeros((0, 3)) if with_size else None)

    @classmethod
    def concat(cls, tables: Iterable[PoseTable]) -> PoseTable:
        tables = list(tables)
        if not tables:
            return cls.empty()
        with_size = all(t.size is not None for t in tables)
        with_source = all(t.source is not None for t in tables)
        with_r90 = all(t.r90 is not None for t in tables)
        return cls(np.concatenate([t.frame for t in tables]),
                   np.concatenate([t.track_id for t in tables]),
                   np.concatenate([t.cls for t in tables]),
                   np.concatenate([t.xyz for t in tables]),
                   np.concatenate([t.heading for t in tables]),
                   np.concatenate([t.size for t in tables]) if with_size else None,
                   np.concatenate([t.source for t in tables]) if with_source else None,
                   np.concatenate([t.r90 for t in tables]) if with_r90 else None)


def _f(v: float) -> str:
    return repr(float(v))


def format_poses(table: PoseTable, file: str | Path | None = None) -> str:
    """poses.csv's text, checked against ``io.schemas.POSES`` (``file``: named in the message)."""
    POSES.check(pose_columns(table), file=file)
    if table.source is not None and not set(table.source.tolist()) <= set(SOURCES):
        bad = next(s for s in table.source.tolist() if s not in SOURCES)
        raise InputError(f"unknown source {bad!r}; expected one of {', '.join(SOURCES)}", file=file,
                         field=SOURCE_COLUMN)
    buf = io.StringIO()
    cols = BASE_COLUMNS + (SIZE_COLUMNS if table.size is not None else []) + (
        [SOURCE_COLUMN] if table.source is not None else []) + (
        [R90_COLUMN] if table.r90 is not None else [])
    buf.write(",".join(cols) + "\n")
    for i in range(len(table)):
        row = [str(table.frame[i]), str(table.track_id[i]), str(table.cls[i]),
               _f(table.xyz[i, 0]), _f(table.xyz[i, 1]), _f(table.xyz[i, 2]), _f(table.heading[i])]
        if table.size is not None:
            row += [_f(v) for v in table.size[i]]
        if table.source is not None:
            row.append(str(table.source[i]))
        if table.r90 is not None:
            row.append(_f(table.r90[i]))
        buf.write(",".join(row) + "\n")
    return buf.getvalue()


def write_poses(path: str | Path, table: PoseTable) -> None:
    """Write a pose table; what ``read_poses`` would refuse (``io.schemas.POSES``: NaN
    positions, frames out of order, a road user twice in a frame, ...) is refused first and
    nothing is written."""
    atomic_write_text(path, format_poses(table, file=path))


def read_poses(path: str | Path, known_classes: Iterable[str] | None = None) -> PoseTable:
    """Read a pose CSV; errors name the file, line and column."""
    path = Path(path)
    kc = set(known_classes) if known_classes is not None else None
    text = read_text(path, "pose file")
    reader = csv.reader(io.StringIO(text))
    try:
        return parse_poses(reader, path, kc)
    except csv.Error as e:
        raise InputError(f"malformed CSV: {e}", file=path, line=reader.line_num) from None


def parse_poses(reader, path: Path, kc: set[str] | None) -> PoseTable:
    """The pose table of a CSV ``reader`` (rows of ``path``, for messages); ``kc``: the known
    classes (None: any)."""
    header = next(reader, None)
    if header is None:
        raise InputError(f"empty file; expected a header {','.join(BASE_COLUMNS)}", file=path, line=1)
    header = [h.strip() for h in header]
    with_r90 = header[-1:] == [R90_COLUMN]
    if with_r90:
        header = header[:-1]
    with_source = header[-1:] == [SOURCE_COLUMN]
    if with_source:
        header = header[:-1]
    if header[:7] != BASE_COLUMNS or header[7:] not in ([], SIZE_COLUMNS):
        raise InputError(f"expected header {','.join(BASE_COLUMNS)}[,l,w,h][,source][,r90_m], got "
                         f"{','.join(header)}{',source' if with_source else ''}"
                         f"{',r90_m' if with_r90 else ''}", file=path, line=1)
    ncol = len(header)
    frames, tids, classes, nums, sources, r90s = [], [], [], [], [], []
    lines: list[int] = []
    for row in reader:
        lineno = reader.line_num
        if not row:
            continue
        if len(row) != ncol + with_source + with_r90:
            raise InputError(f"expected {ncol + with_source + with_r90} fields, got {len(row)}",
                             file=path, line=lineno)
        if with_r90:
            r90s.append(_parse_r90(row.pop(), path, lineno))
        if with_source:
            src = row.pop().strip()
            if src not in SOURCES:
                raise InputError(f"unknown source {src!r}; expected one of {', '.join(SOURCES)}",
                                 file=path, line=lineno, field=SOURCE_COLUMN)
            sources.append(src)
        if not (_INT.match(row[0].strip()) and _INT.match(row[1].strip())):  # int() takes "1_4"
            raise InputError(f"frame and track_id must be integers, got {row[:2]}", file=path,
                             line=lineno)
        fr, tid = int(row[0]), int(row[1])
        if not (abs(fr) < 2**63 and abs(tid) < 2**63):  # int64 columns; POSES checks the range
            raise InputError(f"frame must be {FRAME.expected()} and track_id {ID.expected()}, got "
                             f"{fr}, {tid}", file=path, line=lineno)
        c = row[2].strip()
        if kc is not None and c not in kc:
            raise InputError(f"unknown class {c!r}; the scene knows {sorted(kc)}", file=path,
                             line=lineno, field="class")
        try:
            v = [float(x) for x in row[3:]]
        except ValueError:
            raise InputError(f"expected numbers in {','.join(header[3:])}", file=path,
                             line=lineno) from None
        frames.append(fr)
        tids.append(tid)
        classes.append(c)
        nums.append(v)
        lines.append(lineno)
    a = np.array(nums, dtype=np.float64).reshape(-1, ncol - 3)
    t = PoseTable(np.asarray(frames, np.int64), np.asarray(tids, np.int64), np.array(classes, dtype=object),
                     a[:, :3], a[:, 3],
                     a[:, 4:7] if ncol == 10 else None,
                     np.array(sources, dtype=object) if with_source else None,
                     np.array(r90s, dtype=np.float64) if with_r90 else None)
    POSES.check(pose_columns(t), file=path, lines=lines)
    return t


def _parse_r90(text: str, path: Path, lineno: int) -> float:
    """An r90_m cell's number (its range is POSES's)."""
    try:
        return float(text)
    except ValueError:
        raise InputError(f"r90_m must be a radius in metres (>= 0, or nan), got {text.strip()!r}",
                         file=path, line=lineno, field=R90_COLUMN) from None
