"""What the engine knows besides the annotator: a run folder's Seg2Pose estimates, the normal
positions of a scene's masks (paper 3.2) — for placement, pre-annotation and suggestions — and
the scene's frame range."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from annotate.model import EditError
from seg2pose.core.errors import InputError
from seg2pose.geometry.normal import DEFAULT_CENTER_METHOD, normal_positions
from seg2pose.io.mots import MaskTable
from seg2pose.io.poses import PoseTable
from seg2pose.io.scene import Scene
from seg2pose.structures.masks import mask_centers


def _fill_headings(table: PoseTable) -> np.ndarray:
    """Headings (N,) with NaN (a track that has not moved yet, eq. 2) replaced by the track's
    nearest finite heading; 0 where a track never has one. Rows sorted by track, frame."""
    h = table.heading.copy()
    tid = table.track_id
    starts = np.flatnonzero(np.r_[True, tid[1:] != tid[:-1]])
    ends = np.r_[starts[1:], len(tid)]
    for a, b in zip(starts, ends):
        seg = h[a:b]
        ok = np.flatnonzero(np.isfinite(seg))
        if not len(ok):
            seg[:] = 0.0
            continue
        idx = np.arange(len(seg))
        nearest = ok[np.clip(np.searchsorted(ok, idx), 0, len(ok) - 1)]
        prev = ok[np.clip(np.searchsorted(ok, idx, side="right") - 1, 0, len(ok) - 1)]
        pick = np.where(np.abs(prev - idx) <= np.abs(nearest - idx), prev, nearest)
        h[a:b] = seg[pick]
    return h


class RunEstimates:
    """A run folder's fused poses (``RUN/poses.csv``), indexed by (track, frame)."""

    def __init__(self, table: PoseTable, path: Path):
        order = np.lexsort((table.frame, table.track_id))
        self.table = table.take(order)
        self.table.heading = _fill_headings(self.table)
        self.path = path
        keys = self.table.track_id * (1 << 32) + self.table.frame
        self._keys = keys

    @classmethod
    def load(cls, run: str | Path, scene: Scene) -> RunEstimates:
        """Read ``RUN/poses.csv``; refuse a run made on another scene (run.json's fingerprint)."""
        from seg2pose.io.run import RUN_FILE, read_run_meta, read_run_poses

        run = Path(run)
        if (run / RUN_FILE).exists():
            fp = read_run_meta(run).get("scene_fingerprint")
            if fp is not None and fp != scene.fingerprint():
                raise InputError(f"this run was made on another scene (fingerprint {fp}, this "
                                 f"scene's is {scene.fingerprint()})", file=run / RUN_FILE,
                                 field="scene_fingerprint")
        table = read_run_poses(run, known_classes=scene.class_names)
        return cls(table.take(table.track_id >= 0), run)

    def at(self, run_track: int, frame: int) -> tuple[float, float, float] | None:
        """(x, y, heading) of a run track at a frame, None when it has no estimate there."""
        k = int(run_track) * (1 << 32) + int(frame)
        i = int(np.searchsorted(self._keys, k))
        if i < len(self._keys) and self._keys[i] == k:
            return (float(self.table.xyz[i, 0]), float(self.table.xyz[i, 1]),
                    float(self.table.heading[i]))
        return None

    def track(self, run_track: int) -> PoseTable:
        """All estimates of one run track, by frame."""
        return self.table.take(self.table.track_id == int(run_track))

    def track_ids(self) -> np.ndarray:
        return np.unique(self.table.track_id)

    def frames(self, frame: int) -> PoseTable:
        return self.table.take(self.table.frame == int(frame))


class MaskIndex:
    """A scene's masks per camera, read on first use, with their normal positions by frame."""

    def __init__(self, scene: Scene):
        self.scene = scene
        self._tables: dict[str, MaskTable] = {}

    def table(self, camera: str) -> MaskTable:
        if camera not in self.scene.cameras:
            raise EditError(f"unknown camera {camera!r}; the scene has {', '.join(self.scene.cameras)}")
        if camera not in self._tables:
            self._tables[camera] = self.scene.read_masks(camera)  # checked against the camera
        return self._tables[camera]

    def presence(self) -> dict[int, np.ndarray]:
        """Mask track id -> sorted frames in which some camera has its mask (presence.py)."""
        if getattr(self, "_presence", None) is None:
            from annotate.presence import presence
            self._presence = presence(self.table(c) for c in self.scene.cameras)
        return self._presence

    def seen(self, road_user: int) -> np.ndarray | None:
        """Frames in which some camera has a mask of ``road_user`` (a mask track id); None when
        no mask carries that id (the run's ids are not the masks': presence unknown)."""
        return self.presence().get(int(road_user))

    def normal_position(self, camera: str, frame: int, mask_track: int
                        ) -> tuple[float, float, str]:
        """Normal position (x, y metres) and class name of one mask (camera, frame, its track id)."""
        t = self.table(camera)
        hit = np.flatnonzero((t.frame == frame) & (t.track_id == mask_track))
        if not len(hit):
            raise EditError(f"camera {camera} has no mask of track {mask_track} in frame {frame}")
        xy, cls = self.normal_positions(camera, t.take(hit[:1]))
        if not np.isfinite(xy[0, 0]):
            raise EditError(f"the ray through mask {mask_track} (camera {camera}, frame {frame}) "
                            "misses the ground")
        return float(xy[0, 0]), float(xy[0, 1]), str(cls[0])

    def normal_positions(self, camera: str, t: MaskTable) -> tuple[np.ndarray, np.ndarray]:
        """Normal positions (N, 2) metres (NaN: no class or a missed ray) and class names (N,)."""
        by_id = self.scene.class_by_id()
        cls = np.array([by_id[c].name if c in by_id else "" for c in t.class_id], dtype=object)
        h = np.array([by_id[c].default_height if c in by_id else np.nan for c in t.class_id])
        out = np.full((len(t), 2), np.nan)
        ok = np.isfinite(h)
        if ok.any():
            uv = mask_centers([t.rles[i] for i in np.flatnonzero(ok)], t.height, t.width,
                              DEFAULT_CENTER_METHOD)
            X, _ = normal_positions(self.scene.cameras[camera], self.scene.ground, uv, h[ok])
            out[ok] = X[:, :2]
        return out, cls

    def fused_normal_positions(self, cameras: list[str] | None = None) -> PoseTable:
        """Late fusion (3.3) of all masks' normal positions per (frame, mask track id): a
        reference for suggestions when no run exists. Heading NaN."""
        cams = list(self.scene.cameras) if cameras is None else cameras
        rows = []
        for cam in cams:
            t = self.table(cam)
            t = t.take(t.track_id >= 0)
            xy, cls = self.normal_positions(cam, t)
            rows.append((t.frame, t.track_id, cls, xy))
        if not rows:
            return PoseTable.empty()
        frame = np.concatenate([r[0] for r in rows])
        tid = np.concatenate([r[1] for r in rows])
        cls = np.concatenate([r[2] for r in rows])
        xy = np.concatenate([r[3] for r in rows])
        ok = np.isfinite(xy[:, 0])
        frame, tid, cls, xy = frame[ok], tid[ok], cls[ok], xy[ok]
        keys, first, inv = np.unique(np.stack([frame, tid], 1), axis=0, return_index=True,
                                     return_inverse=True)
        inv = inv.reshape(-1)
        n = np.bincount(inv, minlength=len(keys)).astype(float)
        mx = np.bincount(inv, xy[:, 0], len(keys)) / n
        my = np.bincount(inv, xy[:, 1], len(keys)) / n
        z = self.scene.ground.height(np.column_stack([mx, my]))
        return PoseTable(keys[:, 0], keys[:, 1], cls[first], np.column_stack([mx, my, z]),
                         np.full(len(keys), np.nan))


def scene_frames(scene: Scene) -> tuple[int, int] | None:
    """(first, last) frame of a scene: its splits' extent, else the last frame of its masks
    files (read from their ends), else None (unknown: only frame >= 0 is checked)."""
    if scene.splits:
        return 0, max(b for _, b in scene.splits.values())
    if isinstance(scene.extra.get("frames"), int):
        return 0, int(scene.extra["frames"]) - 1
    last = -1
    for cam in scene.cameras:
        last = max(last, _last_mask_frame(scene.masks_path(cam)))
    return (0, last) if last >= 0 else None


def _last_mask_frame(path: Path) -> int:
    try:
        with open(path, "rb") as f:
            f.seek(0, 2)
            f.seek(max(f.tell() - 65536, 0))
            lines = f.read().splitlines()
    except OSError:
        return -1
    for line in reversed(lines):
        parts = line.split()
        if parts and not parts[0].startswith(b"#"):
            try:
                return int(parts[0])
            except ValueError:
                return -1
    return -1
