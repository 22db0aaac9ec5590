"""Hostile, broken and mismatched inputs (issue 10): each case is refused with an S2PError that
names the file and the field or line, and nothing outside the output folder is touched."""

from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest
from hostile_fixtures import H, W, write_scene, write_utocs

from seg2pose.core.errors import InputError
from seg2pose.io.coco import read_coco
from seg2pose.io.mots import read_mots
from seg2pose.io.poses import read_poses
from seg2pose.io.scene import load_scene

# --- scene.json -------------------------------------------------------------------------------

def _mutate_scene(root, mutate=None, text=None):
    d = json.loads((root / "scene.json").read_text())
    if mutate is not None:
        mutate(d)
    s = json.dumps(d)
    if text is not None:
        s = text(s)
    (root / "scene.json").write_text(s)


def _cam(d):
    return d["cameras"][0]


SCENE_CASES = {
    "width true": (lambda d: _cam(d).update(width=True), None,
                   r"cameras\[c0\]\.width': expected an integer in \[1, 1048576\], got true"),
    "width 1280.7": (lambda d: _cam(d).update(width=1280.7), None,
                     r"cameras\[c0\]\.width': expected an integer .* got 1280\.7"),
    "width 64.0": (lambda d: _cam(d).update(width=64.0), None, r"cameras\[c0\]\.width': expected an integer"),
    "width Infinity": (lambda d: _cam(d).update(width=math.inf), None,
                       r"cameras\[c0\]\.width': expected an integer .* got inf"),
    "width 1e400": (None, lambda s: s.replace('"width": 64', '"width": 1e400'),
                    r"cameras\[c0\]\.width': expected an integer"),
    "width 10**400": (None, lambda s: s.replace('"width": 64', '"width": 1' + "0" * 400),
                      r"cameras\[c0\]\.width': expected an integer in \[1, 1048576\]"),
    "missing width": (lambda d: _cam(d).pop("width"), None, r"cameras\[c0\]\.width': missing field 'width'"),
    "class id 1.9": (lambda d: d["classes"][0].update(id=1.9), None,
                     r"classes\[0\]\.id': expected an integer in \[1, 65535\], got 1\.9"),
    "class id true": (lambda d: d["classes"][0].update(id=True), None, r"classes\[0\]\.id'"),
    "default height 1e9": (lambda d: d["classes"][0].update(default_height=1e9), None,
                           r"classes\[0\]\.default_height': expected a number in \[0, 20\]"),
    "K last row 0 0 0": (lambda d: _cam(d)["K"].__setitem__(2, [0, 0, 0]), None,
                         r"cameras\[c0\]\.K': the last row of K must be \[0, 0, 1\]"),
    "K huge": (lambda d: _cam(d)["K"][0].__setitem__(0, 1e300), None,
               r"cameras\[c0\]\.K': K entries must be within"),
    "t 1e300": (lambda d: _cam(d).update(t=[0, 0, 1e300]), None,
                r"cameras\[c0\]\.t': the camera centre must be within \+-1e\+06 m"),
    "fps 1e308": (lambda d: d.update(fps=1e308), None, r"'fps': expected a number in \[0.001, 1e\+06\]"),
    "fps huge int": (None, lambda s: s.replace('"fps": 10.0', '"fps": 1' + "0" * 400),
                     r"'fps': expected a number in \[0.001, 1e\+06\], got an integer of 401 digits"),
    "fps true": (lambda d: d.update(fps=True), None, r"'fps': expected a number"),
    "fps NaN": (lambda d: d.update(fps=math.nan), None, r"'fps': expected a finite number"),
    "distortion names camera": (lambda d: _cam(d).update(distortion={"k1": "x"}), None,
                                r"cameras\[c0\]\.distortion\.k1': expected a number"),
    "distortion absurd": (lambda d: _cam(d).update(distortion={"k1": 1e300}), None,
                          r"cameras\[c0\]\.distortion\.k1': expected a number in \[-1e\+06, 1e\+06\]"),
    "distortion model names camera": (lambda d: _cam(d).update(distortion={"model": "x"}), None,
                                      r"cameras\[c0\]\.distortion\.model'"),
    "split bool": (lambda d: d.update(splits={"train": [False, 3]}), None, r"splits\.train'"),
    "split negative": (lambda d: d.update(splits={"train": [-4, 3]}), None, r"splits\.train'"),
    "camera name ..": (lambda d: (_cam(d).update(name="../evil"), d.update(configs={})), None,
                       r"cameras\[0\]\.name': camera name '\.\./evil' cannot be used in a file name"),
    "camera name not a string": (lambda d: (_cam(d).update(name=5), d.update(configs={})), None,
                                 r"cameras\[0\]\.name': expected a camera name \(a string\), got 5"),
    "class name with /": (lambda d: d["classes"][0].update(name="a/b"), None,
                          r"classes\[0\]\.name': class name 'a/b' cannot be used"),
    "config name ..": (lambda d: d.update(configs={"..": ["c0"]}), None,
                       r"configs\.\.\.': configuration name '\.\.' cannot be used"),
    "ground points ../": (lambda d: d.update(ground_points="../x.csv"), None,
                          r"'ground_points': ground points file '\.\./x\.csv' leads outside"),
    "ground points absolute": (lambda d: d.update(ground_points="/etc/passwd"), None,
                               r"'ground_points': ground points file '/etc/passwd' leads outside"),
    "ground points not a string": (lambda d: d.update(ground_points=["a"]), None, r"'ground_points'"),
    "class sizes absurd": (lambda d: d.update(extra={"class_sizes": {"car": [1, 2, -3]}}), None,
                           r"extra\.class_sizes\.car': expected a number in \(0, 1000\]"),
}


@pytest.mark.parametrize("case", list(SCENE_CASES))
def test_scene_json_refuses(tmp_path, case):
    mutate, text, match = SCENE_CASES[case]
    write_scene(tmp_path)
    _mutate_scene(tmp_path, mutate, text)
    with pytest.raises(InputError, match=match) as e:
        s = load_scene(tmp_path)
        s.class_sizes()
    assert str(tmp_path / "scene.json") in str(e.value)


def test_scene_ground_points_link_outside(tmp_path):
    root = tmp_path / "scene"
    write_scene(root)
    outside = tmp_path / "elsewhere.csv"
    outside.write_text((root / "ground_points.csv").read_text())
    (root / "ground_points.csv").unlink()
    (root / "ground_points.csv").symlink_to(outside)
    with pytest.raises(InputError, match=r"leads outside .* \(through a link\)"):
        load_scene(root)


def test_scene_ground_points_absurd(tmp_path):
    write_scene(tmp_path)
    p = tmp_path / "ground_points.csv"
    p.write_text("x,y,z\n0,0,0\n1,0,0\n0,1,1e308\n")
    with pytest.raises(InputError, match=r"ground_points.csv:4: ground point .* more than 1e\+06 m"):
        load_scene(tmp_path)


def test_valid_scene_reads_back_exactly(tmp_path):
    s = write_scene(tmp_path)
    r = load_scene(tmp_path)
    assert r.fps == 10.0 and [c.id for c in r.classes] == [1, 2, 3]
    assert np.array_equal(r.ground_points, s.ground_points)
    assert np.array_equal(r.cameras["c0"].K, s.cameras["c0"].K)


# --- masks ------------------------------------------------------------------------------------

def _lines(path):
    return path.read_text().splitlines()


def test_mots_track_id_with_underscore(tmp_path):
    s = write_scene(tmp_path)
    p = s.masks_path("c0")
    lines = _lines(p)
    parts = lines[0].split()
    parts[1] = "1_4"  # int() reads this as 14
    p.write_text("\n".join([" ".join(parts)] + lines[1:]) + "\n")
    with pytest.raises(InputError, match=r"c0\.txt:1: expected integers .*'1_4'"):
        read_mots(p)


def test_mots_duplicate_detection(tmp_path):
    s = write_scene(tmp_path)
    p = s.masks_path("c0")
    lines = _lines(p)
    p.write_text("\n".join([lines[0], lines[1], lines[0]] + lines[2:]) + "\n")
    with pytest.raises(InputError, match=r"c0\.txt:3: duplicate detection: track 1 appears twice "
                                         r"in frame 0 \(also line 1\)"):
        read_mots(p)


def test_mots_untracked_detections_may_repeat(tmp_path):
    s = write_scene(tmp_path)
    p = s.masks_path("c0")
    lines = _lines(p)
    untracked = [" ".join([ln.split()[0], "-1", *ln.split()[2:]]) for ln in lines[:2]]
    p.write_text("\n".join(untracked + lines[2:]) + "\n")
    assert (read_mots(p).track_id[:2] == -1).all()


def test_masks_of_another_size_than_the_camera(tmp_path):
    """Swapped height and width: refused wherever masks meet a camera (on the old main, s2p
    run used them and reported errors of metres instead of centimetres)."""
    from seg2pose.method.pipeline import RunOptions, run_scene

    s = write_scene(tmp_path / "s")
    p = s.masks_path("c0")
    p.write_text("".join(ln.replace(f" {H} {W} ", f" {W} {H} ", 1) + "\n" for ln in _lines(p)))
    assert read_mots(p).height == W  # a valid MOTS file on its own
    with pytest.raises(InputError, match=rf"c0\.txt:1: mask size {W}x{H} \(height x width\) differs "
                                         rf"from the camera's image size {H}x{W}"):
        run_scene(load_scene(tmp_path / "s"), tmp_path / "run", RunOptions(baseline=True, progress=False))
    assert not (tmp_path / "run").exists()
    from seg2pose.method.heights import collect_height_views

    with pytest.raises(InputError, match="differs from the camera's image size"):
        collect_height_views(load_scene(tmp_path / "s"), split=None)
    with pytest.raises(InputError, match="differs from the camera's image size"):
        load_scene(tmp_path / "s").read_masks("c0")  # annotation's normal positions use this
    from s2p_review.imagery import mask_frames

    with pytest.raises(InputError, match="differs from the camera's image size"):
        list(mask_frames(load_scene(tmp_path / "s"), "c0", 0, 5))  # review and export


def test_coco_duplicate_detection(tmp_path):
    from seg2pose.io.coco import write_coco

    s = write_scene(tmp_path)
    t = read_mots(s.masks_path("c0"))
    write_coco(tmp_path / "m.json", t)
    recs = json.loads((tmp_path / "m.json").read_text())
    (tmp_path / "m.json").write_text(json.dumps(recs + [recs[0]]))
    with pytest.raises(InputError, match=rf"m\.json: field '\[{len(recs)}\]\.track_id': duplicate "
                                         r"detection: track 1 appears twice in frame 0 \(also record 0\)"):
        read_coco(tmp_path / "m.json")


# --- poses.csv --------------------------------------------------------------------------------

POSE_CASES = {
    "inf x": (lambda r: r.__setitem__(3, "inf"), r":2: x, y, z must be finite metres"),
    "1e308 y": (lambda r: r.__setitem__(4, "1e308"), r":2: x, y, z must be finite metres in \[-1000000, 1000000\]"),
    "inf heading": (lambda r: r.__setitem__(6, "-inf"), r":2: heading must be finite"),
    "negative size": (lambda r: r.__setitem__(7, "-4.5"), r":2: l, w, h must be finite metres in \(0, 1000\]"),
    "inf size": (lambda r: r.__setitem__(9, "inf"), r":2: l, w, h must be finite metres in"),
    "track 1_4": (lambda r: r.__setitem__(1, "1_4"), r":2: frame and track_id must be integers"),
}


@pytest.mark.parametrize("case", list(POSE_CASES))
def test_poses_csv_refuses(tmp_path, case):
    mutate, match = POSE_CASES[case]
    s = write_scene(tmp_path)
    lines = _lines(s.gt_path)
    row = lines[1].split(",")
    mutate(row)
    s.gt_path.write_text("\n".join([lines[0], ",".join(row)] + lines[2:]) + "\n")
    with pytest.raises(InputError, match=r"poses\.csv" + match):
        read_poses(s.gt_path)


def test_poses_csv_duplicate_rows(tmp_path):
    s = write_scene(tmp_path)
    lines = _lines(s.gt_path)
    s.gt_path.write_text("\n".join([lines[0], lines[1], lines[1]] + lines[2:]) + "\n")
    with pytest.raises(InputError, match=r"poses\.csv:3: duplicate row: track 1 appears twice in "
                                         r"frame 0 \(also line 2\)"):
        read_poses(s.gt_path)


def test_poses_csv_nan_sizes_and_heading_mean_unknown(tmp_path):
    s = write_scene(tmp_path)
    lines = _lines(s.gt_path)
    row = lines[1].split(",")
    row[6], row[7] = "nan", "nan"
    s.gt_path.write_text("\n".join([lines[0], ",".join(row)] + lines[2:]) + "\n")
    t = read_poses(s.gt_path)
    assert math.isnan(t.heading[0]) and math.isnan(t.size[0, 0])


# --- s2p eval -----------------------------------------------------------------------------------

@pytest.fixture
def scene_and_run(tmp_path):
    from seg2pose.method.pipeline import RunOptions, run_scene

    write_scene(tmp_path / "s")
    run_scene(load_scene(tmp_path / "s"), tmp_path / "run", RunOptions(baseline=True, progress=False))
    return tmp_path / "s", tmp_path / "run"


def test_eval_refuses_a_run_of_another_scene(tmp_path, scene_and_run):
    from seg2pose.eval.paper_table import evaluate_run

    scene, run = scene_and_run
    res = evaluate_run(load_scene(scene), run)
    assert res.n_matched > 0 and res.mean_error < 5
    other = tmp_path / "other"
    write_scene(other)
    gp = other / "ground_points.csv"
    gp.write_text(gp.read_text().replace("\n2.0,-8.0,0.0", "\n2.0,-8.0,0.5"))  # another ground
    with pytest.raises(InputError, match=r"run\.json: field 'scene_fingerprint': this run was made "
                                         r"on another scene"):
        evaluate_run(load_scene(other), run)


@pytest.mark.parametrize("missing", ["run.json", "poses.csv"])
def test_eval_refuses_a_half_written_run(scene_and_run, missing):
    from seg2pose.eval.paper_table import evaluate_run

    scene, run = scene_and_run
    (run / missing).unlink()
    with pytest.raises(InputError, match=rf"{missing}: not a finished run"):
        evaluate_run(load_scene(scene), run)


def test_eval_and_heights_agree_on_classes(scene_and_run):
    """A truth file with a class the scene does not know: `heights` refused it, `eval` did not."""
    from seg2pose.eval.paper_table import evaluate_run
    from seg2pose.method.heights import collect_height_views

    scene, run = scene_and_run
    gt = scene / "gt" / "poses.csv"
    gt.write_text(gt.read_text().replace(",car,", ",tram,"))
    with pytest.raises(InputError, match=r"poses\.csv:\d+: field 'class': unknown class 'tram'"):
        collect_height_views(load_scene(scene), split=None)
    with pytest.raises(InputError, match=r"poses\.csv:\d+: field 'class': unknown class 'tram'"):
        evaluate_run(load_scene(scene), run)


# --- UTOCS --------------------------------------------------------------------------------------

@pytest.mark.parametrize("kw,match", [
    (dict(fps=-5.0), r"field 'fps': expected a number in \[0.001, 1e\+06\], got -5.0"),
    (dict(fps=math.nan), r"field 'fps': expected a finite number"),
    (dict(fps=math.inf), r"field 'fps': expected a finite number"),
    (dict(size_scale=-2.0), r"field 'size_scale': expected a number in \(0, 100\], got -2.0"),
    (dict(size_scale=0.0), r"field 'size_scale'"),
])
def test_utocs_options_refused(tmp_path, kw, match):
    from seg2pose.io.utocs import import_utocs

    src = write_utocs(tmp_path / "u")
    with pytest.raises(InputError, match=match):
        import_utocs(src, tmp_path / "out", log=lambda *a: None, **kw)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("change,match", [
    (dict(l=-4.5), r"000001\.json: field '\[0\]\.l': expected a size in \[0, 1000\] metres, got -4.5"),
    (dict(h=1e9), r"field '\[0\]\.h': expected a size in \[0, 1000\]"),
    (dict(forward_x=0.0, forward_y=0.0), r"field '\[0\]\.forward_x': forward vector .* is zero"),
    (dict(type="../../etc"), r"field '\[0\]\.type': type name '\.\./\.\./etc' cannot be used"),
    (dict(x=1e300), r"field '\[0\]\.x': position more than 1e\+06 m"),
])
def test_utocs_positions_refused(tmp_path, change, match):
    from seg2pose.io.utocs import import_utocs

    src = write_utocs(tmp_path / "u")
    p = src / "positions" / "000001.json"
    recs = json.loads(p.read_text())
    recs[0].update(change)
    p.write_text(json.dumps(recs))
    with pytest.raises(InputError, match=match):
        import_utocs(src, tmp_path / "out", log=lambda *a: None)


def test_utocs_camera_id_cannot_leave_the_folder(tmp_path):
    """A camera id names images/cam<id>/ and video/cam<id>: '/../../x' would reach outside."""
    from seg2pose.io.utocs import import_utocs

    cams = [{"id": "0/../../../x", "x": 0.0, "y": 0.0, "z": 6.0, "pitch": -20.0, "roll": 0.0, "yaw": 0.0}]
    src = write_utocs(tmp_path / "u", cams=cams)
    with pytest.raises(InputError, match=r"cameras\.json: field 'cams\[0\]\.id': camera id "
                                         r"'0/\.\./\.\./\.\./x' cannot be used in a file name"):
        import_utocs(src, tmp_path / "out", log=lambda *a: None)
    assert sorted(os.listdir(tmp_path)) == ["u"]


def test_utocs_valid_import_reads_back(tmp_path):
    from seg2pose.io.utocs import import_utocs

    src = write_utocs(tmp_path / "u")
    import_utocs(src, tmp_path / "out", fps=20.0, size_scale=2.0, log=lambda *a: None)
    s = load_scene(tmp_path / "out")
    gt = read_poses(s.gt_path)
    assert s.fps == 20.0 and len(gt) == 6
    assert gt.size[gt.track_id == 7][0].tolist() == [9.0, 3.6, 3.0]


# --- checkpoints ----------------------------------------------------------------------------------

@pytest.mark.parametrize("complete", [False, True])
def test_incomplete_checkpoint_refused_unless_allowed(tmp_path, complete):
    """Old main used a checkpoint of a training killed at epoch 1 of 6 without a word."""
    import torch

    from seg2pose.io.run import read_run_meta
    from seg2pose.method.checkpoint import Checkpoint
    from seg2pose.method.net import NetConfig, Normalisation, Seg2PoseNet
    from seg2pose.method.pipeline import RunOptions, run_scene

    s = write_scene(tmp_path / "s")
    torch.manual_seed(0)
    ck = Checkpoint(Seg2PoseNet(NetConfig.named("lite", 3, 0)), Normalisation(W, H), camera="*",
                    cls="*", scene_fingerprint=s.fingerprint(), classes=[c.name for c in s.classes],
                    info={"complete": complete, "epoch": 1, "val_loss": 0.5})
    ck.save(s.root / "models" / "all__all.safetensors")
    if not complete:
        with pytest.raises(InputError, match=r"all__all\.json: field 'complete': its training did "
                                             r"not finish \(epoch 1, val loss 0\.5\).*allow incomplete models"):
            run_scene(s, tmp_path / "run", RunOptions(progress=False))
        assert not (tmp_path / "run").exists()
    run_scene(s, tmp_path / "run", RunOptions(progress=False, allow_incomplete=not complete))
    used = read_run_meta(tmp_path / "run")["models"]
    assert used and all(len(m["sha256"]) == 64 for m in used.values())


def test_coco_empty_polygon_list(tmp_path):
    """Found by the fuzzer: 'segmentation': [] crashed in pycocotools (IndexError)."""
    recs = [{"frame": 0, "image_id": 0, "category_id": 1, "segmentation": []}]
    (tmp_path / "m.json").write_text(json.dumps({"images": [{"id": 0, "height": H, "width": W}],
                                                 "annotations": recs}))
    with pytest.raises(InputError, match=r"m\.json: field '\[0\]\.segmentation': expected at "
                                         r"least one polygon"):
        read_coco(tmp_path / "m.json")
