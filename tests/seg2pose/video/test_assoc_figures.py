"""benches/assoc_figures.py's comparison of a multi-camera run with its cameras alone on the
same truth (docs/RESULTS.md "Multi-camera association"), on a hand-made case."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from seg2pose.io.poses import PoseTable

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "benches"))
from assoc_figures import same_truth  # noqa: E402


def poses(rows):
    """rows: (frame, x, y)."""
    f = [r[0] for r in rows]
    xyz = [(r[1], r[2], 0.0) for r in rows]
    return PoseTable(f, np.arange(len(rows)), ["car"] * len(rows), xyz, np.full(len(rows), np.nan))


def test_same_truth_by_hand():
    gt = poses([(0, 0, 0), (0, 10, 0), (1, 0, 1)])  # truth rows 0, 1, 2
    fused = poses([(0, 0.2, 0), (0, 10, 0.4), (1, 0, 1.1)])  # matches 0, 1, 2: 0.2, 0.4, 0.1 m
    a = poses([(0, 0.3, 0), (0, 10, 0.5), (1, 50, 50)])  # 0, 1 (0.3, 0.5 m) and a false one
    b = poses([(0, 0.1, 0), (1, 0, 1.3)])  # 0, 2 (0.1, 0.3 m)
    r = same_truth(fused, {"a": a, "b": b}, gt)
    assert r["alone"]["a"] == pytest.approx({"recall": 2 / 3, "precision": 2 / 3, "error_m": 0.4})
    assert r["alone"]["b"] == pytest.approx({"recall": 2 / 3, "precision": 1.0, "error_m": 0.2})
    c = r["common"]  # truth row 0 is the only one all three matched
    assert c["n"] == 1
    assert c["error_m"] == pytest.approx(0.2)
    assert c["alone_error_m"] == pytest.approx({"a": 0.3, "b": 0.1})
    assert c["alone_mean_error_m"] == pytest.approx(0.2)


def test_same_truth_nothing_common():
    gt = poses([(0, 0, 0)])
    r = same_truth(poses([(0, 0.5, 0)]), {"a": poses([(0, 9, 9)])}, gt)
    assert r["alone"]["a"]["recall"] == 0 and np.isnan(r["alone"]["a"]["error_m"])
    assert r["common"]["n"] == 0 and np.isnan(r["common"]["error_m"])
