"""Traffic conflicts: every pair of road users that came close, its surrogate safety measures,
its type, and the table ``conflicts.csv``.

An *encounter* is a pair of road users that were within ``near_m`` of each other at some frame,
or whose footprints occupied a common spot within the PET window; one row per pair (a pair
that meets twice gets the extremes of both meetings). Per encounter:

- min TTC and its frame (``ttc``: constant-velocity prediction, exact footprint overlap), over
  the frames the two are within ``near_m``;
- Time-to-Accident in the Swedish Traffic Conflict Technique's sense: the TTC at the first frame
  (up to the min-TTC frame, on a collision course) at which one of the two takes evasive action,
  i.e. brakes harder than ``brake_mps2`` or swerves (lateral acceleration above
  ``swerve_mps2``); the *conflicting speed* is that road user's speed then (both empty when
  neither reacts);
- PET (``pet``), who was first, and the two frames;
- SSAM's MaxS (the higher speed of either over the encounter), DeltaS (the magnitude of the
  difference of their velocities at the reference frame), max deceleration of each;
- the type from the angle between the two directions of travel at the reference frame (min-TTC
  frame, else the PET frames): rear-end below 30 degrees, head-on above 150, crossing between;
  "pedestrian" or "bicyclist" when one of the two is one (the road-user type a researcher sorts
  by first);
- whether it passes the thresholds: min TTC <= ``ttc_s`` or PET <= ``pet_s``.

Streaming: a long recording is analysed in time chunks of ``chunk_s`` seconds so that memory
does not grow with its length. Velocities and accelerations are computed once for all rows
(O(rows), exact at every chunk border: the fits see the whole track); the pair frames (TTC and
distance at every frame two road users are near) are same-frame quantities, so each belongs
to exactly one chunk; of a chunk's pair frames only the few that can decide a row of the table
are kept (per pair: the first and last frame, the first minimum of TTC and of distance, the
frames of the largest speed and decelerations, the first evasive frame on a collision course):
every column is a first/last, minimum or maximum over frames, so the table made from the kept
frames is the same, bit for bit, as from all of them. PET's search is chunked on its own with
``window_s`` of overlap (``pet.overlapping_rows``).
"""

from __future__ import annotations

import io
from dataclasses import dataclass, field

import numpy as np

from seg2pose.safety.encounters import class_rows, frame_pairs, pair_codes
from seg2pose.safety.footprints import Footprints
from seg2pose.safety.kinematics import Motion, MotionOptions, motion
from seg2pose.safety.pet import PetOptions, PetResult, pet
from seg2pose.safety.tracks import Tracks
from seg2pose.safety.ttc import ttc_rows
from seg2pose.safety.workers import map_chunks

VULNERABLE = ("pedestrian", "bicyclist")
TTC_BLOCK = 1 << 20  # pair-frames per block of the TTC computation


@dataclass(frozen=True)
class ConflictOptions:
    """ttc_s, pet_s: the conflict thresholds (SSAM's defaults); near_m: road users farther
    apart than this (centre to centre) are not compared for TTC; horizon_s: TTC beyond this is
    "none"; brake_mps2, swerve_mps2: evasive action thresholds; all_pairs: keep every encounter,
    not only conflicts; pedestrian_pairs: also pairs of two pedestrians (walking past each
    other in a crowd is no traffic conflict; left out by default)."""

    ttc_s: float = 1.5
    pet_s: float = 5.0
    near_m: float = 25.0
    horizon_s: float = 10.0
    brake_mps2: float = 3.0
    swerve_mps2: float = 3.0
    all_pairs: bool = False
    pedestrian_pairs: bool = False
    chunk_s: float = 60.0
    workers: int = 2
    motion: MotionOptions = field(default_factory=MotionOptions)

    def pet_options(self) -> PetOptions:
        return PetOptions(window_s=self.pet_s, moving_mps=self.motion.moving_mps)


@dataclass
class PairFrames:
    """The P frames at which two road users are within ``near_m``: rows a, b (P,) into the
    Tracks (a: the lower track id); ttc (P,) seconds, NaN = none; distance (P,) metres,
    centre to centre."""

    a: np.ndarray
    b: np.ndarray
    ttc: np.ndarray
    distance: np.ndarray


class RowData:
    """What ``pair_frames`` gathers per pair, made once per row for all chunks: the
    footprints (``footprints.Footprints``), the velocity's components, and each row's track
    ordinal (rows are sorted by track, so it orders the track ids)."""

    def __init__(self, tracks: Tracks, mot: Motion, fp: Footprints | None = None):
        self.fp = Footprints(tracks.xy, mot.heading, tracks.size) if fp is None else fp
        self.vx, self.vy = mot.vel[:, 0], mot.vel[:, 1]  # views
        tid = tracks.track_id
        self.track = np.cumsum(np.r_[True, tid[1:] != tid[:-1]]) - 1 if len(tid) else np.zeros(0, np.int64)


def pair_frames(tracks: Tracks, mot: Motion, opts: ConflictOptions,
                rows: np.ndarray | None = None, apart: np.ndarray | None = None,
                data: RowData | None = None) -> PairFrames:
    """TTC and distance at every frame two road users are within ``near_m`` (``rows``: only
    these rows of ``tracks``; default all; ``apart``: (N,) bool, rows not paired with each
    other, see ``apart_rows``; ``data``: ``RowData(tracks, mot)`` when made already)."""
    rows = np.arange(len(tracks)) if rows is None else rows
    data = RowData(tracks, mot) if data is None else data
    fp, vx, vy = data.fp, data.vx, data.vy
    p = frame_pairs(tracks, rows, opts.near_m, apart)
    a, b = p[:, 0], p[:, 1]
    d = np.hypot(fp.x[a] - fp.x[b], fp.y[a] - fp.y[b])
    keep = d <= opts.near_m
    a, b, d = a[keep], b[keep], d[keep]
    order = _pair_frame_order(tracks, data, a, b)
    a, b, d = a[order], b[order], d[order]
    # exact shortcut: apart (farther than their reaches) and not closing in, or too far to
    # meet within the horizon: no collision course (the centre distance of two bodies at
    # constant velocity is convex in time)
    rx, ry = fp.x[b] - fp.x[a], fp.y[b] - fp.y[a]
    wx, wy = vx[b] - vx[a], vy[b] - vy[a]
    gap = d - fp.reach[a] - fp.reach[b]
    speed = np.hypot(wx, wy)
    maybe = ~((gap > 0) & ((rx * wx + ry * wy >= 0) | (gap > speed * opts.horizon_s)))
    x = np.full(len(a), np.nan)
    idx = np.flatnonzero(maybe)
    for i in range(0, len(idx), TTC_BLOCK):  # in blocks: the temporaries stay small
        sl = idx[i:i + TTC_BLOCK]
        x[sl] = ttc_rows(fp, vx, vy, a[sl], b[sl], opts.horizon_s)
    return PairFrames(a, b, x, d)


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


COLUMNS = ["track_a", "class_a", "track_b", "class_b", "type", "conflict", "first_frame",
           "last_frame", "min_ttc_s", "min_ttc_frame", "ta_s", "ta_frame", "evasive_track",
           "conflicting_speed_mps", "pet_s", "pet_first_track", "pet_exit_frame",
           "pet_enter_frame", "angle_deg", "speed_a_mps", "speed_b_mps", "max_s_mps",
           "delta_s_mps", "max_decel_a_mps2", "max_decel_b_mps2", "min_distance_m",
           "min_distance_frame"]
INTERVAL_COLUMNS = ["min_ttc_lo_s", "min_ttc_hi_s", "pet_lo_s", "pet_hi_s", "ttc_found_share",
                    "pet_found_share"]


@dataclass
class ConflictTable:
    """One row per encounter (``columns``: name -> (K,) array, COLUMNS in order, plus
    INTERVAL_COLUMNS when intervals were sampled); ``pairs``: the pair frames that decide its
    indicators; ``pets``: the PET of every pair; ``compared``: how many pair frames were
    compared for TTC."""

    columns: dict
    pairs: PairFrames | None = None
    pets: PetResult | None = None
    compared: int = 0

    def __len__(self) -> int:
        return len(self.columns["track_a"])

    def take(self, idx) -> ConflictTable:
        return ConflictTable({k: v[idx] for k, v in self.columns.items()}, self.pairs, self.pets,
                             self.compared)


def _group_starts(keys: np.ndarray) -> np.ndarray:
    return np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]]) if len(keys) else np.zeros(0, int)


def _pair_key(a_id, b_id) -> np.ndarray:
    # track ids are < 2**62 (the pose reader's limit); pairs are sorted by (a, b) separately
    return np.c_[np.asarray(a_id, np.int64), np.asarray(b_id, np.int64)]


def classify(cls_a, cls_b, angle_deg) -> np.ndarray:
    """(K,) conflict types: "pedestrian" / "bicyclist" when one road user is one, else by the
    angle between the directions of travel: "rear-end" (< 30 degrees), "head-on" (> 150),
    "crossing"."""
    ca = np.char.lower(np.asarray(cls_a, str))
    cb = np.char.lower(np.asarray(cls_b, str))
    ang = np.asarray(angle_deg, float)
    out = np.where(ang < 30, "rear-end", np.where(ang > 150, "head-on", "crossing")).astype(object)
    out[~np.isfinite(ang)] = "unknown"
    for v in VULNERABLE[::-1]:  # a pedestrian outranks a bicyclist
        out[(ca == v) | (cb == v)] = v
    return out


def _deciding(tracks: Tracks, mot: Motion, pf: PairFrames, opts: ConflictOptions) -> np.ndarray:
    """(P,) which of the pair frames ``pf`` (sorted by pair, then frame) can decide a row of
    the table (see the module's doc): per pair the first and last frame, the first minimum of
    TTC and of distance, the first frame of the largest of each maximum, the first evasive
    frame on a collision course. The table from these alone equals the table from all."""
    P = len(pf.a)
    keep = np.zeros(P, bool)
    if P == 0:
        return keep
    tid = tracks.track_id
    code = tid[pf.a].astype(np.int64)
    new = np.r_[True, (code[1:] != code[:-1]) | (tid[pf.b][1:] != tid[pf.b][:-1])]
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
    ev = ((mot.along[pf.a] <= -opts.brake_mps2) | (np.abs(mot.lateral[pf.a]) >= opts.swerve_mps2)
          | (mot.along[pf.b] <= -opts.brake_mps2) | (np.abs(mot.lateral[pf.b]) >= opts.swerve_mps2))
    first_ev = np.minimum.reduceat(np.where(np.isfinite(pf.ttc) & ev, idx, P), st)
    keep[first_ev[first_ev < P]] = True
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
    chunk = opts.chunk_s if opts.chunk_s > 0 else np.inf
    k = np.floor((t - t.min()) / chunk).astype(np.int64) if np.isfinite(chunk) else np.zeros(len(t), np.int64)
    order = np.argsort(k, kind="stable")
    bounds = np.r_[0, np.flatnonzero(np.diff(k[order])) + 1, len(k)]

    data = RowData(tracks, mot, fp)  # once, shared by the forked workers

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
    """All encounters of ``tracks`` with their indicators (conflicts only unless
    ``opts.all_pairs``), streamed over chunks of ``opts.chunk_s`` seconds (the result does not
    depend on the chunks). ``progress(step)``: called with the name of each step."""
    say = progress or (lambda step: None)
    say("motion")
    mot = motion(tracks, opts.motion) if mot is None else mot
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
    table = ConflictTable(_table(tracks, mot, pf, pr, opts), pf, pr, compared)
    c = table.columns
    keep = np.ones(len(table), bool) if opts.all_pairs else c["conflict"].astype(bool)
    if not opts.pedestrian_pairs:
        keep &= ~((np.char.lower(c["class_a"].astype(str)) == "pedestrian")
                  & (np.char.lower(c["class_b"].astype(str)) == "pedestrian"))
    return table.take(keep)


def _table(tracks: Tracks, mot: Motion, pf: PairFrames, pr: PetResult, opts: ConflictOptions) -> dict:
    tid, frame, speed = tracks.track_id, tracks.frame, mot.speed
    # the encounters: pairs from the near frames and from PET, one row each
    keys = np.r_[_pair_key(tid[pf.a], tid[pf.b]), _pair_key(pr.track_a, pr.track_b)]
    ids = np.unique(keys)
    codes, first, inv = np.unique(pair_codes(keys[:, 0], keys[:, 1], ids), return_index=True,
                                  return_inverse=True)
    enc = keys[first]
    inv = inv.reshape(-1)
    K = len(enc)
    g_pf, g_pr = inv[:len(pf.a)], inv[len(pf.a):]
    nan = np.full(K, np.nan)
    col = {k: nan.copy() for k in COLUMNS}
    col["track_a"], col["track_b"] = enc[:, 0], enc[:, 1]
    # a row of each road user, for classes
    order = np.argsort(tid, kind="stable")
    pos = np.searchsorted(tid[order], enc)
    ra, rb = order[pos[:, 0]], order[pos[:, 1]]
    col["class_a"], col["class_b"] = tracks.cls[ra], tracks.cls[rb]
    big = np.iinfo(np.int64).max
    ff = np.full(K, big)
    lf = np.full(K, -1)
    ref_a = np.full(K, -1)  # rows of a and b at the reference frame
    ref_b = np.full(K, -1)
    max_s = np.full(K, -np.inf)
    dec_a = np.full(K, -np.inf)
    dec_b = np.full(K, -np.inf)
    P = len(pf.a)
    if P:
        fa = frame[pf.a]
        np.minimum.at(ff, g_pf, fa)
        np.maximum.at(lf, g_pf, fa)
        np.maximum.at(max_s, g_pf, np.maximum(speed[pf.a], speed[pf.b]))
        np.maximum.at(dec_a, g_pf, -mot.along[pf.a])
        np.maximum.at(dec_b, g_pf, -mot.along[pf.b])
        # pair frames are sorted by (a, b, frame): groups are contiguous
        st = _group_starts(g_pf)
        gid = g_pf[st]
        x = np.where(np.isfinite(pf.ttc), pf.ttc, np.inf)
        mins = np.minimum.reduceat(x, st)
        # the first frame reaching the minimum
        is_min = x == np.repeat(mins, np.diff(np.r_[st, P]))
        cand = np.where(is_min, np.arange(P), P)
        at_min = np.minimum.reduceat(cand, st)
        has = np.isfinite(mins)
        col["min_ttc_s"][gid[has]] = mins[has]
        col["min_ttc_frame"][gid[has]] = fa[at_min[has]]
        ref_a[gid[has]] = pf.a[at_min[has]]
        ref_b[gid[has]] = pf.b[at_min[has]]
        dmin = np.minimum.reduceat(pf.distance, st)
        at_d = np.minimum.reduceat(np.where(pf.distance == np.repeat(dmin, np.diff(np.r_[st, P])),
                                            np.arange(P), P), st)
        col["min_distance_m"][gid] = dmin
        col["min_distance_frame"][gid] = fa[at_d]
        # Time-to-Accident: first frame on a collision course, not after the min-TTC frame,
        # with an evasive action of either road user
        ev_a = (mot.along[pf.a] <= -opts.brake_mps2) | (np.abs(mot.lateral[pf.a]) >= opts.swerve_mps2)
        ev_b = (mot.along[pf.b] <= -opts.brake_mps2) | (np.abs(mot.lateral[pf.b]) >= opts.swerve_mps2)
        min_frame_rep = np.repeat(np.where(has, fa[np.minimum(at_min, P - 1)], -1),
                                  np.diff(np.r_[st, P]))
        ok = np.isfinite(pf.ttc) & (ev_a | ev_b) & (fa <= min_frame_rep)
        first_ev = np.minimum.reduceat(np.where(ok, np.arange(P), P), st)
        got = first_ev < P
        i = first_ev[got]
        col["ta_s"][gid[got]] = pf.ttc[i]
        col["ta_frame"][gid[got]] = fa[i]
        who_a = ev_a[i]
        col["evasive_track"][gid[got]] = np.where(who_a, tid[pf.a[i]], tid[pf.b[i]])
        col["conflicting_speed_mps"][gid[got]] = np.where(who_a, speed[pf.a[i]], speed[pf.b[i]])
    if len(g_pr):
        col["pet_s"][g_pr] = pr.pet
        col["pet_first_track"][g_pr] = pr.first
        col["pet_exit_frame"][g_pr] = frame[pr.row_first]
        col["pet_enter_frame"][g_pr] = frame[pr.row_second]
        a_first = pr.first == pr.track_a
        pa = np.where(a_first, pr.row_first, pr.row_second)
        pb = np.where(a_first, pr.row_second, pr.row_first)
        np.minimum.at(ff, g_pr, np.minimum(frame[pa], frame[pb]))
        np.maximum.at(lf, g_pr, np.maximum(frame[pa], frame[pb]))
        np.maximum.at(max_s, g_pr, np.maximum(speed[pa], speed[pb]))
        np.maximum.at(dec_a, g_pr, -mot.along[pa])
        np.maximum.at(dec_b, g_pr, -mot.along[pb])
        no_ref = ref_a[g_pr] < 0
        ref_a[g_pr[no_ref]] = pa[no_ref]
        ref_b[g_pr[no_ref]] = pb[no_ref]
    col["first_frame"], col["last_frame"] = ff, lf
    col["max_s_mps"] = max_s
    col["max_decel_a_mps2"] = np.maximum(dec_a, 0.0)
    col["max_decel_b_mps2"] = np.maximum(dec_b, 0.0)
    va, vb = mot.vel[ref_a], mot.vel[ref_b]
    col["speed_a_mps"], col["speed_b_mps"] = speed[ref_a], speed[ref_b]
    col["delta_s_mps"] = np.hypot(*(va - vb).T)
    ha, hb = mot.heading[ref_a], mot.heading[ref_b]
    # directions of travel: the velocity where the road user moves, else its heading
    da = np.where((speed[ref_a] >= opts.motion.moving_mps), np.arctan2(va[:, 1], va[:, 0]), ha)
    db = np.where((speed[ref_b] >= opts.motion.moving_mps), np.arctan2(vb[:, 1], vb[:, 0]), hb)
    col["angle_deg"] = np.degrees(np.abs(np.angle(np.exp(1j * (da - db)))))
    col["type"] = classify(col["class_a"], col["class_b"], col["angle_deg"])
    col["conflict"] = ((col["min_ttc_s"] <= opts.ttc_s) | (col["pet_s"] <= opts.pet_s)).astype(int)
    return col


def format_conflicts(table: ConflictTable, fps: float) -> str:
    """conflicts.csv text: the columns of COLUMNS (and INTERVAL_COLUMNS when sampled); empty
    fields where an indicator does not exist (no collision course, no common spot);
    seconds and metres to the millisecond / millimetre."""
    cols = COLUMNS + [c for c in INTERVAL_COLUMNS if c in table.columns]
    ints = {"track_a", "track_b", "conflict", "first_frame", "last_frame", "min_ttc_frame",
            "ta_frame", "evasive_track", "pet_first_track", "pet_exit_frame", "pet_enter_frame",
            "min_distance_frame"}
    buf = io.StringIO()
    buf.write(",".join(cols) + "\n")
    data = [table.columns[c] for c in cols]
    for i in range(len(table)):
        cells = []
        for c, v in zip(cols, data):
            x = v[i]
            if isinstance(x, str) or (v.dtype == object and not isinstance(x, (float, int, np.number))):
                cells.append(str(x))
            elif not np.isfinite(x):
                cells.append("")
            elif c in ints:
                cells.append(str(int(x)))
            else:
                cells.append(f"{float(x):.3f}")
        buf.write(",".join(cells) + "\n")
    return buf.getvalue()
