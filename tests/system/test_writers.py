"""Issue 24: every writing command keeps the promise (nothing half-written under a final name,
outputs checked up front and replaced as a unit, one lock per output, stale partials removed)
and importers refuse what the scene's readers would refuse. One test per failure of the
issue's table; the outputs written as one set (annotate export, import-mcap) are in
tests/system/test_writer_sets.py; tests/system/test_kill.py kills the commands for real."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import warnings

import pytest
from hostile_fixtures import write_scene
from scene_fixtures import s2p
from video_fixtures import calibration, det, rle, single_threaded_opencv, write_folder

from seg2pose.core.errors import InputError, S2PError
from seg2pose.io.atomic import output_lock
from seg2pose.io.mots import read_mots

opencv_one_thread = pytest.fixture(autouse=True)(single_threaded_opencv)

BG = {"min_area": 40, "init_samples": 8}
BOXES = [dict(id=1, x=10, y=60, w=10, h=24, vx=2, vy=0)]


@pytest.fixture
def video_scene(tmp_path):
    """A scene made by new-scene from a 12-frame image folder, with a detector's masks."""
    from seg2pose.video.video_scene import new_scene, scene_import_detections

    calibration(tmp_path)
    write_folder(tmp_path / "frames", 12, BOXES)
    root = tmp_path / "sc"
    new_scene(root, {"c0": tmp_path / "frames"}, tmp_path / "calib.json", tmp_path / "ground.csv",
              fps=10, log=lambda s: None)
    (tmp_path / "d.json").write_text(json.dumps([det(f, 3, rle(20 + 2 * f, 40, 12, 10))
                                                 for f in range(12)]))
    scene_import_detections(root, "c0", tmp_path / "d.json", log=lambda s: None)
    return root


def _boom(*a, **k):
    raise RuntimeError("killed here")


# --- masks-from-video, import-detections, track --------------------------------------------------

def test_masks_from_video_keeps_the_old_masks_until_all_stages_are_done(video_scene, monkeypatch):
    """A stop between the tracker and the size classes (where a kill left track ids without
    classes under the final name) leaves the old masks whole, and nothing beside them."""
    import seg2pose.video.video_scene as vs
    from seg2pose.video.video_scene import scene_masks_from_video

    old = (video_scene / "masks" / "c0.txt").read_bytes()
    monkeypatch.setattr(vs, "classify_mots", _boom)
    with pytest.raises(RuntimeError, match="killed here"):
        scene_masks_from_video(video_scene, bg=BG, force=True, log=lambda s: None)
    assert (video_scene / "masks" / "c0.txt").read_bytes() == old
    assert sorted(p.name for p in (video_scene / "masks").iterdir()) == ["c0.txt", "ids.json"]


def test_import_detections_tracks_before_the_masks_reach_their_name(video_scene, tmp_path,
                                                                  monkeypatch):
    import seg2pose.video.video_scene as vs
    from seg2pose.video.video_scene import scene_import_detections

    old = (video_scene / "masks" / "c0.txt").read_bytes()
    (tmp_path / "e.json").write_text(json.dumps([det(f, 1, rle(60, 40 + f, 8, 20))
                                                 for f in range(12)]))
    monkeypatch.setattr(vs, "track_mots", _boom)
    with pytest.raises(RuntimeError, match="killed here"):
        scene_import_detections(video_scene, "c0", tmp_path / "e.json", force=True,
                                log=lambda s: None)
    assert (video_scene / "masks" / "c0.txt").read_bytes() == old


def test_a_second_writer_of_the_masks_is_refused_and_dead_partials_removed(video_scene):
    from seg2pose.video.video_scene import scene_masks_from_video, scene_track

    masks = video_scene / "masks"
    with output_lock(masks / "c0.txt"):
        # what a second `s2p masks-from-video --force` meets while the first one writes
        with pytest.raises(S2PError, match="is being written by process"):
            scene_masks_from_video(video_scene, bg=BG, force=True, log=lambda s: None)
        with pytest.raises(S2PError, match="is being written by process"):
            scene_track(video_scene, log=lambda s: None)
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True).stdout.strip()
    (masks / f".c0.txt.partial-{dead}-abc.tmp").write_text("1 -1 0 1 1 1\n")
    (masks / f".c0.txt.partial-{dead}-def").mkdir()
    (masks / f".c0.txt.partial-{dead}-def" / "c0.txt").write_text("x")
    (masks / f"..c0.txt.partial-{dead}-abc.tmp.partial-{dead}-x.tmp").write_text("x")
    scene_masks_from_video(video_scene, bg=BG, force=True, log=lambda s: None)
    assert sorted(p.name for p in masks.iterdir()) == ["c0.txt", "ids.json"]
    t = read_mots(masks / "c0.txt")
    assert len(t) and (t.track_id >= 0).all() and (t.class_id > 0).all()


def test_track_in_place_is_all_or_nothing(video_scene, monkeypatch):
    import seg2pose.video.video_scene as vs
    from seg2pose.video.video_scene import scene_masks_from_video, scene_track

    scene_masks_from_video(video_scene, bg=BG, track=False, classify=False, force=True,
                           log=lambda s: None)
    old = (video_scene / "masks" / "c0.txt").read_bytes()
    monkeypatch.setattr(vs, "classify_mots", _boom)
    with pytest.raises(RuntimeError, match="killed here"):
        scene_track(video_scene, classify=True, log=lambda s: None)
    assert (video_scene / "masks" / "c0.txt").read_bytes() == old


# --- new-scene ----------------------------------------------------------------------------------

def test_new_scene_force_replaces_the_scene_whole_and_copies_the_video(video_scene, tmp_path):
    """--force with a new .avi: the old masks and the old video/c0.mp4-or-folder are gone, the
    scene reads the new video (named in scene.json), and the scene's video is a copy: editing
    it leaves the original as it was."""
    from video_fixtures import write_video

    from seg2pose.io.scene import load_scene
    from seg2pose.video.video_scene import new_scene

    avi = write_video(tmp_path / "new.avi", 12, BOXES)
    (video_scene / "video" / "c0.mp4").write_bytes(b"an old video preferred by name")
    new_scene(video_scene, {"c0": avi}, tmp_path / "calib.json", tmp_path / "ground.csv",
              fps=10, force=True, log=lambda s: None)
    s = load_scene(video_scene)
    assert s.video_path("c0") == video_scene / "video" / "c0.avi"
    assert s.videos == {"c0": "video/c0.avi"}
    assert sorted(p.name for p in (video_scene / "video").iterdir()) == ["c0.avi"]
    assert not (video_scene / "masks" / "c0.txt").exists()
    assert os.stat(avi).st_nlink == 1
    original = avi.read_bytes()
    with open(video_scene / "video" / "c0.avi", "r+b") as f:
        f.write(b"edited")
    assert avi.read_bytes() == original
    assert sorted(p.name for p in video_scene.parent.iterdir() if p.name.startswith(".")) == []


def test_new_scene_refuses_up_front_and_old_scenes_keep_their_video(video_scene, tmp_path):
    from seg2pose.io.scene import load_scene
    from seg2pose.video.video_scene import new_scene

    before = sorted(p.relative_to(video_scene) for p in video_scene.rglob("*"))
    with pytest.raises(S2PError, match="exists; pass --force"):
        new_scene(video_scene, {"c0": tmp_path / "frames"}, tmp_path / "calib.json",
                  tmp_path / "ground.csv", fps=10, log=lambda s: None)
    assert sorted(p.relative_to(video_scene) for p in video_scene.rglob("*")) == before
    # a scene.json without "videos" (older scenes) still finds video/<camera>...
    d = json.loads((video_scene / "scene.json").read_text())
    d.pop("videos")
    (video_scene / "scene.json").write_text(json.dumps(d))
    assert load_scene(video_scene).video_path("c0") == video_scene / "video" / "c0"
    # ...and one that names a video outside the scene is refused
    d["videos"] = {"c0": "../frames"}
    (video_scene / "scene.json").write_text(json.dumps(d))
    with pytest.raises(InputError, match="videos.c0"):
        load_scene(video_scene)


# --- batch --------------------------------------------------------------------------------------

def test_batch_resumes_after_a_kill_while_the_masks_are_written(tmp_path):
    """SIGKILL the serial batch the moment masks/c0.txt appears (on the old code: a stage's
    file with class 0), then re-run without --force: it completes."""
    from command_zygote import zygote

    from seg2pose.io.scene import load_scene
    from seg2pose.video.video_scene import new_scene

    calibration(tmp_path)
    write_folder(tmp_path / "frames", 12, BOXES)
    study = tmp_path / "study"
    new_scene(study / "s1", {"c0": tmp_path / "frames"}, tmp_path / "calib.json",
              tmp_path / "ground.csv", fps=10, log=lambda s: None)
    s = load_scene(study / "s1")
    s.extra["video_masks"] = BG
    s.save()
    argv = ["batch", study, "masks-from-video", "run", "--baseline", "--serial", "--no-progress"]
    z = zygote()
    pid = z.start(argv)
    masks = study / "s1" / "masks" / "c0.txt"
    while z.wait(0.002) is None:
        if masks.exists():
            os.killpg(pid, 9)
            z.wait()
            break
    assert masks.exists()
    z.start(argv)
    assert z.wait(300) == 0, z.error_text()
    summary = json.loads((study / "summary.json").read_text())
    assert summary["n_failed"] == 0 if "n_failed" in summary else True
    t = read_mots(masks)
    assert len(t) and (t.class_id > 0).all() and (t.track_id >= 0).all()
    assert (study / "s1" / "batch" / "baseline" / "poses.csv").exists()


def test_batch_starts_a_ray_of_its_own_unless_given_an_address(tmp_path, monkeypatch, capsys):
    """Without --address, batch starts a local Ray of its own (address 'local': never a
    cluster another command started on this machine, which a plain ray.init() would join),
    sized by --cpus; --cpus with --address is refused in one line."""
    import seg2pose.batch.study as ST

    calls = []

    class FakeRay:
        @staticmethod
        def is_initialized():
            return False

        @staticmethod
        def init(**kw):
            calls.append(kw)
            raise S2PError("stop here")

    monkeypatch.setattr(ST, "import_ray", lambda: FakeRay)
    study = tmp_path / "study"
    (study / "s1").mkdir(parents=True)
    (study / "s1" / "scene.json").write_text("{}")
    for extra, want in (([], {"address": "local", "num_cpus": None}),
                        (["--cpus", "1"], {"address": "local", "num_cpus": 1}),
                        (["--address", "auto"], {"address": "auto", "num_cpus": None})):
        code, _, err = s2p(monkeypatch, capsys, "batch", study, "eval", *extra, "--no-progress")
        assert code != 0 and "stop here" in err
        assert {k: calls[-1][k] for k in want} == want
    code, _, err = s2p(monkeypatch, capsys, "batch", study, "eval", "--cpus", "1", "--address",
                       "auto")
    assert code == 2 and err.count("\n") == 1 and "--cpus" in err
    assert len(calls) == 3


# --- importers: the readers' limits --------------------------------------------------------------

def test_import_detections_drops_empty_masks_and_refuses_frames_past_the_scene(tmp_path):
    from seg2pose.video.video_scene import scene_import_detections

    scene = write_scene(tmp_path / "sc", frames=6)  # 64x48, splits train 0..5
    outside = [[100, 100, 120, 100, 120, 130, 100, 130]]  # a polygon wholly outside the image
    recs = [det(f, 1, [[10, 10, 20, 10, 20, 30, 10, 30]]) for f in range(5)] + \
           [det(f, 1, outside) for f in range(5)]
    (tmp_path / "d.json").write_text(json.dumps(recs))
    said = []
    n = scene_import_detections(scene.root, "c0", tmp_path / "d.json", force=True, log=said.append)
    t = read_mots(scene.masks_path("c0"))
    written = scene.masks_path("c0").read_bytes()
    assert n == len(t) == 5 and any("5 empty masks" in s for s in said)
    (tmp_path / "far.json").write_text(json.dumps([det(10**15, 1, [[10, 10, 20, 10, 20, 30]])]))
    with pytest.raises(InputError, match="image_id.*frame 1000000000000000 matches no video frame"):
        scene_import_detections(scene.root, "c0", tmp_path / "far.json", force=True,
                                log=said.append)
    assert scene.masks_path("c0").read_bytes() == written


@pytest.mark.parametrize("field,value,match", [
    ("k", "1e30", "field 'k': 'k' must be within"),
    ("f", "1e308", "field 'f'"),
    ("Cx", "1e300", "field 'Cx'"),
])
def test_import_tacal_refuses_what_the_scene_reader_refuses(tmp_path, field, value, match):
    from seg2pose.io.tacal import camera_to_tacal, format_tacal, scene_from_tacals

    cam = calibration(tmp_path)
    text = format_tacal(camera_to_tacal(cam))
    lines = [f"{field}: {value}" if ln.startswith(f"{field}:") else ln for ln in text.splitlines()]
    (tmp_path / "c0.tacal").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=match) as e:
        scene_from_tacals([tmp_path / "c0.tacal"], tmp_path / "ground.csv", tmp_path / "out", 10.0)
    assert str(e.value).startswith(str(tmp_path / "c0.tacal"))
    assert not (tmp_path / "out").exists()


def test_import_tacal_size_is_bounded(tmp_path, monkeypatch, capsys):
    from seg2pose.io.tacal import camera_to_tacal, write_tacal

    write_tacal(tmp_path / "c0.tacal", camera_to_tacal(calibration(tmp_path)))
    code, _, err = s2p(monkeypatch, capsys, "import-tacal", tmp_path / "c0.tacal", "--ground",
                       tmp_path / "ground.csv", "-o", tmp_path / "out", "--fps", "10", "--size",
                       "99999999x99999999")
    assert code == 2 and err.count("\n") == 1 and "--size" in err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("row,match", [
    ("1;Car;1000000000000000000000000000000;-8;-1,5;12:00:00.000", r":2: field 'Road user ID'"),
    ("1;Car;3;1e300;-1,5;12:00:00.000", r":2: field 'X \(m\)'"),
    ("1;Car;3;1e999;-1,5;12:00:00.000", r":2: field 'X \(m\)'"),
])
def test_import_tanalyst_bounds_ids_and_coordinates(tmp_path, row, match):
    from seg2pose.io.tanalyst import read_tanalyst

    (tmp_path / "t.csv").write_text("Detection ID;Type of road user;Road user ID;X (m);Y (m);"
                                    f"Time Stamp\n{row}\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(InputError, match=match):
            read_tanalyst(tmp_path / "t.csv")


def test_run_on_untracked_masks_says_to_track_them(video_scene, tmp_path, monkeypatch, capsys):
    from seg2pose.video.video_scene import scene_masks_from_video

    scene_masks_from_video(video_scene, bg=BG, track=False, force=True, log=lambda s: None)
    code, _, err = s2p(monkeypatch, capsys, "run", video_scene, "-o", tmp_path / "run",
                       "--baseline")
    assert code == 2 and err.count("\n") == 1
    assert "c0.txt: none of its" in err and "s2p track" in err
