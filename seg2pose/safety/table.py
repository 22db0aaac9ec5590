"""The conflict table: one row per encounter from the deciding pair frames and the PETs
(``conflicts``), its columns, and the text of ``conflicts.csv``.

The reference frame of a row (where the speeds, DeltaS, the angle and the type are read) is
the minimum-TTC frame; without a collision course, the PET frames; without either, the frame
of the least gap (so a pair that is no conflict is typed as one that is).
"""

from __future__ import annotations

import io

import numpy as np

from seg2pose.safety.encounters import pair_codes
from seg2pose.safety.evasive import onsets, tct_severity, time_to_accident
from seg2pose.safety.measures import angle_type, classify, conflict_angle, max_delta_v, second_road_user

COLUMNS = ["track_a", "class_a", "track_b", "class_b", "type", "ssam_type", "conflict", "pet_only",
           "first_frame", "last_frame", "start_frame", "end_frame", "min_ttc_s", "min_ttc_frame",
           "ta_s", "ta_frame", "evasive_track", "evasive_kind", "conflicting_speed_mps",
           "tct_severity", "pet_s", "pet_first_track", "pet_exit_frame", "pet_enter_frame",
           "angle_deg", "speed_a_mps", "speed_b_mps", "max_s_mps", "delta_s_mps", "second_track",
           "dr_mps2", "max_d_mps2", "max_delta_v_mps", "max_decel_a_mps2", "max_decel_b_mps2",
           "min_distance_m", "min_distance_frame", "start_x", "start_y", "end_x", "end_y",
           "min_ttc_x", "min_ttc_y"]
INTERVAL_COLUMNS = ["min_ttc_lo_s", "min_ttc_hi_s", "pet_lo_s", "pet_hi_s", "ta_lo_s", "ta_hi_s",
                    "ttc_found_share", "pet_found_share"]
DR_MIN_MPS2 = 0.5  # braking at least this hard counts as braking for SSAM's DR
TEXT = {"class_a", "class_b", "type", "ssam_type", "evasive_kind", "tct_severity"}
INTS = {"track_a", "track_b", "conflict", "pet_only", "first_frame", "last_frame", "start_frame",
        "end_frame", "min_ttc_frame", "ta_frame", "evasive_track", "pet_first_track",
        "pet_exit_frame", "pet_enter_frame", "second_track", "min_distance_frame"}


def _pair_key(a_id, b_id) -> np.ndarray:
    return np.c_[np.asarray(a_id, np.int64), np.asarray(b_id, np.int64)]


def _first_where(mask: np.ndarray, st: np.ndarray, P: int, last: bool = False) -> np.ndarray:
    """Per group (starts ``st``), the first (last) index where ``mask``; P (-1) where none."""
    idx = np.arange(P)
    if last:
        return np.maximum.reduceat(np.where(mask, idx, -1), st)
    return np.minimum.reduceat(np.where(mask, idx, P), st)


def build_table(tracks, mot, pf, pr, opts) -> dict:
    """The columns (COLUMNS) of every encounter: the pairs of ``pf`` (deciding pair frames,
    sorted by pair, then frame) and of ``pr`` (PETs)."""
    tid, frame, speed = tracks.track_id, tracks.frame, mot.speed
    keys = np.r_[_pair_key(tid[pf.a], tid[pf.b]), _pair_key(pr.track_a, pr.track_b)]
    ids = np.unique(keys)
    codes, first, inv = np.unique(pair_codes(keys[:, 0], keys[:, 1], ids), return_index=True,
                                  return_inverse=True)
    enc = keys[first]
    inv = inv.reshape(-1)
    K = len(enc)
    g_pf, g_pr = inv[:len(pf.a)], inv[len(pf.a):]
    col = {k: np.full(K, np.nan) for k in COLUMNS}
    col["track_a"], col["track_b"] = enc[:, 0], enc[:, 1]
    order = np.argsort(tid, kind="stable")
    pos = np.searchsorted(tid[order], enc)
    col["class_a"], col["class_b"] = tracks.cls[order[pos[:, 0]]], tracks.cls[order[pos[:, 1]]]
    ff, lf = np.full(K, np.iinfo(np.int64).max), np.full(K, -1)
    ref_a, ref_b = np.full(K, -1), np.full(K, -1)  # rows of a and b at the reference frame
    dist_a, dist_b = np.full(K, -1), np.full(K, -1)  # ... at the least gap
    max_s, dec_a, dec_b = (np.full(K, -np.inf) for _ in range(3))
    P = len(pf.a)
    if P:
        fa = frame[pf.a]
        np.minimum.at(ff, g_pf, fa)
        np.maximum.at(lf, g_pf, fa)
        np.maximum.at(max_s, g_pf, np.maximum(speed[pf.a], speed[pf.b]))
        np.maximum.at(dec_a, g_pf, -mot.along[pf.a])
        np.maximum.at(dec_b, g_pf, -mot.along[pf.b])
        st = np.flatnonzero(np.r_[True, g_pf[1:] != g_pf[:-1]])  # groups are contiguous
        cnt = np.diff(np.r_[st, P])
        gid = g_pf[st]
        x = np.where(np.isfinite(pf.ttc), pf.ttc, np.inf)
        mins = np.minimum.reduceat(x, st)
        at_min = _first_where(x == np.repeat(mins, cnt), st, P)
        has = np.isfinite(mins)
        i = at_min[has]
        col["min_ttc_s"][gid[has]] = mins[has]
        col["min_ttc_frame"][gid[has]] = fa[i]
        ref_a[gid[has]], ref_b[gid[has]] = pf.a[i], pf.b[i]
        # the predicted point of contact: midway between the two after min TTC seconds
        ahead = 0.5 * (tracks.xy[pf.a[i]] + tracks.xy[pf.b[i]]
                       + (mot.vel[pf.a[i]] + mot.vel[pf.b[i]]) * mins[has, None])
        col["min_ttc_x"][gid[has]], col["min_ttc_y"][gid[has]] = ahead[:, 0], ahead[:, 1]
        hot = pf.ttc <= opts.ttc_s
        s0, s1 = _first_where(hot, st, P), _first_where(hot, st, P, last=True)
        got = s0 < P
        for name, j in (("start", s0[got]), ("end", s1[got])):
            mid = 0.5 * (tracks.xy[pf.a[j]] + tracks.xy[pf.b[j]])
            col[f"{name}_frame"][gid[got]] = fa[j]
            col[f"{name}_x"][gid[got]], col[f"{name}_y"][gid[got]] = mid[:, 0], mid[:, 1]
        dmin = np.minimum.reduceat(pf.distance, st)
        at_d = _first_where(pf.distance == np.repeat(dmin, cnt), st, P)
        col["min_distance_m"][gid] = dmin
        col["min_distance_frame"][gid] = fa[at_d]
        dist_a[gid], dist_b[gid] = pf.a[at_d], pf.b[at_d]
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
        ref_a[g_pr[no_ref]], ref_b[g_pr[no_ref]] = pa[no_ref], pb[no_ref]
    no_ref = ref_a < 0
    ref_a[no_ref], ref_b[no_ref] = dist_a[no_ref], dist_b[no_ref]
    col["first_frame"], col["last_frame"] = ff, lf
    col["max_s_mps"] = max_s
    col["max_decel_a_mps2"] = np.maximum(dec_a, 0.0)
    col["max_decel_b_mps2"] = np.maximum(dec_b, 0.0)
    _reference(col, tracks, mot, ref_a, ref_b, pr, g_pr, opts)
    col["conflict"] = (col["min_ttc_s"] <= opts.ttc_s).astype(int)
    col["pet_only"] = ((col["conflict"] == 0) & (col["pet_s"] <= opts.pet_s)).astype(int)
    _second_measures(col, tracks, mot)
    last = np.where(np.isfinite(col["min_ttc_frame"]), col["min_ttc_frame"], col["last_frame"])
    ta = time_to_accident(tracks, mot, onsets(tracks, mot, opts.evasive), col["track_a"], col["track_b"],
                          last.astype(np.int64), col["first_frame"].astype(np.int64), opts.horizon_s)
    col.update(ta)
    col["tct_severity"] = tct_severity(col["ta_s"], col["conflicting_speed_mps"], opts.evasive)
    return col


def _reference(col, tracks, mot, ref_a, ref_b, pr, g_pr, opts) -> None:
    """Speeds, DeltaS, MaxDeltaV, the signed angle, the types and the second road user, read
    at the reference rows ``ref_a``, ``ref_b`` (K,)."""
    speed, vel = mot.speed, mot.vel
    va, vb = vel[ref_a], vel[ref_b]
    col["speed_a_mps"], col["speed_b_mps"] = speed[ref_a], speed[ref_b]
    col["delta_s_mps"] = np.hypot(*(va - vb).T)
    col["max_delta_v_mps"] = max_delta_v(col["class_a"], col["class_b"], col["delta_s_mps"])
    # directions of travel: the velocity where the road user moves, else its heading
    moving = opts.motion.moving_mps
    da = np.where(speed[ref_a] >= moving, np.arctan2(va[:, 1], va[:, 0]), mot.heading[ref_a])
    db = np.where(speed[ref_b] >= moving, np.arctan2(vb[:, 1], vb[:, 0]), mot.heading[ref_b])
    b_second = second_road_user(tracks.xy[ref_a], va, tracks.xy[ref_b], vb)
    if len(g_pr):  # without a collision course: the one that entered the spot second
        no_ttc = ~np.isfinite(col["min_ttc_s"][g_pr])
        b_second[g_pr[no_ttc]] = pr.first[no_ttc] == pr.track_a[no_ttc]
    col["second_track"] = np.where(b_second, col["track_b"], col["track_a"])
    # SSAM's angle: from the first road user's direction to the second's
    col["angle_deg"] = conflict_angle(np.where(b_second, da, db), np.where(b_second, db, da))
    col["type"] = classify(col["class_a"], col["class_b"], col["angle_deg"])
    col["ssam_type"] = angle_type(col["angle_deg"])


def _second_measures(col, tracks, mot) -> None:
    """SSAM's DR and MaxD of the second road user over each conflict's frames (start to end
    frame): DR its first acceleration along its travel at or below -DR_MIN_MPS2 (its least,
    if it never brakes that hard: a smoothed track is never exactly steady), MaxD its least
    acceleration, m/s^2 (negative: braking)."""
    tid, frame = tracks.track_id, tracks.frame
    for k in np.flatnonzero(col["conflict"] == 1):
        t = col["second_track"][k]
        lo = np.searchsorted(tid, t, "left")
        hi = np.searchsorted(tid, t, "right")
        f0, f1 = col["start_frame"][k], col["end_frame"][k]
        r = lo + np.flatnonzero((frame[lo:hi] >= f0) & (frame[lo:hi] <= f1))
        if not len(r):
            continue
        acc = mot.along[r]
        neg = np.flatnonzero(acc <= -DR_MIN_MPS2)
        col["max_d_mps2"][k] = acc.min()
        col["dr_mps2"][k] = acc[neg[0]] if len(neg) else acc.min()


def format_conflicts(table, fps: float) -> str:
    """conflicts.csv text: the columns of COLUMNS (and INTERVAL_COLUMNS when sampled); empty
    fields where an indicator does not exist (no collision course, no common spot, no
    evasive action, no interval); seconds and metres to the millisecond / millimetre."""
    cols = COLUMNS + [c for c in INTERVAL_COLUMNS if c in table.columns]
    buf = io.StringIO()
    buf.write(",".join(cols) + "\n")
    data = [table.columns[c] for c in cols]
    for i in range(len(table)):
        cells = []
        for c, v in zip(cols, data):
            x = v[i]
            if c in TEXT:
                cells.append(str(x))
            elif not np.isfinite(x):
                cells.append("")
            elif c in INTS:
                cells.append(str(int(x)))
            else:
                cells.append(f"{float(x):.3f}")
        buf.write(",".join(cells) + "\n")
    return buf.getvalue()
