"""Cross-camera association: one road user, one track id in every camera.

Each camera's tracker numbers its own tracks 1, 2, 3 ...; late fusion (paper 3.3) joins views by
track id, so before fusing, the tracks of the cameras must be given common ids. The cameras share
the world frame, so the cue is where each mask stands on the ground: its normal position (3.2).

1. *Per frame, per camera pair*: masks are paired one to one (Hungarian,
   ``scipy.optimize.linear_sum_assignment``) by the ground distance of their normal positions,
   inside a gate that grows with what the default heights leave uncertain: a road user whose
   centre is ``dh`` above the class's default height has its normal position moved along the
   camera's ray by ``dh * r / H`` (r the ground distance from the camera, H the camera's height
   above the point). The cost also holds the mean distance of the two masks' *tracks* over all
   the frames they share, so a crossing, where two road users come close for a few frames, does
   not swap the pairs, and a class difference.
2. *Pieces*: a track whose partner in another camera changes for good (``min_run`` frames)
   from one track to another that lived at the same time is cut there: one of the two cameras'
   trackers swapped road users. Brief changes are noise and do not cut.
3. *Join*: pieces matched in at least ``min_votes`` frames are joined, strongest first (union
   find); a join is refused when it would give one camera two masks of one road user in a frame
   (pieces of one camera that overlap in time): no road user gets two ids, no two one id. Then
   the pieces of one track are joined again where nothing forbids it (a cut that other cameras do
   not confirm heals).
4. *Ids*: one per joined group, numbered 1.. in order of first appearance (stable over time); a
   road user only one camera saw keeps its track, under an id of its own.

The arrays in, ids out: ``associate``. The scene-level command (reading and writing masks,
merged blobs split by the other cameras' views) is ``seg2pose.video.associate_scene``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from seg2pose.video.assoc_pairs import AssociateConfig, CameraViews, pair_cameras, position_spread

__all__ = ["AssociateConfig", "Association", "CameraViews", "associate", "majority_class",
           "position_spread"]


@dataclass
class Association:
    """What ``associate`` found. ids: camera -> (N,) common track id per mask (1..);
    road_users: ids handed out; pieces: tracks after cutting; cuts: tracks cut where a tracker
    swapped; refused: joins refused because a camera would have seen one road user twice;
    pairs: masks paired across cameras (all camera pairs, all frames); groups: camera ->
    (N,) index of each mask's piece in ``piece_camera`` etc. (for flags and tests)."""

    ids: dict[str, np.ndarray]
    road_users: int
    pieces: int
    cuts: int
    refused: int
    pairs: int
    cameras_of_id: dict[int, list[str]] = field(default_factory=dict)
    blobs: object = None  # what the scene-level step did with merged blobs (associate_scene)

    def summary(self) -> dict:
        multi = sum(1 for v in self.cameras_of_id.values() if len(v) > 1)
        return {"road_users": self.road_users, "seen_by_several_cameras": multi,
                "pieces": self.pieces, "cuts": self.cuts, "joins_refused": self.refused,
                "pairs": self.pairs}


# ----------------------------------------------------------------------------------------------
# 2. pieces: tracks cut where a tracker swapped road users


def _track_spans(track: np.ndarray, frame: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    first = np.full(n, np.iinfo(np.int64).max)
    last = np.full(n, np.iinfo(np.int64).min)
    np.minimum.at(first, track, frame)
    np.maximum.at(last, track, frame)
    return first, last


def _runs(t_self: np.ndarray, frame: np.ndarray, t_other: np.ndarray, min_run: int
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Runs of one partner per track, in frame order, those of at least ``min_run`` paired
    frames (shorter ones are noise): track, partner, first and last frame (R,) each."""
    o = np.lexsort((frame, t_self))
    ts, fs, to = t_self[o], frame[o], t_other[o]
    new = np.r_[True, (ts[1:] != ts[:-1]) | (to[1:] != to[:-1])] if len(ts) else np.zeros(0, bool)
    start = np.flatnonzero(new)
    end = np.r_[start[1:], len(ts)] - 1
    long = (end - start + 1) >= min_run
    return ts[start[long]], to[start[long]], fs[start[long]], fs[end[long]]


def _cuts(runs: list[tuple[np.ndarray, ...]], spans: list[tuple[np.ndarray, np.ndarray]],
          min_run: int) -> tuple[np.ndarray, np.ndarray]:
    """Where a track's partners change for good: (track, first frame of the new partners).

    runs, spans: per other camera, ``_runs`` of this camera's tracks against it and the frame
    spans of its tracks. A change to a partner that did not live at the same time as the old
    one is the other camera's tracker losing and re-finding the road user: it cuts nothing. A
    change cuts when more than half of the other cameras that pair the track around that frame
    change partner there: with three cameras, the one camera whose tracker swapped is cut, not
    the two that saw it right."""
    props = []  # (track, frame, camera) of each proposed cut
    for k, ((t, p, f0, _f1), (first, last)) in enumerate(zip(runs, spans)):
        change = np.flatnonzero((t[1:] == t[:-1]) & (p[1:] != p[:-1])) + 1
        old, nw = p[change - 1], p[change]
        alive = (last[old] >= first[nw]) & (last[nw] >= first[old])
        change = change[alive]
        props += [(int(t[c]), int(f0[c]), k) for c in change]
    by_track: dict[int, list[tuple[int, int]]] = {}
    for track, f, k in props:
        by_track.setdefault(track, []).append((f, k))
    out_t: list[int] = []
    out_f: list[int] = []
    for track, f, _k in sorted(props):
        if out_t and out_t[-1] == track and abs(out_f[-1] - f) <= min_run:
            continue  # one cut per change, however many cameras saw it
        changed = {kk for ff, kk in by_track[track] if abs(ff - f) <= min_run}
        steady = 0
        for kk, (t, _p, f0, f1) in enumerate(runs):
            if kk not in changed and np.any((t == track) & (f0 < f - min_run) & (f1 > f + min_run)):
                steady += 1
        if len(changed) > steady:
            out_t.append(track)
            out_f.append(f)
    return np.array(out_t, np.int64), np.array(out_f, np.int64)


# ----------------------------------------------------------------------------------------------
# 3. joins under the rule "one camera never sees one road user twice in a frame"


class _Groups:
    """Union-find over pieces; each group keeps, per camera, the frame spans of its pieces."""

    def __init__(self, camera: np.ndarray, first: np.ndarray, last: np.ndarray):
        n = len(camera)
        self.parent = np.arange(n)
        self.spans: list[dict[int, list[tuple[int, int]]]] = [
            {int(camera[k]): [(int(first[k]), int(last[k]))]} for k in range(n)]
        self.refused = 0

    def find(self, k: int) -> int:
        root = k
        while self.parent[root] != root:
            root = self.parent[root]
        while self.parent[k] != root:
            self.parent[k], k = root, self.parent[k]
        return root

    def join(self, a: int, b: int) -> bool:
        ra, rb = self.find(a), self.find(b)
        if ra == rb:
            return True
        sa, sb = self.spans[ra], self.spans[rb]
        for cam, spans in sb.items():
            for f0, f1 in spans:
                if any(f0 <= g1 and g0 <= f1 for g0, g1 in sa.get(cam, ())):
                    self.refused += 1
                    return False
        if len(sa) < len(sb):
            ra, rb, sa, sb = rb, ra, sb, sa
        for cam, spans in sb.items():
            sa.setdefault(cam, []).extend(spans)
        self.parent[rb] = ra
        self.spans[rb] = {}
        return True


# ----------------------------------------------------------------------------------------------


def associate(views: dict[str, CameraViews], cfg: AssociateConfig | None = None) -> Association:
    """Common track ids for the masks of several cameras of one scene (see the module
    docstring). Masks without a track (-1) are road users of one frame."""
    cfg = cfg or AssociateConfig()
    names = list(views)
    # tracks per camera: index 0.. (a mask without a track is a track of its own)
    t_idx, n_t = {}, {}
    for c in names:
        v = views[c]
        key = np.where(v.track >= 0, v.track, -1 - np.arange(len(v)))
        _, t_idx[c] = np.unique(key, return_inverse=True)
        t_idx[c] = t_idx[c].reshape(-1)
        n_t[c] = int(t_idx[c].max(initial=-1)) + 1
    spans = {c: _track_spans(t_idx[c], views[c].frame, n_t[c]) for c in names}

    pairs: dict[tuple[str, str], tuple[np.ndarray, np.ndarray]] = {}
    for ka, a in enumerate(names):
        for b in names[ka + 1:]:
            pairs[(a, b)] = pair_cameras(views[a], views[b], t_idx[a], t_idx[b], spans[a],
                                          spans[b], cfg)

    # 2. cuts, from every camera's point of view
    runs: dict[str, list] = {c: [] for c in names}
    other_spans: dict[str, list] = {c: [] for c in names}
    for (a, b), (i, j) in pairs.items():
        for x, y, ix, iy in ((a, b, i, j), (b, a, j, i)):
            runs[x].append(_runs(t_idx[x][ix], views[x].frame[ix], t_idx[y][iy], cfg.min_run))
            other_spans[x].append(spans[y])
    cut_t, cut_f = {}, {}
    for c in names:
        cut_t[c], cut_f[c] = _cuts(runs[c], other_spans[c], cfg.min_run)
    piece = {}
    p_cam, p_first, p_last, p_track, p_rank, p_start_xy, p_end_xy = [], [], [], [], [], [], []
    n_pieces = n_cuts = 0
    for k, c in enumerate(names):
        v = views[c]
        t = t_idx[c]
        ck = np.unique(cut_t[c] * (1 << 32) + cut_f[c])
        n_cuts += len(ck)
        mk = t * (1 << 32) + v.frame
        rank = np.searchsorted(ck, mk, "right") - np.searchsorted(ck, t * (1 << 32), "left")
        n_rank = int(rank.max(initial=0)) + 1  # pieces (track, rank) in that order, one int key
        uk, inv = np.unique(t * n_rank + rank, return_inverse=True)
        uk = np.stack([uk // n_rank, uk % n_rank], axis=1)
        inv = inv.reshape(-1)
        piece[c] = inv + n_pieces
        first, last = _track_spans(inv, v.frame, len(uk))
        o = np.lexsort((v.frame, inv))
        # a camera without masks has no pieces (np.r_[True] would make one at index 0)
        starts = np.flatnonzero(np.r_[True, inv[o][1:] != inv[o][:-1]]) if len(o) else np.zeros(0, int)
        ends = np.r_[starts[1:], len(o)] - 1
        p_start_xy.append(v.xy[o[starts]])
        p_end_xy.append(v.xy[o[ends]])
        p_cam.append(np.full(len(uk), k))
        p_first.append(first)
        p_last.append(last)
        p_track.append(uk[:, 0] + sum(n_t[x] for x in names[:k]))
        p_rank.append(uk[:, 1])
        n_pieces += len(uk)

    def cat(xs: list[np.ndarray]) -> np.ndarray:
        return np.concatenate(xs) if xs else np.zeros(0, np.int64)

    p_cam, p_first, p_last, p_track, p_rank = map(cat, (p_cam, p_first, p_last, p_track, p_rank))

    # 3. joins: pieces paired across cameras, most votes first; then a track's own pieces
    groups = _Groups(p_cam, p_first, p_last)
    edge = [piece[a][i] * n_pieces + piece[b][j] for (a, b), (i, j) in pairs.items()]
    edge = cat(edge)
    ue, votes = np.unique(edge, return_counts=True)
    strong = votes >= cfg.min_votes
    ue, votes = ue[strong], votes[strong]
    order = np.lexsort((ue, -votes))
    for e in ue[order]:
        groups.join(int(e // n_pieces), int(e % n_pieces))
    # a track's own pieces, smoothest seam first: with two cameras a swap cuts both cameras'
    # tracks, and the tracker that swapped is the one whose track jumps at the cut
    o = np.lexsort((p_rank, p_track))
    same = np.flatnonzero(p_track[o][1:] == p_track[o][:-1])
    p_start_xy, p_end_xy = np.concatenate(p_start_xy), np.concatenate(p_end_xy)
    jump = np.linalg.norm(p_start_xy[o[same + 1]] - p_end_xy[o[same]], axis=1)
    jump = np.where(np.isfinite(jump), jump, np.inf)
    for k in same[np.argsort(jump, kind="stable")]:
        groups.join(int(o[k]), int(o[k + 1]))

    # 4. ids in order of first appearance
    root = np.array([groups.find(k) for k in range(n_pieces)], np.int64)
    first_of_root = np.full(n_pieces, np.iinfo(np.int64).max)
    np.minimum.at(first_of_root, root, p_first)
    roots = np.unique(root)
    roots = roots[np.lexsort((roots, first_of_root[roots]))]
    gid = np.zeros(n_pieces, np.int64)
    gid[roots] = np.arange(1, len(roots) + 1)
    ids = {c: gid[root[piece[c]]] for c in names}
    cams_of: dict[int, list[str]] = {}
    for c in names:
        for g in np.unique(ids[c]):
            cams_of.setdefault(int(g), []).append(c)
    return Association(ids=ids, road_users=len(roots), pieces=n_pieces, cuts=n_cuts,
                       refused=groups.refused, pairs=int(sum(len(i) for i, _ in pairs.values())),
                       cameras_of_id=cams_of)


def majority_class(ids: dict[str, np.ndarray], classes: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """One class per road user: the most frequent known class (> 0) of its masks over all
    cameras (the size classes of a far camera can differ from a near one's). Masks of a road
    user without any known class keep theirs."""
    names = list(ids)
    g = np.concatenate([ids[c] for c in names])
    k = np.concatenate([classes[c] for c in names])
    known = k > 0
    out = {c: classes[c].copy() for c in names}
    if not known.any():
        return out
    pairs, n = np.unique(np.stack([g[known], k[known]], axis=1), axis=0, return_counts=True)
    o = np.lexsort((pairs[:, 1], -n, pairs[:, 0]))  # per id: most masks first, then lower class
    pairs = pairs[o]
    top = pairs[np.r_[True, pairs[1:, 0] != pairs[:-1, 0]]]
    best = np.zeros(int(g.max()) + 1, np.int64)
    best[top[:, 0]] = top[:, 1]
    for c in names:
        cls = best[ids[c]]
        out[c] = np.where(cls > 0, cls, classes[c])
    return out
