"""Run folders (the output of ``s2p run``) read for review, and checked against their scene.

RUN/run.json, RUN/poses.csv (PoseTable with l, w, h), RUN/views.csv (one row per detection per
view: frame,track_id,camera,class,u,v,xn,yn,zn,dx,dy; u, v pixels; the rest metres).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seg2pose.errors import InputError
from seg2pose.io.poses import PoseTable, read_poses
from seg2pose.io.scene import Scene

VIEW_COLUMNS = ["frame", "track_id", "camera", "class", "u", "v", "xn", "yn", "zn", "dx", "dy"]


@dataclass
class Views:
    """Per-view rows of a run. frame, track_id: (N,) int64; camera, cls: (N,) str;
    uv: (N, 2) pixels; xn: (N, 3) normal positions, metres; dxy: (N, 2) residuals, metres."""

    frame: np.ndarray
    track_id: np.ndarray
    camera: np.ndarray
    cls: np.ndarray
    uv: np.ndarray
    xn: np.ndarray
    dxy: np.ndarray

    def __len__(self) -> int:
        return len(self.frame)

    def take(self, idx) -> "Views":
        return Views(self.frame[idx], self.track_id[idx], self.camera[idx], self.cls[idx],
                     self.uv[idx], self.xn[idx], self.dxy[idx])


def read_views(path: Path) -> Views:
    """Read RUN/views.csv; errors name the file, line and what was expected."""
    path = Path(path)
    if not path.exists():
        raise InputError("views file not found", file=path)
    with open(path, encoding="utf-8") as f:
        header = f.readline().strip().split(",")
        if [h.strip() for h in header] != VIEW_COLUMNS:
            raise InputError(f"expected header {','.join(VIEW_COLUMNS)}, got {','.join(header)}",
                             file=path, line=1)
        lines = f.read().splitlines()
    rows = [ln.split(",") for ln in lines if ln.strip()]
    linenos = [i + 2 for i, ln in enumerate(lines) if ln.strip()]
    for r, ln in zip(rows, linenos):
        if len(r) != len(VIEW_COLUMNS):
            raise InputError(f"expected {len(VIEW_COLUMNS)} fields, got {len(r)}", file=path, line=ln)
    if not rows:
        z = np.zeros(0)
        return Views(z.astype(np.int64), z.astype(np.int64), z.astype(object), z.astype(object),
                     np.zeros((0, 2)), np.zeros((0, 3)), np.zeros((0, 2)))
    a = np.array(rows, dtype=object)
    try:
        ints = a[:, :2].astype(np.int64)
    except ValueError:
        bad = next(ln for r, ln in zip(rows, linenos) if not (r[0].strip().lstrip("-").isdigit()
                                                            and r[1].strip().lstrip("-").isdigit()))
        raise InputError("frame and track_id must be integers", file=path, line=bad) from None
    try:
        nums = a[:, 4:].astype(np.float64)
    except ValueError:
        for r, ln in zip(rows, linenos):
            try:
                [float(x) for x in r[4:]]
            except ValueError:
                raise InputError("expected numbers in u,v,xn,yn,zn,dx,dy", file=path, line=ln) from None
        raise
    return Views(ints[:, 0], ints[:, 1], np.char.strip(a[:, 2].astype(str)).astype(object),
                 np.char.strip(a[:, 3].astype(str)).astype(object), nums[:, 0:2], nums[:, 2:5],
                 nums[:, 5:7])


@dataclass
class Run:
    """A run folder in memory: name (entity path part), meta (run.json), poses, views."""

    path: Path
    name: str
    meta: dict
    poses: PoseTable
    views: Views | None

    @property
    def cameras(self) -> list[str]:
        return list(self.meta.get("cameras") or [])

    @property
    def frame_range(self) -> tuple[int, int] | None:
        fr = self.poses.frame if self.views is None else np.r_[self.poses.frame, self.views.frame]
        return (int(fr.min()), int(fr.max())) if len(fr) else None


def load_run(path: Path, scene: Scene, scene_last_frame: int | None = None) -> Run:
    """Read a run folder and check it against ``scene``: its cameras must exist in the scene,
    its classes must be known and its frames must lie within ``scene_last_frame`` (when known)."""
    from s2p_review.layout import safe_name

    path = Path(path)
    if not path.is_dir():
        raise InputError("run folder not found", file=path)
    meta_path = path / "run.json"
    if not meta_path.exists():
        raise InputError("no run.json here (is this a run folder made by `s2p run`?)", file=meta_path)
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as e:
        raise InputError(f"invalid JSON: {e.msg}", file=meta_path, line=e.lineno) from None
    if not isinstance(meta, dict):
        raise InputError("expected a JSON object", file=meta_path)
    fp = meta.get("scene_fingerprint")
    if fp and fp != scene.fingerprint():
        raise InputError(f"the run was made on another scene: its scene fingerprint is {fp}, "
                         f"{scene.root} has {scene.fingerprint()} (other calibration or ground "
                         f"points)", file=meta_path, field="scene_fingerprint")
    cams = meta.get("cameras") or []
    if not isinstance(cams, list):
        raise InputError("expected a list of camera names", file=meta_path, field="cameras")
    unknown = [c for c in cams if c not in scene.cameras]
    if unknown:
        raise InputError(f"the run names cameras the scene {scene.name!r} lacks: {unknown}; "
                         f"the scene has {sorted(scene.cameras)}", file=meta_path, field="cameras")
    poses = read_poses(path / "poses.csv", known_classes=[c.name for c in scene.classes])
    views = read_views(path / "views.csv") if (path / "views.csv").exists() else None
    if views is not None and len(views):
        bad = sorted(set(views.camera.tolist()) - set(scene.cameras))
        if bad:
            raise InputError(f"views name cameras the scene {scene.name!r} lacks: {bad}",
                             file=path / "views.csv", field="camera")
        if not cams:
            meta["cameras"] = sorted(set(views.camera.tolist()))
    if scene_last_frame is not None:
        for what, fr, f in (("poses", poses.frame, path / "poses.csv"),
                            ("views", None if views is None else views.frame, path / "views.csv")):
            if fr is not None and len(fr) and (fr.max() > scene_last_frame or fr.min() < 0):
                raise InputError(f"{what} reach frame {int(fr.max())} (min {int(fr.min())}) but the "
                                 f"scene's frames are 0..{scene_last_frame}", file=f, field="frame")
    return Run(path=path, name=safe_name(path.name), meta=meta, poses=poses, views=views)


def scene_last_frame(scene: Scene) -> int | None:
    """The last frame the scene knows: from the split table, the truth, or the masks' last line
    (read from the file's end, not parsed whole)."""
    last = []
    if scene.splits:
        last.append(max(b for _, b in scene.splits.values()))
    if scene.gt_path.exists():
        last.append(_last_int_field(scene.gt_path, 0, ","))
    for cam in scene.cameras:
        p = scene.masks_path(cam)
        if p.exists():
            last.append(_last_int_field(p, 0, None))
    last = [v for v in last if v is not None]
    return max(last) if last else None


def _last_int_field(path: Path, col: int, sep: str | None) -> int | None:
    """The integer in column ``col`` of the last non-empty line of a text file."""
    with open(path, "rb") as f:
        f.seek(0, 2)
        size = f.tell()
        f.seek(max(0, size - 65536))
        tail = f.read().decode("ascii", "replace").splitlines()
    for ln in reversed(tail):
        parts = ln.split(sep)
        if parts and parts[0].strip():
            try:
                return int(parts[col])
            except ValueError:
                return None
    return None
