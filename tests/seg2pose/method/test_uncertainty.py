"""r90_m, the error bar (seg2pose.method.uncertainty): the quantile regression on known answers,
coverage on fresh draws of a known error model, the pose features by hand, the columns'
round trips (poses.csv, views.csv, MCAP records, calibration JSON), bad input, and the whole
path run -> calibrate -> run -> eval on a tiny scene. The view cues and the per-class
calibration: tests/seg2pose/method/test_uncertainty_cues.py."""

from __future__ import annotations

import json

import numpy as np
import pytest

from seg2pose.core.errors import InputError
from seg2pose.io.poses import PoseTable, format_poses, read_poses
from seg2pose.io.run import ViewTable, format_views, read_views
from seg2pose.method.r90_features import POSE_FEATURES, VIEW_FEATURES, pose_features
from seg2pose.method.uncertainty import Calibration, StageModel, fit_quantile, r90_scores, read_calibration


def test_quantile_of_a_constant_model_is_the_sample_quantile():
    y = np.arange(100.0)  # the pinball loss at q = 0.9 is least anywhere in [89, 90]
    b = fit_quantile(np.ones((100, 1)), y, 0.9)
    assert 89.0 <= b[0] <= 90.0


def test_quantile_regression_recovers_a_line_and_zeroes_a_constant_column():
    rng = np.random.default_rng(0)
    x = rng.uniform(0, 5, 4000)
    y = 2.0 + 3.0 * x + rng.uniform(0, 1, 4000)  # 90th percentile: 2.9 + 3 x
    X = np.column_stack([np.ones_like(x), x, np.full_like(x, 7.0)])
    b = fit_quantile(X, y, 0.9)
    assert b[0] == pytest.approx(2.9, abs=0.05) and b[1] == pytest.approx(3.0, abs=0.02)
    assert b[2] == 0.0


def test_heteroscedastic_errors_covered_on_fresh_draws():
    """Errors that grow with distance: the fitted bar covers ~90 % of a fresh draw, is larger
    where the errors are, and ranks them (Spearman)."""
    def draw(seed, n=2000):
        rng = np.random.default_rng(seed)
        d = rng.uniform(5, 60, n)
        err = np.linalg.norm(rng.normal(0, 1, (n, 2)), axis=1) * 0.02 * d
        X = np.column_stack([np.ones(n), np.log(d), np.zeros((n, len(VIEW_FEATURES) - 2))])
        return X, err
    X, err = draw(1)
    cls = np.array(["car"] * len(err), object)
    m = StageModel.fit(VIEW_FEATURES, cls, X, err)
    X2, err2 = draw(2)
    sc = r90_scores(err2, m.predict(cls, X2))
    assert 0.87 <= sc["coverage"] <= 0.93
    assert sc["spearman"] > 0.4 and sc["sharpness"] < 2.5


def test_pose_features_by_hand():
    # one pose seen by two cameras 2 m apart (r90 1 m each), one seen by one camera
    est = np.array([[[0.0, 0.0], [5.0, 5.0]], [[2.0, 0.0], [np.nan, np.nan]]])
    r = np.array([[1.0, 0.5], [1.0, np.nan]])
    X = pose_features(est, r)
    assert X.shape == (2, len(POSE_FEATURES))
    np.testing.assert_allclose(np.exp(X[:, 1]), [np.sqrt(2) / 2, 0.5])
    np.testing.assert_allclose(np.exp(X[:, 2]), [2, 1])
    np.testing.assert_allclose(np.exp(X[:, 3]) - 0.05, [1.0, 0.0], atol=1e-12)


def test_pose_r90_column_round_trip_and_old_files(tmp_path):
    t = PoseTable([0, 1], [3, 3], ["car", "car"], [[1, 2, 0], [1.5, 2, 0]], [0.1, np.nan],
                  [[4, 2, 1.5]] * 2, r90=[0.75, np.nan])
    p = tmp_path / "poses.csv"
    p.write_text(format_poses(t))
    assert p.read_text().splitlines()[0].endswith(",h,r90_m")
    back = read_poses(p)
    np.testing.assert_array_equal(back.r90, t.r90)
    p.write_text(format_poses(PoseTable(t.frame, t.track_id, t.cls, t.xyz, t.heading, t.size)))
    assert read_poses(p).r90 is None
    p.write_text("frame,track_id,class,x,y,z,heading,r90_m\n0,1,car,1,2,0,0,-0.5\n")
    with pytest.raises(InputError, match=r"poses.csv:2: r90_m must be finite metres in \[0, "):
        read_poses(p)


def test_view_cue_columns_round_trip_and_old_files(tmp_path):
    v = ViewTable([1, 1], [2, 3], ["c0", "c1"], ["car", "pedestrian"], [[1, 2], [3, 4]],
                  [[5, 6, 0], [7, 8, 0]], [[0.1, 0.2], [0, 0]], [[1, 0, 0.3], [0, 1, 0]],
                  [1.25, np.nan])
    p = tmp_path / "views.csv"
    p.write_text(format_views(v))
    back = read_views(p)
    np.testing.assert_array_equal(back.cues, v.cues)
    np.testing.assert_array_equal(back.r90, v.r90)
    assert read_views(p).take([1]).r90.tolist() != []
    old = ViewTable(v.frame, v.track_id, v.camera, v.cls, v.uv, v.normal, v.residual)
    p.write_text(format_views(old))
    assert read_views(p).cues is None
    lines = format_views(v).splitlines()
    p.write_text("\n".join([lines[0], lines[1].replace(",1.0,0.0,0.3,", ",2.0,0.0,0.3,")]) + "\n")
    with pytest.raises(InputError, match=r"views.csv:2: cut, far must be integers in \[0, 1\]"):
        read_views(p)


def test_view_box_columns_round_trip_old_files_and_bad_boxes(tmp_path):
    """views.csv's box columns (after the cues) round-trip exactly, an empty mask's NaN box
    too; a file with the cues and no box reads box None; x1 < x0 is refused naming the line;
    the MCAP records carry the box."""
    from s2p_review import mcap_records as R

    box = [[10.0, 20.5, 30.0, 44.0], [np.nan] * 4]
    v = ViewTable([1, 1], [2, 3], ["c0", "c1"], ["car", "pedestrian"], [[1, 2], [3, 4]],
                  [[5, 6, 0], [7, 8, 0]], [[0.1, 0.2], [0, 0]], [[1, 0, 0.3], [0, 1, 0]],
                  [1.25, np.nan], box)
    p = tmp_path / "views.csv"
    p.write_text(format_views(v))
    assert p.read_text().splitlines()[0].endswith(",r90_m,box_x0,box_y0,box_x1,box_y1")
    back = read_views(p)
    np.testing.assert_array_equal(back.box, v.box)
    np.testing.assert_array_equal(back.take([1, 0]).box, v.box[[1, 0]])
    np.testing.assert_array_equal(ViewTable.concat([back, back]).box, np.vstack([box, box]))
    vb = R.views_table([m for _, m in R.view_messages(v)])
    np.testing.assert_array_equal(vb.box, v.box)
    np.testing.assert_array_equal(vb.r90, v.r90)
    no_box = ViewTable(v.frame, v.track_id, v.camera, v.cls, v.uv, v.normal, v.residual, v.cues,
                       v.r90)
    p.write_text(format_views(no_box))
    assert read_views(p).box is None and read_views(p).cues is not None
    assert R.views_table([m for _, m in R.view_messages(no_box)]).box is None
    lines = format_views(v).splitlines()
    p.write_text("\n".join([lines[0], lines[1].replace(",10.0,20.5,30.0,", ",31.0,20.5,30.0,")])
                 + "\n")
    with pytest.raises(InputError, match=r"views.csv:2: box_x0,box_y0,box_x1,box_y1 must be"):
        read_views(p)
    with pytest.raises(ValueError, match="box needs the cues"):
        ViewTable([1], [2], ["c0"], ["car"], [[1, 2]], [[5, 6, 0]], [[0, 0]], box=[box[0]])


def test_calibration_json_round_trip_and_bad_files(tmp_path):
    k = len(VIEW_FEATURES)
    view = StageModel(VIEW_FEATURES, {"*": [0.1] * k, "car": [0.2] * k}, {"*": 50, "car": 45},
                      {"*": [0.0] * k, "car": [0.0] * k}, {"*": [1.0] * k, "car": [1.0] * k},
                      {"*": 5.0, "car": 0.5})
    pose = StageModel(POSE_FEATURES, {"*": [0.0, 1.0, 0.0, 0.0]}, {"*": 50},
                      {"*": [0.0] * 4}, {"*": [9.0] * 4}, {"*": 5.0})
    cal = Calibration(view, pose, {"method": "baseline", "smooth_frames": 0})
    p = tmp_path / "r90.json"
    p.write_text(cal.to_json())
    back = read_calibration(p)
    assert back.view.coef == view.coef and back.pose.coef == pose.coef
    assert back.meta["method"] == "baseline"
    # unknown classes use the pooled model; features are clipped to the fit's range (here
    # [0, 1]) and the bar to 2 x the largest fitted error (car: e^0.5 < e^(0.2 k))
    X = np.full((2, k), 3.0)
    np.testing.assert_allclose(back.view.predict(np.array(["car", "bus"], object), X),
                               [2 * np.exp(0.5), np.exp(0.1 * k)])
    d = json.loads(p.read_text())
    d["pose"]["coef"]["*"] = [1.0, "x", 0, 0]
    p.write_text(json.dumps(d))
    with pytest.raises(InputError, match=r"r90.json: field 'pose': class '\*': expected 4 finite"):
        read_calibration(p)
    p.write_text("{}")
    with pytest.raises(InputError, match="not an r90 calibration"):
        read_calibration(p)
    d["version"] = 2  # made before the size cue: its view stage has other features
    p.write_text(json.dumps(d))
    with pytest.raises(InputError, match=r"r90.json: field 'version': calibration version 2; "
                                         r"this s2p reads 3"):
        read_calibration(p)


def test_review_disc_geometry_and_colours():
    from s2p_review.error_discs import R90_RED_M, disc_outlines, r90_colors

    rings = disc_outlines(np.array([[1.0, 2.0, 0.5]]), np.array([2.0]))
    np.testing.assert_allclose(np.linalg.norm(rings[0, :, :2] - [1, 2], axis=1), 2.0)
    np.testing.assert_allclose(rings[0, 0], rings[0, -1])  # closed
    c = r90_colors(np.array([0.0, R90_RED_M, 10.0]))
    assert c[0, 1] > c[0, 0] and c[1, 0] > c[1, 1] and (c[1] == c[2]).all()


def test_mcap_records_carry_r90():
    from s2p_review import mcap_records as R

    t = PoseTable([0, 0, 1], [1, 2, 1], ["car"] * 3, np.zeros((3, 3)), [0.0] * 3,
                  np.ones((3, 3)), r90=[0.5, np.nan, 1.5])
    back = R.pose_table([m for _, m in R.pose_messages(t)], True)
    np.testing.assert_array_equal(back.r90, t.r90)
    v = ViewTable([0, 1], [1, 1], ["c0", "c0"], ["car"] * 2, np.zeros((2, 2)), np.zeros((2, 3)),
                  np.zeros((2, 2)), [[1, 0, 0.2], [0, 0, 0]], [0.4, np.nan])
    vb = R.views_table([m for _, m in R.view_messages(v)])
    np.testing.assert_array_equal(vb.cues, v.cues)
    np.testing.assert_array_equal(vb.r90, v.r90)


def test_run_calibrate_run_eval_on_a_tiny_scene(tmp_path):
    """The user's path: a baseline run of the val split, s2p calibrate, a run of the test
    split that carries r90_m in both files, and eval's coverage."""
    from seg2pose.eval.paper_table import evaluate_run
    from seg2pose.io.run import read_run
    from seg2pose.method.pipeline import RunOptions, default_r90_path, run_scene
    from seg2pose.method.r90_calibrate import calibrate_run
    from tests.scene_fixtures import make_tiny_scene

    scene = make_tiny_scene(tmp_path / "s", frames=40, n_users=9)
    run_scene(scene, tmp_path / "val", RunOptions(baseline=True, split="val", progress=False))
    assert np.isnan(read_run(tmp_path / "val").poses.r90).all()  # no calibration yet
    path, cal = calibrate_run(scene, tmp_path / "val")
    assert path == default_r90_path(scene, baseline=True)
    assert 0.8 <= cal.meta["coverage_on_fit"]["poses"] <= 1.0
    run_scene(scene, tmp_path / "test", RunOptions(baseline=True, split="test", progress=False))
    run = read_run(tmp_path / "test")
    assert np.isfinite(run.poses.r90).all() and np.isfinite(run.views.r90).all()
    assert run.meta["r90"]["calibration"].endswith("r90-baseline.json")
    res = evaluate_run(scene, tmp_path / "test", split="test")
    assert res.r90_scores()["n"] == res.n_matched
    with pytest.raises(Exception, match="exists"):
        calibrate_run(scene, tmp_path / "val")
