"""r90_m: an error bar on every view and every fused pose.

``r90_m`` is the radius, metres on the ground around the estimate's (x, y), that holds the true
position with 90 % probability. It is estimated from what the method knows about a detection
(the *cues*, all in views.csv), not from the truth:

- per view: how grazing the ray is (ground distance over the camera's height above the ground
  point: a wrong height moves the estimate along the ray by that factor), a mask cut by the
  image border and how close its box centre is to the border (the less of it is left, the
  further its centre is off), crowding (its centre within the apparent size of a road user
  nearer the camera in the same frame: it may be hidden behind it), how far the ground point
  below the bottom of its mask's box is from where it would be for a road user of the class's
  typical size at the normal position (``foot_offset``: the box bottom is the road user's
  ground contact whatever its size, while the normal position moves along the ray with its
  size -- a van among cars, a child among adults), a residual the far-residual check flagged
  (``seg2pose.ood``), the spread of an ensemble's residuals (repeated ``--models``) and the
  length of the network's residual;
- per fused pose: the views' error bars combined as for a mean of independent errors
  (sqrt(sum r_i^2) / n), the number of views fused and how far the views' estimates disagree.

Both stages are linear *quantile regressions* of log(error) per class (the 90th percentile of
the log error is the log of the 90th percentile of the error), shifted by a conformal step over
whole road users: fitted on runs whose truth is known -- the validation split, of one scene or
several (``fit_calibration``, ``s2p calibrate-errors``) -- written as a JSON beside the models or the
run, and applied to any run of the same method (``s2p run --r90``). A class with too few
validation rows falls back to the pooled model of all classes. A calibration does not
extrapolate: each feature is clipped to the range it had in the fit, and the bar to twice the
largest error fitted (a scene unlike the validation scenes, e.g. another camera height, gets
the bars of the nearest case seen, not a linear guess far outside it).

The cues as feature matrices (VIEW_FEATURES, POSE_FEATURES) are made by
``seg2pose.method.r90_features``; this module fits and applies the two stages.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from seg2pose.core.errors import InputError
from seg2pose.method.r90_features import FLOOR_M, POSE_FEATURES, VIEW_FEATURES, views_matrix

if TYPE_CHECKING:
    from seg2pose.io.poses import PoseTable
    from seg2pose.io.run import ViewTable
    from seg2pose.io.scene import Scene

QUANTILE = 0.9
FORMAT = "s2p-r90"
# 2: views cut_edge and crowd, no log_distance (collinear with grazing on one pole);
# 3: views log_foot (needs views.csv's box columns)
VERSION = 3
MIN_ROWS = 200         # a class with fewer validation rows uses the pooled model
MAX_FIT_ROWS = 3000    # rows per class in a fit (an even subsample; the LP stays < 1 s)


# ----------------------------------------------------------------------------------------------
# the quantile regression


def fit_quantile(X: np.ndarray, y: np.ndarray, q: float = QUANTILE) -> np.ndarray:
    """Coefficients b (k,) of the linear ``q``-quantile regression of y (N,) on X (N, k):
    min sum of the pinball loss, solved as a linear programme (HiGHS). Columns constant over
    the rows (other than the first, the intercept) get 0."""
    from scipy.optimize import linprog
    from scipy.sparse import csr_matrix, hstack, identity

    X = np.asarray(X, float)
    y = np.asarray(y, float)
    n, k = X.shape
    varies = np.ones(k, bool)
    varies[1:] = X[:, 1:].std(axis=0) > 1e-9
    Xv = X[:, varies]
    kv = Xv.shape[1]
    c = np.concatenate([np.zeros(kv), np.full(n, q), np.full(n, 1.0 - q)])
    A = hstack([csr_matrix(Xv), identity(n, format="csr"), -identity(n, format="csr")]).tocsr()
    bounds = [(None, None)] * kv + [(0, None)] * (2 * n)
    res = linprog(c, A_eq=A, b_eq=y, bounds=bounds, method="highs")
    if res.status != 0:  # cannot happen for finite data (the LP is always feasible and bounded)
        raise RuntimeError(f"quantile regression failed: {res.message}")
    b = np.zeros(k)
    b[varies] = res.x[:kv]
    return b


FOLDS = 5
# the conformal shift aims a little above QUANTILE: a new scene's road users are fewer than
# its rows, so coverage on a new scene scatters around the aim (docs/RESULTS.md)
CONFORMAL_Q = 0.92


def _subsample(X: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """At most MAX_FIT_ROWS rows, evenly spaced (deterministic)."""
    if len(y) <= MAX_FIT_ROWS:
        return X, y
    idx = np.linspace(0, len(y) - 1, MAX_FIT_ROWS).astype(int)
    return X[idx], y[idx]


def _group_conformal_shift(X: np.ndarray, y: np.ndarray, groups: np.ndarray, q: float,
                           q_shift: float) -> float:
    """The q_shift-quantile of out-of-fold residuals y - X b (b: the q-quantile fit), folds
    made of whole groups (FOLDS, or one per group when fewer); 0 with fewer than two groups."""
    ug = np.unique(groups)
    if len(ug) < 2:
        return 0.0
    fold_of = dict(zip(ug.tolist(), np.random.default_rng(0).permutation(len(ug)) % min(FOLDS, len(ug))))
    fold = np.array([fold_of[g] for g in groups.tolist()])
    scores = []
    for k in np.unique(fold):
        test = fold == k
        b = fit_quantile(*_subsample(X[~test], y[~test]), q)
        scores.append(y[test] - X[test] @ b)
    s = np.concatenate(scores)
    return float(np.quantile(s, min(1.0, q_shift * (len(s) + 1) / len(s))))


@dataclass
class StageModel:
    """One stage (views or poses): features, and per class (and "*" pooled) coefficients b,
    the feature ranges of the fit (lo, hi) and the largest log error fitted (y_max)."""

    features: list[str]
    coef: dict[str, list[float]] = field(default_factory=dict)
    n_rows: dict[str, int] = field(default_factory=dict)
    lo: dict[str, list[float]] = field(default_factory=dict)
    hi: dict[str, list[float]] = field(default_factory=dict)
    y_max: dict[str, float] = field(default_factory=dict)

    def predict(self, cls: np.ndarray, X: np.ndarray) -> np.ndarray:
        """r90 (N,) metres for rows of classes cls (N,) with features X (N, k): features
        clipped to the fit's range, the result to [FLOOR_M, 2 x the largest fitted error]."""
        out = np.full(len(X), np.nan)
        for c in np.unique(cls):
            sel = cls == c
            k = str(c) if str(c) in self.coef else "*"
            Xc = np.clip(X[sel], self.lo[k], self.hi[k])
            y = np.minimum(Xc @ np.asarray(self.coef[k]), self.y_max[k] + math.log(2.0))
            out[sel] = np.maximum(np.exp(y), FLOOR_M)
        return out

    @classmethod
    def fit(cls_, features: list[str], cls: np.ndarray, X: np.ndarray, err: np.ndarray,
            groups: np.ndarray | None = None, q: float = QUANTILE) -> StageModel:
        """Per class (and pooled), the q-quantile regression of log(error) on X, then shifted
        up by conformal calibration over ``groups`` (road users: a road user's errors are
        alike, so a new road user is what the bar must cover): each fold of road users is
        predicted by a fit on the others, and the intercept moves by the q-quantile of the
        out-of-fold log(error / bar)."""
        ok = np.isfinite(err) & np.isfinite(X).all(axis=1)
        groups = np.arange(len(err)) if groups is None else np.asarray(groups)
        cls, X, y, groups = cls[ok], X[ok], np.log(np.maximum(err[ok], FLOOR_M)), groups[ok]
        if not len(y):
            raise InputError("no rows with a known error to calibrate r90_m on (does the run "
                             "share track ids and frames with the ground truth?)")
        m = cls_(list(features))
        for name, sel in [("*", np.ones(len(y), bool))] + [(str(c), cls == c) for c in np.unique(cls)]:
            idx = np.flatnonzero(sel)
            if name != "*" and len(idx) < MIN_ROWS:
                continue
            if name != "*" and len(idx) == len(y):  # the only class: the pooled model is its own
                columns: tuple[dict[str, Any], ...] = (m.coef, m.n_rows, m.lo, m.hi, m.y_max)
                for d in columns:
                    d[name] = d["*"]
                continue
            b = fit_quantile(*_subsample(X[idx], y[idx]), q)
            shift = _group_conformal_shift(X[idx], y[idx], groups[idx], q, CONFORMAL_Q)
            b[0] += shift
            m.coef[name] = [float(v) for v in b]
            m.n_rows[name] = int(sel.sum())
            m.lo[name] = [float(v) for v in X[sel].min(axis=0)]
            m.hi[name] = [float(v) for v in X[sel].max(axis=0)]
            m.y_max[name] = float(y[sel].max() + max(shift, 0.0))
        return m

    def to_dict(self) -> dict:
        return {"features": self.features, "coef": self.coef, "n_rows": self.n_rows,
                "lo": self.lo, "hi": self.hi, "y_max": self.y_max}

    @classmethod
    def from_dict(cls, d: dict, features: list[str], where: str) -> StageModel:
        if d.get("features") != features or "*" not in d.get("coef", {}):
            raise InputError(f"expected features {features} and a pooled ('*') model", field=where)
        def vec(v) -> bool:
            return (isinstance(v, list) and len(v) == len(features)
                    and all(isinstance(x, (int, float)) and math.isfinite(x) for x in v))

        for k in d["coef"]:
            if not all(vec((d.get(key) or {}).get(k)) for key in ("coef", "lo", "hi")) or not (
                    isinstance((d.get("y_max") or {}).get(k), (int, float))):
                raise InputError(f"class {k!r}: expected {len(features)} finite coefficients, "
                                 "feature ranges lo and hi, and y_max", field=where)
        return cls(list(features), {k: [float(v) for v in b] for k, b in d["coef"].items()},
                   dict(d.get("n_rows", {})),
                   {k: [float(v) for v in d["lo"][k]] for k in d["coef"]},
                   {k: [float(v) for v in d["hi"][k]] for k in d["coef"]},
                   {k: float(d["y_max"][k]) for k in d["coef"]})


@dataclass
class Calibration:
    """The two stages and where they were fitted (``meta``: method, smooth_frames, scene,
    split, coverage on the fitted rows)."""

    view: StageModel
    pose: StageModel
    meta: dict = field(default_factory=dict)
    quantile: float = QUANTILE

    def to_json(self) -> str:
        return json.dumps({"format": FORMAT, "version": VERSION, "quantile": self.quantile,
                           **self.meta, "view": self.view.to_dict(),
                           "pose": self.pose.to_dict()}, indent=1) + "\n"


def read_calibration(path: str | Path) -> Calibration:
    """An r90 calibration JSON (``s2p calibrate-errors``); errors name the file and field."""
    path = Path(path)
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError("r90 calibration not found (make one with s2p calibrate-errors)", file=path) from None
    except json.JSONDecodeError as e:
        raise InputError(f"invalid JSON: {e.msg}", file=path, line=e.lineno) from None
    if not isinstance(d, dict) or d.get("format") != FORMAT:
        raise InputError(f"not an r90 calibration (expected \"format\": \"{FORMAT}\")", file=path)
    if d.get("version") != VERSION:
        raise InputError(f"calibration version {d.get('version')!r}; this s2p reads {VERSION}",
                         file=path, field="version")
    try:
        view = StageModel.from_dict(d.get("view") or {}, VIEW_FEATURES, "view")
        pose = StageModel.from_dict(d.get("pose") or {}, POSE_FEATURES, "pose")
    except InputError as e:
        raise InputError(e.message, file=path, field=e.field) from None
    meta = {k: v for k, v in d.items() if k not in ("format", "version", "quantile", "view", "pose")}
    return Calibration(view, pose, meta, float(d.get("quantile", QUANTILE)))


# ----------------------------------------------------------------------------------------------
# applying and fitting on a run's views


def view_r90(cal: Calibration, scene, views) -> np.ndarray:
    """(N,) r90 of each view, metres (NaN where the ray missed the ground)."""
    r = cal.view.predict(views.cls, views_matrix(scene, views))
    r[~np.isfinite(views.normal[:, :2]).all(axis=1)] = np.nan
    return r


@dataclass
class FitRun:
    """One run whose truth is known, as the fit needs it: the scene, the run's ViewTable (with
    cues), its fused poses -- keys (P, 2) frame and track id, est (P, 2), cls (P,) -- a function
    ``pose_X(view_r90)`` -> (P, k) their POSE_FEATURES, and the truth's PoseTable."""

    scene: Scene
    views: ViewTable
    pose_keys: np.ndarray
    pose_est: np.ndarray
    pose_cls: np.ndarray
    pose_X: Callable[[np.ndarray], np.ndarray]
    gt: PoseTable


def pose_errors(keys: np.ndarray, est: np.ndarray, gt) -> np.ndarray:
    """(N,) ground distance of est (N, 2) to the truth of the same (frame, track id) keys (N, 2),
    NaN where the truth has none (or the id is -1, untracked)."""
    g_index = {(int(f), int(t)): i for i, (f, t) in enumerate(zip(gt.frame, gt.track_id))}
    gi = np.array([g_index.get((int(f), int(t)), -1) if t >= 0 else -1 for f, t in keys], np.int64)
    err = np.full(len(gi), np.nan)
    hit = gi >= 0
    err[hit] = np.linalg.norm(est[hit] - gt.xyz[gi[hit], :2], axis=1)
    return err


def fit_calibration(runs: list[FitRun], meta: dict) -> tuple[Calibration, dict]:
    """Fit both stages on runs whose truth is known (e.g. the train and val splits of a
    scene; more road users make steadier quantiles). Road users are told apart by run and
    track id within a scene (the conformal folds keep each road user's rows together, across
    runs of one scene too). Returns the
    calibration and its coverage on the fitted rows (views and poses)."""
    scene_no: dict = {}
    Xv, v_err, v_cls, v_grp = [], [], [], []
    for r in runs:
        k = scene_no.setdefault(_scene_key(r.scene), len(scene_no))
        v = r.views
        Xv.append(views_matrix(r.scene, v))
        v_err.append(pose_errors(np.column_stack([v.frame, v.track_id]), v.normal[:, :2] + v.residual,
                             r.gt))
        v_cls.append(v.cls)
        v_grp.append(np.where(v.track_id >= 0, k * GROUP_STRIDE + v.track_id, -1))
    Xv, v_err, v_cls, v_grp = (np.concatenate(a) for a in (Xv, v_err, v_cls, v_grp))
    view = StageModel.fit(VIEW_FEATURES, v_cls, Xv, v_err, v_grp)
    r_v = view.predict(v_cls, Xv)
    Xp, p_err, p_cls, p_grp = [], [], [], []
    start = 0
    for r in runs:
        k = scene_no[_scene_key(r.scene)]
        n = len(r.views)
        Xp.append(r.pose_X(r_v[start:start + n]))
        start += n
        p_err.append(pose_errors(r.pose_keys, r.pose_est, r.gt))
        p_cls.append(r.pose_cls)
        p_grp.append(np.where(r.pose_keys[:, 1] >= 0, k * GROUP_STRIDE + r.pose_keys[:, 1], -1))
    Xp, p_err, p_cls, p_grp = (np.concatenate(a) for a in (Xp, p_err, p_cls, p_grp))
    pose = StageModel.fit(POSE_FEATURES, p_cls, Xp, p_err, p_grp)
    r_p = pose.predict(p_cls, Xp)
    hv, hp = np.isfinite(v_err), np.isfinite(p_err)
    fit_cov = {"views": float(np.mean(v_err[hv] <= r_v[hv])),
               "poses": float(np.mean(p_err[hp] <= r_p[hp]))}
    return Calibration(view, pose, {**meta, "coverage_on_fit": fit_cov}), fit_cov


GROUP_STRIDE = 10 ** 9  # road-user groups: scene index * GROUP_STRIDE + track id


def _scene_key(scene) -> str:
    """Runs of one scene share its road users (the splits of a synthetic scene hold the same
    track ids): they are one group per track id. A scene is its folder: two recordings of one
    site share the calibration (and the fingerprint) but not their road users."""
    root = getattr(scene, "root", None)
    if root is not None:
        return str(Path(root).resolve())
    fp = getattr(scene, "fingerprint", None)
    return fp() if callable(fp) else str(id(scene))


# ----------------------------------------------------------------------------------------------
# how good an error bar is


def r90_scores(errors: np.ndarray, r90: np.ndarray) -> dict:
    """Coverage (share with error <= r90), mean r90, mean error, their ratio (sharpness) and
    the Spearman correlation of r90 with the error, over pairs with a finite r90."""
    ok = np.isfinite(r90) & np.isfinite(errors)
    e, r = errors[ok], r90[ok]
    if not len(e):
        return {"n": 0}
    from scipy.stats import spearmanr

    rho = float(spearmanr(r, e).statistic) if len(e) > 2 and np.ptp(r) > 0 and np.ptp(e) > 0 else float("nan")
    return {"n": int(len(e)), "coverage": float(np.mean(e <= r)), "mean_r90": float(r.mean()),
            "mean_error": float(e.mean()),
            "sharpness": float(r.mean() / e.mean()) if e.mean() > 0 else float("nan"),
            "spearman": rho}
