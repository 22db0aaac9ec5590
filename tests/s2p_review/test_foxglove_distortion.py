"""Tsai cameras (T-Analyst .tacal) in Foxglove: their distortion is written as plumb_bob
k1..k3 fitted to the Tsai curve over the image, or refused when no fit is within tolerance."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from s2p_review import foxglove as F
from seg2pose.core.errors import InputError
from seg2pose.geometry.camera import OpenCVDistortion
from seg2pose.io.atomic import atomic_write_text
from seg2pose.io.tacal import Tacal, tacal_to_camera

R_Y = [1, 0, 0, 0, 0, -1, 0, 1, 0]  # looking along world +y
# f = 10 mm, k = 0.001 / mm^2, 0.01 mm pixels: kappa = k f^2 = 0.1 on normalised coordinates,
# 1000 px focal length; an image corner is 0.73 (normalised) from the centre
MODERATE = Tacal(dx=0.01, dy=0.01, Cx=640, Cy=360, Sx=1.0, f=10.0, k=0.001, Tx=0.5, Ty=1.5,
                 Tz=4.0, **{f"r{i + 1}": float(v) for i, v in enumerate(R_Y)})


def _points_in_view(cam, n=4000, seed=0):
    """World points (n, 3) whose Tsai projection lands inside the image."""
    rng = np.random.default_rng(seed)
    uv = rng.uniform([0, 0], [cam.width, cam.height], (n, 2))
    depth = rng.uniform(3.0, 60.0, n)
    rays = cam.unproject(uv)
    cos = rays @ cam.R[2]  # the depth per unit of ray length
    return cam.center + rays * (depth / cos)[:, None], uv


def test_fitted_plumb_bob_projects_like_tsai_within_the_tolerance():
    cam = tacal_to_camera(MODERATE, "c0", 1280, 720)
    fit = F.plumb_bob(cam)
    assert fit.fitted and fit.max_px < F.PLUMB_BOB_TOLERANCE_PX
    # the series inverse of Tsai's x_u = x_d (1 + kappa r_d^2): x_d = x_u (1 - kappa r^2 +
    # 3 kappa^2 r^4 - ...), so k1 is close to -kappa and k2 to 3 kappa^2
    assert abs(fit.D[0] + 0.1) < 0.005 and abs(fit.D[1] - 0.03) < 0.01 and fit.D[2:4] == (0.0, 0.0)
    X, uv = _points_in_view(cam)
    tsai_uv, _, front = cam.project_points(X)
    assert front.all()
    np.testing.assert_allclose(tsai_uv, uv, atol=1e-6)  # the reference: Tsai's own projection
    plumb = dataclasses.replace(cam, distortion=OpenCVDistortion(k1=fit.D[0], k2=fit.D[1], k3=fit.D[4]))
    plumb_uv, _, _ = plumb.project_points(X)
    err = np.linalg.norm(plumb_uv - tsai_uv, axis=1)
    assert err.max() < F.PLUMB_BOB_TOLERANCE_PX
    assert err.max() <= fit.max_px * 1.05 + 1e-6  # the reported error bounds what is seen
    # and the fit is worth having: with zero distortion (the old export) points land far off
    flat = dataclasses.replace(cam, distortion=None).project_points(X)[0]
    assert np.linalg.norm(flat - tsai_uv, axis=1).max() > 20.0


def test_a_wide_lens_no_plumb_bob_can_follow_is_refused_in_one_line():
    wide = dataclasses.replace(MODERATE, k=0.006)  # kappa 0.6: fisheye-like at the corners
    cam = tacal_to_camera(wide, "wide cam", 1280, 720)
    with pytest.raises(InputError) as e:
        F.plumb_bob(cam)
    msg = str(e.value)
    assert "'wide cam'" in msg and "plumb_bob within 0.5 px" in msg and "\n" not in msg


def test_opencv_and_no_distortion_pass_through_unchanged():
    cam = tacal_to_camera(MODERATE, "c0", 1280, 720)
    d = OpenCVDistortion(k1=-0.2, k2=0.05, p1=0.001, p2=-0.002, k3=0.01)
    fit = F.plumb_bob(dataclasses.replace(cam, distortion=d))
    assert fit.D == (-0.2, 0.05, 0.001, -0.002, 0.01) and not fit.fitted and fit.max_px == 0
    assert F.plumb_bob(dataclasses.replace(cam, distortion=None)).D == (0.0,) * 5


def test_export_writes_the_fitted_distortion_and_says_how_close(tmp_path):
    from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory
    from review_fixtures import make_run, make_scene

    from s2p_review.mcap_export import ExportOptions, export_mcap
    from seg2pose.io.scene import load_scene

    root = tmp_path / "scene"
    make_scene(root, n_frames=3)
    meta = json.loads((root / "scene.json").read_text())
    for cam in meta["cameras"]:
        cam["distortion"] = {"model": "tsai", "k": 0.001, "f": 10.0}
    atomic_write_text(root / "scene.json", json.dumps(meta))
    scene = load_scene(root)
    run = make_run(scene, root / "out" / "r")
    res = export_mcap(scene, run, tmp_path / "x.mcap", ExportOptions(video=False, layout=False))
    want = F.fit_plumb_bob(scene.cameras["c0"])
    assert any("c0" in n and "plumb_bob" in n and f"{want.max_px:.3f} px" in n for n in res.notes)
    with open(res.path, "rb") as f:
        cals = [m for _, ch, _, m in make_reader(f, decoder_factories=[DecoderFactory()])
                .iter_decoded_messages(topics=["/cameras/c0/calibration"])]
    assert len(cals) == 1 and type(cals[0]).__name__ == CameraCalibration.__name__
    np.testing.assert_allclose(list(cals[0].D), want.D, rtol=1e-12)
    assert cals[0].D[0] < 0  # barrel: Tsai's k > 0 pulls points in
