"""Cameras from clicked pairs (geometry/calibrate.py, calib_quality.py, calib_site.py,
ground_fit.py): known answers from synthetic cameras projected to pixels."""

from __future__ import annotations

import numpy as np
import pytest

from seg2pose.core.errors import InputError
from seg2pose.geometry import calib_quality as Q
from seg2pose.geometry.calib_site import SiteInput, calibrate_site
from seg2pose.geometry.calibrate import PairSet, SolveOptions, solve_camera, solve_group
from seg2pose.geometry.camera import Camera, OpenCVDistortion
from seg2pose.geometry.ground_fit import fit_plane, ground_from_elevations
from seg2pose.synth.clicks import noisy_clicks, spread_clicks
from seg2pose.synth.rig import device_at, make_device

W, H = 1280, 720


def road_pairs(cam: Camera, n: int, rng: np.random.Generator, lift: bool = False
               ) -> tuple[np.ndarray, np.ndarray]:
    """n exact pairs spread over the road in view (the scripted user of synth/clicks.py);
    ``lift``: every second world point raised 0-4 m (poles, signs: off the ground)."""
    uv, X = spread_clicks(cam, 2 * n if lift else n, rng)
    if lift:
        X[1::2, 2] += rng.uniform(0, 4, len(X[1::2]))
        uv = cam.project_points(X)[0]
        keep = np.flatnonzero(cam.in_image(uv))[:n]
        uv, X = uv[keep], X[keep]
    return uv, X


@pytest.mark.parametrize("rig,lens", [(make_device(), "c1"), (device_at(7.0), "c0"), (device_at(14.0), "c4")])
def test_noise_free_pairs_give_the_camera_back(rig, lens):
    cam = rig.cameras[lens]
    uv, X = road_pairs(cam, 8, np.random.default_rng(0))
    s = solve_camera(PairSet(lens, W, H, uv, X))
    assert s.used.all()
    np.testing.assert_allclose(s.camera.K, cam.K, rtol=0, atol=1e-6 * cam.K[0, 0])
    np.testing.assert_allclose(s.camera.R, cam.R, atol=1e-6)
    np.testing.assert_allclose(s.camera.t, cam.t, atol=1e-6)
    assert s.scale < 1e-6  # the noise scale goes to 0: the focal prior has no say


def test_noise_free_principal_point_and_k1():
    """An off-centre lens with barrel distortion, pairs off the ground (poles) as well."""
    ref = make_device().cameras["c1"]
    K = ref.K.copy()
    K[0, 0] = K[1, 1] = 1100.0
    K[:2, 2] = [655.0, 350.0]
    cam = Camera("c", K, ref.R, ref.t, W, H, distortion=OpenCVDistortion(k1=-0.08))
    uv, X = road_pairs(cam, 14, np.random.default_rng(1), lift=True)
    s = solve_camera(PairSet("c", W, H, uv, X), SolveOptions(principal_point=True, k1=True))
    np.testing.assert_allclose(s.camera.K, cam.K, atol=1e-5)
    assert s.camera.distortion.k1 == pytest.approx(-0.08, abs=1e-7)
    np.testing.assert_allclose(s.camera.t, cam.t, atol=1e-6)


def test_one_pixel_noise_within_the_stated_bounds():
    """1 px click noise, 0.1 m world noise, 8 pairs spread over the road: focal within 5 % and
    within 3 of its own stated standard deviations, the camera centre within 0.5 m, on 5 draws
    (measured on 48 draws of three pole heights: within 3 %)."""
    cam = make_device().cameras["c1"]
    rng = np.random.default_rng(7)
    for _ in range(5):
        uv, X = noisy_clicks(*road_pairs(cam, 8, rng), cam, rng, pixel_sigma=1.0)
        s = solve_camera(PairSet("c1", W, H, uv, X), SolveOptions(pixel_sigma=1.0))
        f = s.camera.K[0, 0]
        assert abs(f / cam.K[0, 0] - 1) < 0.05
        assert abs(f - cam.K[0, 0]) < 3 * s.focal_sd
        assert np.linalg.norm(s.camera.center - cam.center) < 0.5


def test_a_swapped_pair_is_dropped_and_named():
    cam = make_device().cameras["c1"]
    uv, X = road_pairs(cam, 9, np.random.default_rng(2))
    uv[[2, 6]] = uv[[6, 2]]
    s = solve_camera(PairSet("c1", W, H, uv, X))
    assert s.used.tolist() == [i not in (2, 6) for i in range(9)]
    np.testing.assert_allclose(s.camera.K, cam.K, atol=1e-4)
    warnings = Q.disagreeing(s, Q.pair_ground_errors(s))
    assert len(warnings) == 2 and "pair 3" in warnings[0] and "pair 7" in warnings[1]


def test_a_device_solves_together_and_lends_its_focal():
    rig = make_device()
    rng = np.random.default_rng(3)
    sets = []
    for lens, n in (("c0", 8), ("c2", 5)):
        uv, X = road_pairs(rig.cameras[lens], n, rng)
        sets.append(PairSet(lens, W, H, uv, X))
    sols = solve_group(sets)
    for s, lens in zip(sols, ("c0", "c2"), strict=True):
        np.testing.assert_allclose(s.camera.K, rig.cameras[lens].K, atol=1e-5)
        np.testing.assert_allclose(s.camera.center, rig.cameras[lens].center, atol=1e-5)
    assert "solved with its device's focal length" in " ".join(sols[1].notes)


@pytest.mark.parametrize("edit,msg", [
    (lambda uv, X: (uv[:5], X[:5]), "5 pairs, at least 6 needed"),
    (lambda uv, X: (np.vstack([uv[:-1], [[1300.0, 10.0]]]), X), "outside the 1280x720 image"),
    (lambda uv, X: (uv, np.column_stack([np.linspace(0, 20, 8), np.zeros(8), np.zeros(8)])), "lie on one line"),
])
def test_bad_pairs_one_clear_line(edit, msg):
    uv, X = road_pairs(make_device().cameras["c1"], 8, np.random.default_rng(4))
    uv, X = edit(uv, X)
    with pytest.raises(InputError, match=msg):
        solve_camera(PairSet("c1", W, H, uv, X))


def test_costs_in_metres_and_next_point():
    """Exact pairs: ground errors 0; one pixel at a normal position costs what a hand
    computation gives at the image centre; the next point lies on the road in view."""
    cam = make_device().cameras["c1"]
    uv, X = road_pairs(cam, 8, np.random.default_rng(5))
    uv = uv + np.random.default_rng(6).normal(0, 1.0, uv.shape)
    s = solve_camera(PairSet("c1", W, H, uv, X))
    flat = Q.flat
    assert np.all(Q.pair_ground_errors(s) < 0.5)
    m = Q.cost_maps(s, flat, step=64)
    # hand: at the centre pixel the ray meets z = 0.9 at range d along the axis; one pixel
    # sideways moves the point d / f, one pixel down d / (f sin(tilt)) along the ground
    iy, ix = np.argmin(np.abs(m.v - 360)), np.argmin(np.abs(m.u - 640))
    c = s.camera
    axis = c.R[2]
    d = (c.center[2] - 0.9) / -axis[2]
    f = c.K[0, 0]
    tilt = np.arcsin(-axis[2])
    assert m.m_per_px[iy, ix] == pytest.approx(d / (f * np.sin(tilt)), rel=0.05)
    nxt = Q.suggest_next(s, SolveOptions(), flat)
    assert nxt is not None and 0 < nxt[2] <= 1
    assert np.linalg.norm(nxt[1][:2] - c.center[:2]) <= Q.MAX_RANGE


def test_ground_from_elevations():
    P = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0], [10, 10, 0], [5, 3, 0]], float)
    P[:, 2] = 0.02 * P[:, 0] - 0.01 * P[:, 1] + 1.0
    assert fit_plane(P) == pytest.approx((0.02, -0.01, 1.0), abs=1e-12)
    g = ground_from_elevations(P, P[:, :2])
    assert g.coef == pytest.approx((0.02, -0.01, 1.0), abs=1e-12)
    np.testing.assert_allclose(g.residuals, 0, atol=1e-12)
    got = g.points[:5]  # the measured points themselves first
    np.testing.assert_allclose(got[np.lexsort(got.T[::-1])], P[np.lexsort(P.T[::-1])])
    np.testing.assert_allclose(g.points[:, 2], g.height(g.points[:, :2]), atol=1e-12)
    flat = ground_from_elevations(P[:2], P[:, :2])
    assert flat.coef is None and "flat" in flat.summary
    np.testing.assert_allclose(flat.points[2:, 2], np.mean(P[:2, 2]))  # beyond the measured two
    none = ground_from_elevations(np.empty((0, 3)), P[:, :2])
    assert "no elevation known" in none.summary and np.all(none.points[:, 2] == 0)


def test_site_fills_unknown_elevations_from_the_plane():
    cam = make_device().cameras["c1"]
    rng = np.random.default_rng(8)
    uv, X = road_pairs(cam, 8, rng)
    Xs = X.copy()
    Xs[::3, 2] = np.nan
    res = calibrate_site(SiteInput({"c1": {"uv": uv, "X": Xs, "names": [f"p{i}" for i in range(8)]}},
                                   {"c1": (W, H)}), maps_step=64)
    rep = res.report()
    assert rep["cameras"]["c1"]["pairs_used"] == 8
    assert "without elevation placed on the ground" in " ".join(res.notes)
    assert res.cameras["c1"].solution.camera.K[0, 0] == pytest.approx(cam.K[0, 0], rel=0.02)
    assert "camera c1: focal" in res.text()


def test_survey_coordinates_keep_their_precision():
    """The same site in a national grid (400 km east, 600 km north, 50 m up): the same camera,
    moved; the position covariance is carried to that frame (the focal's sd unchanged)."""
    cam = make_device().cameras["c1"]
    uv, X = noisy_clicks(*road_pairs(cam, 8, np.random.default_rng(9)), cam, np.random.default_rng(10))
    shift = np.array([4e5, 6e5, 50.0])
    a = solve_camera(PairSet("c1", W, H, uv, X))
    b = solve_camera(PairSet("c1", W, H, uv, X + shift))
    np.testing.assert_allclose(b.camera.K, a.camera.K, rtol=1e-7)
    np.testing.assert_allclose(b.camera.R, a.camera.R, atol=1e-8)
    np.testing.assert_allclose(b.camera.center, a.camera.center + shift, atol=1e-5)
    assert b.focal_sd == pytest.approx(a.focal_sd, rel=1e-5)
    np.testing.assert_allclose(Q.pair_ground_errors(b), Q.pair_ground_errors(a), atol=1e-6)
