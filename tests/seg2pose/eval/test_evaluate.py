"""Evaluation: hand-computed toy cases."""

import json
import math

import numpy as np
import pytest

from seg2pose.eval.evaluate import (
    EvalResult,
    evaluate,
    format_table,
    match_poses,
    per_frame_errors,
    plot_error_vs_distance,
)
from seg2pose.io.poses import PoseTable


def table(rows):
    """rows: (frame, track_id, cls, x, y)"""
    f, t, c, x, y = zip(*rows) if rows else ((), (), (), (), ())
    xyz = np.stack([np.array(x, float), np.array(y, float), np.zeros(len(x))], axis=1)
    return PoseTable(np.array(f), np.array(t), np.array(c, object), xyz, np.zeros(len(x)))


GT = table([
    (0, 1, "car", 3.0, 0.0),         # distance 3 -> bin 0
    (0, 2, "pedestrian", 0.0, 7.0),  # distance 7 -> bin 1
    (1, 1, "car", 4.0, 0.0),         # distance 4 -> bin 0
    (1, 2, "pedestrian", 0.0, 12.0),  # distance 12 -> bin 2, not estimated
])
EST = table([
    (0, 2, "pedestrian", 0.0, 7.5),  # error 0.5
    (0, 1, "car", 3.0, 1.0),         # error 1.0
    (1, 1, "car", 7.0, 4.0),         # error 5 (3-4-5)
    (2, 1, "car", 0.0, 0.0),         # no truth in frame 2
])


def test_match_by_frame_and_track():
    ie, ig = match_poses(EST, GT)
    assert sorted(zip(ie.tolist(), ig.tolist())) == [(0, 1), (1, 0), (2, 2)]


def test_match_skips_nan_and_duplicates():
    est = table([(0, 1, "car", np.nan, 0.0), (0, 2, "pedestrian", 1.0, 1.0),
                 (0, 2, "pedestrian", 5.0, 5.0)])
    ie, ig = match_poses(est, GT)
    assert ie.tolist() == [1] and ig.tolist() == [1]


def test_match_empty():
    ie, ig = match_poses(table([]), GT)
    assert len(ie) == len(ig) == 0


def test_evaluate_hand_computed():
    r = evaluate(EST, GT, origin_xy=(0.0, 0.0))
    assert (r.n_est, r.n_gt, r.n_matched) == (4, 4, 3)
    assert r.mean_error == pytest.approx((0.5 + 1.0 + 5.0) / 3)
    assert r.per_class == pytest.approx({"car": 3.0, "pedestrian": 0.5})
    assert len(r.bins) == 2  # the 12 m truth was not matched: bins come from matched pairs
    assert r.bins[0][:3] == (0.0, 5.0, 2) and r.bins[0][3] == pytest.approx(3.0)
    assert r.bins[1][:3] == (5.0, 10.0, 1) and r.bins[1][3] == pytest.approx(0.5)
    assert r.recall == pytest.approx(0.75)
    d = r.to_dict()
    json.dumps(d, allow_nan=False)
    assert d["bins"][1] == {"lo": 5.0, "hi": 10.0, "count": 1, "mean_error": 0.5}


def test_evaluate_origin_and_empty_bins():
    # origin at (0, 7): pedestrian truth at 0 m (bin 0), cars at sqrt(58) = 7.62 m (bin 3)
    # and sqrt(65) = 8.06 m (bin 4) with 2 m bins
    r = evaluate(EST, GT, origin_xy=np.array([0.0, 7.0, 99.0]), bin_size=2.0)
    counts = [b[2] for b in r.bins]
    assert counts == [1, 0, 0, 1, 1]
    assert math.isnan(r.bins[1][3])
    assert r.to_dict()["bins"][1]["mean_error"] is None


def test_evaluate_frame_range():
    r = evaluate(EST, GT, origin_xy=(0, 0), frame_range=(1, 5))
    assert (r.n_est, r.n_gt, r.n_matched) == (2, 2, 1)
    assert r.mean_error == pytest.approx(5.0)


def test_nothing_matched():
    r = evaluate(table([(9, 9, "car", 0, 0)]), GT, origin_xy=(0, 0))
    assert r.n_matched == 0 and math.isnan(r.mean_error) and r.bins == []
    json.dumps(r.to_dict(), allow_nan=False)


def test_per_frame_errors():
    frames, mean, pc = per_frame_errors(EST, GT)
    assert frames.tolist() == [0, 1]
    assert mean == pytest.approx([0.75, 5.0])
    assert pc["car"] == pytest.approx([1.0, 5.0])
    assert pc["pedestrian"][0] == pytest.approx(0.5) and math.isnan(pc["pedestrian"][1])


def test_format_table_and_plot(tmp_path):
    a = evaluate(EST, GT, origin_xy=(0, 0))
    b = evaluate(GT, GT, origin_xy=(0, 0))
    txt = format_table({"baseline": a, "perfect": b})
    lines = txt.splitlines()
    assert lines[0].split()[:3] == ["run", "matched/gt", "mean"]
    assert "0-5 m" in lines[0] and "10-15 m" in lines[0]
    assert lines[2].split()[:3] == ["baseline", "3/4", "2.1667"]
    assert lines[3].split()[:3] == ["perfect", "4/4", "0.0000"]
    assert lines[2].split()[-1] == "-"  # baseline has no 10-15 m bin
    out = tmp_path / "fig.png"
    plot_error_vs_distance({"baseline": a, "perfect": b}, out)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert isinstance(a, EvalResult)


def test_heading_error():
    gt = table([(0, 1, "car", 0, 0), (1, 1, "car", 0, 0), (2, 1, "car", 0, 0)])
    gt.heading[:] = [3.1, 0.0, 1.0]
    est = table([(0, 1, "car", 0, 0), (1, 1, "car", 0, 0), (2, 1, "car", 0, 0)])
    est.heading[:] = [-3.1, np.pi / 2, np.nan]  # wraps: 0.0832 rad; 90 deg; unknown
    r = evaluate(est, gt, origin_xy=(0, 0))
    assert r.mean_heading_error_deg == pytest.approx((np.degrees(2 * np.pi - 6.2) + 90) / 2)
    assert r.to_dict()["mean_heading_error_deg"] == pytest.approx(r.mean_heading_error_deg)


def _tracker_like():
    """Three road users 4 m apart walking along x for 6 frames; the estimate is 0.3 m off in y
    and carries a tracker's ids: numbered in order of appearance, not the truth's 7, 3, 5."""
    rows_gt, rows_est = [], []
    for f in range(6):
        for k, (tid, est_id) in enumerate(((7, 1), (3, 2), (5, 3))):
            rows_gt.append((f, tid, "pedestrian", 0.5 * f, 4.0 * k))
            rows_est.append((f, est_id, "pedestrian", 0.5 * f, 4.0 * k + 0.3))
    return table(rows_est), table(rows_gt)


def test_nearest_pairs_tracker_ids_and_auto_chooses_it():
    from seg2pose.eval.evaluate import choose_match

    est, gt = _tracker_like()
    by_ids = evaluate(est, gt, (0.0, 0.0))
    assert by_ids.n_matched == 6 * 1  # only id 3 exists in both: paired with the wrong user
    near = evaluate(est, gt, (0.0, 0.0), match="nearest")
    assert near.n_matched == 18 and near.mean_error == pytest.approx(0.3)
    assert choose_match(est, gt, 3.0) == ("nearest", 0, 18)  # id 3's pairs are 4.3 m apart
    auto = evaluate(est, gt, (0.0, 0.0), match="auto")
    assert (auto.match, auto.n_matched, auto.mean_error) == ("nearest", 18, pytest.approx(0.3))
    assert "0 of the 18 pairs" in auto.match_note and auto.to_dict()["match"] == "nearest"
    # the truth's own ids (and an error inside the gate): auto keeps matching by id, silently
    same = table([(f, t, c, x, y + 0.3) for f, t, c, x, y in
                  zip(gt.frame, gt.track_id, gt.cls, gt.xyz[:, 0], gt.xyz[:, 1])])
    auto = evaluate(same, gt, (0.0, 0.0), match="auto")
    assert (auto.match, auto.n_matched, auto.match_note) == ("ids", 18, "")


def test_seen_truth_keeps_the_rows_with_a_mask_in_the_cameras(tmp_path):
    """Known answer on the tiny scene (every road user visible in every camera) after removing
    masks: camera c1 keeps the even frames of every road user but 2; c0 keeps road user 2 only.
    A truth row is seen when one of the configuration's cameras has its mask in that frame."""
    from scene_fixtures import make_tiny_scene

    from seg2pose.eval.evaluate import seen_truth
    from seg2pose.io.mots import read_mots, write_mots
    from seg2pose.io.poses import read_poses

    scene = make_tiny_scene(tmp_path, frames=20, n_users=6, seed=3)
    gt = read_poses(scene.gt_path)
    c1, c0 = read_mots(scene.masks_path("c1")), read_mots(scene.masks_path("c0"))
    write_mots(scene.masks_path("c1"), c1.take(np.flatnonzero((c1.track_id != 2) & (c1.frame % 2 == 0))))
    write_mots(scene.masks_path("c0"), c0.take(np.flatnonzero(c0.track_id == 2)))
    rows = list(zip(gt.frame.tolist(), gt.track_id.tolist()))
    got = seen_truth(scene, ["c1"], gt, None)
    assert list(zip(got.frame.tolist(), got.track_id.tolist())) == [
        (f, k) for f, k in rows if k != 2 and f % 2 == 0]
    got = seen_truth(scene, ["c0", "c1"], gt, (5, 14))
    assert list(zip(got.frame.tolist(), got.track_id.tolist())) == [
        (f, k) for f, k in rows if 5 <= f <= 14 and (k == 2 or f % 2 == 0)]
