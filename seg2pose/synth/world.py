"""The simulated world as flat arrays: every road user's pose in every frame, and its shape.

Rows are sorted by frame, then track id, so frame f's road users are the rows
``frame_ptr[f]:frame_ptr[f + 1]``. Shapes are concatenated part arrays indexed by track.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seg2pose.io.poses import PoseTable
from seg2pose.synth import junction as J
from seg2pose.synth.raster import pose_parts
from seg2pose.synth.shapes import CLASS_NAMES, MAKERS
from seg2pose.synth.traffic import Visit


@dataclass
class World:
    frame: np.ndarray      # (R,) int64
    track: np.ndarray      # (R,) int64, 1-based track ids
    cls: np.ndarray        # (R,) int8, index into CLASS_NAMES
    xyz: np.ndarray        # (R, 3) metres, ground contact on the true surface
    heading: np.ndarray    # (R,) radians
    phase: np.ndarray      # (R,) gait phase, radians
    frame_ptr: np.ndarray  # (n_frames + 1,)
    verts: np.ndarray      # (Ptot, 8, 3) local part vertices, metres
    swing: np.ndarray      # (Ptot,) metres
    kind: np.ndarray       # (Ptot,) part kinds
    part_ptr: np.ndarray   # (T + 1,) parts of track k (1-based) are part_ptr[k-1]:part_ptr[k]
    size: np.ndarray       # (T, 3) l, w, h metres per track
    colour: np.ndarray     # (T, 3) uint8 BGR body / clothing colour per track
    # (R,) int64, 1-based id of each row's visit (one pass through the scene): the track id the
    # ground truth and the masks carry. ``track`` indexes the road user's shape (a re-entering
    # road user looks the same, so the pixels do not depend on the id scheme); None: = track
    visit: np.ndarray | None = None

    @property
    def ids(self) -> np.ndarray:
        """(R,) the track ids written to gt/poses.csv and the masks: one per visit."""
        return self.track if self.visit is None else self.visit

    @property
    def n_frames(self) -> int:
        return len(self.frame_ptr) - 1

    def rows(self, f: int) -> slice:
        return slice(int(self.frame_ptr[f]), int(self.frame_ptr[f + 1]))

    def frame_parts(self, f: int) -> tuple[slice, np.ndarray, np.ndarray]:
        """Frame f: its row slice, the world vertices (P, 8, 3) of all its road users' parts
        and each part's owner (P,) as an index into the frame's rows."""
        r = self.rows(f)
        tr = self.track[r] - 1
        n = self.part_ptr[tr + 1] - self.part_ptr[tr]
        owner = np.repeat(np.arange(len(tr)), n)
        idx = np.repeat(self.part_ptr[tr] - np.concatenate([[0], np.cumsum(n)[:-1]]), n) \
            + np.arange(int(n.sum()))
        wv = pose_parts(self.verts[idx], self.swing[idx], owner, self.xyz[r], self.heading[r],
                        self.phase[r])
        return r, wv, owner

    def part_kinds(self, f: int) -> np.ndarray:
        r = self.rows(f)
        tr = self.track[r] - 1
        return np.concatenate([self.kind[self.part_ptr[t]:self.part_ptr[t + 1]] for t in tr]) \
            if len(tr) else np.zeros(0, np.int8)

    def poses(self) -> PoseTable:
        names = np.array(CLASS_NAMES, dtype=object)
        return PoseTable(self.frame, self.ids, names[self.cls], self.xyz, self.heading,
                         self.size[self.track - 1])


PALETTE = {  # BGR
    "car": [(40, 40, 180), (200, 200, 200), (30, 30, 30), (150, 90, 30), (60, 140, 60),
            (220, 220, 230), (40, 160, 200), (90, 90, 90)],
    "pedestrian": [(60, 50, 40), (30, 30, 120), (140, 100, 40), (50, 120, 50), (200, 200, 200),
                   (40, 40, 40), (120, 60, 130)],
    "bicyclist": [(0, 140, 255), (200, 80, 20), (40, 40, 40), (30, 180, 30)],
}


def build_world(visits: list[Visit], n_frames: int, seed: int, ids: str = "road_user",
                makers: dict | None = None) -> World:
    """Shapes and the frame-sorted pose table.

    ids: "road_user" = one shape per population member, kept over all its visits (the paper's
    83 road users: a re-entering road user looks as before), or "visit" = a new shape for
    every visit. Either way every visit has its own track id in ``World.ids`` (the ground
    truth's and the masks'): a road user that leaves and comes back, or a population slot
    used again, is a new road user to a tracker, and one id over two visits made a track
    jump across the scene between frames. Ids are 1, 2, ... in order of first appearance.
    makers: class -> shape maker (default ``shapes.MAKERS``;
    the wide preset's ``shapes_wide.WIDE_MAKERS``)."""
    makers = MAKERS if makers is None else makers
    if ids not in ("road_user", "visit"):
        raise ValueError(f"ids must be 'road_user' or 'visit', got {ids!r}")
    if not visits:
        raise ValueError("no road users")
    cls_idx = {n: i for i, n in enumerate(CLASS_NAMES)}
    keys = [v.member if ids == "road_user" else k for k, v in enumerate(visits)]
    first: dict[int, tuple[int, int]] = {}
    for k, v in zip(keys, visits):
        first[k] = min(first.get(k, (1 << 62, 0)), (int(v.frames[0]), k))
    order_keys = sorted(first, key=lambda k: first[k])
    tid = {k: i + 1 for i, k in enumerate(order_keys)}
    cls_of = {k: v.cls for k, v in zip(keys, visits)}
    verts, swing, kind, counts, sizes, colours = [], [], [], [], [], []
    for k in order_keys:
        # one random stream per road user: its shape does not depend on the others
        rng = np.random.default_rng([seed, 21, int(k) + 1, 0 if ids == "road_user" else 1])
        sh = makers[cls_of[k]](rng)
        verts.append(sh.verts)
        swing.append(sh.swing)
        kind.append(sh.kind)
        counts.append(len(sh.verts))
        sizes.append(sh.size)
        pal = PALETTE[cls_of[k]]
        colours.append(pal[int(rng.integers(len(pal)))])
    frame = np.concatenate([v.frames for v in visits]).astype(np.int64)
    track = np.concatenate([np.full(len(v.frames), tid[k]) for k, v in zip(keys, visits)]).astype(np.int64)
    # visits come sorted by first frame: visit k is track k + 1 in order of first appearance
    start = sorted(range(len(visits)), key=lambda k: (int(visits[k].frames[0]), k))
    vid = np.empty(len(visits), np.int64)
    vid[start] = np.arange(1, len(visits) + 1)
    visit = np.concatenate([np.full(len(v.frames), vid[k]) for k, v in enumerate(visits)])
    order = np.lexsort((track, frame))
    xy = np.concatenate([v.xy for v in visits])[order]
    xyz = np.column_stack([xy, J.true_height(xy)])
    frame = frame[order]
    cls = np.concatenate([np.full(len(v.frames), cls_idx[v.cls]) for v in visits]).astype(np.int8)
    return World(frame=frame, track=track[order], cls=cls[order],
                 xyz=xyz, heading=np.concatenate([v.heading for v in visits])[order],
                 phase=np.concatenate([v.phase for v in visits])[order],
                 frame_ptr=np.searchsorted(frame, np.arange(n_frames + 1)),
                 verts=np.concatenate(verts), swing=np.concatenate(swing),
                 kind=np.concatenate(kind), part_ptr=np.concatenate([[0], np.cumsum(counts)]),
                 size=np.array(sizes), colour=np.array(colours, np.uint8), visit=visit[order])
