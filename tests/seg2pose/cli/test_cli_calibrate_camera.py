"""``s2p calibrate-camera --points``: the writer's promises (atomic outputs, --force, the lock,
one-line errors), calib.json read by ``s2p new-scene``, a scene's next calibration version,
and the renamed ``s2p calibrate-errors`` with its deprecated alias."""

from __future__ import annotations

import json

import numpy as np
from scene_fixtures import s2p
from video_fixtures import H, W, calibration, write_folder

from seg2pose.core.locks import LockHolder
from seg2pose.geometry.camera import Camera
from seg2pose.io.atomic_names import lock_path
from seg2pose.io.scene import load_scene


def truth() -> Camera:
    """The camera of video_fixtures.calibration (160x120, f 150 px, 8 m up)."""
    return Camera.look_at("c0", np.array([0.0, -10.0, 8.0]), np.array([0.0, 10.0, 0.0]), 150.0, W, H)


def write_pairs(path, cam: Camera, n: int = 8, u_first: float | None = None) -> None:
    """n exact pairs on z = 0 (a 2 x 4 grid of ground points in view), z empty for the first."""
    xs, ys = np.meshgrid([-3.0, 3.0], [0.5, 4.0, 9.0, 18.0])
    X = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(8)])[:n]
    uv = cam.project_points(X)[0]
    if u_first is not None:
        uv[0, 0] = u_first
    rows = ["camera,u,v,x,y,z"] + [f"c0,{u!r},{v!r},{x!r},{y!r},{'' if i == 0 else '0.0'}"
                                   for i, ((u, v), (x, y, _)) in enumerate(zip(uv.tolist(), X.tolist(),
                                                                               strict=True))]
    path.write_text("\n".join(rows) + "\n")


def test_pairs_to_calib_json_to_new_scene(tmp_path, monkeypatch, capsys):
    cam = truth()
    write_folder(tmp_path / "frames", 3, [])
    write_pairs(tmp_path / "pairs.csv", cam)
    out = tmp_path / "cal" / "calib.json"
    code, text, err = s2p(monkeypatch, capsys, "calibrate-camera", tmp_path / "frames", "--points",
                          tmp_path / "pairs.csv", "-o", out)
    assert code == 0, err
    assert "camera c0: focal 150.0 px" in text and "ground: plane through 7 elevations: slope 0.0 %" in text
    for name in ("calib.json", "calib.ground.csv", "calib.report.txt", "calib.c0.png"):
        assert (tmp_path / "cal" / name).is_file()
    rep = json.loads(out.read_text())["report"]
    assert rep["cameras"]["c0"]["pairs_used"] == 8
    # a second run refuses to replace, --force replaces
    code, _, err = s2p(monkeypatch, capsys, "calibrate-camera", "--points", tmp_path / "pairs.csv",
                       "--image-size", f"{W}x{H}", "-o", out)
    assert code == 2 and "exists; pass --force" in err and len(err.strip().splitlines()) == 1
    code, _, err = s2p(monkeypatch, capsys, "calibrate-camera", "--points", tmp_path / "pairs.csv",
                       "--image-size", f"{W}x{H}", "-o", out, "--force")
    assert code == 0, err
    # new-scene reads it: the truth camera back
    code, _, err = s2p(monkeypatch, capsys, "new-scene", "-o", tmp_path / "scene", "--video",
                       f"c0={tmp_path / 'frames'}", "--calibration", out, "--ground",
                       tmp_path / "cal" / "calib.ground.csv", "--fps", "10")
    assert code == 0, err
    got = load_scene(tmp_path / "scene").cameras["c0"]
    np.testing.assert_allclose(got.K, cam.K, atol=1e-6)
    np.testing.assert_allclose(got.R, cam.R, atol=1e-8)
    np.testing.assert_allclose(got.t, cam.t, atol=1e-6)


def test_a_scene_gets_a_new_calibration_version(tmp_path, monkeypatch, capsys):
    calibration(tmp_path)
    write_folder(tmp_path / "frames", 3, [])
    code, _, err = s2p(monkeypatch, capsys, "new-scene", "-o", tmp_path / "scene", "--video",
                       f"c0={tmp_path / 'frames'}", "--calibration", tmp_path / "calib.json",
                       "--ground", tmp_path / "ground.csv", "--fps", "10")
    assert code == 0, err
    before = (tmp_path / "scene" / "scene.json").read_text()
    moved = Camera.look_at("c0", np.array([0.5, -10.0, 8.5]), np.array([0.0, 10.0, 0.0]), 160.0, W, H)
    write_pairs(tmp_path / "pairs.csv", moved)
    code, _, err = s2p(monkeypatch, capsys, "calibrate-camera", tmp_path / "scene", "--points",
                       tmp_path / "pairs.csv")
    assert code == 2 and "--force replaces them as the scene's next calibration version" in err
    assert (tmp_path / "scene" / "scene.json").read_text() == before  # never a silent change
    code, text, err = s2p(monkeypatch, capsys, "calibrate-camera", tmp_path / "scene", "--points",
                          tmp_path / "pairs.csv", "--force")
    assert code == 0, err
    assert "focal 150.0 -> 160.0 px" in text and "calibration version 1" in text
    v1 = tmp_path / "scene" / "calibrations" / "v1"
    assert (v1 / "scene-before.json").read_text() == before
    assert {p.name for p in v1.iterdir()} == {"scene-before.json", "calib.json", "report.txt", "c0.png"}
    s = load_scene(tmp_path / "scene")
    np.testing.assert_allclose(s.cameras["c0"].center, moved.center, atol=1e-6)
    assert s.extra["calibration"]["version"] == 1
    code, text, err = s2p(monkeypatch, capsys, "calibrate-camera", tmp_path / "scene", "--points",
                          tmp_path / "pairs.csv", "--force")
    assert code == 0 and "calibration version 2" in text
    assert load_scene(tmp_path / "scene").extra["calibration"]["history"] == ["calibrations/v1",
                                                                              "calibrations/v2"]


def test_bad_input_one_line(tmp_path, monkeypatch, capsys):
    cam = truth()
    cases = [(dict(u_first=500.0), "outside the 160x120 image"), (dict(n=5), "5 pairs, at least 6 needed")]
    for kw, msg in cases:
        write_pairs(tmp_path / "pairs.csv", cam, **kw)
        code, _, err = s2p(monkeypatch, capsys, "calibrate-camera", "--points", tmp_path / "pairs.csv",
                           "--image-size", f"{W}x{H}", "-o", tmp_path / "c.json")
        assert code == 2 and msg in err and len(err.strip().splitlines()) == 1, err
    (tmp_path / "line.csv").write_text("".join(f"c0,{20 + 10 * i},{30 + 5 * i},{i},{2 * i},0\n" for i in range(8)))
    code, _, err = s2p(monkeypatch, capsys, "calibrate-camera", "--points", tmp_path / "line.csv",
                       "--image-size", f"{W}x{H}", "-o", tmp_path / "c.json")
    assert code == 2 and "lie on one line" in err
    code, _, err = s2p(monkeypatch, capsys, "calibrate-camera", "--points", tmp_path / "pairs.csv",
                       "--image-size", "160by120", "-o", tmp_path / "c.json")
    assert code == 2 and "--image-size" in err
    assert not (tmp_path / "c.json").exists()


def test_the_output_lock(tmp_path, monkeypatch, capsys):
    import os

    write_pairs(tmp_path / "pairs.csv", truth())
    out = tmp_path / "calib.json"
    lock = lock_path(out)
    h = LockHolder.me("seconds")
    lock.write_text(h.to_json())  # a live writer (this process) holds calib.json
    code, _, err = s2p(monkeypatch, capsys, "calibrate-camera", "--points", tmp_path / "pairs.csv",
                       "--image-size", f"{W}x{H}", "-o", out)
    assert code == 2 and f"being written by process {os.getpid()}" in err
    assert not out.exists()


def test_calibrate_is_renamed(monkeypatch, capsys):
    code, out, _ = s2p(monkeypatch, capsys, "--help")
    assert "calibrate-camera" in out and "calibrate-errors" in out
    code, _, err = s2p(monkeypatch, capsys, "calibrate", "/nonexistent-scene", "--run", "/nonexistent-run")
    assert "`s2p calibrate` is now `s2p calibrate-errors`" in err


def test_from_traffic_needs_a_scene(tmp_path, monkeypatch, capsys):
    write_folder(tmp_path / "frames", 2, [])
    code, _, err = s2p(monkeypatch, capsys, "calibrate-camera", tmp_path / "frames", "--from-traffic",
                       "-o", tmp_path / "t.json")
    assert code == 2 and "--from-traffic needs a scene folder with masks" in err
