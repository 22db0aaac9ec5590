"""A mask tracker for masks without track ids (background subtraction, detector output): the
role SORTS plays in the paper.

Per frame, every live track (seen within ``max_gap`` frames) is scored against every new mask
by two cues: the mask IoU with the track's last mask (pycocotools on RLE: no mask is decoded)
and the world distance between the track's predicted position (constant velocity) and the
mask's normal position, which stays informative for small, far-away masks whose IoU collapses
from frame to frame. One Hungarian assignment (``scipy.optimize.linear_sum_assignment``) per
frame picks the pairs; a pair is allowed when IoU >= ``iou_min`` or the distance is inside a
gate that widens with the gap. Unmatched masks start tracks; a track lost for up to
``max_gap`` frames can be picked up again (re-identification after an occlusion); tracks shorter
than ``min_length`` frames are dropped at the end. Deterministic: same input, same ids.

Long sequences are streamed: the first pass keeps only the live tracks and one id per mask,
the second rewrites the masks with their ids.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Callable, Iterable, Iterator

import numpy as np
from pycocotools import mask as mask_util
from scipy.optimize import linear_sum_assignment

from seg2pose.camera import Camera
from seg2pose.errors import InputError
from seg2pose.ground import GroundSurface
from seg2pose.io.mots import MaskTable, iter_mots, write_mots

_BLOCK = 256          # frames whose normal positions are computed together
_INVALID = 1e6        # cost of a forbidden pair
TRACK_HEIGHT = 0.8    # metres: one default height for all masks (no class is known yet)


@dataclass
class TrackConfig:
    """Tracker settings (``scene.json`` ``extra.tracker`` overrides them)."""

    iou_min: float = 0.15     # least IoU with the track's last mask for an association by overlap
    gate_m: float = 2.0       # world distance gate, metres, for a track seen in the previous frame
    gate_growth: float = 0.4  # metres added to the gate per further missed frame
    max_gap: int = 20         # frames a lost track waits to be picked up again
    min_length: int = 5       # shorter tracks (frames with a mask) are dropped
    gap_penalty: float = 0.02  # cost per missed frame: recent tracks win ties

    @classmethod
    def from_dict(cls, d: dict | None, file: Path | None = None) -> "TrackConfig":
        out = cls()
        known = {f.name for f in fields(cls)}
        for k, v in (d or {}).items():
            if k not in known:
                raise InputError(f"unknown setting {k!r}; known: {', '.join(sorted(known))}",
                                 file=file, field=f"extra.tracker.{k}")
            if isinstance(v, bool) or not isinstance(v, (int, float)) or v < 0:
                raise InputError(f"expected a number >= 0, got {v!r}", file=file,
                                 field=f"extra.tracker.{k}")
            setattr(out, k, type(getattr(out, k))(v))
        return out

    def to_dict(self) -> dict:
        return asdict(self)


class Tracker:
    """Frame-by-frame association. ``update`` returns a provisional id per mask; ``final_ids``
    turns all ids handed out into the final ones (short tracks -> -1, ids renumbered 1.. in
    order of first appearance)."""

    def __init__(self, height: int, width: int, cfg: TrackConfig | None = None):
        self.cfg = cfg or TrackConfig()
        self.size = [int(height), int(width)]
        self.ids = np.zeros(0, np.int64)       # live tracks
        self.last = np.zeros(0, np.int64)      # frame each was last seen
        self.pos = np.zeros((0, 2))            # last world position (x, y) metres, NaN unknown
        self.vel = np.zeros((0, 2))            # metres per frame
        self.rles: list[bytes] = []
        self.length: list[int] = []            # masks per id (index = provisional id)

    def _cost(self, frame: int, rles: list[bytes], xy: np.ndarray) -> np.ndarray:
        c = self.cfg
        gap = (frame - self.last).astype(np.float64)                     # (T,)
        iou = np.asarray(mask_util.iou([{"size": self.size, "counts": r} for r in self.rles],
                                       [{"size": self.size, "counts": r} for r in rles],
                                       [0] * len(rles)), float).reshape(len(self.rles), len(rles))
        pred = self.pos + self.vel * gap[:, None]
        dist = np.linalg.norm(pred[:, None, :] - xy[None, :, :], axis=2)  # (T, D), NaN unknown
        gate = c.gate_m + c.gate_growth * (gap - 1)
        with np.errstate(invalid="ignore"):
            near = dist <= gate[:, None]
            closeness = np.where(near, 1.0 - dist / gate[:, None], 0.0)
        ok = (iou >= c.iou_min) | near
        cost = 1.0 - np.maximum(iou, closeness) + c.gap_penalty * (gap - 1)[:, None]
        return np.where(ok, cost, _INVALID)

    def update(self, frame: int, rles: list[bytes], xy: np.ndarray | None = None) -> np.ndarray:
        """Provisional ids (D,) of one frame's masks. xy: (D, 2) world positions, metres
        (normal positions), NaN where unknown; None = IoU only. Frames must increase."""
        c = self.cfg
        d = len(rles)
        xy = np.full((d, 2), np.nan) if xy is None else np.asarray(xy, float).reshape(d, 2)
        alive = frame - self.last <= c.max_gap
        if not alive.all():
            keep = np.flatnonzero(alive)
            self.ids, self.last = self.ids[keep], self.last[keep]
            self.pos, self.vel = self.pos[keep], self.vel[keep]
            self.rles = [self.rles[i] for i in keep]
        out = np.full(d, -1, np.int64)
        if d == 0:
            return out
        rows = cols = np.zeros(0, np.int64)
        if len(self.ids):
            cost = self._cost(frame, rles, xy)
            rows, cols = linear_sum_assignment(cost)
            good = cost[rows, cols] < _INVALID
            rows, cols = rows[good], cols[good]
        # matched tracks: position, velocity (smoothed, per frame), last mask
        if len(rows):
            gap = (frame - self.last[rows]).astype(np.float64)[:, None]
            step = (xy[cols] - self.pos[rows]) / gap
            fresh = np.isfinite(step).all(axis=1)
            self.vel[rows] = np.where(fresh[:, None] & np.isfinite(self.vel[rows]),
                                      0.6 * self.vel[rows] + 0.4 * step,
                                      np.where(fresh[:, None], step, self.vel[rows]))
            has = np.isfinite(xy[cols]).all(axis=1)
            self.pos[rows] = np.where(has[:, None], xy[cols], self.pos[rows])
            self.last[rows] = frame
            for r, cc in zip(rows, cols):
                self.rles[r] = rles[cc]
            out[cols] = self.ids[rows]
        # births
        new = np.setdiff1d(np.arange(d), cols)
        if len(new):
            nid = np.arange(len(self.length), len(self.length) + len(new))
            self.length.extend([0] * len(new))
            self.ids = np.r_[self.ids, nid]
            self.last = np.r_[self.last, np.full(len(new), frame)]
            self.pos = np.vstack([self.pos, xy[new]])
            self.vel = np.vstack([self.vel, np.zeros((len(new), 2))])
            self.rles.extend(rles[i] for i in new)
            out[new] = nid
        for i in out:
            self.length[i] += 1
        return out

    def final_ids(self, provisional: np.ndarray) -> np.ndarray:
        """Final ids for provisional ones (any shape): tracks shorter than ``min_length`` -> -1,
        the others renumbered 1, 2, ... in order of first appearance."""
        p = np.asarray(provisional, np.int64)
        long_ = np.asarray(self.length) >= max(self.cfg.min_length, 1)
        new = np.full(len(self.length), -1, np.int64)
        new[long_] = np.arange(1, int(long_.sum()) + 1)  # provisional ids are in birth order
        return np.where(p >= 0, new[np.maximum(p, 0)], -1)


def world_positions(table: MaskTable, camera: Camera | None, ground: GroundSurface | None,
                    height: float = TRACK_HEIGHT) -> np.ndarray:
    """(N, 2) metres: where the ray through each mask's bounding-box centre meets the plane
    ``height`` above the ground's mean height (NaN without a camera, or where the ray points
    above the horizon). A cheap stand-in for normal positions: association needs positions
    that are consistent from frame to frame, not exact ones."""
    n = len(table)
    if camera is None or ground is None or n == 0:
        return np.full((n, 2), np.nan)
    box = mask_util.toBbox([{"size": [table.height, table.width], "counts": r}
                            for r in table.rles]).reshape(n, 4)
    cen = box[:, :2] + box[:, 2:] / 2
    d = camera.unproject(cen)
    o = camera.center
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (ground.z_mean + height - o[2]) / d[:, 2]
    s = np.where(s > 0, s, np.nan)
    return o[None, :2] + s[:, None] * d[:, :2]


def _blocks(frames: Iterable[tuple[int, MaskTable]]) -> Iterator[list[tuple[int, MaskTable]]]:
    block: list[tuple[int, MaskTable]] = []
    for item in frames:
        block.append(item)
        if len(block) == _BLOCK:
            yield block
            block = []
    if block:
        yield block


def track_frames(frames: Iterable[tuple[int, MaskTable]], height: int, width: int,
                 camera: Camera | None = None, ground: GroundSurface | None = None,
                 cfg: TrackConfig | None = None, progress: bool = False) -> np.ndarray:
    """Final track ids (N,) for every mask of a frame-ordered stream (in stream order);
    -1 for masks of dropped short tracks."""
    from tqdm import tqdm

    tr = Tracker(height, width, cfg)
    parts = []
    bar = tqdm(desc="tracking", unit="frame", disable=not progress, leave=False)
    last_frame = None
    for block in _blocks(frames):
        tabs = [t for _, t in block]
        xy = world_positions(MaskTable.concat(tabs), camera, ground)
        k = 0
        for f, t in block:
            if last_frame is not None and f <= last_frame:
                raise InputError(f"frame {f} comes after frame {last_frame}: frames must increase")
            last_frame = f
            parts.append(tr.update(f, t.rles, xy[k:k + len(t)]))
            k += len(t)
        bar.update(len(block))
    bar.close()
    return tr.final_ids(np.concatenate(parts) if parts else np.zeros(0, np.int64))


def track_table(table: MaskTable, camera: Camera | None = None,
                ground: GroundSurface | None = None, cfg: TrackConfig | None = None) -> MaskTable:
    """The masks of ``table`` with track ids (frame order; masks of short tracks dropped)."""
    t = table.take(np.argsort(table.frame, kind="stable"))
    ids = track_frames(t.frames(), t.height, t.width, camera, ground, cfg)
    out = MaskTable(t.frame, ids, t.class_id, t.height, t.width, t.rles, t.score)
    return out.take(ids >= 0)


def track_mots(src: str | Path, out: str | Path, camera: Camera | None = None,
               ground: GroundSurface | None = None, cfg: TrackConfig | None = None,
               known_classes=None, progress: bool = False,
               log: Callable[[str], None] = print) -> tuple[int, int]:
    """Track the masks of MOTS file ``src`` into ``out`` (may be the same path; written
    atomically): two streaming passes. Returns (tracks kept, masks kept)."""
    src = Path(src)
    first = None
    for _, t in iter_mots(src, known_classes):
        first = t
        break
    if first is None:
        write_mots(out, [])
        log(f"note: {src} has no masks; wrote an empty file")
        return 0, 0
    ids = track_frames(iter_mots(src, known_classes), first.height, first.width, camera,
                       ground, cfg, progress)

    def rewritten() -> Iterator[MaskTable]:
        k = 0
        for _, t in iter_mots(src, known_classes, check_rles=False):
            tid = ids[k:k + len(t)]
            k += len(t)
            keep = tid >= 0
            if keep.any():
                yield MaskTable(t.frame, tid, t.class_id, t.height, t.width, t.rles).take(keep)

    write_mots(out, rewritten())
    return int(ids.max(initial=0)), int((ids >= 0).sum())
