"""Cross-camera association, step 1: the masks of two cameras paired one to one per frame.

What association sees of a camera (``CameraViews``: normal positions and how far the default
height may have moved them, ``position_spread``), its settings (``AssociateConfig``), and the
pairing of two cameras' masks (``pair_cameras``): candidates within a gate that grows with
the two positions' spread, a cost that mixes the frame's distance with the two tracks' mean
distance over the frames they share (a crossing does not swap pairs) and a class difference,
and a one-to-one choice per frame (``one_to_one``: mutual best pairs at once, the Hungarian
method where that leaves a conflict). Steps 2-4 (cutting, joining, ids) are
``seg2pose.video.associate``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

from seg2pose.io.schema import Num, read_settings

_FAR = 2.0  # gate-normalised distances are clipped here for the track-level mean
_KEY = 1e6  # frame * _KEY + x (metres): one sort key for "same frame, near in x"


@dataclass
class AssociateConfig:
    """Association settings (``scene.json`` ``extra.associate`` overrides them). Chosen on
    synthetic seeds 101-102 (docs/RESULTS.md, "Multi-camera association")."""

    gate_m: float = 1.0       # metres: the gate for two views of a road user of known height
    height_sd: float = 0.3    # metres: spread of a road user's centre about the default height
    gate_sigmas: float = 2.0  # the gate adds this many spreads of the two positions' difference
    track_weight: float = 0.5  # weight of the tracks' mean distance in a frame's cost (0..1)
    class_cost: float = 0.3   # added to the cost of two masks of different known classes
    min_run: int = 8          # frames a track's new partner must hold before the track is cut
    min_votes: int = 3        # frames two pieces must be paired in to be joined
    split_blobs: bool = True  # split a mask that other cameras see as several road users

    @classmethod
    def from_dict(cls, d: dict | None, file: Path | None = None) -> AssociateConfig:
        """Settings from scene.json's ``extra.associate`` merged with ``--set``: numbers finite
        and >= 0 (``--set gate_m=nan`` was taken and gated nothing), integers JSON integers,
        track_weight in [0, 1] (``io.schema.read_settings``)."""
        return read_settings(cls(), d, {"track_weight": Num(0, 1)}, file=file, section="associate")

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class CameraViews:
    """One camera's masks as association sees them: frame, track (the camera's tracker id; -1
    none), cls (class id; 0 unknown): (N,) ints; xy (N, 2) normal positions, metres (NaN where
    the ray missed the ground); spread (N,) metres: how far the normal position may lie from the
    truth because of the default height (``position_spread``)."""

    frame: np.ndarray
    track: np.ndarray
    cls: np.ndarray
    xy: np.ndarray
    spread: np.ndarray

    def __post_init__(self) -> None:
        self.frame = np.asarray(self.frame, np.int64).reshape(-1)
        self.track = np.asarray(self.track, np.int64).reshape(-1)
        self.cls = np.asarray(self.cls, np.int64).reshape(-1)
        self.xy = np.asarray(self.xy, np.float64).reshape(-1, 2)
        self.spread = np.broadcast_to(np.asarray(self.spread, np.float64), self.frame.shape).copy()

    def __len__(self) -> int:
        return len(self.frame)


def position_spread(camera_center: np.ndarray, xyz: np.ndarray, height: np.ndarray,
                    height_sd: float) -> np.ndarray:
    """(N,) metres: how far a normal position ``xyz`` (N, 3) on the ground moves along the
    camera's ray when the road user's centre is ``height_sd`` metres above or below its default
    ``height`` (N,): dh * r / (H - h), r the ground distance from the camera centre (3,), H the
    camera's height above the position."""
    r = np.linalg.norm(xyz[:, :2] - camera_center[:2], axis=1)
    above = np.maximum(camera_center[2] - xyz[:, 2] - height, 0.5)  # a camera at eye level: capped
    return height_sd * r / above


# ----------------------------------------------------------------------------------------------
# 1. per frame, per camera pair


def best_of(group: np.ndarray, cost: np.ndarray) -> np.ndarray:
    """(P,) whether each candidate is the least-cost one of its group (ties: the first).
    ``cost`` is finite. Groups already in order (the pairs' first camera, as ``near_pairs``
    makes them) need no sort; otherwise one stable sort by group."""
    best = np.zeros(len(cost), bool)
    if not len(cost):
        return best
    o = None if (group[1:] >= group[:-1]).all() else np.argsort(group, kind="stable")
    g, c = (group, cost) if o is None else (group[o], cost[o])
    start = np.flatnonzero(np.r_[True, g[1:] != g[:-1]])
    low = np.repeat(np.minimum.reduceat(c, start), np.diff(np.r_[start, len(g)]))
    at = np.flatnonzero(c == low)  # in group order, and within a group in the original order
    first = at[np.r_[True, g[at][1:] != g[at][:-1]]]
    best[first if o is None else o[first]] = True
    return best


def one_to_one(frame: np.ndarray, i: np.ndarray, j: np.ndarray, cost: np.ndarray
                ) -> np.ndarray:
    """Per frame, a one-to-one choice among candidate pairs (i, j) of least total cost.
    Returns a mask (P,) of the chosen pairs.

    Pairs that are each other's best (mutual least cost) are taken at once, all frames
    together; where that leaves a mask with candidates whose best partner went elsewhere, the
    frame is solved exactly (Hungarian, ``linear_sum_assignment``) over what is left. Most
    frames need no solver: a road user's views are far closer to each other than to anyone
    else's, or the track-level term of the cost tells them apart."""
    keep = np.zeros(len(i), bool)
    if not len(i):
        return keep
    ni, nj = int(i.max()) + 1, int(j.max()) + 1
    mutual = best_of(i, cost) & best_of(j, cost)
    keep[mutual] = True
    taken_i = np.zeros(ni, bool)
    taken_j = np.zeros(nj, bool)
    taken_i[i[mutual]] = True
    taken_j[j[mutual]] = True
    rest = np.flatnonzero(~taken_i[i] & ~taken_j[j])
    if not len(rest):
        return keep
    rest = rest[np.argsort(frame[rest], kind="stable")]
    cuts = np.flatnonzero(np.diff(frame[rest])) + 1
    for chunk in np.split(rest, cuts):
        if len(chunk) == 1:
            keep[chunk] = True
            continue
        ui, ii = np.unique(i[chunk], return_inverse=True)
        uj, jj = np.unique(j[chunk], return_inverse=True)
        m = np.full((len(ui), len(uj)), 1e9)
        m[ii, jj] = cost[chunk]
        r, c = linear_sum_assignment(m)
        at = np.full((len(ui), len(uj)), -1)
        at[ii, jj] = chunk
        k = at[r, c]
        keep[k[k >= 0]] = True
    return keep


def near_pairs(a: CameraViews, b: CameraViews, reach: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """(i, j): masks of a and b in the same frame whose x differ by at most ``reach[i]``
    metres (a window along x, found by searchsorted on frame * 1e6 + x: the full product of
    every frame's masks is not formed)."""
    ok_a = np.flatnonzero(np.isfinite(a.xy[:, 0]))
    ok_b = np.flatnonzero(np.isfinite(b.xy[:, 0]))
    if not len(ok_a) or not len(ok_b):
        z = np.zeros(0, np.int64)
        return z, z
    x0 = float(np.median(b.xy[ok_b, 0]))
    kb = b.frame[ok_b] * _KEY + np.clip(b.xy[ok_b, 0] - x0, -_KEY / 4, _KEY / 4)
    o = np.argsort(kb, kind="stable")
    kb, ob = kb[o], ok_b[o]
    ka = a.frame[ok_a] * _KEY + np.clip(a.xy[ok_a, 0] - x0, -_KEY / 4, _KEY / 4)
    lo = np.searchsorted(kb, ka - reach[ok_a], "left")
    hi = np.searchsorted(kb, ka + reach[ok_a], "right")
    n = hi - lo
    i = np.repeat(ok_a, n)
    start = np.repeat(np.cumsum(n) - n, n)
    j = ob[np.repeat(lo, n) + (np.arange(len(i)) - start)]
    return i, j


def pair_cameras(a: CameraViews, b: CameraViews, ta: np.ndarray, tb: np.ndarray,
                  span_a: tuple[np.ndarray, np.ndarray], span_b: tuple[np.ndarray, np.ndarray],
                  cfg: AssociateConfig) -> tuple[np.ndarray, np.ndarray]:
    """Masks of cameras a and b paired per frame (rows of a, rows of b). ta, tb: each mask's
    track index within its camera (0..); span_a, span_b: first and last frame per track."""
    far_b = float(np.nanmax(b.spread, initial=0.0)) if len(b) else 0.0
    reach = cfg.gate_m + cfg.gate_sigmas * np.hypot(a.spread, far_b)
    i, j = near_pairs(a, b, np.nan_to_num(reach, nan=0.0))
    d = np.linalg.norm(a.xy[i] - b.xy[j], axis=1)
    r = d / (cfg.gate_m + cfg.gate_sigmas * np.hypot(a.spread[i], b.spread[j]))
    # the tracks' mean gate-normalised distance (clipped at _FAR) over the frames they share;
    # frames where the two are not within reach count as _FAR
    na, nb = int(ta.max(initial=0)) + 1, int(tb.max(initial=0)) + 1
    key = ta[i] * nb + tb[j]
    if na * nb <= max(4 * len(key), 1 << 20):  # a table of every track pair: no sort
        near_sum = np.bincount(key, weights=np.minimum(r, _FAR), minlength=na * nb)
        near_n = np.bincount(key, minlength=na * nb)
        uk = np.flatnonzero(near_n)
        inv = np.zeros(na * nb, np.int64)
        inv[uk] = np.arange(len(uk))
        inv = inv[key]
        near_sum, near_n = near_sum[uk], near_n[uk]
    else:
        uk, inv = np.unique(key, return_inverse=True)
        near_sum = np.bincount(inv, weights=np.minimum(r, _FAR))
        near_n = np.bincount(inv)
    pa, pb = uk // nb, uk % nb
    shared = np.minimum(span_a[1][pa], span_b[1][pb]) - np.maximum(span_a[0][pa], span_b[0][pb]) + 1
    shared = np.maximum(shared, near_n)
    mean = (near_sum + _FAR * (shared - near_n)) / shared
    near = r <= 1.0
    i, j, r, inv = i[near], j[near], r[near], inv[near]
    w = cfg.track_weight
    cost = (1 - w) * r + w * mean[inv]
    differ = (a.cls[i] > 0) & (b.cls[j] > 0) & (a.cls[i] != b.cls[j])
    cost = cost + cfg.class_cost * differ
    keep = one_to_one(a.frame[i], i, j, cost)
    return i[keep], j[keep]
