"""r90_m's view cues (seg2pose.method.r90_features) computed from views.csv by hand --
crowding, distance, grazing, the cut border, the cuboid box and the foot offset -- and the
per-class calibration on a known error model, over several runs and scenes. The quantile
regression, the columns' round trips and the whole path: tests/seg2pose/method/test_uncertainty.py."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from seg2pose.core.errors import InputError
from seg2pose.io.poses import read_poses
from seg2pose.io.run import ViewTable
from seg2pose.method.r90_features import VIEW_FEATURES
from seg2pose.method.uncertainty import StageModel, r90_scores


def test_crowding_by_hand():
    """A view whose centre lies within a nearer road user's apparent size is crowded by
    1 - distance / size; the nearer one, views of other frames or cameras, and views beyond
    the size are not."""
    from seg2pose.method.r90_features import crowding

    frame = np.array([0, 0, 0, 1, 0])
    camera = np.array(["c0", "c0", "c0", "c0", "c1"], object)
    uv = np.array([[100.0, 100.0], [120.0, 100.0], [300.0, 100.0], [110.0, 100.0], [110.0, 100.0]])
    rng = np.array([10.0, 20.0, 30.0, 25.0, 25.0])
    size = np.array([50.0, 40.0, 10.0, 50.0, 50.0])
    np.testing.assert_allclose(crowding(frame, camera, uv, rng, size), [0.0, 0.6, 0.0, 0.0, 0.0])
    # two nearer road users: the larger overlap counts
    np.testing.assert_allclose(
        crowding(np.zeros(3), np.array(["c0"] * 3, object),
                 np.array([[0.0, 0.0], [30.0, 0.0], [10.0, 0.0]]), np.array([5.0, 6.0, 9.0]),
                 np.array([20.0, 40.0, 1.0])), [0.0, 0.0, 0.5])


def test_view_columns_by_hand():
    """Distance, grazing, the cut mask's distance to the border and crowding from a camera 10 m
    above the ground: known answers."""
    from types import SimpleNamespace

    from seg2pose.geometry.camera import Camera
    from seg2pose.geometry.ground import GroundSurface
    from seg2pose.io.run import ViewTable
    from seg2pose.method.r90_features import view_columns

    cam = Camera.look_at("c0", np.array([0.0, 0.0, 10.0]), np.array([20.0, 0.0, 0.0]), f=500.0,
                         width=640, height=480)
    scene = SimpleNamespace(cameras={"c0": cam}, ground=GroundSurface(_FLAT),
                            class_sizes=lambda: {"car": (4.0, 1.8, 1.5), "pedestrian": (0.6, 0.6, 1.8)})
    # the car's box bottom at the image of the ground point 1 m nearer the camera than its
    # normal position (20, 0); the typical car's (heading unknown: the mean over four
    # headings) is elsewhere, so only the difference of the two is known: log_foot below
    v = ViewTable([0, 0], [1, 2], ["c0", "c0"], ["car", "pedestrian"],
                  [[320.0, 300.0], [330.0, 5.0]], [[20.0, 0.0, 0.0], [40.0, 0.0, 1.0]],
                  np.zeros((2, 2)), [[0, 0, 0], [1, 0, 0]],
                  box=[[300.0, 250.0, 340.0, 300.0], [325.0, 0.0, 335.0, 10.0]])
    c = view_columns(scene, v)
    np.testing.assert_allclose(np.exp(c["log_distance"]), [20.0, 40.0])
    np.testing.assert_allclose(np.exp(c["log_grazing"]), [2.0, 40.0 / 9.0])
    np.testing.assert_allclose(c["cut"], [0.0, 1.0])
    np.testing.assert_allclose(c["cut_edge"], [0.0, np.log1p(5.0)])  # 5 px from the top
    # the car (nearer, 500 * 4 / sqrt(500) px) holds the pedestrian's centre? 295 px apart: no
    size_car = 500.0 * 4.0 / np.sqrt(500.0)
    assert size_car < np.hypot(10.0, 295.0)
    np.testing.assert_allclose(c["crowd"], [0.0, 0.0])
    from seg2pose.method.r90_features import FOOT_FLOOR_M, foot_offset, typical_boxes

    foot = foot_offset(scene, v, typical_boxes(scene, v))
    np.testing.assert_allclose(c["log_foot"], np.log(np.abs(foot) + FOOT_FLOOR_M))
    with pytest.raises(InputError, match="no box_x0,box_y0,box_x1,box_y1 columns"):
        view_columns(scene, ViewTable(v.frame, v.track_id, v.camera, v.cls, v.uv, v.normal,
                                      v.residual, v.cues))


_FLAT = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # the plane z = 0


def _side_camera():
    """A camera 10 m up at the origin looking at (20, 0, 0): the ground's x axis is the
    image's vertical centre line."""
    from seg2pose.geometry.camera import Camera

    return Camera.look_at("c0", np.array([0.0, 0.0, 10.0]), np.array([20.0, 0.0, 0.0]), f=500.0,
                          width=640, height=480)


def test_cuboid_box_by_hand():
    """A 4.5 x 1.8 x 1.5 m car at (20, 0) heading along the line of sight: its box is widest
    at the near top corners (17.75, +-0.9, 1.5), 500 x 1.8 / their depth wide, and its bottom
    is the image row of the near bottom corners; turned by 90 degrees it is 4.5 m wide; an
    unknown heading gives the mean of the boxes at 0, 45, 90 and 135 degrees."""
    from seg2pose.geometry.ground import GroundSurface
    from seg2pose.method.r90_features import cuboid_box

    cam, ground = _side_camera(), GroundSurface(_FLAT)
    lwh = np.array([4.5, 1.8, 1.5])
    axis = np.array([20.0, 0.0, -10.0]) / np.sqrt(500.0)
    depth = np.array([17.75, 0.9, 1.5 - 10.0]) @ axis  # near top corner, along the optical axis
    box = cuboid_box(cam, ground, [[20.0, 0.0]], [0.0], lwh)[0]
    assert box[2] - box[0] == pytest.approx(500.0 * 1.8 / depth, rel=1e-9)
    assert box[3] == pytest.approx(cam.project_points(np.array([[17.75, 0.9, 0.0]]))[0][0, 1])
    assert (box[0] + box[2]) / 2 == pytest.approx(320.0)
    depth90 = np.array([19.1, 2.25, 1.5 - 10.0]) @ axis
    box90 = cuboid_box(cam, ground, [[20.0, 0.0]], [np.pi / 2], lwh)[0]
    assert box90[2] - box90[0] == pytest.approx(500.0 * 4.5 / depth90, rel=1e-9)
    mean = np.mean([cuboid_box(cam, ground, [[20.0, 0.0]], [a], lwh)[0]
                    for a in np.deg2rad([0.0, 45.0, 90.0, 135.0])], axis=0)
    np.testing.assert_allclose(cuboid_box(cam, ground, [[20.0, 0.0]], [np.nan], lwh)[0], mean)
    assert np.isnan(cuboid_box(cam, ground, [[np.nan, 0.0]], [0.0], lwh)).all()


def test_foot_offset_is_how_far_the_box_bottom_lands_from_a_typical_road_users():
    """A car moving along the line of sight at normal positions (20, 0), (21, 0): the typical
    car's box bottom lands at its near edge, 2.25 m nearer (x = 18.75 for the second, heading
    0 from its motion). A mask whose box bottom is the image of (17.25, 0) -- a car 3 m longer,
    say -- lands 1.5 m nearer (-1.5); the first view (no heading yet: the typical box is the
    mean over four headings) against the image of (18, 0); no box: NaN."""
    from types import SimpleNamespace

    from seg2pose.geometry.ground import GroundSurface
    from seg2pose.method.r90_features import foot_offset, typical_boxes

    cam = _side_camera()
    scene = SimpleNamespace(cameras={"c0": cam}, ground=GroundSurface(_FLAT),
                            class_sizes=lambda: {"car": (4.5, 1.8, 1.5)})
    bottom = cam.project_points(np.array([[18.0, 0.0, 0.0], [18.0 + 1.0 - 1.75, 0.0, 0.0],
                                          [0.0, 0.0, 0.0]]))[0][:, 1]
    box = [[300.0, 200.0, 340.0, bottom[0]], [300.0, 200.0, 340.0, bottom[1]],
           [np.nan] * 4]
    v = ViewTable([0, 1, 2], [7, 7, 7], ["c0"] * 3, ["car"] * 3, np.full((3, 2), 320.0),
                  [[20.0, 0.0, 0.0], [21.0, 0.0, 0.0], [22.0, 0.0, 0.0]], np.zeros((3, 2)),
                  np.zeros((3, 3)), box=box)
    typical = typical_boxes(scene, v)
    # heading from motion: 0 from the second view on; the first has none yet (mean of four)
    np.testing.assert_allclose(typical[1], _typical_at(cam, 21.0))
    off = foot_offset(scene, v, typical)
    assert np.isnan(off[2])
    assert off[1] == pytest.approx(-1.5, abs=1e-6)
    # the first view: no heading yet, so the typical box is the mean over four headings; its
    # bottom row's ray meets the ground at x = 10 d_x / -d_z (camera 10 m up on the x axis)
    mean_bottom = np.mean([_typical_at(cam, 20.0, a)[3] for a in np.deg2rad([0, 45, 90, 135])])
    assert typical[0, 3] == pytest.approx(mean_bottom)
    d = cam.unproject(np.array([[320.0, mean_bottom]]))[0]
    assert 17.75 < 10.0 * d[0] / -d[2] < 19.1  # between the end-on and the side-on near edge
    assert off[0] == pytest.approx(18.0 - 10.0 * d[0] / -d[2], abs=1e-6)


def _typical_at(cam, x: float, heading: float = 0.0) -> np.ndarray:
    from seg2pose.geometry.ground import GroundSurface
    from seg2pose.method.r90_features import cuboid_box

    return cuboid_box(cam, GroundSurface(_FLAT), [[x, 0.0]], [heading], [4.5, 1.8, 1.5])[0]


def _draw_known(seed: int, n_users: int = 60, rows: int = 40):
    """Errors of a known law per class: |N2(0, (s_class * g)^2 I)| with the grazing g of
    each row, times a road user's own factor exp(0.15 z) (a road user's errors are alike);
    a cut mask doubles the error. Returns cls, X (VIEW_FEATURES), err, groups and the true
    r90 of each row: s times the 90th percentile of |N2(0, I)| exp(0.15 z) (Monte Carlo)."""
    big = np.random.default_rng(99)
    q90 = np.quantile(np.linalg.norm(big.normal(0, 1, (10 ** 6, 2)), axis=1)
                      * np.exp(0.15 * big.normal(0, 1, 10 ** 6)), 0.9)
    rng = np.random.default_rng(seed)
    scale = {"car": 0.20, "pedestrian": 0.06, "bicyclist": 0.12}
    cls, X, err, grp, true_r90 = [], [], [], [], []
    names = list(scale)
    for u in range(n_users):
        c = names[u % 3]
        own = np.exp(0.15 * rng.normal())
        g = rng.uniform(1.0, 5.0, rows)
        cut = (rng.uniform(size=rows) < 0.15).astype(float)
        s = scale[c] * g * (1.0 + cut)
        e = np.linalg.norm(rng.normal(0, 1, (rows, 2)), axis=1) * s * own
        cols = {"one": np.ones(rows), "log_distance": np.log(g * 10), "log_grazing": np.log(g),
                "cut": cut, "cut_edge": np.zeros(rows), "crowd": np.zeros(rows),
                "far": np.zeros(rows), "log_spread": np.full(rows, np.log(0.02)),
                "log_residual": np.full(rows, np.log(0.05)), "log_foot": np.full(rows, np.log(0.05))}
        cls += [c] * rows
        X.append(np.column_stack([cols[k] for k in VIEW_FEATURES]))
        err.append(e)
        grp += [u] * rows
        true_r90.append(s * q90)
    return (np.array(cls, object), np.vstack(X), np.concatenate(err), np.array(grp),
            np.concatenate(true_r90))


def test_per_class_bars_on_a_known_error_law_cover_90_percent_of_new_road_users():
    """Per class, on fresh road users of the same law: coverage about 0.9 (the conformal step
    aims at CONFORMAL_Q = 0.92 over 40 road users a class), the bar within 15 % of the law's
    true 90 % radius, sharper than one radius per class, and ranking the errors."""
    cls, X, err, grp, _ = _draw_known(1, n_users=120, rows=15)
    m = StageModel.fit(VIEW_FEATURES, cls, X, err, grp)
    cls2, X2, err2, _, true2 = _draw_known(2, n_users=300)
    r = m.predict(cls2, X2)
    for c in ("car", "pedestrian", "bicyclist"):
        s = cls2 == c
        sc = r90_scores(err2[s], r[s])
        assert 0.87 <= sc["coverage"] <= 0.96, (c, sc)
        assert np.median(r[s] / true2[s]) == pytest.approx(1.0, abs=0.15), c
        # sharper than one radius per class of the same coverage, and ranking the errors
        assert sc["mean_r90"] < np.quantile(err2[s], sc["coverage"]) and sc["spearman"] > 0.4


def test_calibrate_on_several_runs_and_scenes(tmp_path):
    """s2p calibrate --run A --run B: two splits of one scene and a run of another scene (read
    against the truth its run.json names) make one calibration; its fitted_on lists the three;
    a run of another method is refused."""
    from seg2pose.method.pipeline import RunOptions, run_scene
    from seg2pose.method.r90_calibrate import calibrate_run
    from tests.scene_fixtures import make_tiny_scene

    a = make_tiny_scene(tmp_path / "a", frames=40, n_users=9)
    b = make_tiny_scene(tmp_path / "b", frames=40, n_users=9, seed=1)
    for scene, split in ((a, "val"), (a, "train"), (b, "val")):
        run_scene(scene, tmp_path / f"{scene.root.name}-{split}",
                  RunOptions(baseline=True, split=split, progress=False))
    runs = [tmp_path / "a-val", tmp_path / "a-train", tmp_path / "b-val"]
    path, cal = calibrate_run(a, runs, tmp_path / "r90.json")
    fitted = json.loads(path.read_text())["fitted_on"]
    assert [f["split"] for f in fitted] == ["val", "train", "val"]
    assert [f["scene_fingerprint"] for f in fitted] == [a.fingerprint()] * 2 + [b.fingerprint()]
    assert 0.8 <= cal.meta["coverage_on_fit"]["poses"] <= 1.0
    # a and b are two recordings of one site (same cameras and ground: one fingerprint): b's run
    # is read against b's truth, not a's
    from seg2pose.method.r90_calibrate import fit_run

    assert a.fingerprint() == b.fingerprint() and a.root != b.root
    fb, _ = fit_run(a, tmp_path / "b-val")
    assert Path(fb.scene.root).resolve() == Path(b.root).resolve()
    assert np.array_equal(fb.gt.xyz, read_poses(b.gt_path).xyz)
    assert not np.array_equal(fb.gt.xyz, read_poses(a.gt_path).xyz)
    # each scene may have its own models (runs of another scene pool), one scene's runs may not
    def set_models(run, models):
        m = json.loads((tmp_path / run / "run.json").read_text())
        m["models"] = models
        (tmp_path / run / "run.json").write_text(json.dumps(m))

    set_models("b-val", {"car": {"path": "../b/models/car.safetensors"}})
    calibrate_run(a, runs, tmp_path / "r90-b.json")
    set_models("a-train", {"car": {"path": "../a/other/car.safetensors"}})
    with pytest.raises(InputError, match=r"a-train/run.json: field 'models': this run's models "
                                         r".* one set of models"):
        calibrate_run(a, runs, tmp_path / "r90-a.json")
    set_models("a-train", json.loads((tmp_path / "a-val" / "run.json").read_text()).get("models"))
    meta = json.loads((tmp_path / "b-val" / "run.json").read_text())
    meta["method"] = "s2pn"
    (tmp_path / "b-val" / "run.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match="differs from the first run's"):
        calibrate_run(a, runs, tmp_path / "r90-2.json")
    # a views.csv of an s2p before the size cue (no box columns) is refused, naming the file
    views = tmp_path / "a-val" / "views.csv"
    views.write_text("\n".join(",".join(ln.split(",")[:15]) for ln in views.read_text().splitlines())
                     + "\n")
    with pytest.raises(InputError, match=r"a-val/views.csv: this run's views.csv has no "
                                         r"box_x0,box_y0,box_x1,box_y1 columns"):
        calibrate_run(a, runs[:1], tmp_path / "r90-3.json")
