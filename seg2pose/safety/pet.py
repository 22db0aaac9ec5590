"""Post-encroachment time: the time from the first road user's footprint leaving a spot to
the second one's entering it (SSAM: "the time between when the first vehicle last occupied a
position and the second vehicle first occupied the same position").

Found from the footprints at every frame: PET is the smallest time between a frame of one road
user and a frame of the other whose footprints overlap (they occupied a common spot), then
refined between frames: the first one's exit from the second's footprint and the second's entry
into the first's, found together (``latest_exit``), with each moving in a straight line between
its frames. For two cars crossing at right angles this is exactly "rear leaves the shared
square" to "front enters it".

Only moving rows (speed >= ``moving_mps``) are searched: a road user that stands still
occupies one spot for long and is the subject of TTC, not PET. Rows more than ``window_s``
apart are never paired (PET above that is not reported).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seg2pose.safety.encounters import near_pairs, pair_codes
from seg2pose.safety.footprints import Footprints, reach, separating_axes
from seg2pose.safety.kinematics import Motion
from seg2pose.safety.tracks import Tracks
from seg2pose.safety.workers import map_chunks

SIZE_GROUPS = np.array([1.0, 2.0, 3.0, 4.5])  # metres of reach + travel: the search's groups
EDGE_M = 1e-9  # refine's footprints are this much larger: a touching at the edge stays one


@dataclass(frozen=True)
class PetOptions:
    """window_s: largest PET looked for, seconds; moving_mps: rows slower than this are not
    searched; sample_s: the coarse search's step (then refined at every frame)."""

    window_s: float = 5.0
    moving_mps: float = 0.5
    sample_s: float = 0.1


@dataclass
class PetResult:
    """K pairs of road users whose footprints occupied a common spot within ``window_s``:
    track_a < track_b: (K,) ids; pet: (K,) seconds; first: (K,) the track id that was there
    first; row_first, row_second: (K,) the rows (frames) of the closest pair of frames;
    t_exit, t_enter: (K,) seconds, the refined exit of the first and entry of the second."""

    track_a: np.ndarray
    track_b: np.ndarray
    pet: np.ndarray
    first: np.ndarray
    row_first: np.ndarray
    row_second: np.ndarray
    t_exit: np.ndarray
    t_enter: np.ndarray


def _pair_in(a: np.ndarray, b: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """(M,) whether (a, b) is one of ``pairs`` (K, 2) of track ids."""
    ids, inv = np.unique(np.r_[a, b, pairs[:, 0], pairs[:, 1]], return_inverse=True)
    M, K = len(a), len(pairs)
    key = inv[:2 * M + 2 * K].reshape(-1)
    n = np.int64(len(ids))
    return np.isin(key[:M] * n + key[M:2 * M], key[2 * M:2 * M + K] * n + key[2 * M + K:])


def overlapping_rows(tracks: Tracks, mot: Motion, opts: PetOptions,
                     exclude: np.ndarray | None = None, chunk_s: float = 60.0,
                     workers: int = 1, apart: np.ndarray | None = None,
                     fp: Footprints | None = None) -> np.ndarray:
    """(K, 2) for each pair of road users whose footprints overlapped at two frames at most
    ``window_s`` apart: the pair of rows closest in time (first column the lower track id).
    ``exclude``: (E, 2) pairs of track ids not to search (their PET is known: 0); the
    chunks of ``chunk_s`` seconds are searched in ``workers`` processes; ``apart``: (N,) bool,
    rows not paired with each other (``encounters.near_pairs``); ``fp``: the rows'
    footprints (``Footprints(tracks.xy, mot.heading, tracks.size)``) when made already.

    Coarse to fine: rows every ``sample_s`` (moving ones only) are paired by the k-d tree with
    footprints grown by the travel to the frames in between; then, per pair of road users,
    only the coarse pairs closest in time are looked at frame by frame (a band of a few
    samples, widened until the closest overlap is certain): two cars following each other
    overlap at hundreds of pairs of frames, of which one is wanted."""
    fps = tracks.fps
    s = max(1, int(round(opts.sample_s * fps)))
    h = s // 2  # every frame is within h of a sample (s = 1: the samples are all frames)
    moving = mot.speed >= opts.moving_mps
    sampled = np.flatnonzero(moving & (tracks.frame % s == 0))
    travel = mot.speed * h / fps
    span = reach(tracks.size) + travel
    t = tracks.t
    if len(sampled) < 2:
        return np.zeros((0, 2), np.int64)
    ts = t[sampled]
    t0 = float(ts.min())
    k = np.floor((ts - t0) / chunk_s).astype(np.int64)
    geo = _Geometry(tracks, mot, travel, fp)  # once, shared by the forked workers

    def chunk(c: int) -> np.ndarray:
        # this chunk, and the next one's first window_s seconds (pairs reaching across)
        mine = k == c
        rows = sampled[mine | ((k == c + 1) & (ts - t0 - (c + 1) * chunk_s <= opts.window_s + s / fps))]
        cand = _candidates(tracks, geo, rows, span, opts.window_s + 2 * h / fps, exclude, apart)
        is_mine = np.zeros(len(tracks), bool)
        is_mine[sampled[mine]] = True
        in_chunk = is_mine[cand].any(axis=1)
        return _closest_overlaps(tracks, geo, cand[in_chunk], s, h, opts.window_s)

    best = map_chunks(chunk, np.unique(k), workers)
    return closest_in_time(tracks, np.concatenate(best))


class _Geometry:
    """The rows' footprints (``footprints.Footprints``), as they are and grown by the travel
    to the neighbouring frames: made once, gathered per pair."""

    def __init__(self, tracks: Tracks, mot: Motion, travel: np.ndarray, fp: Footprints | None = None):
        self.exact = Footprints(tracks.xy, mot.heading, tracks.size) if fp is None else fp
        self.grown = self.exact.grown(2 * travel)

    def overlap(self, a: np.ndarray, b: np.ndarray, grown: bool = False) -> np.ndarray:
        """(M,) bool: footprints of rows a (M,) and b (M,) overlap (``grown``: the grown
        ones)."""
        return (self.grown if grown else self.exact).overlap(a, b)


def _candidates(tracks, geo: _Geometry, rows, span, dt, exclude, apart=None) -> np.ndarray:
    """(C, 2) pairs of ``rows`` of two road users within ``dt`` seconds whose footprints,
    grown by their travel, overlap."""
    # the search box must hold the pair's largest reach: search road users by size group
    # (pedestrians with pedestrians need a box of 1 m, not a bus's 7 m)
    groups = np.digitize(span[rows], SIZE_GROUPS)
    cand = [np.zeros((0, 2), np.int64)]
    for g1 in np.unique(groups):
        for g2 in np.unique(groups):
            if g2 < g1:
                continue
            r1, r2 = rows[groups == g1], rows[groups == g2]
            r = float(span[r1].max() + span[r2].max())
            cand.append(near_pairs(tracks, r1, r, dt, chunk_s=np.inf,
                                   other=None if g1 == g2 else r2, apart=apart))
    cand = np.concatenate(cand)
    a, b = cand[:, 0], cand[:, 1]
    hit = geo.overlap(a, b, grown=True)
    a, b = a[hit], b[hit]
    if exclude is not None and len(exclude):
        keep = ~_pair_in(tracks.track_id[a], tracks.track_id[b], exclude)
        a, b = a[keep], b[keep]
    return np.c_[a, b]


def _closest_overlaps(tracks, geo: _Geometry, cand, s: int, h: int, window_s: float) -> np.ndarray:
    """(K, 2) per pair of road users in ``cand`` (coarse pairs of sample rows), the pair of
    frames closest in time whose footprints overlap (ties: the earliest, then the one whose
    first column is the earlier frame). A coarse pair's gap is within 2h frames of the gaps
    of the frames around it, so the candidates are taken in rounds: first each pair's
    closest coarse pair (earliest among equals), then those that could still beat (or tie
    with an earlier frame) the best overlap found (while none is found, a band of a few
    samples beyond the pair's closest candidate not yet looked at: every candidate is looked
    at before a pair is given up); candidates and frame pairs that cannot beat the best are
    not tested. Two cars following each other overlap at hundreds of pairs of frames at
    nearly the same gap: the first round finds the earliest, the next tests only the few
    frame pairs closer in time."""
    if len(cand) == 0:
        return np.zeros((0, 2), np.int64)
    fps = tracks.fps
    tid, frame = tracks.track_id, tracks.frame
    ids = np.unique(tid[cand.ravel()])
    _, key = np.unique(pair_codes(tid[cand[:, 0]], tid[cand[:, 1]], ids), return_inverse=True)
    key = key.reshape(-1)
    fa_c, fb_c = frame[cand[:, 0]], frame[cand[:, 1]]
    gap = np.abs(fa_c - fb_c)
    order = np.lexsort((np.minimum(fa_c, fb_c), gap, key))
    cand, key, gap = cand[order], key[order], gap[order]
    npair = int(key.max()) + 1
    first = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    band = 3 * s
    # the order of frame pairs as one integer: gap, then the earlier frame, then which of the
    # two is earlier (a frame pair and its mirror image tie otherwise)
    f0 = int(min(fa_c.min(), fb_c.min())) - h
    span_f = int(max(fa_c.max(), fb_c.max())) - f0 + h + 1
    BIG = np.iinfo(np.int64).max
    best_score = np.full(npair, BIG)
    best = np.full((npair, 2), -1, np.int64)
    done = np.zeros(len(cand), bool)
    todo = np.zeros(len(cand), bool)
    todo[first] = True
    starts, ends = tracks.starts(), tracks.ends()
    offs = np.arange(-h, h + 1)
    max_gap = int(np.floor(window_s * fps + 1e-9))
    n = len(offs)
    mf = np.minimum(frame[cand[:, 0]], frame[cand[:, 1]])
    while todo.any():
        done |= todo
        # the least score any frame pair around a candidate can have: skip those that
        # cannot beat the best
        lb = (np.maximum(gap - 2 * h, 0) * span_f + (mf - h - f0)) * 2
        sel = np.flatnonzero(todo & (lb < best_score[key]))
        a, b, kk = cand[sel, 0], cand[sel, 1], key[sel]
        ra = a[:, None] + offs[None, :]
        rb = b[:, None] + offs[None, :]
        ra = np.where((ra >= starts[a][:, None]) & (ra <= ends[a][:, None]), ra, -1)
        rb = np.where((rb >= starts[b][:, None]) & (rb <= ends[b][:, None]), rb, -1)
        fa = np.repeat(ra, n, axis=1).ravel()
        fb = np.tile(rb, (1, n)).ravel()
        kf = np.repeat(kk, n * n)
        ok = (fa >= 0) & (fb >= 0)
        fa, fb, kf = fa[ok], fb[ok], kf[ok]
        ga, gb = frame[fa], frame[fb]
        g = np.abs(ga - gb)
        score = (g * span_f + (np.minimum(ga, gb) - f0)) * 2 + (ga > gb)
        ok = (g <= max_gap) & (score < best_score[kf])
        fa, fb, kf, score = fa[ok], fb[ok], kf[ok], score[ok]
        hit = geo.overlap(fa, fb)
        fa, fb, kf, score = fa[hit], fb[hit], kf[hit], score[hit]
        o = np.lexsort((score, kf))
        fa, fb, kf, score = fa[o], fb[o], kf[o], score[o]
        new = np.r_[True, kf[1:] != kf[:-1]] if len(kf) else np.zeros(0, bool)
        fa, fb, kf, score = fa[new], fb[new], kf[new], score[new]
        better = score < best_score[kf]
        best_score[kf[better]] = score[better]
        best[kf[better]] = np.c_[fa[better], fb[better]]
        # a candidate can beat (or tie with) the best only if its gap is at most best + 2h;
        # with none found yet, the band beyond the pair's closest candidate not yet looked at
        found = best_score < BIG
        best_gap = np.where(found, best_score // (2 * span_f), 0)
        next_gap = np.full(npair, BIG)
        next_gap[key[first]] = np.minimum.reduceat(np.where(done, BIG, gap), first)
        limit = np.where(found, best_gap + 2 * h, np.minimum(next_gap, BIG - band) + band)
        todo = ~done & (gap <= limit[key])
    return best[best[:, 0] >= 0]


def closest_in_time(tracks: Tracks, rows: np.ndarray) -> np.ndarray:
    """(K, 2) of ``rows`` (P, 2) (first column the lower track id): per pair of road users, the
    pair of rows closest in time (ties: the earliest)."""
    if len(rows) == 0:
        return rows.reshape(0, 2)
    tid = tracks.track_id
    gap = np.abs(tracks.frame[rows[:, 0]] - tracks.frame[rows[:, 1]])
    order = np.lexsort((np.minimum(tracks.frame[rows[:, 0]], tracks.frame[rows[:, 1]]), gap,
                        tid[rows[:, 1]], tid[rows[:, 0]]))
    rows = rows[order]
    new = np.r_[True, (np.diff(tid[rows[:, 0]]) != 0) | (np.diff(tid[rows[:, 1]]) != 0)]
    return rows[new]


def refine(tracks: Tracks, mot: Motion, first: np.ndarray, second: np.ndarray):
    """Exit and entry times between frames for rows ``first`` (K,) and ``second`` (K,) whose
    footprints overlap, ``first`` not later: (t_exit, t_enter), (K,) seconds.

    Each road user moves in a straight line between its frames: the first one ``a`` seconds
    after its frame (towards its next one), the second one ``b`` seconds before its frame
    (back towards its previous one). PET is the frames' time apart less the largest a + b at
    which the two footprints still overlap (``latest_exit``: exact, both offsets together).
    Taking a first (the first one's exit from the second's footprint at its frame) and then b
    from there lost up to a frame where the exit point only touches the second's edge and mm
    of noise carry the second off that edge at once. Footprints are taken ``EDGE_M`` larger
    here, so that rounding (times of frame 1e6, positions far from the origin) cannot turn a
    touching into a miss. Times between frames are measured from the row's own frame
    (integer differences): the result depends on the frames' differences only, not on where
    the frame count starts."""
    xy, hd = tracks.xy, mot.heading
    size = tracks.size + 2 * EDGE_M
    frame, fps = tracks.frame, tracks.fps
    starts, ends = tracks.starts(), tracks.ends()
    nxt = np.where(first < ends[first], first + 1, first)
    prv = np.where(second > starts[second], second - 1, second)
    dt1 = (frame[nxt] - frame[first]) / fps
    dt2 = (frame[second] - frame[prv]) / fps
    v1 = _per_second(xy[nxt] - xy[first], dt1)  # the first one's velocity
    v2 = _per_second(xy[prv] - xy[second], dt2)  # the second one's, backwards in time
    alpha, beta = latest_exit(xy[second] - xy[first], -v1, v2, hd[first], size[first], hd[second],
                              size[second], dt1, dt2)
    # PET from the frames' difference and the two offsets (exact for any frame numbers)
    gap = (frame[second] - frame[first]) / fps - beta - alpha
    t0 = frame[first] / fps
    t_exit = t0 + alpha
    same = frame[first] == frame[second]  # side by side at one moment: PET 0
    return np.where(same, t0, t_exit), np.where(same, t0, t_exit + np.maximum(gap, 0.0))


def _per_second(d: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """(K, 2) displacements ``d`` over ``dt`` (K,) seconds as velocities (0 where dt is 0)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where((dt > 0)[:, None], d / np.where(dt > 0, dt, 1)[:, None], 0.0)


# the pairs of the 12 lines that cross (not the two sides of one axis, nor of the box)
_I, _J = (np.array(x) for x in zip(*[(i, j) for i in range(12) for j in range(i + 1, 12)
                                    if not (j == i + 1 and i % 2 == 0)]))


def latest_exit(r, va, vb, heading_a, size_a, heading_b, size_b, a_max, b_max):
    """(a, b), (K,) each: the offsets in [0, a_max] x [0, b_max] with the largest a + b (ties:
    the largest a) at which footprint B, centred at ``r + va a + vb b`` (K, 2) relative to
    A's, overlaps footprint A (headings (K,), sizes (K, 2)); (0, 0) where none does.

    The footprints overlap where B's centre, relative to A's, lies within a half-width of
    each of the 4 axes (``footprints.separating_axes``): 8 half-planes in (a, b), with the 4 of the box. The
    largest a + b over that convex polygon lies at one of its corners: every crossing of two
    of the 12 lines is tried and the feasible ones (to ``EDGE_M`` metres, 1e-12 s) kept."""
    axes = separating_axes(np.cos(heading_a), np.sin(heading_a), size_a[:, 0] / 2, size_a[:, 1] / 2,
                           np.cos(heading_b), np.sin(heading_b), size_b[:, 0] / 2, size_b[:, 1] / 2)
    K = len(r)
    zero, one = np.zeros(K), np.ones(K)
    P, Q, C = [], [], []  # 12 lines: P a + Q b <= C
    for ux, uy, R in axes:
        s0 = r[:, 0] * ux + r[:, 1] * uy
        p, q = va[:, 0] * ux + va[:, 1] * uy, vb[:, 0] * ux + vb[:, 1] * uy
        P += [p, -p]
        Q += [q, -q]
        C += [R - s0, R + s0]
    P, Q = np.array(P + [-one, one, zero, zero]), np.array(Q + [zero, zero, -one, one])
    C = np.array(C + [zero, a_max, zero, b_max])
    tol = np.r_[np.full(8, EDGE_M), np.full(4, 1e-12)]
    best_a, best_b = np.zeros(K), np.zeros(K)
    for k in range(0, K, 4096):  # (60, 4096) at a time
        sl = slice(k, k + 4096)
        p, q, c = P[:, sl], Q[:, sl], C[:, sl]
        pi, qi, ci, pj, qj, cj = p[_I], q[_I], c[_I], p[_J], q[_J], c[_J]
        det = pi * qj - qi * pj
        with np.errstate(divide="ignore", invalid="ignore"):
            a = (ci * qj - qi * cj) / det
            b = (pi * cj - ci * pj) / det
            ok = np.abs(det) > 1e-12 * (np.abs(pi) + np.abs(qi)) * (np.abs(pj) + np.abs(qj))
            for m in range(12):
                ok &= p[m] * a + q[m] * b <= c[m] + tol[m]
            val = np.where(ok, a + b, -np.inf)
        top = val.max(axis=0, initial=0.0)  # (0, 0) is a corner, feasible
        # ties (to rounding): the largest a, the first one's exit as late as it can be
        a = np.where(ok & (val >= top - 1e-12), a, -np.inf)
        i = np.argmax(a, axis=0)
        cols = np.arange(a.shape[1])
        found = np.isfinite(a[i, cols])
        best_a[sl] = np.where(found, a[i, cols], 0.0)
        best_b[sl] = np.where(found, b[i, cols], 0.0)
    return np.clip(best_a, 0, a_max), np.clip(best_b, 0, b_max)


def pet(tracks: Tracks, mot: Motion, opts: PetOptions = PetOptions(),
        rows: np.ndarray | None = None, touching: np.ndarray | None = None,
        workers: int = 1, apart: np.ndarray | None = None,
        fp: Footprints | None = None) -> PetResult:
    """PET of every pair of road users that occupied a common spot within ``window_s``;
    ``rows``: the overlapping pairs of rows to use (default: found by ``overlapping_rows``);
    ``touching``: (K, 2) rows (lower track id first) of pairs already known to overlap at
    one frame (PET 0 there; such pairs are not searched: groups walking together would
    cost most of the search); ``apart``: (N,) bool, rows not paired with each other; ``fp``:
    the rows' footprints when made already."""
    if rows is None:
        excl = None if touching is None else np.c_[tracks.track_id[touching[:, 0]],
                                                   tracks.track_id[touching[:, 1]]]
        rows = overlapping_rows(tracks, mot, opts, excl, workers=workers, apart=apart, fp=fp)
    if touching is not None and len(touching):
        rows = np.r_[rows, touching]
    best = closest_in_time(tracks, rows)
    a, b = best[:, 0], best[:, 1]
    a_first = tracks.t[a] <= tracks.t[b]
    f1, f2 = np.where(a_first, a, b), np.where(a_first, b, a)
    t_exit, t_enter = refine(tracks, mot, f1, f2)
    return PetResult(tracks.track_id[a], tracks.track_id[b], t_enter - t_exit,
                     tracks.track_id[f1], f1, f2, t_exit, t_enter)
