"""The run folder: the one module that reads and writes it.

A run folder is the contract between ``s2p run`` (pipeline), evaluation, review and export::

    RUN/run.json    {"scene" (path of the scene folder relative to RUN), "scene_fingerprint",
                     "config", "cameras", "method", "center_method", "models" (per
                     "camera/class": "path" relative to RUN, "file", "sha256", "val_loss",
                     "epoch", "seed"), "split", "frame_range", "created", "n_frames",
                     "n_views", "n_poses"}
    RUN/poses.csv   fused poses: frame,track_id,class,x,y,z,heading,l,w,h (metres, radians)
    RUN/track_heights.csv  (runs with --track-heights) track_id,class,default_height,height,
                    n_views: the height fitted per road user; run.json's "track_heights" holds
                    the settings, views.csv the normal positions at those heights
    RUN/views.csv   one row per detection per view: frame,track_id,camera,class,u,v,xn,yn,zn,dx,dy
                    (u, v mask centre in pixels; xn, yn, zn normal position, metres; dx, dy the
                    Seg2PoseNet residual, metres, 0 for the baseline), then (runs since r90_m)
                    cut,far,spread_m,r90_m: the mask touches the image border (0/1), the
                    residual was flagged far (0/1), the spread of an ensemble's residuals
                    (metres, 0 for one model) and the view's error bar (metres, 90 %; NaN
                    without a calibration; ``seg2pose.method.uncertainty``), then (runs since
                    the size cue) box_x0,box_y0,box_x1,box_y1: the mask's bounding box, pixels
                    (x1, y1 exclusive; NaN for an empty mask)

The folder is written as a unit (``write_run_folder``): the files go into a temporary sibling
folder, are flushed to disk, and the folder is renamed into place, so a reader never sees a mix
of two runs. A second writer of the same folder is refused while the first holds its lock file
(``.RUN.lock`` beside the folder: pid, host, time); the lock of a process that died is taken
over with a note.
"""

from __future__ import annotations

import io
import json
import os
import re
import shutil
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seg2pose.core.errors import InputError, S2PError
from seg2pose.io.atomic import atomic_write_text, os_errors, output_lock, swap_in, temp_sibling_dir
from seg2pose.io.poses import PoseTable, format_poses, read_poses
from seg2pose.io.schema import check
from seg2pose.io.schemas import RUN_META, VIEWS, check_frame_range, check_view_boxes, check_view_names, view_columns
from seg2pose.io.text import load_json, read_text

_INT = re.compile(r"^[+-]?[0-9]{1,18}$")  # int64 without overflow (the range is VIEWS')
RUN_FILE = "run.json"
POSES_FILE = "poses.csv"
VIEWS_FILE = "views.csv"
VIEW_COLUMNS = ["frame", "track_id", "camera", "class", "u", "v", "xn", "yn", "zn", "dx", "dy"]
CUE_COLUMNS = ["cut", "far", "spread_m", "r90_m"]  # optional: files without them stay valid
BOX_COLUMNS = ["box_x0", "box_y0", "box_x1", "box_y1"]  # optional, after CUE_COLUMNS


# ----------------------------------------------------------------------------------------------
# views.csv


@dataclass
class ViewTable:
    """Per-view rows of a run, column-wise. frame, track_id: (N,) int64; camera, cls: (N,) str;
    uv: (N, 2) mask centres, pixels; normal: (N, 3) normal positions, metres (NaN where the ray
    missed the ground); residual: (N, 2) Seg2PoseNet residuals, metres (0 for the baseline);
    cues: (N, 3) what the error bar is estimated from -- mask cut by the image border (0/1),
    residual flagged far (0/1), ensemble spread (metres) -- and r90: (N,) the view's error bar,
    metres; both None for a views.csv without them. box: (N, 4) the mask's bounding box
    x0, y0, x1, y1, pixels (NaN for an empty mask); None for a views.csv without it (it needs
    the cues)."""

    frame: np.ndarray
    track_id: np.ndarray
    camera: np.ndarray
    cls: np.ndarray
    uv: np.ndarray
    normal: np.ndarray
    residual: np.ndarray
    cues: np.ndarray | None = None
    r90: np.ndarray | None = None
    box: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.frame = np.asarray(self.frame, dtype=np.int64).reshape(-1)
        if self.box is not None:
            if self.cues is None:
                raise ValueError("ViewTable: box needs the cues")
            self.box = np.asarray(self.box, dtype=np.float64).reshape(-1, 4)
        if self.cues is not None:
            self.cues = np.asarray(self.cues, dtype=np.float64).reshape(-1, 3)
            self.r90 = (np.full(len(self.cues), np.nan) if self.r90 is None
                        else np.asarray(self.r90, dtype=np.float64).reshape(-1))
        elif self.r90 is not None:
            raise ValueError("ViewTable: r90 needs the cues it was estimated from")
        self.track_id = np.asarray(self.track_id, dtype=np.int64).reshape(-1)
        self.camera = np.asarray(self.camera, dtype=object).reshape(-1)
        self.cls = np.asarray(self.cls, dtype=object).reshape(-1)
        self.uv = np.asarray(self.uv, dtype=np.float64).reshape(-1, 2)
        self.normal = np.asarray(self.normal, dtype=np.float64).reshape(-1, 3)
        self.residual = np.asarray(self.residual, dtype=np.float64).reshape(-1, 2)
        n = len(self.frame)
        optional = [c for c in (self.cues, self.r90, self.box) if c is not None]
        if not all(len(c) == n for c in (self.track_id, self.camera, self.cls, self.uv,
                                         self.normal, self.residual, *optional)):
            raise ValueError("ViewTable columns differ in length")

    def __len__(self) -> int:
        return len(self.frame)

    def take(self, idx) -> ViewTable:
        return ViewTable(self.frame[idx], self.track_id[idx], self.camera[idx], self.cls[idx],
                         self.uv[idx], self.normal[idx], self.residual[idx],
                         None if self.cues is None else self.cues[idx],
                         None if self.r90 is None else self.r90[idx],  # (set with the cues)
                         None if self.box is None else self.box[idx])

    def sorted(self) -> ViewTable:
        """Rows by frame, track id, camera (the order ``s2p run`` writes)."""
        return self.take(np.lexsort((self.camera, self.track_id, self.frame)))

    def of_cameras(self, cameras: Iterable[str]) -> ViewTable:
        """The rows seen by ``cameras``."""
        return self.take(np.isin(self.camera, list(cameras)))

    @classmethod
    def empty(cls) -> ViewTable:
        return cls(np.zeros(0), np.zeros(0), np.zeros(0, object), np.zeros(0, object),
                   np.zeros((0, 2)), np.zeros((0, 3)), np.zeros((0, 2)))

    @classmethod
    def concat(cls, tables: Iterable[ViewTable]) -> ViewTable:
        tables = list(tables)
        if not tables:
            return cls.empty()
        cols = [np.concatenate([getattr(t, k) for t in tables])
                for k in ("frame", "track_id", "camera", "cls", "uv", "normal", "residual")]
        if all(t.cues is not None for t in tables):
            cols += [np.concatenate([t.cues for t in tables]), np.concatenate([t.r90 for t in tables])]
            if all(t.box is not None for t in tables):
                cols.append(np.concatenate([t.box for t in tables]))
        return cls(*cols)


def format_views(table: ViewTable, file: str | Path | None = None) -> str:
    """views.csv text, rows in the table's order; floats with ``repr`` (exact round trip).
    What ``read_views`` would refuse (``io.schemas.VIEWS``) is refused first."""
    VIEWS.check(view_columns(table), file=file)
    check_view_boxes(table.box, file=file)
    check_view_names(table.camera, table.cls, file=file)
    buf = io.StringIO()
    cues = table.cues is not None
    box = table.box is not None
    buf.write(",".join(VIEW_COLUMNS + (CUE_COLUMNS if cues else []) + (BOX_COLUMNS if box else []))
              + "\n")
    num = np.column_stack([table.uv, table.normal, table.residual]  # then cues, r90, box if there
                          + [c for c in (table.cues, table.r90, table.box) if c is not None])
    for i in range(len(table)):
        buf.write(f"{table.frame[i]},{table.track_id[i]},{table.camera[i]},{table.cls[i]},"
                  + ",".join(repr(float(x)) for x in num[i]) + "\n")
    return buf.getvalue()


def read_views(path: str | Path) -> ViewTable:
    """Read RUN/views.csv; errors name the file, line and what was expected."""
    path = Path(path)
    first, _, rest = read_text(path, "views file").partition("\n")
    header = [h.strip() for h in first.strip().split(",")]
    if header not in (VIEW_COLUMNS, VIEW_COLUMNS + CUE_COLUMNS,
                      VIEW_COLUMNS + CUE_COLUMNS + BOX_COLUMNS):
        raise InputError(f"expected header {','.join(VIEW_COLUMNS)}[,{','.join(CUE_COLUMNS)}"
                         f"[,{','.join(BOX_COLUMNS)}]], got {','.join(header)[:200]}", file=path,
                         line=1)
    lines = rest.split("\n")
    rows = [ln.split(",") for ln in lines if ln.strip()]
    linenos = [i + 2 for i, ln in enumerate(lines) if ln.strip()]
    for r, ln in zip(rows, linenos):
        if len(r) != len(header):
            raise InputError(f"expected {len(header)} fields, got {len(r)}", file=path, line=ln)
    if not rows:
        return ViewTable.empty()
    a = np.array(rows, dtype=object)
    for r, ln in zip(rows, linenos):  # int() would take "1_4", "\u0663" and 30 digits
        if not (_INT.match(r[0].strip()) and _INT.match(r[1].strip())):
            raise InputError(f"frame and track_id must be integers, got {r[:2]}", file=path, line=ln)
    ints = a[:, :2].astype(np.int64)
    try:
        nums = a[:, 4:].astype(np.float64)
    except ValueError:
        for r, ln in zip(rows, linenos):
            try:
                [float(x) for x in r[4:]]
            except ValueError:
                raise InputError(f"expected numbers in {','.join(header[4:])}", file=path,
                                 line=ln) from None
        raise
    cues = nums.shape[1] > 7
    box = nums[:, 11:15] if nums.shape[1] > 11 else None
    t = ViewTable(ints[:, 0], ints[:, 1], np.char.strip(a[:, 2].astype(str)).astype(object),
                  np.char.strip(a[:, 3].astype(str)).astype(object), nums[:, 0:2], nums[:, 2:5],
                  nums[:, 5:7], nums[:, 7:10] if cues else None, nums[:, 10] if cues else None, box)
    VIEWS.check(view_columns(t), file=path, lines=linenos)
    check_view_names(t.camera, t.cls, file=path, lines=linenos)
    check_view_boxes(box, file=path, lines=linenos)
    return t



# ----------------------------------------------------------------------------------------------
# run.json


def read_run_meta(path: str | Path) -> dict:
    """RUN/run.json as a dict (``path`` is the run folder)."""
    meta_path = Path(path) / RUN_FILE
    if not meta_path.exists():
        raise InputError("no run.json here (is this a run folder made by `s2p run`?)", file=meta_path)
    meta = load_json(meta_path, "run.json")
    if not isinstance(meta, dict):
        raise InputError("expected a JSON object", file=meta_path)
    check_run_meta(meta, file=meta_path)
    return meta


def check_run_meta(meta: dict, file=None) -> None:
    """run.json's fields against ``io.schemas.RUN_META`` (its writer and its reader)."""
    check(meta, RUN_META, file=file)
    check_frame_range(meta, file=file)
    try:  # Python's json reads NaN and Infinity, which JSON does not have
        json.dumps(meta, allow_nan=False)
    except ValueError:
        raise InputError("a value of run.json is not a finite number", file=file) from None


def run_meta_text(meta: dict, file=None) -> str:
    """run.json's text: checked as its reader checks it, JSON without NaN."""
    check_run_meta(meta, file=file)
    return json.dumps(meta, indent=1, allow_nan=False) + "\n"


def relative_path(target: str | Path, folder: str | Path) -> str:
    """``target`` as a path relative to ``folder`` (run.json holds no machine-specific
    absolute paths; POSIX separators)."""
    return Path(os.path.relpath(Path(target).resolve(), Path(folder).resolve())).as_posix()


# ----------------------------------------------------------------------------------------------
# the whole folder


@dataclass
class RunFolder:
    """A run folder in memory: path, meta (run.json), poses, views (None without views.csv)."""

    path: Path
    meta: dict
    poses: PoseTable
    views: ViewTable | None


def read_run(path: str | Path, known_classes: Iterable[str] | None = None) -> RunFolder:
    """Read RUN/run.json, RUN/poses.csv and (when present) RUN/views.csv."""
    path = Path(path)
    if not path.is_dir():
        raise InputError("run folder not found", file=path)
    meta = read_run_meta(path)
    poses = read_poses(path / POSES_FILE, known_classes=known_classes)
    views = read_views(path / VIEWS_FILE) if (path / VIEWS_FILE).exists() else None
    return RunFolder(path, meta, poses, views)


def read_run_poses(path: str | Path, known_classes: Iterable[str] | None = None) -> PoseTable:
    """Only RUN/poses.csv (evaluation needs no more)."""
    return read_poses(Path(path) / POSES_FILE, known_classes=known_classes)


def run_lock(run_dir: str | Path):
    """Hold ``.RUN.lock`` beside ``run_dir`` while writing it (``seg2pose.io.atomic.output_lock``:
    a live holder is refused; the lock of a process that no longer runs is taken over)."""
    return output_lock(run_dir)


def check_run_writable(run_dir: str | Path, force: bool) -> None:
    """Refuse an existing non-empty ``run_dir`` unless ``force``."""
    run_dir = Path(run_dir)
    if run_dir.exists() and (not run_dir.is_dir() or any(run_dir.iterdir())) and not force:
        raise S2PError(f"{run_dir} exists and is not empty; pass --force to overwrite it")


def write_run_folder(run_dir: str | Path, poses: PoseTable, views: ViewTable | None, meta: dict,
                     force: bool = False, extra_files: dict[str, str] | None = None) -> Path:
    """Write RUN/poses.csv, RUN/views.csv (when ``views`` is given) and RUN/run.json as a unit:
    into a temporary sibling folder, flushed, then renamed into place; an existing non-empty
    ``run_dir`` is only replaced with ``force`` (the new folder is swapped in, then the old one
    removed). ``extra_files``: more text files of the run (name -> text, e.g. flagged.csv).
    Returns ``run_dir``."""
    run_dir = Path(run_dir)
    for name in extra_files or {}:
        if Path(name).name != name or name in (POSES_FILE, VIEWS_FILE, RUN_FILE):
            raise ValueError(f"not an extra run file name: {name!r}")
    texts = {POSES_FILE: format_poses(poses, file=run_dir / POSES_FILE),
             RUN_FILE: run_meta_text(meta, file=run_dir / RUN_FILE)}
    if views is not None:
        texts[VIEWS_FILE] = format_views(views, file=run_dir / VIEWS_FILE)
    with output_lock(run_dir):
        check_run_writable(run_dir, force)
        tmp = temp_sibling_dir(run_dir)
        try:
            with os_errors(run_dir):
                for name, text in {**texts, **(extra_files or {})}.items():
                    atomic_write_text(tmp / name, text)
                swap_in(tmp, run_dir)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
    return run_dir
