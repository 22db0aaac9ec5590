"""One schema per file type (seg2pose/io/schemas.py), used by the file's writer and its reader:
a writer refuses, in one line naming the file and the field and with nothing written, what the
reader refuses; settings (--set) are read by the same schema. Each test here failed before the
schemas: the writer wrote what its reader then refused (or crashed on), or a reader passed
what its users crashed on or silently rounded."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from io_fixtures import RLE

from seg2pose.core.errors import InputError, S2PError
from seg2pose.io.coco import read_coco, write_coco
from seg2pose.io.mots import MaskTable, read_mots, write_mots
from seg2pose.io.poses import PoseTable, read_poses, write_poses
from seg2pose.io.run import ViewTable, read_run_meta, read_views, write_run_folder

NAN = math.nan


def one_line(e: BaseException, *names: str) -> None:
    assert isinstance(e, S2PError), repr(e)
    assert "\n" not in str(e) and all(n in str(e) for n in names), str(e)


def poses(frame=(0,), tid=(1,), xyz=((1.0, 2.0, 0.0),), heading=(0.5,), size=None) -> PoseTable:
    return PoseTable(list(frame), list(tid), ["car"] * len(frame), np.array(xyz, float), list(heading),
                     None if size is None else np.array(size, float))


POSE_CASES = {
    "nan x": (poses(xyz=[(NAN, 2, 0)]), "x, y, z"),
    "x of 1e7 m": (poses(xyz=[(1e7, 2, 0)]), "x, y, z"),
    "inf heading": (poses(heading=[math.inf]), "heading"),
    "size 0": (poses(size=[(0, 1, 1)]), "l, w, h"),
    "frames out of order": (poses([3, 1], [1, 1], [(0, 0, 0)] * 2, [0, 0]), "frames must be in order"),
    "road user twice in a frame": (poses([3, 3], [1, 1], [(0, 0, 0)] * 2, [0, 0]), "duplicate row"),
    "negative frame": (poses(frame=[-4]), "frame"),
}


@pytest.mark.parametrize("case", sorted(POSE_CASES))
def test_poses_writer_refuses_what_read_poses_refuses(tmp_path, case):
    table, what = POSE_CASES[case]
    p = tmp_path / "p.csv"
    with pytest.raises(InputError) as e:
        write_poses(p, table)
    one_line(e.value, "p.csv", what)
    assert not p.exists() and list(tmp_path.iterdir()) == []
    # and the run folder's writer, which import-mcap restores through, refuses it whole
    with pytest.raises(InputError) as e:
        write_run_folder(tmp_path / "run", table, None, {})
    one_line(e.value, "poses.csv", what)
    assert list(tmp_path.iterdir()) == []


def views(**kw) -> ViewTable:
    d = dict(frame=[0], track_id=[1], camera=["c0"], cls=["car"], uv=[[10.0, 20.0]],
             normal=[[1.0, 2.0, 0.0]], residual=[[0.0, 0.0]])
    d.update(kw)
    return ViewTable(**d)


@pytest.mark.parametrize("kw,what", [({"uv": [[math.inf, 0.0]]}, "u, v"),
                                    ({"frame": [-1]}, "frame"),
                                    ({"camera": ["c,0"]}, "commas"), ({"camera": [""]}, "not empty"),
                                    ({"normal": [[1e300, 0.0, 0.0]]}, "xn, yn, zn")])
def test_views_writer_refuses_what_read_views_refuses(tmp_path, kw, what):
    with pytest.raises(InputError) as e:
        write_run_folder(tmp_path / "run", poses(), views(**kw), {})
    one_line(e.value, "views.csv", what)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("row,what", [("-3,1,c0,car,1,2,0,0,0,0,0", "frame"),
                                      ("99999999999999999999,1,c0,car,1,2,0,0,0,0,0", "integers"),
                                      ("1_4,1,c0,car,1,2,0,0,0,0,0", "integers"),
                                      ("0,1,c0,car,inf,2,0,0,0,0,0", "u, v")])
def test_read_views_refuses_what_its_users_crash_on(tmp_path, row, what):
    """A negative frame passed (review and export then failed); 20 digits gave an OverflowError
    traceback; '1_4' was read as 14; an infinite pixel passed."""
    p = tmp_path / "views.csv"
    p.write_text("frame,track_id,camera,class,u,v,xn,yn,zn,dx,dy\n" + row + "\n")
    with pytest.raises(InputError) as e:
        read_views(p)
    one_line(e.value, "views.csv:2", what)


def masks(frame=(0,), tid=(1,), rles=(RLE,), score=None) -> MaskTable:
    return MaskTable(list(frame), list(tid), [1] * len(frame), 2, 3, [r if isinstance(r, bytes)
                                                                     else r.encode() for r in rles],
                     score)


MASK_CASES = {
    "negative frame": (masks(frame=[-1]), "frame"),
    "runs that do not cover the image": (masks(rles=[b"3"]), "RLE covers"),
    "track twice in a frame": (masks([0, 0], [1, 1], [RLE, RLE]), "duplicate detection"),
    "score 1.5": (masks(score=[1.5]), "score"),
}


@pytest.mark.parametrize("fmt,case", [(f, c) for f in ("mots", "coco") for c in sorted(MASK_CASES)
                                      if (f, c) != ("mots", "score 1.5")])  # MOTS holds no score
def test_mask_writers_refuse_what_the_mask_readers_refuse(tmp_path, case, fmt):
    table, what = MASK_CASES[case]
    p = tmp_path / ("m.txt" if fmt == "mots" else "m.json")
    with pytest.raises(InputError) as e:
        (write_mots if fmt == "mots" else write_coco)(p, table)
    one_line(e.value, p.name, what)
    assert list(tmp_path.iterdir()) == []


def test_coco_score_and_import_detections_score_share_one_schema(tmp_path):
    """A COCO score outside [0, 1] was read (and --score compared with it); the file and the
    setting now take the same range."""
    from seg2pose.video.detections import DetectionConfig

    p = tmp_path / "d.json"
    p.write_text(json.dumps([{"frame": 0, "category_id": 1, "score": 5,
                              "segmentation": {"size": [2, 3], "counts": RLE}}]))
    with pytest.raises(InputError) as e:
        read_coco(p)
    one_line(e.value, "d.json", "[0].score", "[0, 1]")
    for bad in (NAN, 1.5, -0.1):
        with pytest.raises(InputError) as e:
            DetectionConfig(score_min=bad)
        one_line(e.value, "--score", "[0, 1]")
    write_mots(tmp_path / "ok.txt", masks())
    assert len(read_mots(tmp_path / "ok.txt")) == 1


def test_run_json_writer_and_reader_share_one_schema(tmp_path):
    """run.json was written with NaN (not JSON) and read with any field of any type (cameras: 5
    then crashed review; smooth_frames 'x' crashed calibrate-errors)."""
    with pytest.raises(InputError) as e:
        write_run_folder(tmp_path / "run", poses(), None, {"n_frames": NAN})
    one_line(e.value, "run.json", "n_frames")
    assert list(tmp_path.iterdir()) == []
    for meta, field in (({"cameras": 5}, "cameras"), ({"smooth_frames": "x"}, "smooth_frames"),
                        ({"frame_range": [9, 2]}, "frame_range"), ({"cameras": ["../x"]}, "cameras[0]")):
        d = tmp_path / "r"
        d.mkdir(exist_ok=True)
        (d / "run.json").write_text(json.dumps(meta))
        with pytest.raises(InputError) as e:
            read_run_meta(d)
        one_line(e.value, "run.json", field)
    good = {"cameras": ["c0"], "n_frames": 3, "frame_range": [0, 2], "method": "baseline"}
    write_run_folder(tmp_path / "ok", poses(), views(), good)
    assert read_run_meta(tmp_path / "ok") == good
    assert read_poses(tmp_path / "ok" / "poses.csv").xyz.tolist() == [[1.0, 2.0, 0.0]]
    assert read_views(tmp_path / "ok" / "views.csv").uv.tolist() == [[10.0, 20.0]]


def test_settings_are_read_by_the_schema(tmp_path):
    """--set max_gap=2.5 was cut to 2 silently; every settings class refuses it now, as it
    refuses nan (the same read_settings)."""
    from seg2pose.video.assoc_pairs import AssociateConfig
    from seg2pose.video.bg_config import BgConfig
    from seg2pose.video.track import TrackConfig

    for cls, key, section in ((TrackConfig, "max_gap", "tracker"), (AssociateConfig, "min_run", "associate"),
                              (BgConfig, "history", "video_masks")):
        for bad in (2.5, NAN, True, "3"):
            with pytest.raises(InputError) as e:
                cls.from_dict({key: bad})
            one_line(e.value, f"extra.{section}.{key}")
        assert getattr(cls.from_dict({key: 7}), key) == 7
    with pytest.raises(InputError) as e:
        TrackConfig.from_dict({"iou_min": 1.5})
    one_line(e.value, "extra.tracker.iou_min", "[0, 1]")
    assert TrackConfig.from_dict({"gate_m": 3}).gate_m == 3.0


def test_calib_json_writer_refuses_a_camera_new_scene_refuses(tmp_path):
    """A degenerate solve's NaN camera gave a ValueError traceback from json.dumps; now the
    writer checks its cameras as s2p new-scene reads them."""
    from seg2pose.io.calib_files import read_calib_json, write_calibration

    cam = {"name": "c0", "width": 64, "height": 48, "K": [[50, 0, 32], [0, 50, 24], [0, 0, 1]],
           "R": [[1, 0, 0], [0, -1, 0], [0, 0, -1]], "t": [0, 0, 10]}
    ground = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    bad = dict(cam, K=[[NAN, 0, 32], [0, 50, 24], [0, 0, 1]])
    for c, field in ((bad, "cameras[c0].K"), (dict(cam, name="../c0"), "cameras[0].name")):
        with pytest.raises(InputError) as e:
            write_calibration(tmp_path / "calib.json", [c], {}, "", ground, {})
        one_line(e.value, "calib.json", field)
        assert list(tmp_path.iterdir()) == []
    with pytest.raises(InputError) as e:
        write_calibration(tmp_path / "calib.json", [cam, cam], {}, "", ground, {})
    one_line(e.value, "duplicate camera name")
    write_calibration(tmp_path / "calib.json", [cam], {"rms_px": NAN}, "", ground, {})
    cams, unsized = read_calib_json(tmp_path / "calib.json")
    assert list(cams) == ["c0"] and unsized == [] and cams["c0"].K[0, 0] == 50
    assert json.loads((tmp_path / "calib.json").read_text())["report"] == {"rms_px": None}


def test_a_ray_meeting_the_ground_beyond_what_files_hold_is_a_miss():
    """A nearly level ray met the ground 2.8e9 m away: s2p run then wrote a poses.csv that
    read_poses refused (found by the T-Analyst fuzz)."""
    from seg2pose.geometry.ground import TOO_FAR, GroundSurface

    g = GroundSurface(np.array([[0.0, 0, 0], [10, 0, 0], [0, 10, 0], [10, 10, 0]]))
    X, status = g.intersect_rays(np.array([0.0, 0, 10]), np.array([[1.0, 0, -1e-9], [1.0, 0, -1.0]]))
    assert status.tolist() == [TOO_FAR, 0] and np.isnan(X[0]).all()
    np.testing.assert_allclose(X[1], [10.0, 0, 0], atol=1e-6)


def _journal_with(tmp_path, op: dict):
    """A scene whose journal ends with one edit record holding ``op`` (as a foreign or damaged
    journal would)."""
    from review_fixtures import make_scene

    from annotate import Project
    from annotate import journal as J

    scene = make_scene(tmp_path / "scene", n_frames=10)
    with Project.open(scene) as p:
        t = p.create_track("car").track
        p.set_keyframe(t, 2, 1.0, 2.0, heading=0.0)
        seq = p.seq
    segs, _ = J.list_files(scene.root / "annotations")
    seg = segs[max(segs)]
    rec = {"seq": seq + 1, "kind": "edit", "name": "x", "ops": [dict(op, id=t)], "t": "2026-01-01T00:00:00Z"}
    with open(seg, "a") as f:
        f.write(json.dumps(rec) + "\n")
    return scene, seg, t


@pytest.mark.parametrize("op,what", [
    ({"op": "set_keyframes", "set": [[1.5, 0.0, 0.0, 0.0, []]]}, "set[0][0]"),   # was frame 1
    ({"op": "set_keyframes", "set": [[-5, 0.0, 0.0, 0.0, []]]}, "set[0][0]"),
    ({"op": "set_keyframes", "set": [[3, 1e300, 0.0, 0.0, []]]}, "set[0][1]"),
    ({"op": "set_keyframes", "set": [[10**15, 0.0, 0.0, 0.0, []]]}, "outside the scene's frames 0..9"),
    ({"op": "set_fields", "fields": {"size": [0, 1, 1]}}, "fields.size"),
    ({"op": "set_fields", "fields": {"spans": [[5, 2, "occluded"]]}}, "fields.spans[0]"),
    ({"op": "set_fields", "fields": {"cls": "../car"}}, "fields.cls"),
])
def test_journal_replay_refuses_records_outside_the_schema(tmp_path, op, what):
    """Replay took int(1.5) = 1, frames -5 and 10^15 (its interpolation then asked for 7 PiB;
    an edit there is refused), x = 1e300 (no poses.csv holds it), a size of 0 and a span that
    ends before it starts: now the one schema of the journal's operations refuses
    them, naming the segment and its line."""
    from annotate import JournalError, Project

    scene, seg, _ = _journal_with(tmp_path, op)
    with pytest.raises(JournalError) as e:
        Project.open(scene, read_only=True)
    one_line(e.value, seg.name, what)



def test_import_detections_refuses_frames_s2p_run_refuses(tmp_path):
    """A scene with neither video nor splits: a COCO detection at frame 10^15 was imported,
    and s2p run (and review, export) then refused the masks; the importer now takes the same
    last frame (the last one MCAP and Rerun can time), and nothing is written."""
    from io_fixtures import make_scene

    from seg2pose.video.video_scene import scene_import_detections

    scene = make_scene(tmp_path / "s")
    scene.splits = {}
    scene.save()
    poly = [[100, 100, 140, 100, 140, 160, 100, 160]]
    recs = [{"frame": f, "category_id": 3, "segmentation": poly, "score": 0.9} for f in (0, 10**15)]
    (tmp_path / "d.json").write_text(json.dumps({"images": [{"id": 0, "height": 480, "width": 640},
                                                            {"id": 10**15, "height": 480, "width": 640}],
                                                 "annotations": [dict(r, image_id=r["frame"]) for r in recs]}))
    with pytest.raises(InputError) as e:
        scene_import_detections(scene.root, "c0", tmp_path / "d.json", force=True, log=lambda s: None)
    one_line(e.value, "d.json", "frame 1000000000000000")
    assert not scene.masks_path("c0").exists()
