"""Structured fuzzing of the importers (issue 24; the readers themselves in test_fuzz_scene,
_masks, _poses and _mcap): COCO detections, T-Analyst ``.tacal`` calibrations, T-Analyst tracks
CSV, videos, calibration files of ``new-scene``, UTOCS. Near-valid inputs (one field mutated,
truncated, swapped or absurd) end in the project's one-line error or are imported; valid
inputs import exactly; and the
property every importer keeps: what it wrote is accepted by the commands that read it (the
scene by ``s2p info`` and ``s2p run --baseline``, masks by ``run``, annotations by reopening
the project and exporting its ground truth). In-process, for speed."""

from __future__ import annotations

import contextlib
import io
import json
import warnings

import numpy as np
from fuzz_fixtures import FUZZ, folder, importing, mutate_json, mutate_text
from hostile_fixtures import write_scene, write_utocs
from hypothesis import given
from hypothesis import strategies as st
from video_fixtures import calibration, det, write_folder, write_video

SMALL = 2048 * 2048  # pixels: larger accepted cameras get `info` only (a mask would be huge)


def scene_is_usable(root, run_dir) -> None:
    """``s2p info`` and ``s2p run --baseline`` on an imported scene succeed (a camera without
    masks gets one box mask of its size, as a user's detector would give)."""
    from seg2pose.cli.scene import info
    from seg2pose.io.mots import MaskTable, write_mots
    from seg2pose.io.scene import load_scene
    from seg2pose.method.pipeline import RunOptions, run_scene
    from seg2pose.structures.masks import encode

    with contextlib.redirect_stdout(io.StringIO()):
        info(root)
    s = load_scene(root)
    if any(c.width * c.height > SMALL for c in s.cameras.values()):
        return
    for c in s.cameras.values():
        if not s.masks_path(c.name).exists() or not s.masks_path(c.name).stat().st_size:
            m = np.zeros((c.height, c.width), np.uint8)
            m[c.height // 2:c.height // 2 + max(1, c.height // 8), c.width // 3:c.width // 3 + 4] = 1
            write_mots(s.masks_path(c.name), MaskTable([0, 1], [1, 1], [s.classes[0].id] * 2,
                                                       c.height, c.width, [encode(m)] * 2))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # the method's own (rays missing the ground)
        run_scene(s, run_dir, RunOptions(baseline=True, progress=False, force=True))


# --- COCO detections ----------------------------------------------------------------------------

def _coco(n=4):
    return [det(f, 1 + f % 3, [[10 + f, 10, 20 + f, 10, 20 + f, 30, 10 + f, 30]], 0.9)
            for f in range(n)]


@FUZZ
@given(st.data())
def test_coco_detections_near_valid(data):
    from seg2pose.video.video_scene import scene_import_detections

    with folder() as d:
        scene = write_scene(d / "sc", frames=6)
        recs = _coco()
        (d / "d.json").write_text(mutate_json(data, recs))
        n = importing(lambda: scene_import_detections(scene.root, "c0", d / "d.json", force=True,
                                                      log=lambda s: None))
        if n is not None:
            from seg2pose.io.mots import read_mots

            t = read_mots(scene.masks_path("c0"), [c.id for c in scene.classes])
            assert len(t) == n and (t.frame < 6).all()
            scene_is_usable(scene.root, d / "run")


def test_coco_detections_valid_import_exactly(tmp_path):
    from seg2pose.io.mots import read_mots
    from seg2pose.structures.masks import decode
    from seg2pose.video.video_scene import scene_import_detections

    scene = write_scene(tmp_path / "sc", frames=6)
    recs = [dict(det(f, 3, [[10, 10, 20, 10, 20, 30, 10, 30]]), track_id=5) for f in range(4)]
    (tmp_path / "d.json").write_text(json.dumps(recs))
    assert scene_import_detections(scene.root, "c0", tmp_path / "d.json", force=True,
                                   log=lambda s: None) == 4
    t = read_mots(scene.masks_path("c0"))
    assert t.frame.tolist() == [0, 1, 2, 3] and set(t.track_id.tolist()) == {5}
    assert set(t.class_id.tolist()) == {3}  # COCO's car is the scene's car
    m = decode(t.rles[0], t.height, t.width)
    assert m[15:25, 12:18].all() and not m[:, 30:].any()


# --- .tacal -------------------------------------------------------------------------------------

def _tacal_text(tmp):
    from seg2pose.io.tacal import camera_to_tacal, format_tacal

    return format_tacal(camera_to_tacal(calibration(tmp)))


@FUZZ
@given(st.data())
def test_tacal_near_valid(data):
    from seg2pose.io.tacal import scene_from_tacals

    with folder() as d:
        text = _tacal_text(d)
        (d / "c0.tacal").write_text(mutate_text(data, text, ":"))
        s = importing(lambda: scene_from_tacals([d / "c0.tacal"], d / "ground.csv", d / "out", 10.0))
        if s is None:
            assert not (d / "out").exists()
        else:
            scene_is_usable(d / "out", d / "run")


@FUZZ
@given(st.sampled_from(["k", "f", "dx", "dy", "Cx", "Cy", "Sx", "Tx", "Tz", "r1", "r5"]),
       st.sampled_from([1e30, -1e30, 1e308, 1e-308, 0.0, -1.0, 5e6, 3e5, 1e-9]))
def test_tacal_absurd_numbers(name, value):
    from seg2pose.io.tacal import scene_from_tacals

    with folder() as d:
        lines = [f"{name}: {value!r}" if ln.startswith(f"{name}:") else ln
                 for ln in _tacal_text(d).splitlines()]
        (d / "c0.tacal").write_text("\n".join(lines) + "\n")
        s = importing(lambda: scene_from_tacals([d / "c0.tacal"], d / "ground.csv", d / "out", 10.0))
        if s is not None:
            scene_is_usable(d / "out", d / "run")


def test_tacal_valid_import_exactly(tmp_path):
    from seg2pose.io.scene import load_scene
    from seg2pose.io.tacal import camera_to_tacal, scene_from_tacals, write_tacal

    cam = calibration(tmp_path)
    write_tacal(tmp_path / "c0.tacal", camera_to_tacal(cam))
    scene_from_tacals([tmp_path / "c0.tacal"], tmp_path / "ground.csv", tmp_path / "out", 10.0,
                      size=(cam.width, cam.height))
    back = load_scene(tmp_path / "out").cameras["c0"]
    np.testing.assert_allclose(back.K, cam.K, rtol=1e-12)
    np.testing.assert_allclose(back.R, cam.R, atol=1e-12)
    np.testing.assert_allclose(back.t, cam.t, atol=1e-12)


# --- T-Analyst tracks CSV -----------------------------------------------------------------------

TCSV = "\n".join(["Detection ID;Type of road user;Road user ID;X (m);Y (m);Time Stamp",
                  "1;Car;3;-8;-1,5;12:00:00.000", "2;Car;3;-5;-1,5;12:00:00.500",
                  "3;Car;3;-2;-1,5;12:00:01.000", "4;Pedestrian;7;1;2;12:00:00.200",
                  "5;Pedestrian;7;1;4;12:00:00.600"]) + "\n"


@FUZZ
@given(st.data())
def test_tanalyst_near_valid(data):
    from review_fixtures import make_scene

    from annotate import Project
    from annotate.export import export_gt
    from annotate.tanalyst_io import import_tanalyst
    from seg2pose.io.tanalyst import read_tanalyst

    with folder() as d:
        scene = make_scene(d / "sc", n_frames=30)
        (d / "t.csv").write_text(mutate_text(data, TCSV, ";"))

        def imp():
            table = read_tanalyst(d / "t.csv")
            with Project.open(scene) as p:
                return import_tanalyst(p, table, start_ms=12 * 3600_000, file=d / "t.csv")

        if importing(imp) is not None:
            with Project.open(scene.root, read_only=True) as p:
                assert not p.notes
                if len(p.poses()):
                    export_gt(p, d / "gt.csv")


def test_tanalyst_valid_import_exactly(tmp_path):
    from review_fixtures import make_scene

    from annotate import Project
    from annotate.tanalyst_io import import_tanalyst
    from seg2pose.io.tanalyst import parse_tanalyst

    scene = make_scene(tmp_path / "sc", n_frames=30)
    with Project.open(scene) as p:
        import_tanalyst(p, parse_tanalyst(TCSV), start_ms=12 * 3600_000)
    with Project.open(scene.root, read_only=True) as p:
        assert p.track(3).frames == [0, 5, 10] and p.track(7).frames == [2, 6]
        assert p.track(3).keyframes[5][:2] == (-5.0, -1.5)


# --- videos and calibration files of new-scene --------------------------------------------------

@FUZZ
@given(st.data())
def test_new_scene_calibration_near_valid(data):
    from seg2pose.video.video_scene import new_scene

    with folder() as d:
        calibration(d)
        write_folder(d / "frames", 3, [dict(id=1, x=10, y=60, w=10, h=24, vx=2, vy=0)])
        cal = json.loads((d / "calib.json").read_text())
        (d / "calib.json").write_text(mutate_json(data, cal))
        s = importing(lambda: new_scene(d / "sc", {"c0": d / "frames"}, d / "calib.json",
                                        d / "ground.csv", fps=10, log=lambda s: None))
        if s is None:
            assert not (d / "sc").exists()
        else:
            scene_is_usable(d / "sc", d / "run")


@FUZZ
@given(st.sampled_from(["truncate", "bytes", "empty"]), st.integers(0, 10 ** 6))
def test_new_scene_damaged_video(kind, cut):
    from seg2pose.video.video_scene import new_scene, scene_masks_from_video

    with folder() as d:
        calibration(d)
        v = write_video(d / "v.avi", 6, [dict(id=1, x=10, y=60, w=10, h=24, vx=2, vy=0)])
        raw = v.read_bytes()
        v.write_bytes(raw[:cut % len(raw)] if kind == "truncate" else
                      b"" if kind == "empty" else bytes(np.random.default_rng(cut).integers(
                          0, 256, 2000, dtype=np.uint8)))
        s = importing(lambda: new_scene(d / "sc", {"c0": v}, d / "calib.json", d / "ground.csv",
                                        fps=10, log=lambda s: None))
        if s is not None:
            scene_is_usable(d / "sc", d / "run")
            importing(lambda: scene_masks_from_video(d / "sc", log=lambda s: None))


# --- UTOCS --------------------------------------------------------------------------------------

@FUZZ
@given(st.data())
def test_utocs_import_is_usable(data):
    from seg2pose.io.utocs import import_utocs

    with folder() as d:
        src = write_utocs(d / "u", frames=2)
        which = data.draw(st.sampled_from(["cameras.json", "positions/000001.json"]))
        p = src / which
        p.write_text(mutate_json(data, json.loads(p.read_text())))
        if importing(lambda: import_utocs(src, d / "out", log=lambda *a: None)) is not None:
            scene_is_usable(d / "out", d / "run")
