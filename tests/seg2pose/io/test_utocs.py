"""UTOCS import: a tiny CARLA-style recording, imported and checked against CARLA's own camera
model (written out here independently from the formulas of the issue)."""

import json
import math

import numpy as np
import pytest

from seg2pose.core.errors import InputError, S2PError
from seg2pose.io.poses import read_poses
from seg2pose.io.scene import load_scene
from seg2pose.io.utocs import carla_rotation, default_splits, import_utocs

F, CX, CY = 400.0, 160.0, 120.0
CAMS = [
    {"id": 0, "x": -12.0, "y": 3.0, "z": 6.0, "pitch": -25.0, "roll": 0.0, "yaw": 20.0},
    {"id": 1, "x": 10.0, "y": -8.0, "z": 5.0, "pitch": -20.0, "roll": 3.0, "yaw": 140.0},
]
USERS = [  # CARLA (left-handed) bottom centres
    {"type": "car", "id": 7, "x": 1.0, "y": 2.0, "z": 0.1, "l": 4.5, "w": 1.8, "h": 1.5,
     "forward_x": 0.6, "forward_y": 0.8, "speed": 3.0},
    {"type": "Pedestrian", "id": 9, "x": -2.0, "y": 4.0, "z": 0.0, "l": 0.5, "w": 0.5, "h": 1.8,
     "forward_x": -1.0, "forward_y": 0.0},
    {"type": "truck", "id": 11, "x": 3.0, "y": -3.0, "z": 0.0, "l": 8.0, "w": 2.5, "h": 3.2,
     "forward_x": 0.0, "forward_y": -1.0},
]


def carla_project(cam: dict, X_ue: np.ndarray) -> np.ndarray:
    """CARLA's pinhole: camera looks along local +x, image right = +y, image down = -z."""
    R = carla_rotation(cam["pitch"], cam["roll"], cam["yaw"])
    xl = R.T @ (X_ue - np.array([cam["x"], cam["y"], cam["z"]]))
    assert xl[0] > 0
    return np.array([F * xl[1] / xl[0] + CX, -F * xl[2] / xl[0] + CY])


def test_carla_rotation_is_a_rotation():
    R = carla_rotation(-25, 7, 130)
    assert np.allclose(R @ R.T, np.eye(3)) and np.linalg.det(R) == pytest.approx(1.0)
    # yaw 90: the camera's forward (local x) is the world's +y in Unreal
    assert np.allclose(carla_rotation(0, 0, 90)[:, 0], [0, 1, 0])


@pytest.fixture
def utocs(tmp_path):
    src = tmp_path / "utocs"
    (src / "positions").mkdir(parents=True)
    (src / "cameras.json").write_text(json.dumps({"instrinsics": {"f": F, "Cx": CX, "Cy": CY},
                                                  "cams": CAMS}))
    g = [(x, y, 0.05 * x) for x in range(-10, 11, 5) for y in range(-10, 11, 5)]
    (src / "ground_points.txt").write_text("\n".join(f"{x},{y},{z}" for x, y, z in g) + "\n")
    for frame in (0, 1, 2):
        users = [dict(u, x=u["x"] + 0.5 * frame) for u in USERS]
        (src / "positions" / f"{frame:06d}.json").write_text(json.dumps(users))
    import cv2
    (src / "images" / "cam0").mkdir(parents=True)
    for frame in (0, 1, 2):
        cv2.imwrite(str(src / "images" / "cam0" / f"{frame:06d}.jpg"),
                    np.full((int(2 * CY), int(2 * CX), 3), 80, np.uint8))
    return src


def test_import_projects_like_carla(utocs, tmp_path):
    out = tmp_path / "scene"
    import_utocs(utocs, out, log=lambda *a: None)
    scene = load_scene(out)
    assert sorted(scene.cameras) == ["cam0", "cam1"]
    assert {c.name for c in scene.classes} >= {"pedestrian", "car", "truck"}
    gt = read_poses(out / "gt" / "poses.csv", {c.name for c in scene.classes})
    assert len(gt) == 9 and gt.size is not None
    for cam_d in CAMS:
        cam = scene.cameras[f"cam{cam_d['id']}"]
        assert (cam.width, cam.height) == (320, 240)
        for frame in (0, 2):
            for u in USERS:
                row = np.flatnonzero((gt.frame == frame) & (gt.track_id == u["id"]))[0]
                X_ue = np.array([u["x"] + 0.5 * frame, u["y"], u["z"]])
                # the box centre and a point 2 m ahead along the heading
                for lift, ahead in ((0.0, 0.0), (u["h"] / 2, 0.0), (0.0, 2.0)):
                    fwd = np.array([u["forward_x"], u["forward_y"], 0.0])
                    p_ue = X_ue + [0, 0, lift] + ahead * fwd / np.linalg.norm(fwd)
                    h = gt.heading[row]
                    p_rh = gt.xyz[row] + [0, 0, lift] + ahead * np.array([math.cos(h), math.sin(h), 0])
                    uv, _, front = cam.project_points(p_rh[None])
                    assert front[0]
                    assert np.allclose(uv[0], carla_project(cam_d, p_ue), atol=1e-9)
    car = np.flatnonzero(gt.track_id == 7)[0]
    assert gt.cls[car] == "car" and np.allclose(gt.size[car], [4.5, 1.8, 1.5])
    assert gt.heading[car] == pytest.approx(math.atan2(-0.8, 0.6))
    assert np.allclose(scene.ground_points[:, 1], -np.array(
        [y for x in range(-10, 11, 5) for y in range(-10, 11, 5)], float))
    # frames came along for cam0 only
    assert sorted(p.name for p in (out / "video" / "cam0").iterdir()) == [
        "000000.jpg", "000001.jpg", "000002.jpg"]
    assert scene.video_path("cam0") is not None and scene.video_path("cam1") is None


def test_import_refuses_overwrite_and_bad_input(utocs, tmp_path):
    out = tmp_path / "scene"
    import_utocs(utocs, out, log=lambda *a: None)
    with pytest.raises(S2PError, match="--force"):
        import_utocs(utocs, out, log=lambda *a: None)
    import_utocs(utocs, out, force=True, log=lambda *a: None)
    (utocs / "positions" / "000001.json").write_text(json.dumps([{**USERS[0], "x": "a"}]))
    with pytest.raises(InputError, match=r"000001.json: field '\[0\].x': expected a finite number"):
        import_utocs(utocs, tmp_path / "s2", log=lambda *a: None)
    (utocs / "cameras.json").write_text(json.dumps({"intr": {}, "cams": CAMS}))
    with pytest.raises(InputError, match=r"cameras.json: field 'instrinsics'"):
        import_utocs(utocs, tmp_path / "s3", log=lambda *a: None)


def test_default_splits():
    s = default_splits(np.arange(0, 1000))
    assert s == {"train": (0, 232), "val": (383, 615), "test": (766, 999)}
    assert default_splits(np.arange(0, 9)) == {"train": (0, 2), "val": (3, 5), "test": (6, 8)}


def test_cli_import(utocs, tmp_path):
    from typer.testing import CliRunner

    from seg2pose.cli import app

    r = CliRunner().invoke(app, ["import-utocs", str(utocs), "-o", str(tmp_path / "sc"), "--no-frames",
                                 "--start-time", "2021-06-14T10:00:00+02:00"])
    assert r.exit_code == 0, r.output
    assert "imported 2 cameras" in r.output
    assert not (tmp_path / "sc" / "video").exists()
    from seg2pose.io.scene import load_scene

    assert load_scene(tmp_path / "sc").start_time_ns == 1623657600 * 10**9  # 08:00 UTC


from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.floats() | st.text(max_size=5),
    lambda kids: st.lists(kids, max_size=4) | st.dictionaries(st.text(max_size=6), kids, max_size=4),
    max_leaves=15)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.sampled_from(["cameras", "position", "record", "bytes"]), json_values, st.binary(max_size=100))
def test_fuzz_utocs_inputs_raise_own_errors(utocs, tmp_path, where, value, data):
    from seg2pose.io.utocs import read_cameras_json, read_positions

    if where == "cameras":
        d = {"instrinsics": {"f": F, "Cx": CX, "Cy": CY}, "cams": [dict(CAMS[0])]}
        d["cams"][0]["pitch"] = value
        (utocs / "cameras.json").write_text(json.dumps(d))
    elif where == "position":
        (utocs / "positions" / "000001.json").write_text(json.dumps(value))
    elif where == "record":
        (utocs / "positions" / "000001.json").write_text(json.dumps([{**USERS[0], "id": value}]))
    else:
        (utocs / "positions" / "000001.json").write_bytes(data)
    try:
        read_cameras_json(utocs / "cameras.json")
        read_positions(utocs / "positions")
    except S2PError:
        pass
