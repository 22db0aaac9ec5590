"""A check on Seg2PoseNet's residuals: does the network move an estimate further than it ever
learned to?

A model stores, per class, a high percentile (``LIMIT_PERCENTILE``) of the residual lengths it
was trained on (``residual_limits``, kept in the checkpoint's metadata as ``residual_limit``).
At inference a view whose predicted residual is longer than its class's limit times
``LIMIT_FACTOR`` is *flagged*: the mask is probably unlike anything in training (a merged blob,
a mask cut by the image border, a background-subtraction artefact), and the network
extrapolates. Flagged views are reported (``flagged.csv`` in the run folder, counts in
run.json and on the command line); with the ``fallback`` policy their residual is dropped, so
the estimate is the normal position.
"""

from __future__ import annotations

import io

import numpy as np

LIMIT_PERCENTILE = 99.0
LIMIT_FACTOR = 1.0
POLICIES = ("warn", "fallback", "off")
FLAGGED_COLUMNS = ["frame", "track_id", "camera", "class", "residual_m", "limit_m"]


def residual_limits(target: np.ndarray, cls: np.ndarray, q: float = LIMIT_PERCENTILE
                    ) -> dict[str, float]:
    """Per class, the ``q``-th percentile of the training residual lengths (target (N, 2)
    metres, cls (N,) names): what the network learned to output."""
    length = np.linalg.norm(np.asarray(target, float).reshape(-1, 2), axis=1)
    cls = np.asarray(cls, object)
    out = {}
    for c in np.unique(cls):
        v = length[(cls == c) & np.isfinite(length)]
        if len(v):
            out[str(c)] = float(np.percentile(v, q))
    return out


def flag_far(residual: np.ndarray, cls: np.ndarray, limits: dict[str, float] | None,
             factor: float = LIMIT_FACTOR) -> tuple[np.ndarray, np.ndarray]:
    """(flag (N,) bool, limit (N,) metres) for predicted residuals (N, 2) metres of classes
    (N,): longer than ``factor`` x the class's limit. A class without a limit (an old
    checkpoint) is never flagged (limit NaN)."""
    cls = np.asarray(cls, object)
    lim = np.array([(limits or {}).get(str(c), np.nan) for c in cls], float) * factor
    length = np.linalg.norm(np.asarray(residual, float).reshape(-1, 2), axis=1)
    flag = np.isfinite(lim) & (length > lim)
    return flag, lim


def format_flagged(frame, track_id, camera, cls, residual, limit) -> str:
    """flagged.csv text: one row per flagged view (residual and limit in metres)."""
    buf = io.StringIO()
    buf.write(",".join(FLAGGED_COLUMNS) + "\n")
    length = np.linalg.norm(np.asarray(residual, float).reshape(-1, 2), axis=1)
    for f, t, c, k, r, m in zip(frame, track_id, camera, cls, length, limit):
        buf.write(f"{int(f)},{int(t)},{c},{k},{r:.4f},{m:.4f}\n")
    return buf.getvalue()


def flagged_poses(frame: np.ndarray, track_id: np.ndarray) -> int:
    """Fused poses with at least one flagged view: distinct (frame, track) pairs (an untracked
    view, id -1, is a pose of its own)."""
    if len(frame) == 0:
        return 0
    tracked = np.asarray(track_id) >= 0
    pairs = np.unique(np.stack([np.asarray(frame)[tracked], np.asarray(track_id)[tracked]], 1),
                      axis=0)
    return int(len(pairs) + (~tracked).sum())
