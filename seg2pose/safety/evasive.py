"""Time-to-Accident and conflicting speed (the Swedish Traffic Conflict Technique, Hyden 1987).

TA is "the time that remains to an accident from the moment that one of the road users starts
an evasive action if they had continued with unchanged speeds and directions"; the
conflicting speed is the speed of that road user just before the evasive action. So TA is the
TTC (``ttc``) at the *onset* of the evasive action, computed with the evasive road user's
velocity from just before it.

**Evasive action** (per road user, from ``kinematics.Motion``): braking (deceleration along
the direction of travel of at least ``brake_mps2``) or swerving (lateral acceleration of at
least ``swerve_mps2``, or, where ``yaw_dps`` is set, a turning rate of at least that). An
action is a run of frames above its threshold; its **onset** is traced back from the run's
first frame to where the signal (deceleration, |lateral acceleration|) rose through half of
the run's peak: the smoother spreads a sudden change evenly over its window, so the midpoint
of the rise is where the change happened (a gradual onset -- a jerk-limited braking -- is
dated half its rise time late). The speed "just before" is taken at the last frame whose
velocity window ends before the onset. Of the actions during an encounter on a collision
course, the strongest is the evasive action (noise makes weak ones).

**Severity** (TCT): serious when TA is at or below the boundary for the conflicting speed,
slight above it. The TCT draws that boundary as a curve in the TA-speed chart (Hyden 1987;
Laureshyn and Varhelyi 2018, "The Swedish Traffic Conflict Technique: observer's manual",
Lund University, section 4, the chart of severity levels, serious from level 26). The
curve's points were not available to this project (no copy of the chart could be read
offline), so the default boundary is a **stand-in** for it, not the TCT's: the time a road
user at that speed needs to stop at ``TCT_DECEL_MPS2`` = 4 m/s^2, TA_serious(v) = v / (2 a)
(1.74 s at 50 km/h, 3.47 s at 100 km/h: the published curve rises with speed in the same
way, and 4 m/s^2 is a firm but ordinary braking). Both are options (``EvasiveOptions``;
``s2p conflicts --tct-decel`` / ``--tct-curve``): a study with the digitised chart enters its
points (km/h, s), joined by straight lines. Severities from the default are the stand-in's
and must be reported as such.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seg2pose.safety.kinematics import Motion, segments
from seg2pose.safety.tracks import Tracks
from seg2pose.safety.ttc import ttc

TCT_DECEL_MPS2 = 4.0


@dataclass(frozen=True)
class EvasiveOptions:
    """brake_mps2, swerve_mps2: evasive action thresholds; yaw_dps: a turning rate that also
    counts as swerving (None: lateral acceleration only; at low speed a swerve is a turn
    more than a lateral acceleration); min_speed_mps: slower road users take no evasive
    action (a pedestrian stepping aside is no braking); tct_decel_mps2, tct_curve: the TCT
    severity boundary (``tct_boundary_s``): the stand-in's deceleration, or the curve's
    points ((km/h, TA s), ...; when given, it is used)."""

    brake_mps2: float = 3.0
    swerve_mps2: float = 3.0
    yaw_dps: float | None = None
    min_speed_mps: float = 1.0
    tct_decel_mps2: float = TCT_DECEL_MPS2
    tct_curve: tuple[tuple[float, float], ...] = ()


@dataclass
class Onsets:
    """E evasive actions: row (E,) the onset row; before (E,) the row whose velocity is the
    speed just before; kind (E,) "brake" / "swerve"; peak (E,) the run's peak, m/s^2."""

    row: np.ndarray
    before: np.ndarray
    kind: np.ndarray
    peak: np.ndarray


def _runs(flag: np.ndarray, starts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First and last row of each run of True in ``flag`` (runs end at segment starts)."""
    idx = np.arange(len(flag))
    begin = flag & (np.r_[True, ~flag[:-1]] | (starts == idx))
    end = flag & (np.r_[~flag[1:], True] | np.r_[starts[1:] == idx[1:], True])
    return np.flatnonzero(begin), np.flatnonzero(end)


def onsets(tracks: Tracks, mot: Motion, opts: EvasiveOptions = EvasiveOptions()) -> Onsets:
    """Every evasive action of every road user (the module's rule), in row order."""
    starts, _ = segments(tracks)
    decel = -mot.along
    lat = np.abs(mot.lateral)
    fast = mot.speed >= opts.min_speed_mps
    yaw = np.zeros(len(tracks)) if opts.yaw_dps is None else \
        np.degrees(lat / np.maximum(mot.speed, 1e-9))
    out = []
    for kind, sig, thr in (("brake", decel, opts.brake_mps2), ("swerve", lat, opts.swerve_mps2)):
        flag = fast & (sig >= thr)
        if kind == "swerve" and opts.yaw_dps is not None:
            flag |= fast & (yaw >= opts.yaw_dps)
        b, e = _runs(flag, starts)
        if not len(b):
            continue
        peak = _run_max(sig, b, e)
        half = 0.5 * peak
        onset = b.copy()
        # trace back while the signal stays above half the peak (within the segment)
        active = np.ones(len(b), bool)
        while active.any():
            prev = onset - 1
            ok = active & (prev >= starts[b]) & (sig[np.maximum(prev, 0)] >= half)
            onset = np.where(ok, prev, onset)
            active = ok
        # the crossing of half the peak lies between the onset row and the one before it:
        # the nearer of the two
        prev = np.maximum(onset - 1, 0)
        has = onset > starts[onset]
        rise = sig[onset] - sig[prev]
        frac = np.where(has & (rise > 0), (half - sig[prev]) / np.where(rise > 0, rise, 1.0), 1.0)
        onset = np.where(has & (frac < 0.5), prev, onset)
        back = onset - (mot.n_vel[onset] // 2 + 1)
        before = np.maximum(back, starts[onset])
        out.append((onset, before, np.full(len(b), kind, object), peak))
    if not out:
        e = np.zeros(0, np.int64)
        return Onsets(e, e, np.zeros(0, object), np.zeros(0))
    row, before, kind, peak = (np.concatenate([o[k] for o in out]) for k in range(4))
    o = np.argsort(row, kind="stable")
    return Onsets(row[o], before[o], kind[o], peak[o])


def _run_max(sig: np.ndarray, b: np.ndarray, e: np.ndarray) -> np.ndarray:
    """(R,) max of ``sig`` over each run [b, e] (runs disjoint, sorted)."""
    bounds = np.unique(np.r_[b, e + 1])
    bounds = bounds[bounds < len(sig)]
    m = np.maximum.reduceat(sig, bounds)
    pos = np.searchsorted(bounds, b)
    return m[pos]


def time_to_accident(tracks: Tracks, mot: Motion, ons: Onsets, track_a: np.ndarray,
                     track_b: np.ndarray, last_frame: np.ndarray, first_frame: np.ndarray,
                     horizon_s: float) -> dict:
    """TA of K pairs (track_a, track_b (K,) ids): of the evasive actions of either road user
    with their onset within frames [first_frame, last_frame] (K,) at which the two, with the
    evasive one at its speed from just before, are on a collision course within
    ``horizon_s``, the strongest (highest peak deceleration or lateral acceleration).
    Returns (K,) arrays: ta_s, ta_frame, evasive_track, conflicting_speed_mps, evasive_kind
    ("" where none)."""
    K = len(track_a)
    out = {"ta_s": np.full(K, np.nan), "ta_frame": np.full(K, np.nan),
           "evasive_track": np.full(K, np.nan), "conflicting_speed_mps": np.full(K, np.nan),
           "evasive_kind": np.full(K, "", object)}
    if K == 0 or len(ons.row) == 0:
        return out
    tid, frame = tracks.track_id, tracks.frame
    # (track, frame) -> row, for the other road user at the onset's frame
    span = int(frame.max()) + 1
    key = tid.astype(np.int64) * span + frame
    order = np.argsort(key)
    ks = key[order]

    def row_of(t, f):
        k = t.astype(np.int64) * span + f
        p = np.minimum(np.searchsorted(ks, k), len(ks) - 1)
        return np.where(ks[p] == k, order[p], -1)

    on_tid = tid[ons.row]
    cand_k, cand_e, cand_other = [], [], []
    for me, other in ((track_a, track_b), (track_b, track_a)):
        # onsets of ``me``: per pair, the onsets of that track (tracks are sorted, onsets by row)
        lo = np.searchsorted(on_tid, me, "left")
        hi = np.searchsorted(on_tid, me, "right")
        cnt = hi - lo
        k = np.repeat(np.arange(K), cnt)
        e = np.repeat(lo, cnt) + (np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt))
        cand_k.append(k)
        cand_e.append(e)
        cand_other.append(other[k])
    k, e, other = np.concatenate(cand_k), np.concatenate(cand_e), np.concatenate(cand_other)
    f = frame[ons.row[e]]
    keep = (f >= first_frame[k]) & (f <= last_frame[k])
    k, e, other, f = k[keep], e[keep], other[keep], f[keep]
    r_other = row_of(other, f)
    keep = r_other >= 0
    k, e, r_other, f = k[keep], e[keep], r_other[keep], f[keep]
    r_me, r_bef = ons.row[e], ons.before[e]
    x = ttc(tracks.xy[r_me], mot.heading[r_bef], tracks.size[r_me], mot.vel[r_bef],
            tracks.xy[r_other], mot.heading[r_other], tracks.size[r_other], mot.vel[r_other], horizon_s)
    hit = np.isfinite(x)
    k, e, f, x, r_bef = k[hit], e[hit], f[hit], x[hit], r_bef[hit]
    # per pair the strongest action (highest peak; ties: the earlier): noise makes weak
    # spurious "actions" that a first-onset rule would take
    o = np.lexsort((ons.row[e], f, -ons.peak[e], k))
    k, e, f, x, r_bef = k[o], e[o], f[o], x[o], r_bef[o]
    first = np.r_[True, k[1:] != k[:-1]] if len(k) else np.zeros(0, bool)
    k, e, f, x, r_bef = k[first], e[first], f[first], x[first], r_bef[first]
    out["ta_s"][k] = x
    out["ta_frame"][k] = f
    out["evasive_track"][k] = tid[ons.row[e]]
    out["conflicting_speed_mps"][k] = mot.speed[r_bef]
    out["evasive_kind"][k] = ons.kind[e]
    return out


def tct_boundary_s(speed_mps, opts: EvasiveOptions = EvasiveOptions()) -> np.ndarray:
    """(K,) the TA (s) at or below which a conflict at this conflicting speed (K,) m/s is
    serious: ``opts.tct_curve``'s points (km/h, s) joined by straight lines (beyond the
    last point: the line through the last two, at least the last TA); without points the
    module's stand-in v / (2 ``opts.tct_decel_mps2``)."""
    v = np.asarray(speed_mps, np.float64)
    pts = np.asarray(opts.tct_curve, np.float64).reshape(-1, 2)
    if len(pts) == 0:
        return v / (2.0 * opts.tct_decel_mps2)
    order = np.argsort(pts[:, 0])
    kmh, ta = pts[order, 0], pts[order, 1]
    x = v * 3.6
    out = np.interp(x, kmh, ta)
    if len(kmh) >= 2:
        slope = (ta[-1] - ta[-2]) / max(kmh[-1] - kmh[-2], 1e-9)
        out = np.where(x > kmh[-1], np.maximum(ta[-1] + slope * (x - kmh[-1]), ta[-1]), out)
    return out


def tct_severity(ta_s, speed_mps, opts: EvasiveOptions = EvasiveOptions()) -> np.ndarray:
    """(K,) "serious" / "slight" by the TCT boundary (``tct_boundary_s``), "" where there is
    no TA."""
    ta, v = np.asarray(ta_s, np.float64), np.asarray(speed_mps, np.float64)
    out = np.where(ta <= tct_boundary_s(v, opts), "serious", "slight").astype(object)
    out[~(np.isfinite(ta) & np.isfinite(v))] = ""
    return out
