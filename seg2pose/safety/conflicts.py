"""Traffic conflicts: every pair of road users that came close, its surrogate safety measures,
its type, and the table ``conflicts.csv``.

The conflict rule is SSAM's (Gettman and Head 2008, FHWA-HRT-08-050): a pair is a *conflict*
when, at some frame, the two are on a collision course with a TTC at or below ``ttc_s``
(Hayward 1972: both continuing at their current velocities, ``ttc``); its PET (``pet``) is
reported with it. A pair whose footprints crossed a common spot within ``pet_s`` of each
other without a collision course is a *PET-only* encounter, kept in its own list.

Per encounter (one row per pair of road users; a pair that meets twice gets the extremes of
both meetings):

- min TTC and its frame, and the frames the conflict starts and ends (TTC <= ``ttc_s``). TTC is
  looked for up to ``horizon_s`` seconds ahead (beyond it: none); two road users are compared
  at a frame when they could meet within the horizon at their speeds (centre distance <= the
  sum of their half diagonals plus both speeds times the horizon): no pair that can collide
  within the horizon is left out by a fixed distance (frames on no possible collision course
  count for the encounter's span and least gap only within ``NEAR_GAP_M`` of touching);
- Time-to-Accident, conflicting speed, the evasive road user and the TCT severity
  (``evasive``);
- PET, who was first, the two frames;
- SSAM's MaxS (the higher speed of either over the encounter), DeltaS (|v_a - v_b| at the
  minimum-TTC frame), DR and MaxD of the second road user (its first braking value and
  least acceleration over the conflict), MaxDeltaV, the signed conflict angle and the type
  (``measures``);
- the least gap between the two footprints (metres, 0 when they touch) and its frame;
- positions for conflict maps: the midpoint of the two at the conflict's start and end, and
  the predicted point of contact at the minimum-TTC frame.

Streaming: a long recording is analysed in time chunks of ``chunk_s`` seconds so that memory
does not grow with its length. Velocities and accelerations are computed once for all rows
(the smoother sees the whole track); the pair frames (TTC and gap at every frame two road
users are compared) are same-frame quantities, so each belongs to exactly one chunk; of a
chunk's pair frames only those that can decide a row of the table are kept (per pair: the
first and last frame, the first and last frame at or below ``ttc_s``, the first minimum of TTC
and of the gap, the frames of the largest speed and decelerations): every column is a
first/last, minimum or maximum over frames, so the table made from the kept frames is the same,
bit for bit, as from all of them. PET's search is chunked on its own (``pet.overlapping_rows``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from seg2pose.safety.encounters import class_rows, frame_pairs
from seg2pose.safety.evasive import EvasiveOptions
from seg2pose.safety.footprints import Footprints
from seg2pose.safety.gaps import fill_gaps
from seg2pose.safety.kinematics import Motion, MotionOptions, motion
from seg2pose.safety.measures import footprint_gap
from seg2pose.safety.pet import PetOptions, PetResult, pet
from seg2pose.safety.table import COLUMNS, INTERVAL_COLUMNS, build_table, format_conflicts
from seg2pose.safety.tracks import Tracks
from seg2pose.safety.ttc import ttc_rows
from seg2pose.safety.workers import map_chunks

TTC_BLOCK = 1 << 20  # pair-frames per block of the TTC computation
# a pair frame on no possible collision course is kept (for the least gap and the span of the
# encounter) only where the footprints' bounding circles are this close
NEAR_GAP_M = 10.0
__all__ = ["COLUMNS", "INTERVAL_COLUMNS", "ConflictOptions", "ConflictTable", "analyse", "format_conflicts"]


@dataclass(frozen=True)
class ConflictOptions:
    """ttc_s: SSAM's conflict threshold (a collision course with TTC at or below it opens a
    conflict); pet_s: PET reported up to this (and the PET-only list's threshold); horizon_s:
    TTC is looked for this far ahead (beyond it: none; it also sets how far apart two road
    users may be to be compared, with their speeds); max_gap_s: missing frames of a track
    are interpolated over gaps up to this (longer gaps split the track's smoothing);
    evasive: the evasive action's thresholds (Time-to-Accident); all_pairs: keep every
    encounter, not only conflicts and PET-only ones; pedestrian_pairs: also pairs of two
    pedestrians (walking past each other in a crowd is no traffic conflict; left out by
    default); chunk_s, workers: the streaming (the result does not depend on them)."""

    ttc_s: float = 1.5
    pet_s: float = 5.0
    horizon_s: float = 5.0
    max_gap_s: float = 1.0
    evasive: EvasiveOptions = field(default_factory=EvasiveOptions)
    all_pairs: bool = False
    pedestrian_pairs: bool = False
    chunk_s: float = 60.0
    workers: int = 2
    motion: MotionOptions = field(default_factory=MotionOptions)

    def pet_options(self) -> PetOptions:
        return PetOptions(window_s=self.pet_s, moving_mps=self.motion.moving_mps)


@dataclass
class PairFrames:
    """The P frames at which two road users are compared: rows a, b (P,) into the Tracks (a:
    the lower track id); ttc (P,) seconds, NaN = none; distance (P,) metres, the gap between
    the footprints where it can be the pair's least, inf elsewhere."""

    a: np.ndarray
    b: np.ndarray
    ttc: np.ndarray
    distance: np.ndarray


class RowData:
    """What ``pair_frames`` gathers per pair, made once per row for all chunks: the
    footprints (``footprints.Footprints``), the velocity's components, the speed, the reach
    within the horizon, and each row's track ordinal (rows are sorted by track, so it orders
    the track ids)."""

    def __init__(self, tracks: Tracks, mot: Motion, fp: Footprints | None = None,
                 horizon_s: float = 5.0):
        self.fp = Footprints(tracks.xy, mot.heading, tracks.size) if fp is None else fp
        self.heading = mot.heading
        self.vx, self.vy = mot.vel[:, 0], mot.vel[:, 1]  # views
        self.span = self.fp.reach + mot.speed * horizon_s  # how far the footprint gets
        tid = tracks.track_id
        self.track = np.cumsum(np.r_[True, tid[1:] != tid[:-1]]) - 1 if len(tid) else np.zeros(0, np.int64)


def pair_frames(tracks: Tracks, mot: Motion, opts: ConflictOptions,
                rows: np.ndarray | None = None, apart: np.ndarray | None = None,
                data: RowData | None = None) -> PairFrames:
    """TTC and gap at every frame two road users could meet within the horizon, or are
    within NEAR_GAP_M of touching (``rows``:
    only these rows of ``tracks``; default all; ``apart``: (N,) bool, rows not paired with
    each other, see ``apart_rows``; ``data``: ``RowData(tracks, mot)`` when made already)."""
    rows = np.arange(len(tracks)) if rows is None else rows
    data = RowData(tracks, mot, horizon_s=opts.horizon_s) if data is None else data
    fp, vx, vy = data.fp, data.vx, data.vy
    e = np.zeros(0, np.int64)
    if len(rows) < 2:
        return PairFrames(e, e, np.zeros(0), np.zeros(0))
    r = 2.0 * float(data.span[rows].max())  # the box that holds every pair that can meet
    p = frame_pairs(tracks, rows, r, apart)
    a, b = p[:, 0], p[:, 1]
    d = np.hypot(fp.x[a] - fp.x[b], fp.y[a] - fp.y[b])
    keep = d <= data.span[a] + data.span[b]
    a, b, d = a[keep], b[keep], d[keep]
    # exact shortcut: apart (farther than their reaches) and not closing in, too far to meet
    # within the horizon, or passing each other with the centres farther apart than their
    # reaches at the closest approach: no collision course (the bounding circles never meet).
    # Such a frame is kept only where the two are within NEAR_GAP_M of touching (for the
    # least gap and the encounter's span)
    rx, ry = fp.x[b] - fp.x[a], fp.y[b] - fp.y[a]
    wx, wy = vx[b] - vx[a], vy[b] - vy[a]
    reach = fp.reach[a] + fp.reach[b]
    gap = d - reach
    w2 = wx * wx + wy * wy
    cross = rx * wy - ry * wx  # |cross| / |w|: how close the centres pass on this course
    maybe = ~((gap > 0) & ((rx * wx + ry * wy >= 0) | (gap * gap > w2 * opts.horizon_s ** 2)
                           | (cross * cross > reach * reach * w2)))
    keep = maybe | (gap <= NEAR_GAP_M)
    a, b, d, maybe = a[keep], b[keep], d[keep], maybe[keep]
    order = _pair_frame_order(tracks, data, a, b)
    a, b, d, maybe = a[order], b[order], d[order], maybe[order]
    reach = fp.reach[a] + fp.reach[b]
    x = np.full(len(a), np.nan)
    idx = np.flatnonzero(maybe)
    for i in range(0, len(idx), TTC_BLOCK):  # in blocks: the temporaries stay small
        sl = idx[i:i + TTC_BLOCK]
        x[sl] = ttc_rows(fp, vx, vy, a[sl], b[sl], opts.horizon_s)
    return PairFrames(a, b, x, _gaps(tracks, data, a, b, d, reach))


def _gaps(tracks: Tracks, data: RowData, a: np.ndarray, b: np.ndarray, d: np.ndarray,
          reach: np.ndarray) -> np.ndarray:
    """(P,) the footprint gap at the pair frames (sorted by pair) that can hold a pair's
    least gap, inf at the others: the gap is at least d - reach, and at most the gap at the
    frame of least centre distance, so only frames with d - reach below that are measured."""
    P = len(a)
    out = np.full(P, np.inf)
    if P == 0:
        return out
    new = np.r_[True, (data.track[a][1:] != data.track[a][:-1]) | (data.track[b][1:] != data.track[b][:-1])]
    st = np.flatnonzero(new)
    cnt = np.diff(np.r_[st, P])
    dmin = np.minimum.reduceat(d, st)
    at = np.minimum.reduceat(np.where(d == np.repeat(dmin, cnt), np.arange(P), P), st)

    def gap(i):
        return footprint_gap(tracks.xy[a[i]], data.heading[a[i]], tracks.size[a[i]],
                             tracks.xy[b[i]], data.heading[b[i]], tracks.size[b[i]])

    bound = gap(at)
    cand = np.flatnonzero(d - reach <= np.repeat(bound, cnt) + 1e-9)
    out[cand] = gap(cand)
    return out


def _pair_frame_order(tracks: Tracks, data: RowData, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The order of pair frames (a, b) by (track a, track b, frame): one integer key (unique:
    a track is in a frame once) where it fits in 62 bits, else three sort keys."""
    if len(a) == 0:
        return np.zeros(0, np.int64)
    fr = tracks.frame[a]
    f0 = int(fr.min())
    F = int(fr.max()) - f0 + 1
    U = int(data.track[-1]) + 1
    if U * U * F < 2 ** 62:
        return np.argsort((data.track[a] * U + data.track[b]) * F + (fr - f0))
    return np.lexsort((fr, tracks.track_id[b], tracks.track_id[a]))


@dataclass
class ConflictTable:
    """One row per encounter (``columns``: name -> (K,) array, ``table.COLUMNS`` in order,
    plus ``table.INTERVAL_COLUMNS`` when intervals were sampled); ``pairs``: the pair frames
    that decide its indicators; ``pets``: the PET of every pair; ``compared``: how many pair
    frames were compared for TTC; ``tracks``, ``motion``: what it was computed from (the
    tracks with their short gaps filled); ``notes``: what the analysis did to the tracks."""

    columns: dict
    pairs: PairFrames | None = None
    pets: PetResult | None = None
    compared: int = 0
    tracks: Tracks | None = None
    motion: Motion | None = None
    notes: list = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.columns["track_a"])

    def take(self, idx) -> ConflictTable:
        return ConflictTable({k: v[idx] for k, v in self.columns.items()}, self.pairs, self.pets,
                             self.compared, self.tracks, self.motion, self.notes)


def _deciding(tracks: Tracks, mot: Motion, pf: PairFrames, opts: ConflictOptions) -> np.ndarray:
    """(P,) which of the pair frames ``pf`` (sorted by pair, then frame) can decide a row of
    the table (see the module's doc). The table from these alone equals the table from all."""
    P = len(pf.a)
    keep = np.zeros(P, bool)
    if P == 0:
        return keep
    tid = tracks.track_id
    new = np.r_[True, (tid[pf.a][1:] != tid[pf.a][:-1]) | (tid[pf.b][1:] != tid[pf.b][:-1])]
    st = np.flatnonzero(new)
    cnt = np.diff(np.r_[st, P])
    idx = np.arange(P)

    def first_min(x):
        m = np.minimum.reduceat(x, st)
        hit = (x == np.repeat(m, cnt)) | (np.isnan(x) & np.isnan(np.repeat(m, cnt)))
        keep[np.minimum.reduceat(np.where(hit, idx, P), st)] = True

    keep[st] = True
    keep[np.r_[st[1:], P] - 1] = True
    first_min(np.where(np.isfinite(pf.ttc), pf.ttc, np.inf))
    first_min(pf.distance)
    first_min(-np.maximum(mot.speed[pf.a], mot.speed[pf.b]))
    first_min(mot.along[pf.a])
    first_min(mot.along[pf.b])
    hot = pf.ttc <= opts.ttc_s
    first = np.minimum.reduceat(np.where(hot, idx, P), st)
    last = np.maximum.reduceat(np.where(hot, idx, -1), st)
    keep[first[first < P]] = True
    keep[last[last >= 0]] = True
    return keep


def apart_rows(tracks: Tracks, opts: ConflictOptions) -> np.ndarray | None:
    """(N,) bool: the rows whose pairs among themselves the table leaves out (pedestrians,
    unless ``opts.pedestrian_pairs``), so they are not searched at all; None: none."""
    if opts.pedestrian_pairs:
        return None
    ped = class_rows(tracks.cls, "pedestrian")
    return ped if ped.any() else None


def streamed_pair_frames(tracks: Tracks, mot: Motion, opts: ConflictOptions,
                         apart: np.ndarray | None = None,
                         fp: Footprints | None = None) -> tuple[PairFrames, int]:
    """The deciding pair frames of the whole recording (sorted by pair, then frame), found
    chunk by chunk of ``opts.chunk_s`` seconds; and how many pair frames were compared
    (``apart``: see ``pair_frames``; ``fp``: the rows' footprints when made already)."""
    t = tracks.t
    if len(t) == 0:
        e = np.zeros(0, np.int64)
        return PairFrames(e, e, np.zeros(0), np.zeros(0)), 0
    span = opts.chunk_s if opts.chunk_s > 0 else np.inf  # seconds per chunk
    k = np.floor((t - t.min()) / span).astype(np.int64) if np.isfinite(span) else np.zeros(len(t), np.int64)
    order = np.argsort(k, kind="stable")
    bounds = np.r_[0, np.flatnonzero(np.diff(k[order])) + 1, len(k)]

    data = RowData(tracks, mot, fp, opts.horizon_s)  # once, shared by the forked workers

    def chunk(i: int) -> tuple[PairFrames, int]:
        pf = pair_frames(tracks, mot, opts, np.sort(order[bounds[i]:bounds[i + 1]]), apart, data)
        keep = _deciding(tracks, mot, pf, opts)
        return PairFrames(pf.a[keep], pf.b[keep], pf.ttc[keep], pf.distance[keep]), len(pf.a)

    res = map_chunks(chunk, range(len(bounds) - 1), opts.workers)
    parts = [r[0] for r in res]
    compared = sum(r[1] for r in res)
    a = np.concatenate([p.a for p in parts])
    b = np.concatenate([p.b for p in parts])
    o = np.lexsort((tracks.frame[a], tracks.track_id[b], tracks.track_id[a]))
    return PairFrames(a[o], b[o], np.concatenate([p.ttc for p in parts])[o],
                      np.concatenate([p.distance for p in parts])[o]), compared


def analyse(tracks: Tracks, opts: ConflictOptions = ConflictOptions(), mot: Motion | None = None,
            progress=None) -> ConflictTable:
    """All encounters of ``tracks`` with their indicators (conflicts and PET-only ones, every
    encounter with ``opts.all_pairs``), streamed over chunks of ``opts.chunk_s`` seconds (the
    result does not depend on the chunks). ``mot``: the motion of ``tracks`` when known
    (then the tracks are taken as they are: no gaps filled). ``progress(step)``: called with
    the name of each step."""
    say = progress or (lambda step: None)
    notes = []
    if mot is None:
        tracks, _, gaps = fill_gaps(tracks, opts.max_gap_s)
        if gaps["filled"] or gaps["open"]:
            notes.append(f"{gaps['filled']} gaps of up to {opts.max_gap_s:g} s interpolated "
                         f"({gaps['frames']} frames); {gaps['open']} longer gaps left open (the "
                         f"track is smoothed in parts there)")
        say("motion")
        mot = motion(tracks, opts.motion)
    say("TTC")
    # pairs the table leaves out (two pedestrians, by default) are not searched: every row
    # of the table is one pair's, so the others' rows do not change
    apart = apart_rows(tracks, opts)
    fp = Footprints(tracks.xy, mot.heading, tracks.size)  # per row, for TTC and PET
    pf, compared = streamed_pair_frames(tracks, mot, opts, apart, fp)
    say("PET")
    touch = pf.ttc == 0  # footprints overlapping at a frame: PET 0 there
    pr = pet(tracks, mot, opts.pet_options(), workers=opts.workers, touching=np.c_[pf.a[touch], pf.b[touch]],
             apart=apart, fp=fp)
    del fp
    say("table")
    table = ConflictTable(build_table(tracks, mot, pf, pr, opts), pf, pr, compared, tracks, mot, notes)
    c = table.columns
    keep = np.ones(len(table), bool) if opts.all_pairs else (c["conflict"] + c["pet_only"]).astype(bool)
    if not opts.pedestrian_pairs:
        keep &= ~((np.char.lower(c["class_a"].astype(str)) == "pedestrian")
                  & (np.char.lower(c["class_b"].astype(str)) == "pedestrian"))
    return table.take(keep)
