"""Masks as PNG instance-id images, KITTI-MOTS style: one 16-bit PNG per frame, ``NNNNNN.png``
(the frame number, zero-padded to 6 digits), pixel value ``class_id * 1000 + track_id``;
0 is background and 10000 KITTI-MOTS' "ignore" region (skipped on reading).

One pixel holds one id, so overlapping masks cannot be stored: on writing, a later detection
of a frame (in table order) covers earlier ones where they overlap. Round trips are exact for
non-overlapping masks with track ids 0..999 and class ids 1..65. Detections without a track
(-1) cannot be written. Note KITTI-MOTS' own class numbering (1 car, 2 pedestrian) differs from
this project's (1 pedestrian, 3 car): pass ``class_map`` to translate.
"""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np

from seg2pose.core.errors import InputError
from seg2pose.io.atomic import atomic_write_bytes
from seg2pose.io.mots import MaskTable, check_masks
from seg2pose.structures.masks import decode, encode

ID_FACTOR = 1000
IGNORE_ID = 10000
_NAME = re.compile(r"^(\d+)\.png$")


def list_frames(folder: str | Path) -> list[tuple[int, Path]]:
    """(frame, path) of the folder's NNNNNN.png files, in frame order."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("expected a folder of NNNNNN.png instance-id images", file=folder)
    out = []
    for p in folder.iterdir():
        m = _NAME.match(p.name)
        if m:
            if len(m.group(1)) > 15:
                raise InputError("frame number too long", file=p)
            out.append((int(m.group(1)), p))
    return sorted(out)


def read_png_frame(path: Path) -> np.ndarray:
    """One instance-id image (H, W) int64."""
    data = np.fromfile(path, dtype=np.uint8)
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if img is None:
        raise InputError("not a readable PNG image", file=path)
    if img.ndim != 2 or img.dtype not in (np.uint8, np.uint16):
        raise InputError(f"expected a single-channel 8- or 16-bit image, got shape {img.shape} "
                         f"{img.dtype}", file=path)
    return img.astype(np.int64)


def read_png_folder(folder: str | Path, known_classes=None, class_map: dict[int, int] | None = None,
                    frame_range: tuple[int, int] | None = None) -> MaskTable:
    """A folder of instance-id PNGs -> MaskTable (frame order; within a frame, id order)."""
    kc = set(known_classes) if known_classes is not None else None
    tables = []
    size = None
    for frame, path in list_frames(folder):
        if frame_range is not None and not frame_range[0] <= frame <= frame_range[1]:
            continue
        img = read_png_frame(path)
        if size is None:
            size = img.shape
        elif img.shape != size:
            raise InputError(f"image size {img.shape[0]}x{img.shape[1]} differs from earlier "
                             f"frames ({size[0]}x{size[1]})", file=path)
        ids = np.unique(img)
        ids = ids[(ids != 0) & (ids != IGNORE_ID)]
        cls, tid = np.divmod(ids, ID_FACTOR)
        if class_map is not None:
            unknown = [int(c) for c in cls if int(c) not in class_map]
            if unknown:
                raise InputError(f"class {unknown[0]} (id {ids[cls == unknown[0]][0]}) not in the "
                                 f"class map {sorted(class_map)}", file=path)
            cls = np.array([class_map[int(c)] for c in cls], np.int64)
        if kc is not None:
            bad = [int(c) for c in cls if int(c) not in kc]
            if bad:
                raise InputError(f"unknown class {bad[0]}; the scene knows {sorted(kc)}", file=path)
        rles = [encode(img == i) for i in ids]
        n = len(ids)
        tables.append(MaskTable(np.full(n, frame), tid, cls, img.shape[0], img.shape[1], rles))
    if not tables:
        raise InputError("no NNNNNN.png images found", file=folder)
    return MaskTable.concat(tables)


def write_png_folder(folder: str | Path, table: MaskTable) -> list[Path]:
    """One 16-bit PNG per frame that has detections; each file written atomically.
    Returns the paths written."""
    folder = Path(folder)
    check_masks(table, file=folder)
    if len(table) and ((table.track_id < 0).any() or (table.track_id >= ID_FACTOR).any()):
        bad = int(table.track_id[(table.track_id < 0) | (table.track_id >= ID_FACTOR)][0])
        raise InputError(f"track id {bad} cannot be stored in an instance-id PNG (0..999)",
                         field="track_id")
    if len(table) and ((table.class_id < 1).any() or (table.class_id > 65).any()):
        bad = int(table.class_id[(table.class_id < 1) | (table.class_id > 65)][0])
        raise InputError(f"class id {bad} cannot be stored in a 16-bit instance-id PNG (1..65)",
                         field="class_id")
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for frame, t in table.frames():
        img = np.zeros((t.height, t.width), np.uint16)
        ids = t.class_id * ID_FACTOR + t.track_id
        for r, i in zip(t.rles, ids):  # one decode per mask; later masks cover earlier ones
            img[decode(r, t.height, t.width).astype(bool)] = i
        ok, buf = cv2.imencode(".png", img)
        if not ok:
            raise InputError("PNG encoding failed", file=folder / f"{frame:06d}.png")
        path = folder / f"{frame:06d}.png"
        atomic_write_bytes(path, buf.tobytes())
        written.append(path)
    return written
