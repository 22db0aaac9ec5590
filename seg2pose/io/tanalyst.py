"""T-Analyst's tracks CSV, read and written, and its time stamps turned into frames.

As T-Analyst exports them: ``;``-separated, decimal commas, a header and one detection (a road
user's position at one time) per line::

    Detection ID;Type of road user;Road user ID;X (m);Y (m);Time Stamp
    1;Car;3;12,5;-4,25;00:01:23.467

Time stamps are ``HH:MM:SS.mmm`` of the video's clock with no date; frame = (time - start) x fps
where start is the time of the video's first frame (frame 0). The writer writes what it reads
(numbers as the shortest decimal that reads back to the same float), so files written here
read back to the same table and write again to the same text.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from seg2pose.core.errors import InputError
from seg2pose.core.validate import MAX_COORD, MAX_ID, int_text, number
from seg2pose.io.atomic import atomic_write_text
from seg2pose.io.text import read_text

COLUMNS = ["Detection ID", "Type of road user", "Road user ID", "X (m)", "Y (m)", "Time Stamp"]
_TIME = re.compile(r"^(\d{1,3}):([0-5]\d):([0-5]\d)[.,](\d{3})$")
_NUMBER = re.compile(r"^[+-]?(\d+([.,]\d*)?|[.,]\d+)([eE][+-]?\d+)?$")
# a time stamp this far (in frames) from a frame of the video means the frame rate or start is wrong
FRAME_SNAP = 0.25
# T-Analyst's road user types <-> s2p classes (case-insensitive on reading)
TYPE_TO_CLASS = {"pedestrian": "pedestrian", "car": "car", "bicycle": "bicyclist",
                 "bicyclist": "bicyclist", "cyclist": "bicyclist", "bike": "bicyclist",
                 "truck": "truck", "bus": "bus", "motorcycle": "motorcycle", "moped": "moped"}
CLASS_TO_TYPE = {"pedestrian": "Pedestrian", "car": "Car", "bicyclist": "Bicycle", "truck": "Truck",
                 "bus": "Bus", "motorcycle": "Motorcycle", "moped": "Moped"}


@dataclass
class TAnalystTable:
    """N detections. detection_id, road_user_id: (N,) int64; road_user_type: (N,) str as written;
    xy: (N, 2) metres; time_ms: (N,) int64 milliseconds since 00:00:00.000; lines: (N,) the
    file's line of each row (0 when not read from a file: the default, or any empty array);
    decimal: the file's separator."""

    detection_id: np.ndarray
    road_user_type: np.ndarray
    road_user_id: np.ndarray
    xy: np.ndarray
    time_ms: np.ndarray
    lines: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    decimal: str = ","

    def __post_init__(self) -> None:
        self.detection_id = np.asarray(self.detection_id, dtype=np.int64).reshape(-1)
        self.road_user_type = np.asarray(self.road_user_type, dtype=object).reshape(-1)
        self.road_user_id = np.asarray(self.road_user_id, dtype=np.int64).reshape(-1)
        self.xy = np.asarray(self.xy, dtype=np.float64).reshape(-1, 2)
        self.time_ms = np.asarray(self.time_ms, dtype=np.int64).reshape(-1)
        n = len(self.detection_id)
        self.lines = np.asarray(self.lines, dtype=np.int64).reshape(-1)
        if len(self.lines) == 0:
            self.lines = np.zeros(n, np.int64)
        if not all(len(a) == n for a in (self.road_user_type, self.road_user_id, self.xy,
                                         self.time_ms, self.lines)):
            raise ValueError("TAnalystTable columns differ in length")
        if self.decimal not in (",", "."):
            raise ValueError(f"decimal separator must be ',' or '.', got {self.decimal!r}")

    def __len__(self) -> int:
        return len(self.detection_id)

    def __eq__(self, other) -> bool:  # the data, not where it was read from
        return (isinstance(other, TAnalystTable) and len(self) == len(other)
                and np.array_equal(self.detection_id, other.detection_id)
                and list(self.road_user_type) == list(other.road_user_type)
                and np.array_equal(self.road_user_id, other.road_user_id)
                and np.array_equal(self.xy, other.xy) and np.array_equal(self.time_ms, other.time_ms))


def parse_time(text: str, file=None, line: int | None = None) -> int:
    """``HH:MM:SS.mmm`` -> milliseconds since 00:00:00.000."""
    m = _TIME.match(text.strip())
    if not m:
        raise InputError(f"expected a time stamp HH:MM:SS.mmm, got {text.strip()!r}", file=file,
                         line=line, field="Time Stamp")
    h, mi, s, ms = (int(g) for g in m.groups())
    return ((h * 60 + mi) * 60 + s) * 1000 + ms


def format_time(ms: int) -> str:
    """Milliseconds since 00:00:00.000 -> ``HH:MM:SS.mmm`` (hours past 23 keep counting)."""
    ms = int(ms)
    if ms < 0:
        raise ValueError(f"negative time {ms} ms")
    s, ms = divmod(ms, 1000)
    m, s = divmod(s, 60)
    h, m = divmod(m, 60)
    return f"{h:02d}:{m:02d}:{s:02d}.{ms:03d}"


def _format_number(v: float, decimal: str) -> str:
    # positional, shortest digits that read back exactly (repr's would write 1e-05)
    return np.format_float_positional(float(v), unique=True, trim="-").replace(".", decimal)


def format_tanalyst(table: TAnalystTable, decimal: str | None = None) -> str:
    decimal = decimal or table.decimal
    out = [";".join(COLUMNS)]
    for i in range(len(table)):
        out.append(";".join([str(table.detection_id[i]), str(table.road_user_type[i]),
                             str(table.road_user_id[i]), _format_number(table.xy[i, 0], decimal),
                             _format_number(table.xy[i, 1], decimal), format_time(table.time_ms[i])]))
    return "\n".join(out) + "\n"


def write_tanalyst(path: str | Path, table: TAnalystTable, decimal: str | None = None) -> None:
    atomic_write_text(path, format_tanalyst(table, decimal))


def read_tanalyst(path: str | Path) -> TAnalystTable:
    path = Path(path)
    return parse_tanalyst(read_text(path, "T-Analyst tracks file"), path)


def parse_tanalyst(text: str, file: str | Path = "<csv>") -> TAnalystTable:
    """Parse a tracks CSV. Errors name the line: wrong header or field count, non-numbers, a
    decimal separator other than the file's first, a bad time stamp, time stamps of one road
    user that do not increase, a repeated Detection ID, a road user whose type changes."""
    file = Path(file)
    lines = text.lstrip("\ufeff").splitlines()
    if not lines or [c.strip() for c in lines[0].split(";")] != COLUMNS:
        raise InputError(f"expected the header {';'.join(COLUMNS)}, got "
                         f"{lines[0] if lines else 'an empty file'!r}", file=file, line=1)
    det, typ, rid, xy, tms, where = [], [], [], [], [], []
    decimal: str | None = None
    decimal_line = 0
    last: dict[int, tuple[int, int]] = {}  # road user -> (time, line) of its previous detection
    types: dict[int, tuple[str, int]] = {}  # road user -> (type, line first given)
    seen_det: dict[int, int] = {}
    for lineno, raw in enumerate(lines[1:], start=2):
        if not raw.strip():
            continue
        cells = [c.strip() for c in raw.split(";")]
        if len(cells) == len(COLUMNS) + 1 and cells[-1] == "":
            cells = cells[:-1]  # a trailing ';'
        if len(cells) != len(COLUMNS):
            raise InputError(f"expected {len(COLUMNS)} ';'-separated fields, got {len(cells)}",
                             file=file, line=lineno)
        d, r = (int_text(cells[k], file=file, line=lineno, field=COLUMNS[k], lo=0, hi=MAX_ID)
                for k in (0, 2))
        if not cells[1]:
            raise InputError("empty Type of road user", file=file, line=lineno,
                             field="Type of road user")
        v = []
        for col, c in zip(COLUMNS[3:5], cells[3:5]):
            if not _NUMBER.match(c):
                raise InputError(f"expected a number, got {c!r}", file=file, line=lineno, field=col)
            sep = "," if "," in c else "." if "." in c else None
            if sep is not None:
                if decimal is None:
                    decimal, decimal_line = sep, lineno
                elif sep != decimal:
                    raise InputError(f"decimal {sep!r} in {c!r}, but line {decimal_line} uses "
                                     f"{decimal!r}: mixed decimal separators", file=file,
                                     line=lineno, field=col)
            v.append(number(float(c.replace(",", ".")), file=file, line=lineno, field=col,
                            lo=-MAX_COORD, hi=MAX_COORD))
        if d in seen_det:
            raise InputError(f"Detection ID {d} also on line {seen_det[d]}", file=file, line=lineno,
                             field="Detection ID")
        seen_det[d] = lineno
        if r in types and types[r][0] != cells[1]:
            raise InputError(f"road user {r} is {cells[1]!r} here but {types[r][0]!r} on line "
                             f"{types[r][1]}", file=file, line=lineno, field="Type of road user")
        types.setdefault(r, (cells[1], lineno))
        t = parse_time(cells[5], file, lineno)
        if r in last and t <= last[r][0]:
            raise InputError(f"time stamp {cells[5]} of road user {r} is not after its previous one, "
                             f"{format_time(last[r][0])} on line {last[r][1]}: time stamps out of "
                             "order", file=file, line=lineno, field="Time Stamp")
        last[r] = (t, lineno)
        det.append(d)
        typ.append(cells[1])
        rid.append(r)
        xy.append(v)
        tms.append(t)
        where.append(lineno)
    return TAnalystTable(np.array(det, np.int64), np.array(typ, dtype=object), np.array(rid, np.int64),
                         np.array(xy).reshape(-1, 2), np.array(tms, np.int64), np.array(where, np.int64),
                         decimal or ",")


def times_to_frames(table: TAnalystTable, fps: float, start_ms: int = 0,
                    file: str | Path | None = None, snap: float = FRAME_SNAP) -> np.ndarray:
    """(N,) frame numbers of the detections: round((time - start) fps). A time before the start,
    or farther than ``snap`` frames from any frame (a wrong frame rate or start), is an error
    naming the line."""
    if not (np.isfinite(fps) and fps > 0):
        raise InputError(f"frame rate must be positive, got {fps!r}", field="fps")
    exact = (table.time_ms - int(start_ms)) * (float(fps) / 1000.0)
    frames = np.round(exact).astype(np.int64)
    bad = np.flatnonzero((exact < -snap) | (np.abs(exact - frames) > snap))
    if len(bad):
        i = bad[0]
        why = ("is before the video's start" if exact[i] < -snap else
               f"is {abs(exact[i] - frames[i]):.2f} frames from the nearest frame at {fps:g} fps "
               "(is the frame rate or start time right?)")
        raise InputError(f"time stamp {format_time(table.time_ms[i])} {why} "
                         f"(start {format_time(start_ms)})", file=file,
                         line=int(table.lines[i]) or None, field="Time Stamp")
    return frames


def frames_to_times(frames: np.ndarray, fps: float, start_ms: int = 0) -> np.ndarray:
    """(N,) frames -> (N,) milliseconds on the video's clock, rounded to the millisecond
    (exact back to the frame for any fps below 1000)."""
    frames = np.asarray(frames, dtype=np.int64)
    return int(start_ms) + np.round(frames * (1000.0 / float(fps))).astype(np.int64)
