"""Masks in MOTS txt: one detection per line, ``frame track_id class_id height width rle``.

``rle`` is pycocotools' compressed COCO RLE string. A ``track_id`` of -1 means "no track yet"
and a ``class_id`` of 0 "no class yet" (the video path fills them in later). Frames must be
non-decreasing, so files can be streamed frame by frame.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

import numpy as np

from seg2pose.core.errors import InputError
from seg2pose.io.atomic import atomic_open
from seg2pose.io.schemas import FRAME, ID, IMAGE_SIDE, MASKS, mask_columns
from seg2pose.structures.masks import decode_counts

_INT = re.compile(r"^[+-]?[0-9]{1,19}$")
# io.schemas.MASKS's limits, as plain ints for the per-line checks
_FRAME_HI, _ID_LO, _ID_HI, _SIDE_HI = (int(cast(float, v)) for v in (FRAME.hi, ID.lo, ID.hi, IMAGE_SIDE.hi))
_BLOCK = 2048  # detections checked together by iter_mots (whole frames; frames are yielded one by one)


@dataclass
class MaskTable:
    """Detections of one camera, column-wise. frame, track_id, class_id: (N,) int64;
    height, width: image size (pixels); rles: N compressed RLE strings."""

    frame: np.ndarray
    track_id: np.ndarray
    class_id: np.ndarray
    height: int
    width: int
    rles: list[bytes] = field(default_factory=list)
    score: np.ndarray | None = None  # (N,) detector confidence, when known

    def __len__(self) -> int:
        return len(self.rles)

    def __post_init__(self) -> None:
        self.frame = np.asarray(self.frame, dtype=np.int64).reshape(-1)
        self.track_id = np.asarray(self.track_id, dtype=np.int64).reshape(-1)
        self.class_id = np.asarray(self.class_id, dtype=np.int64).reshape(-1)
        if self.score is not None:
            self.score = np.asarray(self.score, dtype=np.float64).reshape(-1)
        if not (len(self.frame) == len(self.track_id) == len(self.class_id) == len(self.rles)) or (
                self.score is not None and len(self.score) != len(self.rles)):
            raise ValueError("MaskTable columns differ in length")

    def take(self, idx) -> MaskTable:
        idx = np.asarray(idx)
        if idx.dtype == bool:
            idx = np.flatnonzero(idx)
        return MaskTable(self.frame[idx], self.track_id[idx], self.class_id[idx], self.height,
                         self.width, [self.rles[i] for i in idx],
                         None if self.score is None else self.score[idx])

    @classmethod
    def empty(cls, height: int, width: int) -> MaskTable:
        z = np.zeros(0, np.int64)
        return cls(z, z, z, height, width, [])

    @classmethod
    def concat(cls, tables: list[MaskTable]) -> MaskTable:
        if not tables:
            raise ValueError("nothing to concatenate")
        with_score = all(t.score is not None for t in tables)
        return cls(np.concatenate([t.frame for t in tables]),
                   np.concatenate([t.track_id for t in tables]),
                   np.concatenate([t.class_id for t in tables]),
                   tables[0].height, tables[0].width, [r for t in tables for r in t.rles],
                   np.concatenate([t.score for t in tables]) if with_score else None)

    def frames(self) -> Iterator[tuple[int, MaskTable]]:
        """(frame, detections of that frame) in frame order."""
        if len(self) == 0:
            return
        order = np.argsort(self.frame, kind="stable")
        f = self.frame[order]
        cuts = np.flatnonzero(np.diff(f)) + 1
        for chunk in np.split(order, cuts):
            yield int(self.frame[chunk[0]]), self.take(chunk)


def _parse_line(line: str, path: Path, lineno: int, known_classes: set[int] | None,
                size: tuple[int, int] | None, image_size: tuple[int, int] | None = None):
    parts = line.split()
    if len(parts) != 6:
        raise InputError(f"expected 6 fields 'frame track_id class_id height width rle', got {len(parts)}",
                         file=path, line=lineno)
    if not all(_INT.match(p) for p in parts[:5]):  # int() would read "1_4" as 14
        raise InputError(f"expected integers for frame track_id class_id height width, got {parts[:5]}",
                         file=path, line=lineno)
    frame, tid, cid, h, w = (int(p) for p in parts[:5])
    # io.schemas.MASKS, one line at a time (a stream's block is checked whole by emit, but the
    # size must be known good before it is compared with the next line's)
    if frame < 0:
        raise InputError(f"negative frame {frame}", file=path, line=lineno)
    if not (frame <= _FRAME_HI and _ID_LO <= tid <= _ID_HI and _ID_LO <= cid <= _ID_HI):
        raise InputError(f"frame must be {FRAME.expected()}, track_id and class_id {ID.expected()}",
                         file=path, line=lineno)
    if h <= 0 or w <= 0:
        raise InputError(f"non-positive image size {h}x{w}", file=path, line=lineno)
    if h > _SIDE_HI or w > _SIDE_HI:
        raise InputError(f"implausible image size {h}x{w} (more than 2^20 pixels a side)",
                         file=path, line=lineno)
    if size is not None and (h, w) != size:
        raise InputError(f"image size {h}x{w} differs from earlier lines ({size[0]}x{size[1]})",
                         file=path, line=lineno)
    if image_size is not None and (h, w) != tuple(image_size):
        raise InputError(f"mask size {h}x{w} (height x width) differs from the camera's image "
                         f"size {image_size[0]}x{image_size[1]} in scene.json", file=path,
                         line=lineno)
    if known_classes is not None and cid != 0 and cid not in known_classes:
        raise InputError(f"unknown class_id {cid}; the scene knows {sorted(known_classes)}",
                         file=path, line=lineno)
    try:
        rle = parts[5].encode("ascii")
    except UnicodeEncodeError:
        raise InputError("RLE string is not ASCII", file=path, line=lineno) from None
    return frame, tid, cid, h, w, rle


def _check_rles(rles: list[bytes], linenos: list[int], h: int, w: int, path: Path) -> None:
    """Each RLE's runs must add up to height*width."""
    try:
        counts, offsets = decode_counts(rles)
    except InputError:
        for r, ln in zip(rles, linenos):  # find the offending line
            try:
                decode_counts([r])
            except InputError as e:
                raise InputError(e.message, file=path, line=ln) from None
        raise
    total = np.add.reduceat(counts, offsets[:-1]) if len(counts) else np.zeros(len(rles))
    total = np.where(np.diff(offsets) == 0, 0, total)
    bad = np.flatnonzero(total != h * w)
    if len(bad):
        i = int(bad[0])
        raise InputError(f"RLE covers {int(total[i])} pixels but height*width = {h * w}",
                         file=path, line=linenos[i])


def _check_duplicates(frame: np.ndarray, tid: np.ndarray, linenos: list[int], path: Path) -> None:
    """One detection per (frame, track id) for tracked detections (track id >= 0)."""
    sel = np.flatnonzero(tid >= 0)
    if len(sel) < 2:
        return
    order = sel[np.lexsort((sel, tid[sel], frame[sel]))]  # by key, then by line
    same = np.flatnonzero((frame[order[1:]] == frame[order[:-1]]) & (tid[order[1:]] == tid[order[:-1]]))
    if len(same):
        k = same[np.argmin(order[same + 1])]  # the earliest line that repeats a detection
        a, b = int(order[k]), int(order[k + 1])
        raise InputError(f"duplicate detection: track {int(tid[b])} appears twice in frame "
                         f"{int(frame[b])} (also line {linenos[a]})", file=path, line=linenos[b])


def iter_mots(path: str | Path, known_classes: Iterable[int] | None = None,
              frame_range: tuple[int, int] | None = None,
              check_rles: bool = True, image_size: tuple[int, int] | None = None
              ) -> Iterator[tuple[int, MaskTable]]:
    """Stream a MOTS txt file frame by frame: yields (frame, MaskTable of that frame).

    frame_range: (first, last) inclusive; frames outside are skipped (and reading stops after
    ``last``). image_size: (height, width) pixels of the camera the masks belong to; masks of
    another size are refused. A track id may appear once per frame (-1, "no track", any
    number of times). Blank lines and lines starting with '#' are skipped."""
    path = Path(path)
    if not path.exists():
        raise InputError("masks file not found", file=path)
    kc = set(known_classes) if known_classes is not None else None
    size = None
    cur = None
    rows: list = []
    linenos: list[int] = []
    last_frame = -1

    def emit():
        """Check a block of whole frames at once (one vectorised RLE check instead of one per
        frame), then yield it frame by frame."""
        assert size is not None  # set by the block's first row
        h, w = size
        rles = [r[5] for r in rows]
        if check_rles:  # False: the caller decodes the runs itself and checks them in bulk
            _check_rles(rles, linenos, h, w, path)
        a = np.array([r[:3] for r in rows], dtype=np.int64)
        _check_duplicates(a[:, 0], a[:, 1], linenos, path)
        cuts = np.flatnonzero(np.diff(a[:, 0])) + 1
        for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, len(a)]):
            yield int(a[lo, 0]), MaskTable(a[lo:hi, 0], a[lo:hi, 1], a[lo:hi, 2], h, w, rles[lo:hi])

    with open(path, "rb") as f:
        for lineno, raw in enumerate(f, start=1):
            try:
                line = raw.decode("ascii").strip()
            except UnicodeDecodeError:
                raise InputError("not ASCII text", file=path, line=lineno) from None
            if not line or line.startswith("#"):
                continue
            row = _parse_line(line, path, lineno, kc, size, image_size)
            size = (row[3], row[4])
            frame = row[0]
            if frame < last_frame:
                raise InputError(f"frame {frame} comes after frame {last_frame}: frames must be in order",
                                 file=path, line=lineno)
            last_frame = frame
            if frame_range is not None:
                if frame < frame_range[0]:
                    continue
                if frame > frame_range[1]:
                    break
            if cur is not None and frame != cur and len(rows) >= _BLOCK:
                yield from emit()
                rows, linenos = [], []
            cur = frame
            rows.append(row)
            linenos.append(lineno)
    if rows:
        yield from emit()


def read_mots(path: str | Path, known_classes: Iterable[int] | None = None,
              frame_range: tuple[int, int] | None = None,
              size: tuple[int, int] | None = None) -> MaskTable:
    """A whole MOTS file as one MaskTable (use ``iter_mots`` for long sequences).
    ``size`` (height, width) is used for an empty file."""
    tables = [t for _, t in iter_mots(path, known_classes, frame_range)]
    if not tables:
        h, w = size if size is not None else (0, 0)
        return MaskTable(np.zeros(0), np.zeros(0), np.zeros(0), h, w, [])
    return MaskTable.concat(tables)


def format_mots_lines(table: MaskTable) -> Iterator[str]:
    for i in np.argsort(table.frame, kind="stable"):
        yield (f"{table.frame[i]} {table.track_id[i]} {table.class_id[i]} "
               f"{table.height} {table.width} {table.rles[i].decode('ascii')}\n")


def check_masks(table: MaskTable, file: str | Path | None = None) -> None:
    """Refuse, before a write, what the masks readers refuse (``io.schemas.MASKS``: frames,
    ids and image sizes in range, a track once per frame; RLE runs covering height x width),
    naming ``file`` and the detection (numbered from 1 in frame order)."""
    MASKS.check(mask_columns(table), file=file)
    if len(table):
        order = np.argsort(table.frame, kind="stable")
        try:
            _check_rles([table.rles[i] for i in order], list(range(1, len(order) + 1)), table.height,
                        table.width, Path(file or "masks"))
        except InputError as e:
            raise InputError(e.message, file=file, field=f"detection {e.line}") from None


def write_mots(path: str | Path, table: MaskTable | Iterable[MaskTable]) -> None:
    """Write one table, or stream many (in frame order, one image size), atomically; what
    ``read_mots`` would refuse (``check_masks``) is refused and nothing is written."""
    tables = [table] if isinstance(table, MaskTable) else table
    with atomic_open(path, "w", encoding="ascii", newline="\n") as f:
        last, size = -1, None
        for t in tables:
            check_masks(t, file=path)
            if len(t):
                if size is not None and (t.height, t.width) != size:
                    raise InputError(f"masks of {t.height}x{t.width} after masks of {size[0]}x{size[1]}: "
                                     "one file holds one image size", file=path)
                if int(t.frame.min()) < last:
                    raise InputError(f"frame {int(t.frame.min())} comes after frame {last}: frames must "
                                     "be in order", file=path)
                last, size = int(t.frame.max()), (t.height, t.width)
            f.writelines(format_mots_lines(t))
