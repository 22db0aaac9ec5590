"""Per-track heights (seg2pose/method/track_heights.py): known answers on a flat ground."""

from types import SimpleNamespace

import numpy as np

from seg2pose.geometry.camera import Camera
from seg2pose.geometry.ground import GroundSurface
from seg2pose.geometry.normal import normal_positions
from seg2pose.io.run import ViewTable
from seg2pose.method.track_heights import (
    TrackHeightSettings,
    apply_track_heights,
    fit_offsets,
    fit_offsets_loop,
    height_directions,
)

W, H = 1280, 720
FLAT = GroundSurface(np.array([(x, y, 0.0) for x in range(-60, 61, 10) for y in range(-20, 81, 10)], float))
# two poles 30 m apart, both looking at the crossing around (0, 30)
CAMS = {"a": Camera.look_at("a", center=[-15, 0, 10], target=[0, 30, 0], f=900, width=W, height=H),
        "b": Camera.look_at("b", center=[15, 0, 10], target=[0, 30, 0], f=900, width=W, height=H)}
SCENE = SimpleNamespace(cameras=CAMS, ground=FLAT, default_heights=lambda: {"car": 0.75})
H0 = 0.75


def views_of(tracks, cams, rng=None, noise_px=0.0):
    """ViewTable of road users ``tracks``: list of (track_id, true centre height, (T, 2) ground
    path) seen by ``cams`` at frames 0..T-1, with normal positions at the default H0."""
    rows = []
    for tid, h_true, path in tracks:
        X = np.column_stack([path, np.full(len(path), h_true)])
        for c in cams:
            uv = CAMS[c].project_points(X)[0]
            if noise_px:
                uv = uv + rng.normal(0, noise_px, uv.shape)
            n, _ = normal_positions(CAMS[c], FLAT, uv, H0)
            rows.append(ViewTable(np.arange(len(path)), np.full(len(path), tid),
                                  np.full(len(path), c, object), np.full(len(path), "car", object),
                                  uv, n, np.zeros((len(path), 2))))
    return ViewTable.concat(rows).sorted()


def crossing(n=60, y=30.0):
    """A straight path across both images, 0.2 m a frame."""
    return np.column_stack([np.linspace(-6, 6, n), np.full(n, y)])


def error_at(views, path, cam="a"):
    v = views.of_cameras([cam])
    return np.abs(v.normal[:, :2] - path).max()


def test_two_cameras_apart_recover_the_true_height():
    # a road user whose centre is at 1.0 m where the default says 0.75 m: both cameras place
    # it too far, each along its own line of sight; the fit finds the height where they agree
    path = crossing()
    v = views_of([(7, 1.0, path)], ["a", "b"])
    assert error_at(v, path) > 0.5  # the default height is badly wrong here
    out, meta, text = apply_track_heights(SCENE, v, TrackHeightSettings(prior=1e-6))
    h = float(text.splitlines()[1].split(",")[3])
    assert abs(h - 1.0) < 0.01, h
    assert error_at(out, path) < 0.02
    assert error_at(out, path, "b") < 0.02
    assert meta["n_tracks"] == 1 and meta["n_moved_1cm"] == 1


def test_one_camera_wrong_height_is_a_similar_path_so_it_keeps_the_default():
    # on a flat ground, the positions at a wrong height are the true ones scaled about the
    # camera's foot: a straight crossing stays straight, so smoothness alone says nothing
    path = crossing()
    v = views_of([(3, 1.0, path)], ["a"])
    foot = CAMS["a"].center[:2]
    ratio = np.linalg.norm(v.normal[:, :2] - foot, axis=1) / np.linalg.norm(path - foot, axis=1)
    assert np.ptp(ratio) < 1e-6 and abs(ratio[0] - 1) > 0.01  # one scale for the whole track
    second = v.normal[2:, :2] - 2 * v.normal[1:-1, :2] + v.normal[:-2, :2]
    assert np.abs(second).max() < 1e-9  # ... and it is still a straight line at constant speed
    out, _, text = apply_track_heights(SCENE, v, TrackHeightSettings(smooth=1.0, cross=1.0))
    assert float(text.splitlines()[1].split(",")[3]) == H0
    assert np.allclose(out.normal, v.normal)


def test_radial_track_keeps_the_default():
    # walking straight away from both cameras' midpoint: no curvature, and seen by one camera
    path = np.column_stack([np.zeros(40), np.linspace(20, 40, 40)])
    v = views_of([(1, 1.1, path)], ["a"])
    _, _, text = apply_track_heights(SCENE, v, TrackHeightSettings(smooth=1.0))
    assert float(text.splitlines()[1].split(",")[3]) == H0


def test_prior_bounds_and_short_tracks():
    path = crossing()
    v = views_of([(1, 1.0, path), (2, 1.0, path[:4])], ["a", "b"])
    _, _, text = apply_track_heights(SCENE, v, TrackHeightSettings(prior=1e-6, bounds=(0.8, 1.2)))
    rows = {int(r.split(",")[0]): float(r.split(",")[3]) for r in text.splitlines()[1:]}
    assert abs(rows[1] - 1.2 * H0) < 1e-9  # the truth (1.0) is above the bound 0.9
    assert rows[2] == H0                    # 4 frames: shorter than min_frames
    # a strong prior keeps the default even where the data are informative
    _, _, text = apply_track_heights(SCENE, v, TrackHeightSettings(prior=1e6))
    assert abs(float(text.splitlines()[1].split(",")[3]) - H0) < 1e-3


def test_robust_to_an_outlier_view():
    rng = np.random.default_rng(0)
    path = crossing()
    v = views_of([(5, 0.9, path)], ["a", "b"], rng, noise_px=0.3)
    v.residual[10] += 8.0  # a network residual throws one view metres off
    _, _, plain = apply_track_heights(SCENE, v, TrackHeightSettings(prior=1e-3, huber=1e6))
    _, _, robust = apply_track_heights(SCENE, v, TrackHeightSettings(prior=1e-3, huber=0.1))
    h_plain, h_robust = (float(t.splitlines()[1].split(",")[3]) for t in (plain, robust))
    assert abs(h_robust - 0.9) < 0.03, h_robust
    assert abs(h_plain - 0.9) > 2 * abs(h_robust - 0.9)


def test_vectorised_equals_a_loop_over_tracks():
    rng = np.random.default_rng(1)
    tracks = [(t, rng.uniform(0.5, 1.1), crossing(int(rng.integers(3, 50)), rng.uniform(20, 40))
               + rng.normal(0, 0.05, 2)) for t in range(12)]
    v = views_of(tracks, ["a", "b"], rng, noise_px=0.5)
    v = v.take(rng.random(len(v)) > 0.1)  # some views missing
    tids, tix = np.unique(v.track_id, return_inverse=True)
    h = np.full(len(v), H0)
    d = height_directions(SCENE, v.camera, v.uv, h)
    p = v.normal[:, :2]
    for s in (TrackHeightSettings(smooth=0.5, huber=0.05, prior=0.1), TrackHeightSettings()):
        a = fit_offsets(tix, v.frame, p, d, np.full(len(tids), H0), len(tids), s)
        b = fit_offsets_loop(tix, v.frame, p, d, np.full(len(tids), H0), len(tids), s)
        assert np.allclose(a, b, atol=1e-12)
        assert np.count_nonzero(a) >= 6  # the comparison is not between zeros


def test_direction_points_to_the_camera_with_distance_over_height():
    path = crossing(5)
    v = views_of([(1, H0, path)], ["a"])
    d = height_directions(SCENE, v.camera, v.uv, np.full(len(v), H0))
    foot = CAMS["a"].center[:2]
    expect = (foot - v.normal[:, :2]) / (10 - H0)  # flat ground: p(h) = foot + (g - foot)(H-h)/H
    assert np.allclose(d, expect, atol=1e-6)


def test_run_records_the_heights_and_its_views_fuse_to_its_poses(tmp_path, monkeypatch):
    # s2p run --track-heights: run.json and track_heights.csv say what was fitted, and fusing
    # the run's views.csv again gives its poses.csv (the correction lives in the views). The
    # tiny scene's lenses share a pole: a weak prior, so that views do move
    from scene_fixtures import make_tiny_scene

    from seg2pose.method import track_heights as th
    monkeypatch.setattr(th, "DEFAULT_SETTINGS", TrackHeightSettings(prior=1e-3))
    from seg2pose.io.poses import read_poses
    from seg2pose.io.run import read_run_meta, read_views
    from seg2pose.method.fusion import fuse
    from seg2pose.method.pipeline import RunOptions, run_scene

    scene = make_tiny_scene(tmp_path / "tiny")
    plain = run_scene(scene, tmp_path / "plain", RunOptions(config="tri-I", baseline=True, progress=False))
    run = run_scene(scene, tmp_path / "th", RunOptions(config="tri-I", baseline=True, progress=False,
                                                       track_heights=True))
    meta = read_run_meta(run)
    assert meta["track_heights"]["file"] == "track_heights.csv" and meta["track_heights"]["prior"] == 1e-3
    lines = (run / "track_heights.csv").read_text().splitlines()
    assert lines[0] == "track_id,class,default_height,height,n_views"
    assert len(lines) - 1 == meta["track_heights"]["n_tracks"] > 0
    assert "track_heights" not in read_run_meta(plain)
    again = fuse(read_views(run / "views.csv"), scene)
    np.testing.assert_allclose(again.xyz, read_poses(run / "poses.csv").xyz, atol=2e-6)
    # each view's normal position is the one at its track's height, on its own ray
    v0, v1 = read_views(plain / "views.csv"), read_views(run / "views.csv")
    rows = {int(r.split(",")[0]): float(r.split(",")[3]) for r in lines[1:]}
    h = np.array([rows.get(int(t), scene.default_heights()[c]) for t, c in zip(v0.track_id, v0.cls)])
    h0 = np.array([scene.default_heights()[c] for c in v0.cls])
    assert np.abs(h - h0).max() > 0.01  # some views did move
    for cam in ("c0", "c1", "c2"):
        i = v0.camera == cam
        X, _ = normal_positions(scene.cameras[cam], scene.ground, v0.uv[i], h[i])
        # (track_heights.csv gives heights to 0.1 mm, views.csv positions to 0.1 mm)
        np.testing.assert_allclose(v1.normal[i], X, atol=0.00005 * 8 + 1e-4)


def test_lenses_of_one_device_min_spread_gate():
    # two lenses 20 cm apart on one pole: their positions at a wrong height differ by
    # 0.2 m / 10 m of the offset; below min_spread the cross rows are dropped, however weak the prior
    cams = {"l": Camera.look_at("l", center=[-0.1, 0, 10], target=[-0.1, 30, 0], f=900, width=W, height=H),
            "r": Camera.look_at("r", center=[0.1, 0, 10], target=[0.1, 30, 0], f=900, width=W, height=H)}
    scene = SimpleNamespace(cameras=cams, ground=FLAT, default_heights=lambda: {"car": 0.75})
    path = crossing()
    X = np.column_stack([path, np.full(len(path), 1.0)])
    rows = []
    for c, cam in cams.items():
        uv = cam.project_points(X)[0]
        n, _ = normal_positions(cam, FLAT, uv, H0)
        rows.append(ViewTable(np.arange(len(path)), np.full(len(path), 1), np.full(len(path), c, object),
                              np.full(len(path), "car", object), uv, n, np.zeros((len(path), 2))))
    v = ViewTable.concat(rows).sorted()
    _, _, text = apply_track_heights(scene, v, TrackHeightSettings(prior=1e-6, min_spread=0.1))
    assert float(text.splitlines()[1].split(",")[3]) == H0
    # without the gate, noise-free lenses find it (the information is there, only small)
    _, _, text = apply_track_heights(scene, v, TrackHeightSettings(prior=1e-6, min_spread=0.0))
    assert abs(float(text.splitlines()[1].split(",")[3]) - 1.0) < 0.01


def test_class_prior_overrides_the_prior_for_its_class():
    path = crossing()
    v = views_of([(1, 1.0, path), (2, 1.0, path)], ["a", "b"])
    v.cls[v.track_id == 2] = "pedestrian"
    scene = SimpleNamespace(cameras=CAMS, ground=FLAT, default_heights=lambda: {"car": H0, "pedestrian": H0})
    s = TrackHeightSettings(prior=1e-6, class_prior=(("pedestrian", 1e9),))
    _, meta, text = apply_track_heights(scene, v, s)
    rows = {int(r.split(",")[0]): float(r.split(",")[3]) for r in text.splitlines()[1:]}
    assert abs(rows[1] - 1.0) < 0.01 and abs(rows[2] - H0) < 1e-4
    assert meta["class_prior"] == {"pedestrian": 1e9}
