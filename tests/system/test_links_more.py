"""Issue 38, the other writing commands (tests/system/test_links.py has export, run,
convert-masks, review -o, import-mcap and annotate export): for each, a link is planted where it
writes -- its output's folder, a folder of the scene it writes into -- pointing at a folder
outside that holds what the linked folder held (so the command finds its inputs through the
link, and would write there if it followed it) and a colleague's files. The command is refused
with one line naming the link, and nothing outside changes."""

from __future__ import annotations

import json
import os
import shutil
import sys
from pathlib import Path

import pytest
from hostile_fixtures import link_test_inputs, write_utocs

from seg2pose.io.nofollow import link_message


def _tree(folder: Path) -> dict[str, bytes | None]:
    """Every file (its bytes) and folder (None) under ``folder``."""
    return {str(p.relative_to(folder)): p.read_bytes() if p.is_file() else None
            for p in sorted(folder.rglob("*"))}


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """Tiny inputs of every writer: a scene and its run, an annotated scene, a three-camera
    scene and its validation run, a video scene (masks without ids, and without masks), its
    frames, calibration, ground points, pairs, a .tacal, a UTOCS recording, COCO detections,
    a T-Analyst CSV and a study of one scene."""
    import numpy as np
    from scene_fixtures import make_tiny_scene
    from video_fixtures import calibration, det, rle, write_folder

    from seg2pose.io.scene import load_scene
    from seg2pose.io.tacal import camera_to_tacal, write_tacal
    from seg2pose.method.pipeline import RunOptions, run_scene
    from seg2pose.video.video_scene import new_scene, scene_masks_from_video

    root, _, _ = link_test_inputs(tmp_path_factory.mktemp("links-more"))
    (root / "t.csv").write_text("\n".join([
        "Detection ID;Type of road user;Road user ID;X (m);Y (m);Time Stamp",
        "1;Car;3;-8;-1,5;12:00:00.000", "2;Car;3;-5;-1,5;12:00:00.300"]) + "\n")
    tiny = make_tiny_scene(root / "tiny", frames=12, n_users=3)
    run_scene(tiny, root / "val", RunOptions(baseline=True, split="val", progress=False))
    # a video scene of six frames, its calibration, ground points and a .tacal of its camera
    cam = calibration(root)
    write_folder(root / "frames", 6, [dict(id=1, x=10, y=60, w=10, h=24, vx=2, vy=0)])
    new_scene(root / "vid", {"c0": root / "frames"}, root / "calib.json", root / "ground.csv",
              fps=10, log=lambda *a: None)
    shutil.copytree(root / "vid", root / "trk")
    scene_masks_from_video(root / "trk", bg={"min_area": 40, "init_samples": 3}, track=False,
                           classify=False, log=lambda *a: None)
    write_tacal(root / "c0.tacal", camera_to_tacal(cam))
    (root / "dets.json").write_text(json.dumps([det(f, 3, rle(20 + 3 * f, 40, 12, 10)) for f in range(6)]))
    write_utocs(root / "utocs", frames=2)
    # calibrate-camera --points: six ground pairs of the camera
    grid = np.array([[x, y, 0.0] for y in (0.5, 4.0, 9.0) for x in (-3.0, 3.0)])
    uv = cam.project_points(grid)[0]
    (root / "pairs.csv").write_text("camera,u,v,x,y,z\n" + "".join(
        f"c0,{u!r},{v!r},{x},{y},0\n" for (u, v), (x, y, _) in zip(uv.tolist(), grid.tolist(), strict=True)))
    (root / "study").mkdir()
    shutil.copytree(root / "scene", root / "study" / "s1")
    (root / "vstudy").mkdir()
    shutil.copytree(root / "vid", root / "vstudy" / "v1")
    v1 = load_scene(root / "vstudy" / "v1")
    v1.extra["video_masks"] = {"min_area": 40, "init_samples": 3}
    v1.save()
    return root


def _run(monkeypatch, capsys, argv: list) -> tuple[int, str]:
    from seg2pose.cli import main

    monkeypatch.setattr(sys, "argv", ["s2p", *map(str, argv)])
    with pytest.raises(SystemExit) as e:
        main()
    got = capsys.readouterr()
    return e.value.code, got.out, got.err


# (name, the inputs copied into the work folder w, the folder planted as a link (relative to
# w), the command's arguments: {w} the work folder, {root} the inputs left where they are;
# optionally code: the exit code (batch: 1, a failed scene, reported in its row on stdout),
# fill: an input copied to the outside folder when the link's place is empty, file: the link
# points at the colleague's file instead of the folder)
CASES = [
    ("synth", [], "out", ["synth", "-o", "{w}/out/s", "--frames", "2", "--workers", "1", "--no-progress"]),
    ("import-utocs", [], "out", ["import-utocs", "{root}/utocs", "-o", "{w}/out/s"]),
    ("import-tacal", [], "out", ["import-tacal", "{root}/c0.tacal", "--ground", "{root}/ground.csv", "-o",
                                 "{w}/out/s", "--fps", "10"]),
    ("new-scene", [], "out", ["new-scene", "-o", "{w}/out/s", "--video", "c0={root}/frames", "--calibration",
                              "{root}/calib.json", "--ground", "{root}/ground.csv", "--fps", "10"]),
    ("calibrate-camera", [], "out", ["calibrate-camera", "{root}/frames", "--points", "{root}/pairs.csv",
                                     "-o", "{w}/out/calib.json"]),
    ("calibrate-camera-scene", ["vid"], "vid/calibrations", ["calibrate-camera", "{w}/vid", "--points",
                                                             "{root}/pairs.csv", "--force"]),
    ("heights", ["scene"], "scene/.scene.json.lock", ["heights", "{w}/scene"], {"file": True}),
    ("masks-from-video", ["vid"], "vid/masks", ["masks-from-video", "{w}/vid", "--no-progress", "--set",
                                                "min_area=40", "--set", "init_samples=3"]),
    ("import-detections", ["vid"], "vid/masks", ["import-detections", "{w}/vid", "{root}/dets.json",
                                                 "--camera", "c0"]),
    ("track", ["trk"], "trk/masks", ["track", "{w}/trk", "--no-progress"]),
    ("associate", ["ann"], "ann/masks", ["associate", "{w}/ann", "--force"]),
    ("train", ["tiny"], "tiny/models", ["train", "{w}/tiny", "--protocol", "quick", "--epochs", "1",
                                        "--batches", "1", "--threads", "1"]),
    ("train-o", [], "out", ["train", "{root}/tiny", "-o", "{w}/out/models", "--protocol", "quick",
                            "--epochs", "1", "--batches", "1", "--threads", "1"]),
    ("calibrate-errors", [], "out", ["calibrate-errors", "{root}/tiny", "--run", "{root}/val", "-o",
                                     "{w}/out/r90.json"]),
    ("paper-table", ["tiny"], "tiny/out", ["paper-table", "{w}/tiny", "--no-seg2posenet"]),
    ("paper-table-o", [], "out", ["paper-table", "{root}/tiny", "--no-seg2posenet", "-o", "{w}/out/pt"]),
    ("conflicts", [], "out", ["conflicts", "{root}/run", "-o", "{w}/out/c.csv", "--draws", "0"]),
    ("conflicts-map", [], "out", ["conflicts", "{root}/run", "-o", "{w}/c.csv", "--map", "{w}/out/m.png",
                                  "--draws", "0"]),
    ("conflicts-pet", [], "out", ["conflicts", "{root}/run", "-o", "{w}/c.csv", "--pet-only",
                                  "{w}/out/p.csv", "--draws", "0"]),
    ("conflicts-review", [], "out", ["conflicts", "{root}/run", "-o", "{w}/c.csv", "--review",
                                     "{w}/out/r.rrd", "--draws", "0"]),
    ("batch", ["study"], "study/s1/batch", ["batch", "{w}/study", "run", "--baseline", "--serial",
                                            "--no-progress"], {"code": 1}),
    ("batch-masks", ["vstudy"], "vstudy/v1/batch", ["batch", "{w}/vstudy", "masks-from-video", "--serial",
                                                    "--no-progress"], {"code": 1}),
    ("batch-scene", ["study"], "study/s2", ["batch", "{w}/study", "run", "--baseline", "--serial",
                                            "--no-progress"], {"code": 1, "fill": "scene"}),
    ("screenshot", [], "out", ["screenshot", "{root}/x.mcap", "-o", "{w}/out/s.png"]),
    ("demo-scene", [], "out", ["demo", "--scene", "{w}/out/demo", "-o", "{w}/logs"]),
    ("demo-out", [], "out", ["demo", "--scene", "{w}/demo", "-o", "{w}/out"]),
    ("bench-accuracy", [], "b/logs", ["bench-accuracy", "{w}/b", "--seed", "1", "--preset", "small"]),
    ("import-tanalyst", ["ann"], "ann/annotations", ["annotate", "import-tanalyst", "{w}/ann", "{root}/t.csv",
                                                     "--start", "12:00:00.000"]),
    ("export-tanalyst", ["ann"], "out", ["annotate", "export-tanalyst", "{w}/ann", "-o", "{w}/out/t.csv"]),
]


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_a_planted_link_is_refused_and_nothing_outside_changes(made, tmp_path, monkeypatch, capsys, case):
    _, copies, link, argv, opts = (*case, {}) if len(case) == 4 else case
    root = made
    w = tmp_path / "w"
    w.mkdir()
    for c in copies:
        shutil.copytree(root / c, w / c, symlinks=True)
    outside = tmp_path / "outside"
    lk = w / link
    if lk.exists():  # what the folder held is outside now, reached through the link
        shutil.move(lk, outside)
    elif "fill" in opts:
        shutil.copytree(root / opts["fill"], outside)
    outside.mkdir(exist_ok=True)
    (outside / "colleague.json").write_text("a colleague's file, not to be touched\n")
    lk.parent.mkdir(parents=True, exist_ok=True)
    os.symlink(outside / "colleague.json" if opts.get("file") else outside, lk)
    before = _tree(outside)
    code, out, err = _run(monkeypatch, capsys, [a.format(w=w, root=root) for a in argv])
    assert code == opts.get("code", 2), err
    assert "Traceback" not in err
    if code == 2:
        assert err.strip() == err.strip().splitlines()[0]
        assert f"{lk} is a symbolic link" in err
    else:  # batch: the scene failed with that line, the study went on
        rows = json.loads((w / argv[1].split("/")[1] / "summary.json").read_text())["scenes"]
        linked = lk.relative_to(w).parts[1]
        assert {r["scene"]: r["failures"] for r in rows} == {
            r["scene"]: [{"step": argv[2], "error": link_message(lk)}] if r["scene"] == linked else []
            for r in rows}
        assert f"{lk} is a symbolic link" in out
    assert _tree(outside) == before
    assert os.path.islink(lk)



def test_an_output_planted_as_a_link_is_replaced_never_written_through(made, tmp_path, monkeypatch, capsys):
    """scene.json itself a link to a copy outside: heights reads it and swaps its new
    scene.json in by name, as a file in the link's place; the copy outside stays as it was."""
    w = tmp_path / "scene"
    shutil.copytree(made / "tiny", w, ignore=shutil.ignore_patterns("out", "models"))
    outside = tmp_path / "outside"
    outside.mkdir()
    (w / "scene.json").rename(outside / "scene.json")
    os.symlink(outside / "scene.json", w / "scene.json")
    before = _tree(outside)
    code, out, err = _run(monkeypatch, capsys, ["heights", w])
    assert code == 0, err
    assert f"wrote default heights into {w / 'scene.json'}" in out
    assert not (w / "scene.json").is_symlink()
    heights = {c["name"]: c["default_height"] for c in json.loads((w / "scene.json").read_text())["classes"]}
    old = {c["name"]: c["default_height"] for c in json.loads(before["scene.json"])["classes"]}
    assert heights.keys() == old.keys() and heights != old  # set from the truth, in the scene
    assert _tree(outside) == before
