"""Cameras: projection conventions, project <-> unproject round trips, RQ decomposition of P."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from seg2pose.core.errors import InputError
from seg2pose.geometry.camera import Camera, OpenCVDistortion, Rig


def random_camera(seed: int, distortion: bool = False) -> Camera:
    rng = np.random.default_rng(seed)
    R = Rotation.random(random_state=seed).as_matrix()
    # with a lens, realistic fields of view (|x/z| < ~0.8) where the model is invertible
    fx, fy = rng.uniform(800 if distortion else 200, 2000, 2)
    if distortion:  # principal point near the centre, so the image stays where the lens is invertible
        cx, cy = rng.uniform(540, 740), rng.uniform(310, 410)
    else:
        cx, cy = rng.uniform(100, 1000), rng.uniform(100, 700)
    K = np.array([[fx, rng.uniform(-5, 5), cx], [0, fy, cy], [0, 0, 1]])
    d = OpenCVDistortion(*rng.uniform(-0.03, 0.03, 5)) if distortion else None
    return Camera("c", K, R, rng.normal(size=3) * 10, 1280, 720, d)


def test_pixel_convention_and_hand_projection():
    # camera at the origin looking along +y world: image x = world x, image y = -world z
    cam = Camera("c", [[100, 0, 50], [0, 100, 40], [0, 0, 1]],
                 [[1, 0, 0], [0, 0, -1], [0, 1, 0]], [0, 0, 0], 100, 80)
    uv, depth, front = cam.project_points([[1.0, 10.0, 2.0], [0, -5, 0]])
    assert np.allclose(uv[0], [50 + 10, 40 - 20]) and depth[0] == pytest.approx(10)
    assert front.tolist() == [True, False]
    assert np.allclose(cam.center, 0)
    # the principal point (50, 40) is the corner between pixels (row 39, col 49) and (40, 50)
    assert cam.in_image([[0, 0], [99.99, 79.99], [100, 5], [-0.01, 5]]).tolist() == [
        True, True, False, False]
    d = cam.unproject([[50, 40]])
    assert np.allclose(d, [[0, 1, 0]])


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1), st.booleans())
def test_project_unproject_round_trip(seed, distortion):
    cam = random_camera(seed, distortion)
    rng = np.random.default_rng(seed + 1)
    uv = rng.uniform([0, 0], [cam.width, cam.height], (50, 2))
    d = cam.unproject(uv)
    assert np.allclose(np.linalg.norm(d, axis=1), 1)
    depth = rng.uniform(0.5, 200, 50)
    X = cam.center + d * depth[:, None]
    uv2, dep, front = cam.project_points(X)
    assert front.all()
    assert np.allclose(uv2, uv, atol=1e-6 if distortion else 1e-8)
    # and the other way round: world points -> pixels -> rays through the points
    X = cam.center + rng.normal(size=(50, 3)) * 20
    uv, dep, front = cam.project_points(X)
    X, uv = X[front], uv[front]
    d = cam.unproject(uv)
    v = X - cam.center
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    # a lens model is not invertible far off-axis (points there fold back into the image);
    # check points inside the realistic field of view
    xc = X @ cam.R.T + cam.t
    near = (np.abs(xc[:, :2] / xc[:, 2:]) < 0.8).all(axis=1) if distortion else slice(None)
    assert np.allclose(d[near], v[near], atol=1e-6)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(-1e3, 1e3).filter(lambda s: abs(s) > 1e-3))
def test_rq_decomposition_round_trip(seed, scale):
    cam = random_camera(seed)
    P = cam.P * scale  # any non-zero scale, sign included
    c2 = Camera.from_P("c2", P, cam.width, cam.height)
    assert c2.K[0, 0] > 0 and c2.K[1, 1] > 0 and c2.K[2, 2] == pytest.approx(1)
    assert np.linalg.det(c2.R) == pytest.approx(1)
    assert np.allclose(c2.K, cam.K, rtol=1e-8, atol=1e-6)
    assert np.allclose(c2.R, cam.R, atol=1e-9)
    assert np.allclose(c2.t, cam.t, atol=1e-7)
    assert np.allclose(c2.P * scale, P, rtol=1e-9, atol=1e-6 * abs(scale))


def test_from_P_rejects_bad_matrices():
    with pytest.raises(InputError, match="3x4"):
        Camera.from_P("c", np.eye(3), 10, 10)
    with pytest.raises(InputError, match="rank < 3"):
        Camera.from_P("c", np.array([[1, 0, 0, 1], [0, 1, 0, 0], [1, 1, 0, 0.0]]), 10, 10)
    with pytest.raises(InputError, match="NaN or inf"):
        Camera.from_P("c", np.array([[1, 0, 0, np.inf], [0, 1, 0, 0], [0, 0, 1, 0.0]]), 10, 10)
    with pytest.raises(InputError, match="positive"):
        Camera.from_P("c", np.hstack([np.eye(3), np.ones((3, 1))]), 0, 10)


def test_look_at_and_dict_round_trip():
    cam = Camera.look_at("c", [0, -10, 5], [0, 0, 0], 500, 640, 480,
                         distortion=OpenCVDistortion(k1=-0.1, p2=0.01))
    uv, _, _ = cam.project_points([[0, 0, 0]])
    assert np.allclose(uv, [[320, 240]])
    # world +x appears to the right, world up appears up
    uv, _, _ = cam.project_points([[1, 0, 0], [0, 0, 1]])
    assert uv[0, 0] > 320 and uv[1, 1] < 240
    down = Camera.look_at("d", [0, 0, 10], [0, 0, 0], 500, 640, 480)  # straight down: no NaN
    assert np.isfinite(down.R).all()
    c2 = Camera.from_dict(cam.to_dict())
    assert np.array_equal(c2.K, cam.K) and np.array_equal(c2.R, cam.R)
    assert c2.distortion == cam.distortion


def test_rig_configs():
    a = Camera.look_at("a", [0, -10, 5], [0, 0, 0], 500, 640, 480)
    b = Camera.look_at("b", [0.3, -10, 5], [0, 0, 0], 500, 640, 480)
    rig = Rig({"a": a, "b": b}, {"mono-1": ["a"], "stereo-30": ["a", "b"]})
    assert [c.name for c in rig.select("stereo-30")] == ["a", "b"]
    assert len(rig.select(None)) == 2
    assert np.allclose(rig.center, [0.15, -10, 5])
    with pytest.raises(InputError, match="unknown configuration"):
        rig.select("trinocular-T")
    with pytest.raises(InputError, match="unknown cameras"):
        Rig({"a": a}, {"x": ["a", "zz"]})
