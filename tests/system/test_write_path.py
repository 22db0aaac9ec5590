"""Issue 38: one way to write. Each group of the issue has a test here that failed before:
(1) masks of several cameras and masks/ids.json swapped in as one set; (2) no link followed
inside a scene or output folder; (3) sets that are sets; (4) writers refuse what readers
refuse; (5) leftovers and locks; (6) one-line messages, these two in
tests/system/test_write_path_locks.py. The AST check of every write is
tests/system/test_write_ast.py; kills timed at each commit step tests/system/test_kill_steps.py."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from video_fixtures import calibration, det, rle, single_threaded_opencv, write_folder

from seg2pose.core.errors import S2PError
from seg2pose.io.track_ids import ids_status, read_ids

opencv_one_thread = pytest.fixture(autouse=True)(single_threaded_opencv)
QUIET = dict(log=lambda s: None)
BG = {"min_area": 40, "init_samples": 8}
BOXES = [dict(id=1, x=10, y=60, w=10, h=24, vx=2, vy=0)]


@pytest.fixture
def two_cameras(tmp_path):
    """A scene made by new-scene from two 10-frame image folders (c0, c1: one camera under two
    names), each camera with a detector's masks, associated: masks/ids.json says so."""
    from seg2pose.video.associate_scene import associate_scene
    from seg2pose.video.video_scene import new_scene, scene_import_detections

    calibration(tmp_path)
    calib = json.loads((tmp_path / "calib.json").read_text())
    c1 = dict(calib["cameras"][0], name="c1")
    (tmp_path / "calib.json").write_text(json.dumps({"cameras": [calib["cameras"][0], c1]}))
    write_folder(tmp_path / "f0", 10, BOXES)
    write_folder(tmp_path / "f1", 10, BOXES, seed=3)
    root = tmp_path / "sc"
    new_scene(root, {"c0": tmp_path / "f0", "c1": tmp_path / "f1"}, tmp_path / "calib.json",
              tmp_path / "ground.csv", fps=10, **QUIET)
    (tmp_path / "d.json").write_text(json.dumps([det(f, 3, rle(20 + 2 * f, 40, 12, 10))
                                                 for f in range(10)]))
    for c in ("c0", "c1"):
        scene_import_detections(root, c, tmp_path / "d.json", associate=False, **QUIET)
    associate_scene(root, **QUIET)
    return root


def _masks(root: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted((root / "masks").iterdir())}


# --- (1) masks of several cameras and their ids record: one set -----------------------------------

def test_masks_from_video_stopped_after_one_camera_leaves_every_mask_and_the_record_old(
        two_cameras, monkeypatch):
    """Stopped while the second camera is processed (where a kill swapped the first camera's
    tracker ids in beside a record calling them associated: ``s2p run`` fused unrelated road
    users), nothing under masks/ changed."""
    import seg2pose.video.video_scene as vs

    old = _masks(two_cameras)
    assert ids_status(two_cameras / "masks", ["c0", "c1"])[0] == "associated"
    real, calls = vs.masks_from_video, []

    def second_fails(*a, **k):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(vs, "masks_from_video", second_fails)
    with pytest.raises(KeyboardInterrupt):
        vs.scene_masks_from_video(two_cameras, bg=BG, force=True, associate=False, **QUIET)
    assert len(calls) == 2
    assert _masks(two_cameras) == old
    monkeypatch.setattr(vs, "masks_from_video", real)
    vs.scene_masks_from_video(two_cameras, bg=BG, force=True, associate=False, **QUIET)
    # complete: both cameras' ids are the tracker's, recorded with the files swapped in
    assert {c: e["ids"] for c, e in read_ids(two_cameras / "masks").items()} == {"c0": "tracker",
                                                                                "c1": "tracker"}
    assert ids_status(two_cameras / "masks", ["c0", "c1"])[0] == "unassociated"


def test_import_detections_masks_and_their_record_change_together(two_cameras, tmp_path,
                                                                  monkeypatch):
    """A stop while the record is made (after the masks were swapped in, before) leaves the
    old masks with their old record."""
    import seg2pose.io.track_ids as ti
    from seg2pose.video.video_scene import scene_import_detections

    old = _masks(two_cameras)
    (tmp_path / "e.json").write_text(json.dumps([det(f, 1, rle(60, 40 + f, 8, 20))
                                                 for f in range(10)]))

    def boom():
        raise KeyboardInterrupt

    monkeypatch.setattr(ti, "utc_now", boom)
    with pytest.raises(KeyboardInterrupt):
        scene_import_detections(two_cameras, "c0", tmp_path / "e.json", force=True,
                                associate=False, **QUIET)
    assert _masks(two_cameras) == old
    assert ids_status(two_cameras / "masks", ["c0", "c1"])[0] == "associated"


# --- (2) no link followed ------------------------------------------------------------------------

def _bait(tmp_path: Path) -> Path:
    bait = tmp_path / "outside.txt"
    bait.write_text("a file outside the scene folder\n")
    return bait


def test_masks_folder_linked_elsewhere_is_refused(two_cameras, tmp_path):
    from seg2pose.video.video_scene import scene_import_detections

    elsewhere = tmp_path / "elsewhere"
    (two_cameras / "masks").rename(elsewhere)
    os.symlink(elsewhere, two_cameras / "masks")
    before = {p.name: p.read_bytes() for p in elsewhere.iterdir()}
    with pytest.raises(S2PError, match="masks is a symbolic link"):
        scene_import_detections(two_cameras, "c0", tmp_path / "d.json", force=True, **QUIET)
    assert {p.name: p.read_bytes() for p in elsewhere.iterdir()} == before


def test_commit_record_planted_as_a_link_is_not_written_through(tmp_path):
    from seg2pose.io.atomic import outputs
    from seg2pose.io.atomic_names import commit_record_path

    bait = _bait(tmp_path)
    a, b = tmp_path / "a.txt", tmp_path / "b.txt"
    os.symlink(bait, commit_record_path(a))
    with pytest.raises(S2PError, match="symbolic link"), outputs([a, b]) as out:
        out.file(a).write_text("A")
        out.file(b).write_text("B")
    assert bait.read_text() == "a file outside the scene folder\n"
    assert not a.exists() and not b.exists()


def test_annotation_lock_and_journal_planted_as_links_are_refused(tmp_path):
    from review_fixtures import make_scene

    from annotate import Project

    root = make_scene(tmp_path / "ann", n_frames=10).root
    with Project.open(root) as p:
        p.create_track("car")
    bait = _bait(tmp_path)
    (root / "annotations" / "lock").unlink()
    os.symlink(bait, root / "annotations" / "lock")
    with pytest.raises(S2PError, match="symbolic link"):
        Project.open(root)
    assert bait.read_text() == "a file outside the scene folder\n"
    # a journal segment planted as a link, with a torn tail: never cut, never appended to
    (root / "annotations" / "lock").unlink()
    seg = sorted((root / "annotations").glob("journal-*.jsonl"))[-1]
    bait.write_bytes(seg.read_bytes() + b'{"torn')
    seg.unlink()
    os.symlink(bait, seg)
    text = bait.read_bytes()
    with pytest.raises(S2PError, match="symbolic link"), Project.open(root) as p:
        p.create_track("pedestrian")
    assert bait.read_bytes() == text


def test_a_linked_annotations_folder_is_refused(tmp_path):
    from review_fixtures import make_scene

    from annotate import Project

    root = make_scene(tmp_path / "ann", n_frames=10).root
    (tmp_path / "elsewhere").mkdir()
    os.symlink(tmp_path / "elsewhere", root / "annotations")
    with pytest.raises(S2PError, match="annotations is a symbolic link"), Project.open(root) as p:
        p.create_track("car")
    assert list((tmp_path / "elsewhere").iterdir()) == []


# --- (3) sets that are sets ------------------------------------------------------------------------

def test_import_detections_of_nothing_then_association_does_not_crash(two_cameras, tmp_path):
    """A detector that found nothing in c0: the empty masks and their record are swapped in,
    then the association (crashed with IndexError after c0.txt was replaced) leaves every
    camera's ids as they are."""
    from seg2pose.video.associate_scene import associate_scene
    from seg2pose.video.video_scene import scene_import_detections

    (tmp_path / "empty.json").write_text("[]")
    assert scene_import_detections(two_cameras, "c0", tmp_path / "empty.json", force=True,
                                   **QUIET) == 0
    ids = read_ids(two_cameras / "masks")
    assert ids["c0"]["ids"] == "tracker" and ids["c1"]["ids"] == "associated"
    assert associate_scene(two_cameras, force=True, **QUIET) is None


def test_export_swaps_the_mcap_and_its_layout_in_as_one_set(tmp_path, monkeypatch):
    """Stopped after the MCAP was complete (where a kill left a new MCAP beside the old
    layout), the old MCAP and layout are both kept; complete, both are new."""
    from hostile_fixtures import write_scene

    import s2p_review.mcap_export as ME
    from seg2pose.io.scene import load_scene
    from seg2pose.method.pipeline import RunOptions, run_scene

    scene = write_scene(tmp_path / "scene", frames=4, users=2)
    run_scene(scene, tmp_path / "run", RunOptions(baseline=True, progress=False))
    out = tmp_path / "x.mcap"
    ME.export_mcap(load_scene(scene.root), tmp_path / "run", out)
    lay = out.with_suffix(".layout.json")
    old = (out.read_bytes(), lay.read_bytes())
    real = ME._layout

    def boom(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(ME, "_layout", boom)
    opts = ME.ExportOptions(frames=(0, 2))
    with pytest.raises(KeyboardInterrupt):
        ME.export_mcap(load_scene(scene.root), tmp_path / "run", out, opts, force=True)
    assert (out.read_bytes(), lay.read_bytes()) == old
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []
    monkeypatch.setattr(ME, "_layout", real)
    ME.export_mcap(load_scene(scene.root), tmp_path / "run", out, opts, force=True)
    assert out.read_bytes() != old[0]


# --- (4) writers refuse what readers refuse ---------------------------------------------------------

@pytest.mark.parametrize("fps", [0, float("nan"), float("inf"), -1, 1e300])
def test_new_scene_refuses_an_fps_that_load_scene_refuses(tmp_path, fps):
    from seg2pose.core.errors import InputError
    from seg2pose.video.video_scene import new_scene

    calibration(tmp_path)
    write_folder(tmp_path / "f0", 3, BOXES)
    with pytest.raises(InputError, match="fps"):
        new_scene(tmp_path / "sc", {"c0": tmp_path / "f0"}, tmp_path / "calib.json",
                  tmp_path / "ground.csv", fps=fps, **QUIET)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["calib.json", "f0", "ground.csv"]


def _mcap(path: Path, scene_d: dict, attachments: dict, rows: list[dict]) -> Path:
    """An `s2p export`-shaped MCAP: scene.json, the given attachments, one /s2p/poses message."""
    from hostile_fixtures import H, W
    from mcap.writer import Writer

    from seg2pose.geometry.camera import Camera

    cam = Camera.look_at("c0", [0.0, 0.0, 6.0], [12.0, 0.0, 0.0], 40.0, W, H)
    scene_d = {"version": 1, "fps": 10.0, "cameras": [cam.to_dict()], "configs": {"mono-1": ["c0"]},
               **scene_d}
    attachments = {"ground_points.csv": b"x,y,z\n0,0,0\n1,0,0\n0,1,0\n", **attachments}
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        for name, data in {"scene.json": json.dumps(scene_d).encode(), **attachments}.items():
            w.add_attachment(create_time=0, log_time=0, name=name, media_type="text/plain", data=data)
        w.add_metadata("s2p", {"run": "run", "poses_with_size": "false"})
        sid = w.register_schema(name="s2p.PoseFrame", encoding="jsonschema", data=b"{}")
        cid = w.register_channel(topic="/s2p/poses", message_encoding="json", schema_id=sid)
        w.add_message(channel_id=cid, log_time=0, publish_time=0,
                      data=json.dumps({"frame": 0, "rows": rows}).encode())
        w.finish()
    return path


ROW = {"frame": 0, "track_id": 1, "class": "car", "x": 1.0, "y": 2.0, "z": 0.0, "heading": 0.5}
CAM_X = {"name": "../x", "width": 64, "height": 48, "K": [[40, 0, 32], [0, 40, 24], [0, 0, 1]],
         "R": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "t": [0, 0, 6]}


@pytest.mark.parametrize("scene_d,att,rows,match", [
    ({"cameras": [CAM_X]}, {}, [ROW], r"camera name '\.\./x' cannot be used"),
    ({"fps": -1}, {}, [ROW], r"fps"),
    ({}, {"ground_points.csv": b"x,y,z\n0,0,0\n1,0,0\n"}, [ROW], r"ground"),
    ({}, {"ground_points.csv": b"\x00\xff garbage"}, [ROW], r"ground"),
    ({"ground_points": "scene.json"}, {}, [ROW], r"ground points file cannot be named scene\.json"),
    ({"start_time": "9999-01-01T00:00:00Z"}, {}, [ROW], r"expected a time from 1970 to 2199"),
    ({}, {}, [dict(ROW, track_id=1.5)], r"expected an integer frame or track id, got 1\.5"),
    ({}, {"run.json": b"{not json"}, [ROW], r"the run\.json attachment is not JSON"),
])
def test_import_mcap_restores_only_what_the_readers_accept(tmp_path, scene_d, att, rows, match):
    from s2p_review.mcap_import import import_mcap
    from seg2pose.core.errors import InputError

    f = _mcap(tmp_path / "x.mcap", scene_d, att, rows)
    with pytest.raises(InputError, match=match) as e:
        import_mcap(f, tmp_path / "out")
    assert str(e.value).startswith(str(f)) and "\n" not in str(e.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.mcap"]


# --- (4) settings: the same checks as scene.json's numbers ---------------------------------------

@pytest.mark.parametrize("where,setting", [("associate", {"gate_m": float("nan")}),
                                           ("associate", {"min_votes": 2.5}),
                                           ("tracker", {"max_gap": float("inf")}),
                                           ("video_masks", {"learning_rate": float("nan")})])
def test_settings_refuse_what_scene_json_would_refuse(where, setting):
    """``--set gate_m=nan`` was taken and silently gated nothing."""
    from seg2pose.core.errors import InputError
    from seg2pose.video.assoc_pairs import AssociateConfig
    from seg2pose.video.bg_config import BgConfig
    from seg2pose.video.track import TrackConfig

    cls = {"associate": AssociateConfig, "tracker": TrackConfig, "video_masks": BgConfig}[where]
    with pytest.raises(InputError, match=rf"extra\.{where}\.{next(iter(setting))}.*expected a"):
        cls.from_dict(setting)


@pytest.mark.parametrize("score", [float("nan"), -0.1, 1.5])
def test_import_detections_refuses_a_score_threshold_that_drops_nothing(score):
    from seg2pose.core.errors import InputError
    from seg2pose.video.detections import DetectionConfig

    with pytest.raises(InputError, match=r"--score.*expected a (finite )?number in \[0, 1\]"):
        DetectionConfig(score_min=score)


def test_new_scene_names_the_camera_a_video_has_no_calibration_for(tmp_path):
    """A video named unlike the calibration's camera read "missing field 'width'"."""
    from seg2pose.core.errors import InputError
    from seg2pose.video.video_scene import new_scene

    calibration(tmp_path)  # one camera, c0, without an image size
    write_folder(tmp_path / "f0", 3, BOXES)
    with pytest.raises(InputError, match=r"no camera named 'cam1' \(the video's name\) in the "
                                         r"calibration; its cameras are \['c0'\]"):
        new_scene(tmp_path / "sc", {"cam1": tmp_path / "f0"}, tmp_path / "calib.json",
                  tmp_path / "ground.csv", fps=10, **QUIET)
    assert not (tmp_path / "sc").exists()


def test_calibrate_says_an_empty_run_has_no_views(tmp_path):
    """An empty views.csv was blamed on "an older s2p"."""
    from hostile_fixtures import write_scene

    from seg2pose.core.errors import InputError
    from seg2pose.io.poses import PoseTable
    from seg2pose.io.run import ViewTable, write_run_folder
    from seg2pose.method.r90_calibrate import fit_run

    scene = write_scene(tmp_path / "scene", frames=2, users=1)
    write_run_folder(tmp_path / "run", PoseTable.empty(True), ViewTable.empty(), {"scene": "../scene"})
    with pytest.raises(InputError, match="this run has no views") as e:
        fit_run(scene, tmp_path / "run")
    assert "older" not in str(e.value)


@pytest.mark.parametrize("frame", [10**15, 20])
def test_run_refuses_masks_at_frames_the_scene_does_not_have(tmp_path, frame):
    """A mask at frame 10^15 of a 4-frame scene made a run that ``export`` (struct.error) and
    ``review`` (7 PiB) then failed on; ``s2p run`` refuses it, naming the frame."""
    from hostile_fixtures import write_scene

    from seg2pose.core.errors import InputError
    from seg2pose.io.mots import MaskTable, read_mots, write_mots
    from seg2pose.method.pipeline import RunOptions, run_scene

    scene = write_scene(tmp_path / "scene", frames=4, users=1)
    t = read_mots(scene.masks_path("c0"))
    far = MaskTable([frame], [9], [1], t.height, t.width, [t.rles[0]])
    write_mots(scene.masks_path("c0"), MaskTable.concat([t, far]))
    with pytest.raises(InputError, match=rf"a mask at frame {frame}: the scene's frames are 0\.\.3 "
                                         r"\(its splits in scene\.json\)"):
        run_scene(scene, tmp_path / "run", RunOptions(baseline=True, progress=False))
    assert not (tmp_path / "run").exists()
