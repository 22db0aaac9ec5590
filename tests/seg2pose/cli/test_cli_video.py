"""The video commands end to end on a tiny rendered scene: new-scene, masks-from-video, track,
import-detections; bad input as one line."""

import json
import sys

import pytest
from typer.testing import CliRunner
from video_fixtures import calibration, det, rle, single_threaded_opencv, write_folder

from seg2pose.io.mots import read_mots

opencv_one_thread = pytest.fixture(autouse=True)(single_threaded_opencv)


def test_video_commands(tmp_path, monkeypatch, capsys):
    from seg2pose.cli import app, main

    calibration(tmp_path)
    boxes = [dict(id=1, x=10, y=60, w=10, h=24, vx=2, vy=0)]
    write_folder(tmp_path / "frames", 20, boxes)
    run = CliRunner().invoke
    sc = str(tmp_path / "sc")
    r = run(app, ["new-scene", "-o", sc, "--video", f"c0={tmp_path / 'frames'}", "--calibration",
                  str(tmp_path / "calib.json"), "--ground", str(tmp_path / "ground.csv"), "--fps", "10"])
    assert r.exit_code == 0, r.output
    assert "1 cameras (c0 160x120, 20 frames)" in r.output
    r = run(app, ["masks-from-video", sc, "--no-progress", "--set", "min_area=40", "--set", "init_samples=8"])
    assert r.exit_code == 0, r.output
    assert "c0: 20 frames -> 20 masks -> 1 tracks (20 masks)" in r.output
    t = read_mots(tmp_path / "sc" / "masks" / "c0.txt")
    assert set(t.track_id.tolist()) == {1} and len(t) == 20
    # the scene runs end to end: world tracks from the video's masks
    r = run(app, ["run", sc, "-o", str(tmp_path / "run"), "--baseline", "-c", "mono-c0"])
    assert r.exit_code == 0, r.output
    from seg2pose.io.run import read_run_poses
    poses = read_run_poses(tmp_path / "run")
    assert len(poses) == 20 and set(poses.track_id.tolist()) == {1}
    r = run(app, ["track", sc, "--no-progress", "--set", "min_length=30"])
    assert r.exit_code == 0 and "c0: 0 tracks, 0 masks" in r.output
    (tmp_path / "d.json").write_text(json.dumps([det(f, 1, rle(10, 10, 8, 20)) for f in range(8)]))
    r = run(app, ["import-detections", sc, str(tmp_path / "d.json"), "--camera", "c0", "--force"])
    assert r.exit_code == 0, r.output
    assert "wrote 8 masks" in r.output
    # bad input: one line naming the file and what was expected
    (tmp_path / "late.json").write_text(json.dumps([det(25, 1, rle(10, 10, 8, 20))]))
    monkeypatch.setattr(sys, "argv", ["s2p", "import-detections", sc, str(tmp_path / "late.json"),
                                      "--camera", "c0", "--force"])
    with pytest.raises(SystemExit) as e:
        main()
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.count("\n") == 1
    assert "late.json: field 'image_id': frame 25 matches no video frame (the video has 20" in err
    r = run(app, ["masks-from-video", sc, "--set", "method=magic", "--force"])
    assert r.exit_code != 0 and "mog2 or knn" in str(r.exception)
