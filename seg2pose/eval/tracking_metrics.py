"""The standard multi-object tracking metrics: HOTA, CLEAR MOT (MOTA) and identity (IDF1).

Definitions, as TrackEval (Luiten & Hoffhues, the MOTChallenge / KITTI / BDD evaluation code)
computes them, so that the figures can stand next to the literature's:

- **HOTA** (Luiten et al., "HOTA: A Higher Order Metric for Evaluating Multi-Object Tracking",
  IJCV 129, 2021, eqs. 3-11): at each localisation threshold alpha in 0.05, 0.10, ..., 0.95,
  DetA = |TP| / (|TP| + |FN| + |FP|); AssA = (1 / |TP|) sum over TP c of A(c),
  A(c) = |TPA(c)| / (|TPA(c)| + |FNA(c)| + |FPA(c)|) (the Jaccard index of the two tracks
  that c joins); HOTA_alpha = sqrt(DetA_alpha * AssA_alpha); LocA = mean similarity of the TPs.
  The reported HOTA, DetA, AssA, LocA, DetRe, DetPr, AssRe, AssPr are means over the 19
  alphas. Per frame, pairs are chosen by the Hungarian method on similarity x the pair's
  global alignment score (the paper's matching that maximises HOTA: section 5).
- **CLEAR MOT** (Bernardin & Stiefelhagen, "Evaluating Multiple Object Tracking Performance:
  The CLEAR MOT Metrics", EURASIP JIVP 2008): per frame a one-to-one matching with similarity
  >= 0.5, keeping last frame's pairs where they still qualify (a bonus of 1000), then the
  highest total similarity; MOTA = 1 - (FN + FP + IDSW) / GT; MOTP = mean similarity of the
  matches; an ID switch is a truth track matched to another estimated id than at its last
  match. With mask IoU as similarity MOTA is MOTS's MOTSA and sMOTA its sMOTSA (Voigtlaender
  et al., "MOTS: Multi-Object Tracking and Segmentation", CVPR 2019).
- **Identity** (Ristani et al., "Performance Measures and a Data Set for Multi-Target,
  Multi-Camera Tracking", ECCV workshops 2016): one global one-to-one assignment of truth to
  estimated tracks (Hungarian on the detections each pair would leave unmatched; a pair's
  detections match where similarity >= 0.5); IDF1 = 2 IDTP / (2 IDTP + IDFP + IDFN),
  IDP = IDTP / (IDTP + IDFP), IDR = IDTP / (IDTP + IDFN).

HOTA and CLEAR follow TrackEval 1.3.0's ``trackeval.metrics.HOTA`` and ``CLEAR`` step for step
(order of matching, tie-breaking); identity solves ``Identity``'s assignment in an equivalent
smaller form (``identity``). The tests compare all three with TrackEval to 1e-9 when it is
installed. TrackEval itself is not a run-time dependency: its
package requires ``opencv-python``, which would sit beside this project's
``opencv-python-headless`` and break ``cv2``.

Input is a ``Sequence``: per frame the truth and estimated ids (dense, 0..n-1) and their
similarity matrix in [0, 1] (mask IoU for masks, ``1 - d / d0`` for world positions:
``seg2pose.eval.tracking_inputs``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

ALPHAS = np.arange(0.05, 0.99, 0.05)    # HOTA's 19 localisation thresholds (TrackEval's array)
THRESHOLD = 0.5                          # CLEAR and identity: a match needs similarity >= 0.5
_EPS = np.finfo(float).eps


@dataclass
class Sequence:
    """One sequence (one camera's masks, or one run's world tracks) as the metrics read it.

    gt_ids[t], tracker_ids[t]: (G_t,), (T_t,) int64 ids in 0..num_gt_ids-1 / 0..num_tracker_ids-1
    of frame t; similarity[t]: (G_t, T_t) float in [0, 1]; frames: (F,) the frames' numbers."""

    gt_ids: list[np.ndarray]
    tracker_ids: list[np.ndarray]
    similarity: list[np.ndarray]
    num_gt_ids: int
    num_tracker_ids: int
    frames: np.ndarray

    @property
    def num_gt_dets(self) -> int:
        return int(sum(len(g) for g in self.gt_ids))

    @property
    def num_tracker_dets(self) -> int:
        return int(sum(len(t) for t in self.tracker_ids))

    def as_trackeval(self) -> dict:
        """The sequence in TrackEval's ``eval_sequence`` data layout (for comparisons)."""
        return {"num_gt_dets": self.num_gt_dets, "num_tracker_dets": self.num_tracker_dets,
                "num_gt_ids": self.num_gt_ids, "num_tracker_ids": self.num_tracker_ids,
                "num_timesteps": len(self.gt_ids), "gt_ids": self.gt_ids,
                "tracker_ids": self.tracker_ids, "similarity_scores": self.similarity}


def _pair_counts(g: np.ndarray, t: np.ndarray, w: np.ndarray, n_gt: int, n_tr: int) -> np.ndarray:
    """(n_gt, n_tr) sums of weights w over pairs (g, t): one bincount instead of a loop."""
    return np.bincount(g * n_tr + t, weights=w, minlength=n_gt * n_tr).reshape(n_gt, n_tr)


def hota(seq: Sequence) -> dict:
    """HOTA and its parts (module docstring) as arrays over ``ALPHAS``: HOTA, DetA, AssA, DetRe,
    DetPr, AssRe, AssPr, LocA (A,) floats and HOTA_TP, HOTA_FN, HOTA_FP (A,) counts."""
    A = len(ALPHAS)
    n_gt, n_tr = seq.num_gt_ids, seq.num_tracker_ids
    res = {k: np.zeros(A) for k in ("HOTA_TP", "HOTA_FN", "HOTA_FP", "LocA", "AssA", "AssRe", "AssPr")}
    if seq.num_tracker_dets == 0 or seq.num_gt_dets == 0:
        res["HOTA_FN"][:] = seq.num_gt_dets if seq.num_tracker_dets == 0 else 0
        res["HOTA_FP"][:] = seq.num_tracker_dets if seq.num_gt_dets == 0 else 0
        res["LocA"][:] = 1.0
        return _hota_final(res)
    # pass 1: the global alignment score of every (truth id, estimated id) pair, eq. 13
    potential = np.zeros((n_gt, n_tr))
    gt_count = np.bincount(np.concatenate(seq.gt_ids), minlength=n_gt).astype(float)[:, None]
    tr_count = np.bincount(np.concatenate(seq.tracker_ids), minlength=n_tr).astype(float)[None, :]
    for g, t, s in zip(seq.gt_ids, seq.tracker_ids, seq.similarity):
        denom = s.sum(0)[None, :] + s.sum(1)[:, None] - s
        s_iou = np.zeros_like(s)
        ok = denom > 0 + _EPS
        s_iou[ok] = s[ok] / denom[ok]
        potential[g[:, None], t[None, :]] += s_iou
    with np.errstate(invalid="ignore", divide="ignore"):   # 0/0 only for ids that never appear
        align = potential / (gt_count + tr_count - potential)
    # pass 2: per frame one matching; every alpha keeps the pairs at least that similar
    mg, mt, ms = [], [], []
    for g, t, s in zip(seq.gt_ids, seq.tracker_ids, seq.similarity):
        if len(g) == 0 or len(t) == 0:
            res["HOTA_FP"] += len(t)
            res["HOTA_FN"] += len(g)
            continue
        r, c = linear_sum_assignment(-(align[g[:, None], t[None, :]] * s))
        keep = s[r, c][None, :] >= ALPHAS[:, None] - _EPS          # (A, K)
        n = keep.sum(1)
        res["HOTA_TP"] += n
        res["HOTA_FN"] += len(g) - n
        res["HOTA_FP"] += len(t) - n
        res["LocA"] += (keep * s[r, c][None, :]).sum(1)
        mg.append(g[r])
        mt.append(t[c])
        ms.append(s[r, c])
    pg, pt, ps = (np.concatenate(x) if x else np.zeros(0, np.int64) for x in (mg, mt, ms))
    for a, alpha in enumerate(ALPHAS):
        w = (ps >= alpha - _EPS).astype(float)
        m = _pair_counts(pg, pt, w, n_gt, n_tr)
        tp = np.maximum(1, res["HOTA_TP"][a])
        res["AssA"][a] = np.sum(m * (m / np.maximum(1, gt_count + tr_count - m))) / tp
        res["AssRe"][a] = np.sum(m * (m / np.maximum(1, gt_count))) / tp
        res["AssPr"][a] = np.sum(m * (m / np.maximum(1, tr_count))) / tp
    res["LocA"] = np.maximum(1e-10, res["LocA"]) / np.maximum(1e-10, res["HOTA_TP"])
    return _hota_final(res)


def _hota_final(res: dict) -> dict:
    tp, fn, fp = res["HOTA_TP"], res["HOTA_FN"], res["HOTA_FP"]
    res["DetRe"] = tp / np.maximum(1, tp + fn)
    res["DetPr"] = tp / np.maximum(1, tp + fp)
    res["DetA"] = tp / np.maximum(1, tp + fn + fp)
    res["HOTA"] = np.sqrt(res["DetA"] * res["AssA"])
    return res


def clear(seq: Sequence, threshold: float = THRESHOLD) -> dict:
    """CLEAR MOT (module docstring): MOTA, MOTP, MODA, sMOTA, CLR_Re, CLR_Pr and the counts
    CLR_TP, CLR_FN, CLR_FP, IDSW, Frag, MT, PT, ML (mostly tracked: matched in > 80 % of its
    frames, mostly lost: < 20 %)."""
    res: dict[str, float] = dict.fromkeys(("CLR_TP", "CLR_FN", "CLR_FP", "IDSW", "MT", "PT", "ML", "Frag"), 0)
    res["MOTP_sum"] = 0.0
    n_gt = seq.num_gt_ids
    if seq.num_tracker_dets == 0 or seq.num_gt_dets == 0:
        res["CLR_FN"] = seq.num_gt_dets if seq.num_tracker_dets == 0 else 0
        res["CLR_FP"] = seq.num_tracker_dets if seq.num_gt_dets == 0 else 0
        res["ML"] = n_gt if seq.num_tracker_dets == 0 else 0
        # as TrackEval: the rates of an empty side are 0 (not -FP / 1)
        return {**res, **dict.fromkeys(("CLR_Re", "CLR_Pr", "MODA", "MOTA", "MOTP", "sMOTA"), 0.0)}
    gt_count, gt_matched, frag = np.zeros(n_gt), np.zeros(n_gt), np.zeros(n_gt)
    # the id a truth track was last matched to (IDSW), and in the frame just before (matching)
    prev_id = np.full(n_gt, np.nan)
    prev_step_id = np.full(n_gt, np.nan)
    for g, t, s in zip(seq.gt_ids, seq.tracker_ids, seq.similarity):
        if len(g) == 0:
            res["CLR_FP"] += len(t)
            continue
        if len(t) == 0:
            res["CLR_FN"] += len(g)
            gt_count[g] += 1
            continue
        score = 1000 * (t[None, :] == prev_step_id[g[:, None]]) + s
        score[s < threshold - _EPS] = 0
        r, c = linear_sum_assignment(-score)
        ok = score[r, c] > 0 + _EPS
        r, c = r[ok], c[ok]
        mg, mt = g[r], t[c]
        before = prev_id[mg]
        res["IDSW"] += int(np.sum(~np.isnan(before) & (mt != before)))
        gt_count[g] += 1
        gt_matched[mg] += 1
        untracked = np.isnan(prev_step_id)
        prev_id[mg] = mt
        prev_step_id[:] = np.nan
        prev_step_id[mg] = mt
        frag += untracked & ~np.isnan(prev_step_id)
        res["CLR_TP"] += len(mg)
        res["CLR_FN"] += len(g) - len(mg)
        res["CLR_FP"] += len(t) - len(mg)
        res["MOTP_sum"] += float(np.sum(s[r, c]))
    ratio = gt_matched[gt_count > 0] / gt_count[gt_count > 0]
    res["MT"] = int(np.sum(ratio > 0.8))
    res["PT"] = int(np.sum(ratio >= 0.2)) - res["MT"]
    res["ML"] = n_gt - res["MT"] - res["PT"]
    res["Frag"] = int(np.sum(frag[frag > 0] - 1))
    return _clear_final(res)


def _clear_final(res: dict) -> dict:
    tp, fn, fp, sw = res["CLR_TP"], res["CLR_FN"], res["CLR_FP"], res["IDSW"]
    gt = max(1.0, tp + fn)
    res["CLR_Re"] = tp / gt
    res["CLR_Pr"] = tp / max(1.0, tp + fp)
    res["MODA"] = (tp - fp) / gt
    res["MOTA"] = (tp - fp - sw) / gt
    res["MOTP"] = res["MOTP_sum"] / max(1.0, tp)
    res["sMOTA"] = (res["MOTP_sum"] - fp - sw) / gt
    return res


def identity(seq: Sequence, threshold: float = THRESHOLD) -> dict:
    """IDF1, IDP, IDR and IDTP, IDFN, IDFP (module docstring)."""
    res = {"IDTP": 0, "IDFN": 0, "IDFP": 0}
    n_gt, n_tr = seq.num_gt_ids, seq.num_tracker_ids
    if seq.num_tracker_dets == 0 or seq.num_gt_dets == 0:
        res["IDFN"], res["IDFP"] = seq.num_gt_dets * (seq.num_tracker_dets == 0), seq.num_tracker_dets * (
            seq.num_gt_dets == 0)
        return _identity_final(res)
    gt_count = np.bincount(np.concatenate(seq.gt_ids), minlength=n_gt).astype(float)
    tr_count = np.bincount(np.concatenate(seq.tracker_ids), minlength=n_tr).astype(float)
    pg, pt = [], []
    for g, t, s in zip(seq.gt_ids, seq.tracker_ids, seq.similarity):
        i, j = np.nonzero(s >= threshold)
        pg.append(g[i])
        pt.append(t[j])
    pg_all, pt_all = np.concatenate(pg), np.concatenate(pt)
    # Ristani et al.'s (G+T) square assignment (truth ids to estimated ids or to "nobody", cost
    # IDFN + IDFP) costs sum(gt_count) + sum(tr_count) - 2 * (the pairs' potential matches): its
    # optimum is the maximum-weight matching of the ids that can match at all, the same IDTP at a
    # fraction of the size ((G' x T') instead of (G + T)^2; TrackEval builds the square)
    gi, g_inv = np.unique(pg_all, return_inverse=True)
    ti, t_inv = np.unique(pt_all, return_inverse=True)
    idtp = 0
    if len(gi):
        potential = _pair_counts(g_inv, t_inv, np.ones(len(g_inv)), len(gi), len(ti))
        r, c = linear_sum_assignment(-potential)
        idtp = int(round(potential[r, c].sum()))
    res["IDTP"] = idtp
    res["IDFN"] = int(gt_count.sum()) - idtp
    res["IDFP"] = int(tr_count.sum()) - idtp
    return _identity_final(res)


def _identity_final(res: dict) -> dict:
    tp, fn, fp = res["IDTP"], res["IDFN"], res["IDFP"]
    res["IDR"] = tp / max(1.0, tp + fn)
    res["IDP"] = tp / max(1.0, tp + fp)
    res["IDF1"] = tp / max(1.0, tp + 0.5 * fp + 0.5 * fn)
    return res


def summary(seq: Sequence, kind: str = "world") -> dict:
    """The figures a tracking paper reports, as one flat JSON-ready dict: HOTA, DetA, AssA,
    LocA, DetRe, DetPr, AssRe, AssPr (means over the alphas), IDF1, IDP, IDR, MOTA, MOTP, MODA,
    sMOTA, IDSW, TP, FP, FN, Frag, MT, PT, ML, and the sequence's size. ``kind="masks"`` names
    MOTA / MOTP / sMOTA as MOTS does: MOTSA, MOTSP, sMOTSA."""
    h, c, i = hota(seq), clear(seq), identity(seq)
    out: dict = {k: float(np.mean(h[k])) for k in
                 ("HOTA", "DetA", "AssA", "LocA", "DetRe", "DetPr", "AssRe", "AssPr")}
    out.update({k: float(i[k]) for k in ("IDF1", "IDP", "IDR")})
    names = {"MOTA": "MOTSA", "MOTP": "MOTSP", "sMOTA": "sMOTSA"} if kind == "masks" else {}
    out.update({names.get(k, k): float(c[k]) for k in ("MOTA", "MOTP", "MODA", "sMOTA")})
    out.update({"IDSW": int(c["IDSW"]), "TP": int(c["CLR_TP"]), "FP": int(c["CLR_FP"]),
                "FN": int(c["CLR_FN"]), "Frag": int(c["Frag"]), "MT": int(c["MT"]),
                "PT": int(c["PT"]), "ML": int(c["ML"]), "IDTP": int(i["IDTP"]),
                "IDFP": int(i["IDFP"]), "IDFN": int(i["IDFN"]),
                "gt_tracks": int(seq.num_gt_ids), "est_tracks": int(seq.num_tracker_ids),
                "gt_dets": seq.num_gt_dets, "est_dets": seq.num_tracker_dets,
                "frames": len(seq.gt_ids)})
    return out


def format_summary(d: dict) -> str:
    """One line of a ``summary``: HOTA with DetA / AssA / LocA, IDF1 with IDP / IDR, MOTA (MOTSA
    for masks) with MOTP, IDSW, FP, FN."""
    mota = "MOTSA" if "MOTSA" in d else "MOTA"
    motp = "MOTSP" if "MOTSP" in d else "MOTP"
    return (f"HOTA {d['HOTA']:.3f} (DetA {d['DetA']:.3f}, AssA {d['AssA']:.3f}, LocA {d['LocA']:.3f})  "
            f"IDF1 {d['IDF1']:.3f} (IDP {d['IDP']:.3f}, IDR {d['IDR']:.3f})  "
            f"{mota} {d[mota]:.3f} ({motp} {d[motp]:.3f}, IDSW {d['IDSW']}, FP {d['FP']}, FN {d['FN']})  "
            f"{d['gt_tracks']} truth / {d['est_tracks']} estimated tracks")
