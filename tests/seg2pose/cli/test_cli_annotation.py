"""The ``s2p annotate`` family and ``s2p import-tacal`` through the command layer."""

from __future__ import annotations

import numpy as np
import pytest
from review_fixtures import make_scene
from scene_fixtures import s2p

CSV = "\n".join(["Detection ID;Type of road user;Road user ID;X (m);Y (m);Time Stamp",
                 "1;Car;3;-8;-1,5;07:30:00.000",
                 "2;Car;3;-5;-1,5;07:30:00.500",
                 "3;Pedestrian;7;1;2;07:30:00.200",
                 "4;Pedestrian;7;1;4;07:30:00.600"]) + "\n"


def test_annotate_scene_is_the_open_command_and_tanalyst_round_trip(monkeypatch, capsys, tmp_path):
    scene = make_scene(tmp_path / "scene", n_frames=20)
    (tmp_path / "t.csv").write_text(CSV)
    code, out, _ = s2p(monkeypatch, capsys, "annotate", "import-tanalyst", scene.root,
                       tmp_path / "t.csv", "--start", "07:30:00.000")
    assert code == 0 and "imported 4 detections of 2 road users as 4 keyframes (tracks 3, 7)" in out
    code, out, _ = s2p(monkeypatch, capsys, "annotate", scene.root, "--help")  # = open SCENE
    assert code == 0 and "Open the annotation app" in out
    code, out, _ = s2p(monkeypatch, capsys, "annotate", "status", scene.root)
    assert code == 0 and "2 tracks (1 car, 1 pedestrian), 4 keyframes, 1 journal records" in out
    code, out, _ = s2p(monkeypatch, capsys, "annotate", "export-tanalyst", scene.root, "-o",
                       tmp_path / "back.csv", "--keyframes-only", "--start", "07:30:00.000")
    assert code == 0 and (tmp_path / "back.csv").read_text() == CSV
    code, _, err = s2p(monkeypatch, capsys, "annotate", "export-tanalyst", scene.root, "-o",
                       tmp_path / "back.csv")
    assert code == 2 and "exists; pass --force" in err
    code, _, err = s2p(monkeypatch, capsys, "annotate", "import-tanalyst", scene.root,
                       tmp_path / "t.csv", "--start", "7:30")
    assert code == 2 and err.strip() == "error: field '--start': expected HH:MM:SS.mmm, got '7:30'"


def test_annotate_export_gt_and_tanalyst(monkeypatch, capsys, tmp_path):
    from seg2pose.io.poses import read_poses

    scene = make_scene(tmp_path / "scene", n_frames=20)
    (tmp_path / "t.csv").write_text(CSV)
    s2p(monkeypatch, capsys, "annotate", "import-tanalyst", scene.root, tmp_path / "t.csv",
        "--start", "07:30:00.000")
    code, _, err = s2p(monkeypatch, capsys, "annotate", "export", scene.root)
    assert code == 2 and "not an annotation export" in err and "--force" in err
    code, out, _ = s2p(monkeypatch, capsys, "annotate", "export", scene.root,
                       "--force", "--start", "07:30:00.000")
    assert code == 0
    gt = read_poses(scene.gt_path)
    assert gt.source.tolist().count("keyframe") == 4 and len(gt) == 6 + 5
    text = (scene.root / "export" / "tanalyst.csv").read_text().splitlines()
    row = text[2].split(";")  # frame 1 of the car: 0.6 m on from -8 m along its path
    assert len(text) == 1 + 11 and row[:3] == ["2", "Car", "3"] and row[5] == "07:30:00.100"
    assert float(row[3].replace(",", ".")) == pytest.approx(-7.4, abs=1e-9)


def test_import_tacal_command(monkeypatch, capsys, tmp_path):
    from seg2pose.io.scene import load_scene, write_ground_points

    (tmp_path / "east.tacal").write_text(
        "dx: 0.01\ndy: 0.01\nCx: 640\nCy: 360\nSx: 1\nf: 10\nk: 0.001\nTx: 0.5\nTy: 1.5\nTz: 4\n"
        "r1: 1\nr2: 0\nr3: 0\nr4: 0\nr5: 0\nr6: -1\nr7: 0\nr8: 1\nr9: 0\n")
    write_ground_points(tmp_path / "g.csv", np.array([[x, y, 0.0] for x in (-20, 0, 20)
                                                      for y in (0, 20, 40)]))
    code, out, _ = s2p(monkeypatch, capsys, "import-tacal", tmp_path / "east.tacal", "--ground",
                       tmp_path / "g.csv", "-o", tmp_path / "sc", "--fps", "15", "--size", "1280x720")
    assert code == 0 and "camera east: 1280x720  f=1000.0px" in out
    s = load_scene(tmp_path / "sc")
    uv = s.cameras["east"].project_points([[0.50125, 16.0, 3.5025]])[0]
    assert np.abs(uv - [[690.0, 260.0]]).max() < 1e-9
    (tmp_path / "bad.tacal").write_text("dx: 0.01\n")
    code, _, err = s2p(monkeypatch, capsys, "import-tacal", tmp_path / "bad.tacal", "--ground",
                       tmp_path / "g.csv", "-o", tmp_path / "sc2", "--fps", "15")
    assert code == 2 and "missing field(s) dy, Cx" in err and len(err.strip().splitlines()) == 1
