"""T-Analyst .tacal calibrations: Tsai's model through the camera's Distortion protocol, checked
against the defining formulas (hand-written numbers and a bisection reference), the file's
reader and writer, and a scene that stores such a camera."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from seg2pose.core.errors import InputError
from seg2pose.geometry.camera import Camera, TsaiDistortion
from seg2pose.io.tacal import (
    TACAL_FIELDS,
    Tacal,
    camera_to_tacal,
    format_tacal,
    parse_tacal,
    read_tacal,
    tacal_to_camera,
    write_tacal,
)

# the camera looks along world +y: camera x = world x, camera y = -world z, camera z = world y
R_Y = [1, 0, 0, 0, 0, -1, 0, 1, 0]
HAND = Tacal(dx=0.01, dy=0.01, Cx=640, Cy=360, Sx=1.0, f=10.0, k=0.001, Tx=0.5, Ty=1.5, Tz=4.0,
             **{f"r{i + 1}": float(v) for i, v in enumerate(R_Y)})


def formula_pixels(cal: Tacal, X: np.ndarray) -> np.ndarray:
    """The .tacal formulas, the distortion solved by bisection on the radius (a reference
    that shares nothing with the camera model's Newton iteration)."""
    X = np.asarray(X, float).reshape(-1, 3)
    Xc = X @ cal.R.T + cal.T
    out = []
    for xc, yc, zc in Xc:
        Xu, Yu = cal.f * xc / zc, cal.f * yc / zc
        ru = np.hypot(Xu, Yu)
        lo, hi = 0.0, ru * 1.5 + 1e-12
        for _ in range(200):  # rd (1 + k rd²) = ru, increasing on [0, hi] for these lenses
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if mid * (1 + cal.k * mid * mid) < ru else (lo, mid)
        s = lo / ru if ru > 0 else 1.0
        out.append([cal.Sx * Xu * s / cal.dx + cal.Cx, Yu * s / cal.dy + cal.Cy])
    return np.array(out)


def formula_rays(cal: Tacal, uv: np.ndarray) -> np.ndarray:
    """Back-projection by the formulas: pixel -> distorted -> undistorted sensor point -> ray."""
    uv = np.asarray(uv, float).reshape(-1, 2)
    Xd = (uv[:, 0] - cal.Cx) * cal.dx / cal.Sx
    Yd = (uv[:, 1] - cal.Cy) * cal.dy
    g = 1 + cal.k * (Xd ** 2 + Yd ** 2)
    d = np.stack([Xd * g, Yd * g, np.full(len(uv), cal.f)], axis=1) @ cal.R  # Rᵀ d per row
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_hand_computed_projection_and_back_projection():
    # distorted sensor point (0.5, -1.0) mm: rd² = 1.25, so the undistorted one is 1.00125 times
    # it, (0.500625, -1.00125) mm; at Zc = 20 m and f = 10 mm that is Xc = 1.00125, Yc = -2.0025.
    # Xc - T = (0.50125, -3.5025, 16) and X = Rᵀ (Xc - T):
    cam = tacal_to_camera(HAND, "c0", 1280, 720)
    X = np.array([[0.50125, 16.0, 3.5025]])
    uv, depth, front = cam.project_points(X)
    # u = Sx Xd / dx + Cx = 0.5 / 0.01 + 640, v = Yd / dy + Cy = -1.0 / 0.01 + 360
    assert np.abs(uv - [[690.0, 260.0]]).max() < 1e-9 and depth[0] == pytest.approx(20.0)
    ray = cam.unproject([[690.0, 260.0]])[0]
    v = X[0] - cam.center
    assert np.allclose(ray, v / np.linalg.norm(v), atol=1e-12)


def test_hand_computed_pincushion_anisotropic():
    # k < 0, dx != dy, Sx != 1, R = I, T = 0: distorted point (-2, 1.5) mm has rd² = 6.25,
    # factor 1 - 0.002 * 6.25 = 0.9875, undistorted (-1.975, 1.48125) mm; at Zc = 10 and f = 8:
    cal = Tacal(dx=0.0086, dy=0.0083, Cx=320, Cy=240, Sx=1.02, f=8.0, k=-0.002, Tx=0, Ty=0, Tz=0,
                r1=1, r2=0, r3=0, r4=0, r5=1, r6=0, r7=0, r8=0, r9=1)
    cam = tacal_to_camera(cal, "c")
    assert (cam.width, cam.height) == (640, 480)
    uv, _, _ = cam.project_points([[-2.46875, 1.8515625, 10.0]])
    expect = [320 + 1.02 * -2 / 0.0086, 240 + 1.5 / 0.0083]  # 82.7907.., 420.7229..
    assert np.abs(uv[0] - expect).max() < 1e-9
    assert np.allclose(cam.unproject([expect])[0],
                       np.array([-2.46875, 1.8515625, 10.0]) / np.linalg.norm([-2.46875, 1.8515625, 10.0]))


def random_tacal(seed: int) -> Tacal:
    rng = np.random.default_rng(seed)
    R = Rotation.random(random_state=seed).as_matrix()
    f = rng.uniform(4, 25)  # mm
    dx, dy = rng.uniform(0.003, 0.012, 2)
    cx, cy = rng.uniform(300, 700), rng.uniform(200, 400)
    # |k rd²| <= 0.2 at the farthest image corner: well inside the range where the lens does
    # not fold over (k rd² > -1/3), so every pixel is the image of one ray
    rd2 = max((a * dx) ** 2 for a in (cx, 1280 - cx)) + max((b * dy) ** 2 for b in (cy, 720 - cy))
    k = rng.uniform(-0.2, 0.2) / rd2
    return Tacal(dx=dx, dy=dy, Cx=cx, Cy=cy,
                 Sx=rng.uniform(0.95, 1.05), f=f, k=k, Tx=rng.normal() * 10, Ty=rng.normal() * 10,
                 Tz=rng.uniform(5, 30), **{f"r{i + 1}": float(v) for i, v in enumerate(R.ravel())})


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_camera_matches_formulas_within_a_hundredth_of_a_pixel(seed):
    cal = random_tacal(seed)
    cam = tacal_to_camera(cal, "c", 1280, 720)
    rng = np.random.default_rng(seed + 1)
    # world points seen within a 6 mm radius on the sensor
    uv = rng.uniform([0, 0], [1280, 720], (30, 2))
    rays = formula_rays(cal, uv)
    assert np.abs(cam.unproject(uv) - rays).max() < 1e-9
    X = cam.center + rays * rng.uniform(1, 150, (30, 1))
    got, _, front = cam.project_points(X)
    assert front.all()
    assert np.abs(got - formula_pixels(cal, X)).max() < 0.01
    assert np.abs(got - uv).max() < 1e-6  # Newton is far better than the requirement


def test_rounded_rotation_is_accepted_and_still_projects_like_the_file():
    cal = random_tacal(7)
    rounded = Tacal(**{n: (round(getattr(cal, n), 6) if n.startswith("r") else getattr(cal, n))
                       for n in TACAL_FIELDS})
    cam = tacal_to_camera(rounded, "c", 1280, 720)  # R Rᵀ = I only to ~1e-6: made a rotation
    X = cam.center + cam.unproject(np.array([[100.0, 100], [640, 360], [1200, 700]])) * 60
    assert np.abs(cam.project_points(X)[0] - formula_pixels(rounded, X)).max() < 0.01
    bad = Tacal(**{**{n: getattr(cal, n) for n in TACAL_FIELDS}, "r1": cal.r1 + 0.1})
    with pytest.raises(InputError, match="not a rotation"):
        tacal_to_camera(bad, "c", 1280, 720)


def test_pincushion_fold_gives_nan_not_a_wrong_pixel():
    d = TsaiDistortion(k=-0.01, f=1.0)  # κ = -0.01: folds at r² = 4 / 27 / 0.01 = 14.8
    xy = d.distort(np.array([[3.0, 0.0], [4.0, 0.0]]))
    assert np.allclose(d.undistort(xy[:1]), [[3.0, 0.0]], atol=1e-12)
    assert np.isnan(xy[1]).all()


def test_file_round_trip_and_camera_round_trip(tmp_path):
    text = format_tacal(HAND)
    assert text.splitlines()[:3] == ["dx: 0.01", "dy: 0.01", "Cx: 640.0"] and len(text.splitlines()) == 19
    write_tacal(tmp_path / "c0.tacal", HAND)
    assert read_tacal(tmp_path / "c0.tacal") == HAND
    back = camera_to_tacal(tacal_to_camera(HAND, "c0", 1280, 720))
    for n in TACAL_FIELDS:
        assert getattr(back, n) == pytest.approx(getattr(HAND, n), rel=1e-14, abs=1e-15), n
    # a camera from elsewhere (no lens model) writes as a pixel-unit sensor and projects the same
    cam = Camera.look_at("s", [0, -20, 8], [0, 10, 0], 900, 1280, 720)
    cam2 = tacal_to_camera(camera_to_tacal(cam), "s", 1280, 720)
    X = np.random.default_rng(0).normal(size=(20, 3)) * 5 + [0, 10, 0]
    assert np.abs(cam.project_points(X)[0] - cam2.project_points(X)[0]).max() < 1e-8


def test_reader_accepts_any_order_blank_lines_and_decimal_commas():
    lines = format_tacal(HAND).splitlines()
    text = "\ufeff" + "\n".join(reversed(lines)).replace("dx: 0.01", "dx : 0,01") + "\n\n"
    assert parse_tacal(text) == HAND


@pytest.mark.parametrize("edit, line, message", [
    (lambda ls: ls[:6] + ls[7:], None, "missing field.*'k'|missing field\\(s\\) k"),
    (lambda ls: ls[:4] + ["Sx: one"] + ls[5:], 5, "expected a number for 'Sx'"),
    (lambda ls: ls[:9] + ["Tz: nan"] + ls[10:], 10, "NaN or inf"),
    (lambda ls: ls + ["dx: 0.02"], 20, "'dx' given twice \\(first on line 1\\)"),
    (lambda ls: ["kappa: 0.1"] + ls, 1, "unknown field 'kappa'"),
    (lambda ls: ls[:2] + ["Cx 640"] + ls[3:], 3, "expected 'name: value'"),
    (lambda ls: ls[:5] + ["f: -8"] + ls[6:], 6, "'f' must be positive"),
])
def test_reader_errors_name_the_line(tmp_path, edit, line, message):
    p = tmp_path / "bad.tacal"
    p.write_text("\n".join(edit(format_tacal(HAND).splitlines())) + "\n")
    with pytest.raises(InputError, match=message) as e:
        read_tacal(p)
    assert e.value.file == str(p) and e.value.line == line
    if line is not None:
        assert str(e.value).startswith(f"{p}:{line}:")
    else:
        assert e.value.field == "k"


def test_cameras_a_tacal_cannot_hold():
    from seg2pose.geometry.camera import OpenCVDistortion

    cam = Camera.look_at("s", [0, -20, 8], [0, 10, 0], 900, 1280, 720,
                         distortion=OpenCVDistortion(k1=0.1))
    with pytest.raises(InputError, match="'opencv' lens distortion"):
        camera_to_tacal(cam)
    skew = Camera("k", [[900, 3, 640], [0, 900, 360], [0, 0, 1]], np.eye(3), [0, 0, 5], 1280, 720)
    with pytest.raises(InputError, match="skew"):
        camera_to_tacal(skew)


def test_scene_json_stores_a_tsai_camera(tmp_path):
    from seg2pose.geometry.camera import Rig
    from seg2pose.io.scene import Scene, load_scene

    cam = tacal_to_camera(HAND, "c0", 1280, 720)
    ground = np.array([[x, y, 0.01 * x] for x in (-20, 0, 20) for y in (0, 20, 40)], float)
    Scene(tmp_path, "t", 15.0, Rig({"c0": cam}, {"all": ["c0"]}), ground,
          [], extra={}).save()
    back = load_scene(tmp_path).cameras["c0"]
    assert isinstance(back.distortion, TsaiDistortion) and back.distortion == cam.distortion
    X = np.array([[0.50125, 16.0, 3.5025], [3, 30, 1]])
    assert np.array_equal(back.project_points(X)[0], cam.project_points(X)[0])
    # validated: a Tsai lens needs a positive f
    import json

    d = json.loads((tmp_path / "scene.json").read_text())
    d["cameras"][0]["distortion"]["f"] = 0
    (tmp_path / "scene.json").write_text(json.dumps(d))
    with pytest.raises(InputError, match="f must be positive") as e:
        load_scene(tmp_path)
    assert e.value.file == str(tmp_path / "scene.json")
    assert e.value.field.endswith("distortion.f") and "cameras[" in e.value.field


def test_scene_from_tacal_files(tmp_path):
    from seg2pose.io.scene import load_scene, write_ground_points
    from seg2pose.io.tacal import scene_from_tacals

    write_tacal(tmp_path / "north.tacal", HAND)
    write_tacal(tmp_path / "south.tacal", random_tacal(3))
    ground = np.array([[x, y, 0.0] for x in (-20, 0, 20) for y in (0, 20, 40)], float)
    write_ground_points(tmp_path / "g.csv", ground)
    out = tmp_path / "scene"
    scene_from_tacals([tmp_path / "north.tacal", tmp_path / "south.tacal"], tmp_path / "g.csv",
                      out, fps=15.0)
    s = load_scene(out)
    assert list(s.cameras) == ["north", "south"] and s.fps == 15.0
    assert s.rig.configs == {"north": ["north"], "south": ["south"], "all": ["north", "south"]}
    assert (s.cameras["north"].width, s.cameras["north"].height) == (1280, 720)
    X = np.array([[0.50125, 16.0, 3.5025]])
    assert np.abs(s.cameras["north"].project_points(X)[0] - [[690, 260]]).max() < 1e-9
    assert np.array_equal(s.ground_points, ground)
    with pytest.raises(Exception, match="exists"):
        scene_from_tacals([tmp_path / "north.tacal"], tmp_path / "g.csv", out, fps=15.0)
    scene_from_tacals([tmp_path / "north.tacal"], tmp_path / "g.csv", out, fps=25.0,
                      size=(1920, 1080), force=True)
    assert load_scene(out).cameras["north"].width == 1920
    (tmp_path / "all.tacal").write_text(format_tacal(HAND))
    with pytest.raises(InputError, match="cannot be named 'all'"):
        scene_from_tacals([tmp_path / "all.tacal"], tmp_path / "g.csv", tmp_path / "s2", fps=15.0)
