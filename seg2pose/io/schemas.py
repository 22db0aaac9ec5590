"""The schema of each file type s2p writes and reads (the language: ``io/schema.py``). A writer
checks its data against the same declaration its reader checks the file against, so what one
writes the other accepts:

- ``POSES``: poses.csv (``io/poses.py``; MCAP ``/s2p/poses`` records restore through it);
- ``VIEWS`` and ``check_view_boxes``: views.csv (``io/run.py``; MCAP ``/s2p/views`` records);
- ``MASKS``: masks, MOTS text, COCO JSON and PNG folders (``io/mots.py``, ``io/coco.py``,
  ``io/png.py``; ``s2p import-detections``, ``convert-masks``); ``DETECTION_SCORE`` a detector's
  score (COCO ``score``; ``import-detections --score``);
- ``RUN_META``: run.json (``io/run.py``);
- ``JOURNAL_OPS``: the annotation journal's operations (``annotate/model.py`` applies them when
  an edit is made and when the journal is replayed);
- ``CALIB_FILE``: calib.json (``io/calib_files.py``: written by ``s2p calibrate-camera``, read by
  ``s2p new-scene --calibration``);
- ``frame_limit``: the last frame whose time MCAP and Rerun can hold.

Frames and ids are integers in [0, 2^62) (int64 with room: a frame time in ns cannot overflow
before ``frame_limit`` says so), positions finite metres within +-1e6 (``core.validate``).
"""

from __future__ import annotations

import numpy as np

from seg2pose.core.errors import InputError
from seg2pose.core.validate import MAX_COORD, MAX_ID, MAX_IMAGE_SIDE, MAX_PIXEL_COORD
from seg2pose.io.schema import ListOf, Name, Num, OneOf, Opt, Record, Table, Text

FRAME = Num(0, MAX_ID - 1, integer=True)
ID = Num(-(MAX_ID - 1), MAX_ID - 1, integer=True)  # track and class ids (-1: none yet)
METRES = Num(-MAX_COORD, MAX_COORD, unit="metres")
METRES_OR_NAN = Num(-MAX_COORD, MAX_COORD, nan=True, unit="metres")
PIXELS_OR_NAN = Num(-MAX_PIXEL_COORD, MAX_PIXEL_COORD, nan=True, unit="pixels")
HEADING = Num(nan=True, unit="radians")
SIZE = Num(0, 1000, lo_open=True, nan=True, unit="metres")
RADIUS = Num(0, MAX_COORD, nan=True, unit="metres")
FLAG01 = Num(0, 1, integer=True)
IMAGE_SIDE = Num(1, MAX_IMAGE_SIDE, integer=True, unit="pixels")
DETECTION_SCORE = Num(0, 1)

POSES = Table("poses.csv", {"frame": FRAME, "track_id": ID, "x, y, z": METRES,
                            "heading": HEADING, "l, w, h": SIZE, "r90_m": RADIUS},
              ordered="frame", unique=("frame", "track_id"))

VIEWS = Table("views.csv", {"frame": FRAME, "track_id": ID, "u, v": PIXELS_OR_NAN,
                            "xn, yn, zn": METRES_OR_NAN, "dx, dy": METRES_OR_NAN,
                            "cut, far": FLAG01, "spread_m": Num(0, MAX_COORD, unit="metres"),
                            "r90_m": RADIUS, "box": PIXELS_OR_NAN})

MASKS = Table("masks", {"frame": FRAME, "track_id": ID, "class_id": ID,
                        "height, width": IMAGE_SIDE, "score": Num(0, 1, nan=True)}, ordered="frame",
              unique=("frame", "track_id"), row="detection")


def pose_columns(t) -> dict:
    """The POSES columns of a ``io.poses.PoseTable``."""
    return {"frame": t.frame, "track_id": t.track_id, "x, y, z": t.xyz, "heading": t.heading,
            "l, w, h": t.size, "r90_m": t.r90}


def view_columns(t) -> dict:
    """The VIEWS columns of a ``io.run.ViewTable``."""
    cues = t.cues
    return {"frame": t.frame, "track_id": t.track_id, "u, v": t.uv, "xn, yn, zn": t.normal,
            "dx, dy": t.residual, "cut, far": None if cues is None else cues[:, :2],
            "spread_m": None if cues is None else cues[:, 2], "r90_m": t.r90, "box": t.box}


def mask_columns(t) -> dict:
    """The MASKS columns of a ``io.mots.MaskTable``, frames in order (its writers' order)."""
    order = np.argsort(t.frame, kind="stable")
    return {"frame": t.frame[order], "track_id": t.track_id[order], "class_id": t.class_id[order],
            "height, width": np.full((len(t.frame), 2), [t.height, t.width], np.int64),
            "score": None if t.score is None else t.score[order]}


def check_view_names(camera, cls, *, file=None, lines=None) -> None:
    """views.csv's camera (non-empty) and class (empty: none yet) names: no commas or line
    breaks (the file is split on them) and no surrounding spaces (the reader strips them)."""
    for col, names, empty_ok in (("camera", camera, False), ("class", cls, True)):
        for i, c in enumerate(np.asarray(names, object).tolist()):
            c = str(c)
            if ("," in c or "\n" in c or "\r" in c or c != c.strip()) or (not c and not empty_ok):
                raise InputError(f"{col} must be a name without commas, line breaks or surrounding "
                                 f"spaces{'' if empty_ok else ' (not empty)'}, got {c[:40]!r}", file=file,
                                 line=None if lines is None else int(lines[i]),
                                 field=col if lines is not None else f"row {i + 1} {col}")


def check_view_boxes(box: np.ndarray | None, *, file=None, lines=None) -> None:
    """A view's mask box is all NaN (an empty mask) or finite with x0 <= x1 and y0 <= y1."""
    if box is None or not len(box):
        return
    nan = np.isnan(box).all(axis=1)
    bad = ~nan & ~(np.isfinite(box).all(axis=1) & (box[:, 2] >= box[:, 0]) & (box[:, 3] >= box[:, 1]))
    if bad.any():
        i = int(np.argmax(bad))
        raise InputError("box_x0,box_y0,box_x1,box_y1 must be pixels with x0 <= x1 and y0 <= y1 (all "
                         "nan for an empty mask)", file=file,
                         line=None if lines is None else int(lines[i]),
                         field=None if lines is not None else f"row {i} box")


# --- run.json -------------------------------------------------------------------------------------
COUNT = Num(0, MAX_ID - 1, integer=True)
RUN_META = Record({
    "scene": Opt(Text()), "scene_fingerprint": Opt(Text(64)),
    "config": Opt(Text(100)), "cameras": Opt(ListOf(Name("camera name"))),
    "method": Opt(Text(100)), "center_method": Opt(Text(100)),
    "smooth_frames": Opt(Num(0, 10**6, integer=True)), "models": Opt(dict),
    "baseline_fallback": Opt(ListOf(Text(200))), "split": Opt(Text(100)),
    "frame_range": Opt(ListOf(FRAME, n=2)), "created": Opt(Text(100)),
    "n_frames": Opt(COUNT), "n_views": Opt(COUNT), "n_poses": Opt(COUNT),
    "fps": Opt(Num(1e-3, 1e6)), "start_ns": Opt(Num(0, 2**63 - 1, integer=True)),
})


def check_frame_range(meta: dict, *, file=None) -> None:
    fr = meta.get("frame_range")
    if fr is not None and fr[0] > fr[1]:
        raise InputError(f"expected [first, last] with first <= last, got {fr}", file=file,
                         field="frame_range")


# --- the annotation journal's operations -----------------------------------------------------------
TRACK_ID = Num(1, MAX_ID - 1, integer=True)
KEYFRAME_ROW = ListOf(Num(-MAX_COORD, MAX_COORD), max_len=5)  # [frame, x, y, heading, [flags]]
SPAN = ListOf(FRAME, n=2)
BOX_SIZE = ListOf(Num(0, 1000, lo_open=True, unit="metres"), n=3)  # a track's l, w, h
TRACK = Record({"id": TRACK_ID, "cls": Name("class name"), "size": BOX_SIZE,
                "interp": Opt(Text(40)), "keyframes": Opt(list), "spans": Opt(list),
                "reviewed": Opt(ListOf(SPAN)), "meta": Opt(dict)})
JOURNAL_OPS = {
    "put_track": Record({"op": str, "id": TRACK_ID, "track": Opt(TRACK)}),
    "set_keyframes": Record({"op": str, "id": TRACK_ID, "set": Opt(list), "del": Opt(ListOf(FRAME))}),
    "set_fields": Record({"op": str, "id": TRACK_ID, "fields": dict}),
}
SPAN_KIND = OneOf(("occluded", "outside"))


def keyframe_values(row, *, file=None, field: str = "") -> tuple[int, float, float, float, tuple]:
    """A journal keyframe row ``[frame, x, y, heading, [flags]]`` checked: frame an integer in
    [0, 2^62), x and y finite metres within +-1e6, heading finite, flags a list of strings."""
    if not isinstance(row, list) or len(row) not in (4, 5):
        raise InputError(f"expected [frame, x, y, heading, [flags]], got {repr(row)[:60]}", file=file,
                         field=field)
    f = FRAME.value(row[0], file=file, field=f"{field}[0]")
    x = METRES.value(row[1], file=file, field=f"{field}[1]")
    y = METRES.value(row[2], file=file, field=f"{field}[2]")
    h = Num(unit="radians").value(row[3], file=file, field=f"{field}[3]")
    flags = row[4] if len(row) > 4 else []
    if not isinstance(flags, list) or not all(isinstance(s, str) for s in flags):
        raise InputError(f"expected a list of flags, got {repr(flags)[:40]}", file=file, field=f"{field}[4]")
    return f, x, y, h, tuple(flags)


def check_span(span, *, file=None, field: str = "") -> tuple[int, int, str]:
    """A track span ``[first, last, kind]``: frames in order, kind occluded or outside."""
    if not isinstance(span, list) or len(span) != 3:
        raise InputError(f"expected [first, last, kind], got {repr(span)[:40]}", file=file, field=field)
    a, b = (FRAME.value(v, file=file, field=field) for v in span[:2])
    if b < a:
        raise InputError(f"span {a}..{b}: the last frame comes before the first", file=file, field=field)
    if isinstance(span[2], bool) or span[2] not in SPAN_KIND.values:
        raise InputError(f"expected a span kind occluded or outside, got {repr(span[2])[:40]}",
                         file=file, field=field)
    return a, b, span[2]


# --- calib.json ----------------------------------------------------------------------------------
CALIB_FILE = Record({"cameras": ListOf(dict), "report": Opt(dict)})


def frame_limit(fps: float, start_ns: int | None) -> int:
    """The last frame whose time (``start_ns`` + frame / ``fps`` s, in ns) MCAP and Rerun can
    hold: signed 64-bit nanoseconds from 1970 (Rerun's limit, the tighter of the two)."""
    return int((2**63 - 1 - (start_ns or 0)) / 1e9 * fps) - 1
