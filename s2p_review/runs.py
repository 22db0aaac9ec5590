"""Run folders (the output of ``s2p run``) read for review, and checked against their scene.

RUN/run.json, RUN/poses.csv (PoseTable with l, w, h), RUN/views.csv (one row per detection per
view: frame,track_id,camera,class,u,v,xn,yn,zn,dx,dy; u, v pixels; the rest metres).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seg2pose.core.errors import InputError
from seg2pose.io.poses import PoseTable
from seg2pose.io.run import ViewTable, read_run
from seg2pose.io.scene import Scene

# the run folder's files are read by seg2pose.io.run (their one owner); Views is its ViewTable
Views = ViewTable


@dataclass
class Run:
    """A run folder in memory: name (its folder's name as it is; entity paths escape it:
    ``layout.entity_part``), meta (run.json), poses, views."""

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
    path = Path(path)
    folder = read_run(path, known_classes=[c.name for c in scene.classes])
    meta, poses, views = folder.meta, folder.poses, folder.views
    meta_path = path / "run.json"
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
    return Run(path=path, name=path.name, meta=meta, poses=poses, views=views)


def scene_last_frame(scene: Scene) -> int | None:
    """The last frame the scene knows: from the split table, the truth, or the masks' last line
    (read from the file's end, not parsed whole)."""
    last: list[int | None] = []
    if scene.splits:
        last.append(max(b for _, b in scene.splits.values()))
    if scene.gt_path.exists():
        last.append(_last_int_field(scene.gt_path, 0, ","))
    for cam in scene.cameras:
        p = scene.masks_path(cam)
        if p.exists():
            last.append(_last_int_field(p, 0, None))
    known = [v for v in last if v is not None]
    return max(known) if known else None


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
