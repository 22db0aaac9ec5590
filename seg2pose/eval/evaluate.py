"""Evaluation against ground truth (paper 4.1.1 / 4.2.1, Figures 6-7, Table 1).

Estimates are matched to ground truth by (frame, track_id), or, for tracks whose ids are not the
truth's (a tracker's), by ``match="nearest"``: per frame, one-to-one by ground-plane distance
(Hungarian method) within ``gate`` metres. The error of a matched pair is the
Euclidean distance in the ground plane (x, y), metres. Errors are also grouped by the distance
of the *true* position from an origin (the rig centre, projected to the ground plane) in bins of
``bin_size`` metres: [0, 5), [5, 10), ... as in the paper's figures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from seg2pose.io.atomic import atomic_path
from seg2pose.io.mots import iter_mots
from seg2pose.io.poses import PoseTable
from seg2pose.io.scene import Scene

BIN_SIZE = 5.0  # metres, as in Figures 6-7


def _dense_keys(est: PoseTable, gt: PoseTable) -> tuple[np.ndarray, np.ndarray]:
    """One int64 key per row for (frame, track_id), shared by both tables."""
    _, f_inv = np.unique(np.concatenate([est.frame, gt.frame]), return_inverse=True)
    t_vals, t_inv = np.unique(np.concatenate([est.track_id, gt.track_id]), return_inverse=True)
    key = f_inv.astype(np.int64) * max(len(t_vals), 1) + t_inv
    return key[:len(est)], key[len(est):]


def match_poses(est: PoseTable, gt: PoseTable) -> tuple[np.ndarray, np.ndarray]:
    """Pairs of rows with equal (frame, track_id): indices into ``est`` (K,) and ``gt`` (K,).

    Only estimates with a finite x, y take part (a NaN estimate counts as missed). A duplicated
    key is matched once (first occurrence in each table)."""
    if len(est) == 0 or len(gt) == 0:
        z = np.zeros(0, np.int64)
        return z, z.copy()
    ke, kg = _dense_keys(est, gt)
    finite = np.isfinite(est.xyz[:, :2]).all(axis=1)
    ue, ie = np.unique(np.where(finite, ke, -1), return_index=True)
    keep = ue >= 0
    ue, ie = ue[keep], ie[keep]
    ug, ig = np.unique(kg, return_index=True)
    _, a, b = np.intersect1d(ue, ug, assume_unique=True, return_indices=True)
    idx_est, idx_gt = ie[a], ig[b]
    order = np.argsort(idx_gt, kind="stable")  # gt order: frame-sorted for sorted gt files
    return idx_est[order].astype(np.int64), idx_gt[order].astype(np.int64)


def match_nearest(est: PoseTable, gt: PoseTable, gate: float = 3.0
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Per frame, estimates and truth paired one to one by least ground-plane distance
    (Hungarian method), pairs farther than ``gate`` metres dropped. Indices into ``est`` (K,)
    and ``gt`` (K,), in gt order."""
    from scipy.optimize import linear_sum_assignment

    finite = np.flatnonzero(np.isfinite(est.xyz[:, :2]).all(axis=1))
    ie_all, ig_all = [], []
    if len(finite) == 0 or len(gt) == 0:
        z = np.zeros(0, np.int64)
        return z, z.copy()
    eo = finite[np.argsort(est.frame[finite], kind="stable")]
    go = np.argsort(gt.frame, kind="stable")
    ef, gf = est.frame[eo], gt.frame[go]
    for f in np.intersect1d(ef, gf):
        e = eo[np.searchsorted(ef, f, "left"):np.searchsorted(ef, f, "right")]
        g = go[np.searchsorted(gf, f, "left"):np.searchsorted(gf, f, "right")]
        d = np.linalg.norm(est.xyz[e, None, :2] - gt.xyz[None, g, :2], axis=2)
        r, c = linear_sum_assignment(np.where(d <= gate, d, 1e9))
        ok = d[r, c] <= gate
        ie_all.append(e[r[ok]])
        ig_all.append(g[c[ok]])
    ie, ig = np.concatenate(ie_all), np.concatenate(ig_all)
    order = np.argsort(ig, kind="stable")
    return ie[order].astype(np.int64), ig[order].astype(np.int64)


def choose_match(est: PoseTable, gt: PoseTable, gate: float = 3.0) -> tuple[str, int, int]:
    """"ids" when the run's track ids are the truth's, else "nearest" (a tracker's ids: ``s2p
    track``, ``masks-from-video``, ``import-detections``). Returns (match, pairs by id within
    ``gate`` metres, pairs by position). Ids are the truth's when at least half of the pairs
    found by position are also found by id: a tracker's ids 1, 2, ... meet a truth track of the
    same number nearby only by chance."""
    ie, ig = match_poses(est, gt)
    by_id = int(np.count_nonzero(np.linalg.norm(est.xyz[ie, :2] - gt.xyz[ig, :2], axis=1) <= gate))
    by_pos = len(match_nearest(est, gt, gate)[0])
    return ("ids" if by_id >= 0.5 * by_pos else "nearest"), by_id, by_pos


def _nan_mean(x: np.ndarray) -> float:
    return float(np.mean(x)) if len(x) else float("nan")


@dataclass
class EvalResult:
    """Errors of one run against ground truth.

    n_est, n_gt: rows considered; n_matched: pairs; mean_error: metres (NaN when nothing
    matched); per_class: class name (of the truth) -> mean error, metres; bins: (lo, hi, count,
    mean_error) per distance bin, metres (mean NaN for an empty bin); errors (K,) and
    distances (K,) metres per matched pair, with the pairs' classes (K,) and frames (K,)."""

    n_est: int
    n_gt: int
    n_matched: int
    mean_error: float
    per_class: dict[str, float]
    bins: list[tuple[float, float, int, float]]
    errors: np.ndarray = field(repr=False)
    distances: np.ndarray = field(repr=False)
    classes: np.ndarray = field(default_factory=lambda: np.zeros(0, object), repr=False)
    frames: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64), repr=False)
    bin_size: float = BIN_SIZE
    # absolute heading differences (K,) radians in [0, pi], NaN where either heading is unknown
    heading_errors: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    # the matched estimates' error bars (K,) metres (NaN: the run has none; r90_m of poses.csv)
    r90: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    match: str = "ids"        # how estimates were paired with the truth: ids | nearest
    match_note: str = ""      # why, when "auto" chose
    # cross-camera id consistency (``id_consistency``): share of a road user's views in one frame
    # carrying its majority id, over road-user frames seen by 2+ cameras; None: not measured
    id_consistency: float | None = None
    n_multi_view: int = 0     # those road-user frames
    # HOTA, IDF1, MOTA... of the world tracks (``tracking_metrics.summary``); None: not measured
    tracking: dict | None = None

    @property
    def mean_heading_error_deg(self) -> float:
        """Mean absolute heading error in degrees over pairs where both headings are known."""
        e = self.heading_errors[np.isfinite(self.heading_errors)]
        return float(np.degrees(e.mean())) if len(e) else float("nan")

    @property
    def recall(self) -> float:
        """Share of ground-truth rows that have an estimate."""
        return self.n_matched / self.n_gt if self.n_gt else float("nan")

    @property
    def median_error(self) -> float:
        return float(np.median(self.errors)) if len(self.errors) else float("nan")

    def r90_scores(self) -> dict | None:
        """How good the run's error bars are (``seg2pose.method.uncertainty.r90_scores``: coverage,
        mean r90, sharpness = mean r90 / mean error, Spearman), overall and per class ("per_class");
        None when the run has no r90_m."""
        from seg2pose.method.uncertainty import r90_scores

        if len(self.r90) != len(self.errors) or not np.isfinite(self.r90).any():
            return None
        out = r90_scores(self.errors, self.r90)
        out["per_class"] = {str(c): r90_scores(self.errors[self.classes == c], self.r90[self.classes == c])
                            for c in sorted(set(self.classes.tolist()))}
        return out

    def to_dict(self) -> dict:
        """JSON-ready summary (no arrays; NaN becomes null)."""
        def num(v: float):
            return None if v is None or not math.isfinite(v) else float(v)

        def nums(d: dict) -> dict:
            return {k: nums(v) if isinstance(v, dict) else v if isinstance(v, int) else num(v)
                    for k, v in d.items()}

        r90 = self.r90_scores()
        return {**({"r90": nums(r90)} if r90 else {}),
            "n_est": int(self.n_est), "n_gt": int(self.n_gt), "n_matched": int(self.n_matched),
            "recall": num(self.recall),
            "mean_error": num(self.mean_error), "median_error": num(self.median_error),
            "per_class": {k: num(v) for k, v in self.per_class.items()},
            "mean_heading_error_deg": num(self.mean_heading_error_deg),
            "match": self.match,
            **({} if self.id_consistency is None else {
                "id_consistency": num(self.id_consistency), "n_multi_view": int(self.n_multi_view)}),
            **({} if self.tracking is None else {"tracking": self.tracking}),
            "bin_size": float(self.bin_size),
            "bins": [{"lo": float(lo), "hi": float(hi), "count": int(c), "mean_error": num(m)}
                     for lo, hi, c, m in self.bins],
        }


def _distance_bins(errors: np.ndarray, distances: np.ndarray, bin_size: float
                   ) -> list[tuple[float, float, int, float]]:
    if len(distances) == 0:
        return []
    b = np.floor(distances / bin_size).astype(np.int64)
    nb = int(b.max()) + 1
    count = np.bincount(b, minlength=nb)
    total = np.bincount(b, weights=errors, minlength=nb)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = total / count
    return [(k * bin_size, (k + 1) * bin_size, int(count[k]),
             float(mean[k]) if count[k] else float("nan")) for k in range(nb)]


def seen_truth(scene: Scene, cameras: list[str], gt: PoseTable,
               frame_range: tuple[int, int] | None) -> PoseTable:
    """The rows of ``gt`` within ``frame_range`` whose road user has a mask in one of
    ``cameras`` in that frame: what the configuration can see at all (the truth a
    configuration is scored against when it should not be charged for road users it never
    saw)."""
    gt = gt.in_frames(frame_range)
    seen: set[tuple[int, int]] = set()
    for cam in cameras:
        for f, t in iter_mots(scene.masks_path(cam), frame_range=frame_range):
            seen.update((f, int(k)) for k in t.track_id)
    keep = np.array([(int(f), int(k)) in seen for f, k in zip(gt.frame, gt.track_id)], bool)
    return gt.take(np.flatnonzero(keep))


def evaluate(est: PoseTable, gt: PoseTable, origin_xy, bin_size: float = BIN_SIZE,
             frame_range: tuple[int, int] | None = None, match: str = "ids",
             gate: float = 3.0) -> EvalResult:
    """Match ``est`` to ``gt`` by (frame, track_id) (``match="ids"``) or by nearest position
    within ``gate`` metres (``"nearest"``), or the one that fits the run's ids (``"auto"``, see
    ``choose_match``; ``match_note`` of the result says why), and measure ground-plane errors.

    origin_xy: (2,) metres, the point distances are measured from (usually the rig centre);
    frame_range: (first, last) inclusive, applied to both tables (None = all frames)."""
    est = est.in_frames(frame_range)
    gt = gt.in_frames(frame_range)
    if match not in ("ids", "nearest", "auto"):
        raise ValueError(f"match must be 'ids', 'nearest' or 'auto', got {match!r}")
    note = ""
    if match == "auto":
        match, by_id, by_pos = choose_match(est, gt, gate)
        if match == "nearest":
            note = (f"the run's track ids are not the truth's (only {by_id} of the {by_pos} pairs "
                    f"found by position within {gate:g} m share an id, e.g. ids from a tracker): "
                    "estimates were paired with the truth per frame by position")
    ie, ig = match_poses(est, gt) if match == "ids" else match_nearest(est, gt, gate)
    origin = np.asarray(origin_xy, dtype=np.float64).reshape(-1)[:2]
    errors = np.linalg.norm(est.xyz[ie, :2] - gt.xyz[ig, :2], axis=1)
    distances = np.linalg.norm(gt.xyz[ig, :2] - origin, axis=1)
    classes = gt.cls[ig]
    per_class = {str(c): _nan_mean(errors[classes == c]) for c in sorted(set(classes.tolist()))}
    dh = np.abs(np.angle(np.exp(1j * (est.heading[ie] - gt.heading[ig]))))
    return EvalResult(n_est=len(est), n_gt=len(gt), n_matched=len(ie),
                      mean_error=_nan_mean(errors), per_class=per_class,
                      bins=_distance_bins(errors, distances, bin_size), errors=errors,
                      distances=distances, classes=classes, frames=gt.frame[ig],
                      bin_size=float(bin_size), heading_errors=dh, match=match, match_note=note,
                      r90=est.r90[ie] if est.r90 is not None else np.full(len(ie), np.nan))


def id_consistency(frame: np.ndarray, camera: np.ndarray, track_id: np.ndarray, xy: np.ndarray,
                   gt: PoseTable, gate: float = 3.0) -> tuple[float, int]:
    """Cross-camera id consistency of per-view estimates: each camera's views (frame (V,),
    camera (V,), track_id (V,), ground position xy (V, 2) metres) are paired with the truth per
    frame (``match_nearest``); then, per true road user and frame seen by two or more cameras,
    the share of its views that carry its most frequent estimated id. Returns (share over all
    those views, number of such road-user frames); NaN and 0 without any."""
    gi, ti = [], []
    for c in np.unique(camera):
        sel = np.flatnonzero(camera == c)
        est = PoseTable(frame[sel], track_id[sel], np.full(len(sel), "", object),
                        np.column_stack([xy[sel], np.zeros(len(sel))]), np.full(len(sel), np.nan))
        ie, ig = match_nearest(est, gt, gate)
        gi.append(ig)
        ti.append(track_id[sel][ie])
    if not gi:
        return float("nan"), 0
    ig, tid = np.concatenate(gi), np.concatenate(ti)
    # groups: (true road user, frame) = one gt row
    rows, n_views = np.unique(ig, return_counts=True)
    multi = rows[n_views >= 2]
    sel = np.isin(ig, multi)
    if not sel.any():
        return float("nan"), 0
    pairs, n = np.unique(np.stack([ig[sel], tid[sel]], axis=1), axis=0, return_counts=True)
    top = np.zeros(int(pairs[:, 0].max()) + 1, np.int64)
    np.maximum.at(top, pairs[:, 0], n)
    return float(top[multi].sum() / sel.sum()), int(len(multi))


def per_frame_errors(est: PoseTable, gt: PoseTable
                     ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Per-frame mean ground-plane error, for review plots.

    Returns frames (F,) with at least one matched pair, sorted; mean error (F,) metres; and
    per class name a (F,) array of that class's mean error (NaN in frames without it)."""
    ie, ig = match_poses(est, gt)
    if len(ie) == 0:
        return np.zeros(0, np.int64), np.zeros(0), {}
    err = np.linalg.norm(est.xyz[ie, :2] - gt.xyz[ig, :2], axis=1)
    frames, inv = np.unique(gt.frame[ig], return_inverse=True)
    nf = len(frames)
    mean = np.bincount(inv, weights=err, minlength=nf) / np.bincount(inv, minlength=nf)
    per_class = {}
    cls = gt.cls[ig]
    for c in sorted(set(cls.tolist())):
        sel = cls == c
        cnt = np.bincount(inv[sel], minlength=nf)
        tot = np.bincount(inv[sel], weights=err[sel], minlength=nf)
        with np.errstate(invalid="ignore", divide="ignore"):
            per_class[str(c)] = np.where(cnt > 0, tot / np.maximum(cnt, 1), np.nan)
    return frames.astype(np.int64), mean, per_class


def _fmt(v: float) -> str:
    return "-" if not math.isfinite(v) else f"{v:.4f}"


def format_table(results: dict[str, EvalResult]) -> str:
    """A table for people: one row per named run; columns matched/truth, mean error and the
    mean error per distance bin (metres). Empty cells are '-'."""
    if not results:
        return "(no results)\n"
    nb = max((len(r.bins) for r in results.values()), default=0)
    bs = next(iter(results.values())).bin_size
    bin_heads = [f"{k * bs:g}-{(k + 1) * bs:g} m" for k in range(nb)]
    classes = sorted({c for r in results.values() for c in r.per_class})
    head = ["run", "matched/gt", "mean m"] + [f"{c} m" for c in classes] + bin_heads
    rows = []
    for name, r in results.items():
        cells = [name, f"{r.n_matched}/{r.n_gt}", _fmt(r.mean_error)]
        cells += [_fmt(r.per_class.get(c, float("nan"))) for c in classes]
        cells += [_fmt(r.bins[k][3]) if k < len(r.bins) else "-" for k in range(nb)]
        rows.append(cells)
    widths = [max(len(head[j]), *(len(row[j]) for row in rows)) for j in range(len(head))]

    def line(cells):
        return "  ".join(c.ljust(widths[0]) if j == 0 else c.rjust(widths[j])
                         for j, c in enumerate(cells)).rstrip()

    out = [line(head), line(["-" * w for w in widths])] + [line(r) for r in rows]
    for name, r in results.items():
        if r.id_consistency is not None:
            out.append(f"{name}: cross-camera id consistency {_fmt(r.id_consistency)} "
                       f"({r.n_multi_view} road-user frames seen by 2+ cameras)")
    return "\n".join(out) + "\n"


def format_r90_table(results: dict[str, EvalResult]) -> str:
    """The error bars of the runs that have them: per run and class, coverage (share of poses
    whose error is at most r90_m; 0.9 is the aim), mean r90_m, mean error, their ratio and the
    Spearman correlation of r90_m with the error. Empty when no run has r90_m."""
    head = ["run", "class", "poses", "coverage", "mean r90 m", "mean err m", "r90/err", "spearman"]
    rows = []
    for name, r in results.items():
        sc = r.r90_scores()
        if sc is None:
            continue
        for cls, d in [("all", sc)] + sorted(sc["per_class"].items()):
            if d.get("n"):
                rows.append([name, cls, str(d["n"]), f"{d['coverage']:.3f}", _fmt(d["mean_r90"]),
                             _fmt(d["mean_error"]), f"{d['sharpness']:.2f}",
                             "-" if not math.isfinite(d["spearman"]) else f"{d['spearman']:.2f}"])
    if not rows:
        return ""
    widths = [max(len(head[j]), *(len(row[j]) for row in rows)) for j in range(len(head))]

    def line(cells):
        return "  ".join(c.ljust(widths[j]) if j < 2 else c.rjust(widths[j])
                         for j, c in enumerate(cells)).rstrip()

    return "\n".join([line(head), line(["-" * w for w in widths])] + [line(r) for r in rows]) + "\n"


def plot_error_vs_distance(results: dict[str, EvalResult], path: str | Path,
                           title: str = "Mean error by distance from the cameras") -> None:
    """Mean error per distance bin, one line per run (like the paper's Figure 6), as PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5), dpi=100)
    for name, r in results.items():
        if not r.bins:
            continue
        x = [0.5 * (lo + hi) for lo, hi, _, _ in r.bins]
        y = [m for _, _, _, m in r.bins]
        ax.plot(x, y, marker="o", label=f"{name} ({_fmt(r.mean_error)} m)")
    bs = next(iter(results.values())).bin_size if results else BIN_SIZE
    ax.set_xlabel(f"distance from the cameras (m), {bs:g} m bins")
    ax.set_ylabel("mean error (m)")
    ax.set_title(title)
    ax.set_ylim(bottom=0)
    ax.grid(True, alpha=0.3)
    if results:
        ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(Path(path).with_suffix(".png") if Path(path).suffix == "" else path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
