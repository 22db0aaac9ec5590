"""A mask tracker for masks without track ids (background subtraction, detector output): the
role SORTS plays in the paper.

Per frame, every live track (seen within ``max_gap`` frames) is scored against every new mask
by two cues: the mask IoU with the track's last mask (pycocotools on RLE: no mask is decoded)
and the world distance between the track's predicted position (constant velocity) and the
mask's normal position, which stays informative for small, far-away masks whose IoU collapses
from frame to frame. One Hungarian assignment (``scipy.optimize.linear_sum_assignment``) per
frame picks the pairs; a pair is allowed when IoU >= ``iou_min`` or the distance is inside a
gate that widens with the gap. First (``split_min`` > 0, the default), a mask that holds most
of the predicted masks of two or more established tracks (road users that overlap in the image
and came out of background subtraction as one blob) is split between them: each track's shape
(its last whole mask, carried along by its pixel motion while it is merged) is its predicted
mask, a pixel inside several goes to the nearest road user (the one reaching lowest in the
image), a pixel outside all to the nearest predicted mask. Unmatched masks start tracks; a
track lost for up to ``max_gap`` frames can be picked up again (re-identification after an
occlusion); tracks shorter than ``min_length`` frames are dropped at the end. Deterministic: same input, same ids.

Long sequences are streamed: the first pass keeps only the live tracks and one id per mask,
the second runs the same (deterministic) tracker again and writes the masks with final ids.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np
from pycocotools import mask as mask_util
from scipy.optimize import linear_sum_assignment

from seg2pose.core.errors import InputError
from seg2pose.geometry.camera import Camera
from seg2pose.geometry.ground import GroundSurface
from seg2pose.io.mots import MaskTable, iter_mots, write_mots
from seg2pose.io.schema import Num, read_settings
from seg2pose.video.track_split import BlobSplitting

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
    split_min: float = 0.5    # > 0: a mask holding this share of two or more tracks' predicted
    #                           masks is split between them (merged blobs); 0: off. Chosen on
    #                           seeds 101-102 (docs/RESULTS.md): recall +3 to +8 points
    # fragments of one road user joined (seg2pose.video.fragments; video masks only): tracks
    # sharing >= join_min_s seconds, touching in >= join_near of them, rigid within join_rigid
    # of their size, whose union is >= join_gain more likely under a size class; 0 gain: off
    join_gain: float = 0.4
    join_near: float = 0.8
    join_rigid: float = 0.3
    join_min_s: float = 1.0

    @classmethod
    def from_dict(cls, d: dict | None, file: Path | None = None) -> TrackConfig:
        """Settings from scene.json's ``extra.tracker`` merged with ``--set``: numbers finite and
        >= 0 (nan was taken before), integers JSON integers (max_gap=2.5 was cut to 2), shares
        in [0, 1] (``io.schema.read_settings``)."""
        return read_settings(cls(), d, {k: Num(0, 1) for k in ("iou_min", "split_min", "join_near")},
                             file=file, section="tracker")

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class LiveTracks:
    """The tracks alive now, one row per track, as a column table: every column has one entry
    per row; ``take`` and ``append`` keep them together."""

    ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # provisional ids
    last: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # frame last seen
    # last world position (x, y) metres, NaN unknown; velocity, metres per frame
    pos: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    vel: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    # last mask's box centre, pixels; its motion, pixels per frame (NaN: seen once)
    box: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    pxvel: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    rles: list[bytes] = field(default_factory=list)  # last mask
    # last whole mask (not a part cut from a merged blob), carried along by the track's motion
    # while it is merged: what the road user looks like when nothing hides it; its box
    # (x, y, w, h) and area, pixels
    shape: list[bytes] = field(default_factory=list)
    shape_box: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    shape_area: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __len__(self) -> int:
        return len(self.ids)

    def take(self, rows: np.ndarray) -> LiveTracks:
        """The rows ``rows`` (indices), in that order."""
        return LiveTracks(**{f.name: [col[i] for i in rows] if isinstance(col, list) else col[rows]  # type: ignore[arg-type]  # list or array columns, by field
                             for f in fields(self) for col in [getattr(self, f.name)]})

    def append(self, more: LiveTracks) -> LiveTracks:
        """These rows, then ``more``'s."""
        return LiveTracks(**{f.name: a + b if isinstance(a, list) else np.concatenate([a, b])  # type: ignore[arg-type]  # list or array columns, by field
                             for f in fields(self)
                             for a, b in [(getattr(self, f.name), getattr(more, f.name))]})


class Tracker(BlobSplitting):
    """Frame-by-frame association. ``update`` returns a provisional id per mask; ``final_ids``
    turns all ids handed out into the final ones (short tracks -> -1, ids renumbered 1.. in
    order of first appearance). Merged masks are split first (``BlobSplitting``,
    ``seg2pose.video.track_split``)."""

    def __init__(self, height: int, width: int, cfg: TrackConfig | None = None):
        self.cfg = cfg or TrackConfig()
        self.size = [int(height), int(width)]
        self.live = LiveTracks()               # the tracks alive now, one row each
        self._pred: dict[int, bytes] = {}      # this frame's predicted masks, by track row
        self._lazy: dict[int, int] = {}        # rows with a predicted mask: their shift
        self.length: list[int] = []            # masks per id (index = provisional id)
        # the last frame's masks after splitting merged ones, the input mask each came from,
        # and whether it is a part of a split mask (``update`` returns their ids)
        self.out_rles: list[bytes] = []
        self.out_source = np.zeros(0, np.int64)
        self.out_split = np.zeros(0, bool)
        # world positions (D, 2) of masks made by splitting; None: unknown (IoU only)
        self.positions: Callable[[list[bytes]], np.ndarray] | None = None

    def _cost(self, frame: int, rles: list[bytes], xy: np.ndarray) -> np.ndarray:
        c = self.cfg
        gap = (frame - self.live.last).astype(np.float64)                     # (T,)
        iou = np.asarray(mask_util.iou([{"size": self.size, "counts": r} for r in self.live.rles],
                                       [{"size": self.size, "counts": r} for r in rles],
                                       [0] * len(rles)), float).reshape(len(self.live.rles), len(rles))
        pred = self.live.pos + self.live.vel * gap[:, None]
        dist = np.linalg.norm(pred[:, None, :] - xy[None, :, :], axis=2)  # (T, D), NaN unknown
        gate = c.gate_m + c.gate_growth * (gap - 1)
        with np.errstate(invalid="ignore"):
            near = dist <= gate[:, None]
            closeness = np.where(near, 1.0 - dist / gate[:, None], 0.0)
        ok = (iou >= c.iou_min) | near
        cost = 1.0 - np.maximum(iou, closeness) + c.gap_penalty * (gap - 1)[:, None]
        return np.where(ok, cost, _INVALID)

    def _boxes(self, rles: list[bytes]) -> tuple[np.ndarray, np.ndarray]:
        """(N, 4) boxes (x, y, w, h) pixels and (N,) areas, pixels, of RLE masks."""
        if not rles:
            return np.zeros((0, 4)), np.zeros(0)
        objs = [{"size": self.size, "counts": r} for r in rles]
        return mask_util.toBbox(objs).reshape(-1, 4), mask_util.area(objs).astype(np.float64)

    def update(self, frame: int, rles: list[bytes], xy: np.ndarray | None = None) -> np.ndarray:
        """Provisional ids of one frame's masks. xy: (D, 2) world positions, metres (normal
        positions), NaN where unknown; None = IoU only. Frames must increase. When a merged
        mask was split, ``self.out_rles`` holds the frame's masks after splitting and
        ``self.out_source`` the input mask each came from; the ids are for those."""
        c = self.cfg
        d = len(rles)
        xy = np.full((d, 2), np.nan) if xy is None else np.asarray(xy, float).reshape(d, 2)
        alive = frame - self.live.last <= c.max_gap
        if not alive.all():
            self.live = self.live.take(np.flatnonzero(alive))
        self._pred, self._lazy = {}, {}
        given = list(rles)
        bb, area = self._boxes(given)
        rles, xy, self.out_source = self._split_merged(frame, given, xy, bb, area)
        if rles is not given:                  # split: boxes of the new masks
            bb, area = self._boxes(rles)
        self.out_rles = rles
        self.out_split = np.r_[False, self.out_source[1:] == self.out_source[:-1]] | \
            np.r_[self.out_source[:-1] == self.out_source[1:], False]
        d = len(rles)
        out = np.full(d, -1, np.int64)
        if d:
            box = bb[:, :2] + bb[:, 2:] / 2
        if d == 0:
            return out
        rows = cols = np.zeros(0, np.int64)
        if len(self.live.ids):
            cost = self._cost(frame, rles, xy)
            rows, cols = linear_sum_assignment(cost)
            good = cost[rows, cols] < _INVALID
            rows, cols = rows[good], cols[good]
        # matched tracks: position, velocity (smoothed, per frame), last mask
        if len(rows):
            gap = (frame - self.live.last[rows]).astype(np.float64)[:, None]
            step = (xy[cols] - self.live.pos[rows]) / gap
            fresh = np.isfinite(step).all(axis=1)
            self.live.vel[rows] = np.where(fresh[:, None] & np.isfinite(self.live.vel[rows]),
                                      0.6 * self.live.vel[rows] + 0.4 * step,
                                      np.where(fresh[:, None], step, self.live.vel[rows]))
            has = np.isfinite(xy[cols]).all(axis=1)
            self.live.pos[rows] = np.where(has[:, None], xy[cols], self.live.pos[rows])
            px = (box[cols] - self.live.box[rows]) / gap
            old = self.live.pxvel[rows]
            self.live.pxvel[rows] = np.where(np.isnan(old), px, 0.6 * old + 0.4 * px)
            self.live.box[rows] = box[cols]
            self.live.last[rows] = frame
            for r, cc in zip(rows, cols):
                self.live.rles[r] = rles[cc]
                whole_mask = not self.out_split[cc] or int(r) not in self._lazy
                if whole_mask:
                    self.live.shape[r], self.live.shape_box[r], self.live.shape_area[r] = rles[cc], bb[cc], area[cc]
                else:
                    self.live.shape[r] = self._predicted(int(r))
                    b, a = self._boxes([self.live.shape[r]])
                    self.live.shape_box[r], self.live.shape_area[r] = b[0], a[0]
            out[cols] = self.live.ids[rows]
        # births
        taken = np.zeros(d, bool)
        taken[cols] = True
        new = np.flatnonzero(~taken)
        if len(new):
            nid = np.arange(len(self.length), len(self.length) + len(new))
            self.length.extend([0] * len(new))
            self.live = self.live.append(LiveTracks(
                ids=nid, last=np.full(len(new), frame), pos=xy[new], vel=np.zeros((len(new), 2)),
                box=box[new], pxvel=np.full((len(new), 2), np.nan),  # pixel motion unknown yet
                rles=[rles[i] for i in new], shape=[rles[i] for i in new], shape_box=bb[new],
                shape_area=area[new]))
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


def _run(frames: Iterable[tuple[int, MaskTable]], tr: Tracker, camera: Camera | None,
         ground: GroundSurface | None, bar=None) -> Iterator[tuple[MaskTable, np.ndarray]]:
    """Per frame with masks: the frame's masks after splitting (class ids and scores of the
    mask each came from) and their provisional ids."""
    last_frame = None
    if camera is not None and ground is not None:
        def parts_xy(rles: list[bytes]) -> np.ndarray:
            z = np.zeros(len(rles), np.int64)
            return world_positions(MaskTable(z, z - 1, z, tr.size[0], tr.size[1], rles), camera, ground)
        tr.positions = parts_xy
    for block in _blocks(frames):
        xy = world_positions(MaskTable.concat([t for _, t in block]), camera, ground)
        k = 0
        for f, t in block:
            if last_frame is not None and f <= last_frame:
                raise InputError(f"frame {f} comes after frame {last_frame}: frames must increase")
            last_frame = f
            ids = tr.update(f, t.rles, xy[k:k + len(t)])
            k += len(t)
            src = tr.out_source
            out = MaskTable(np.full(len(src), f), np.full(len(src), -1), t.class_id[src],
                            t.height, t.width, tr.out_rles,
                            None if t.score is None else t.score[src])
            yield out, ids
        if bar is not None:
            bar.update(len(block))


def track_frames(frames: Iterable[tuple[int, MaskTable]], height: int, width: int,
                 camera: Camera | None = None, ground: GroundSurface | None = None,
                 cfg: TrackConfig | None = None, progress: bool = False) -> np.ndarray:
    """Final track ids of every output mask of a frame-ordered stream (in stream order; split
    masks count one each); -1 for masks of dropped short tracks."""
    from tqdm import tqdm

    tr = Tracker(height, width, cfg)
    with tqdm(desc="tracking", unit="frame", disable=not progress, leave=False) as bar:
        parts = [ids for _, ids in _run(frames, tr, camera, ground, bar)]
    return tr.final_ids(np.concatenate(parts) if parts else np.zeros(0, np.int64))


def track_table(table: MaskTable, camera: Camera | None = None,
                ground: GroundSurface | None = None, cfg: TrackConfig | None = None) -> MaskTable:
    """The masks of ``table`` with track ids (frame order; merged masks split; masks of short
    tracks dropped)."""
    t = table.take(np.argsort(table.frame, kind="stable"))
    tr = Tracker(t.height, t.width, cfg)
    res = list(_run(t.frames(), tr, camera, ground))
    if not res:
        return MaskTable.empty(t.height, t.width)
    out = MaskTable.concat([m for m, _ in res])
    out.track_id = tr.final_ids(np.concatenate([ids for _, ids in res]))
    return out.take(out.track_id >= 0)


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
    h, w = first.height, first.width
    tr = Tracker(h, w, cfg)
    n_prov = 0
    for _, ids in _run(iter_mots(src, known_classes), tr, camera, ground):
        n_prov += len(ids)
    final = tr.final_ids(np.arange(len(tr.length)))          # provisional id -> final id
    kept = {"masks": 0}

    def rewritten() -> Iterator[MaskTable]:
        again = Tracker(h, w, cfg)                              # the same ids, deterministically
        for m, ids in _run(iter_mots(src, known_classes, check_rles=False), again, camera, ground):
            m.track_id = final[ids]
            keep = m.track_id >= 0
            if keep.any():
                kept["masks"] += int(keep.sum())
                yield m.take(keep)

    write_mots(out, rewritten())
    return int(final.max(initial=0)), kept["masks"]
