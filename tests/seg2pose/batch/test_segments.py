"""Long videos in segments (seg2pose/batch/segments.py): a 240-frame synthetic video cut in two at
frame 120 gives the tracks of the uncut run, apart from the seam; a warm-up too short for the
tracker costs a known ID switch at the seam (a road user hidden across the border), which the
stitch reports; a re-run skips finished segments; a failed segment leaves nothing partial."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner
from video_fixtures import calibration, single_threaded_opencv, write_folder

from seg2pose.batch.segments import plan_scene, plan_segments, scene_masks_segmented, segment_path
from seg2pose.eval.mask_eval import score_masks
from seg2pose.io.mots import iter_mots, read_mots
from seg2pose.video.video_scene import new_scene, scene_masks_from_video

opencv_one_thread = pytest.fixture(autouse=True)(single_threaded_opencv)

N, BORDER = 240, 120
# road users (pixels, pixels per frame): three cross the border; "hidden" (id 3) is out of
# sight in frames 115..125, around the border, and comes back on the same path
BOXES = [dict(id=1, x=5 - 1.2 * 60, y=10, w=12, h=16, vx=1.2, frames=(60, 200)),
         dict(id=2, x=145 + 1.5 * 90, y=34, w=14, h=12, vx=-1.5, frames=(90, 180)),
         dict(id=3, x=5 - 70, y=56, w=12, h=18, vx=1.0, frames=(70, 114)),
         dict(id=3, x=5 - 70, y=56, w=12, h=18, vx=1.0, frames=(126, 200)),
         dict(id=4, x=20, y=80, w=16, h=14, vx=1.5, frames=(10, 60)),
         dict(id=5, x=150 + 1.3 * 150, y=96, w=14, h=14, vx=-1.3, frames=(150, 230))]
SETTINGS = {"min_area": 40, "init_samples": 8, "history": 30}


@pytest.fixture(scope="module")
def video_scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("seg")
    calibration(root)
    write_folder(root / "frames", N, BOXES)
    sc = root / "scene"
    new_scene(sc, {"c0": root / "frames"}, root / "calib.json", root / "ground.csv", fps=10,
              log=lambda s: None)
    d = json.loads((sc / "scene.json").read_text())
    d.setdefault("extra", {})["video_masks"] = SETTINGS
    (sc / "scene.json").write_text(json.dumps(d))
    single = root / "single"
    shutil.copytree(sc, single)
    scene_masks_from_video(single, log=lambda s: None)
    return sc, single / "masks" / "c0.txt"


def copy_scene(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def compare(single: Path, split: Path):
    """(MaskScores of split against single, frames whose lines differ)."""
    s = score_masks(iter_mots(single), iter_mots(split), min_area=0)
    a, b = (set(p.read_text().splitlines()) for p in (single, split))
    return s, sorted({int(line.split()[0]) for line in a ^ b})


def test_plan_cuts_long_videos_only():
    f = np.arange(1000, 1000 + 2 * 300, 2)  # 300 frames, scene frames 1000, 1002, ...
    assert len(plan_segments(f, 201, 10)) == 1  # shorter than 1.5 segments: not cut
    segs = plan_segments(f, 100, 10)
    assert [s.n_frames for s in segs] == [100, 100, 100] and segs[0].read_from == 1000
    assert (segs[1].first, segs[1].last, segs[1].read_from, segs[1].match_from) == (1200, 1398, 1180, 1190)
    assert segs[2].last == 1598 and segs[1].n_warm == 10


def test_two_segments_give_the_uncut_tracks(video_scene, tmp_path):
    sc, single = video_scene
    plan = plan_scene(sc, BORDER)["c0"]
    assert [(s.first, s.last, s.read_from) for s in plan] == [(0, 119, 0), (120, 239, 30)]  # warm-up 90
    split = copy_scene(sc, tmp_path / "split")
    info = scene_masks_segmented(split, BORDER, log=lambda s: None)["c0"]
    s, frames = compare(single, split / "masks" / "c0.txt")
    print(f"\nseam (warm-up 90 frames): {s.switches} ID switches against the uncut run, "
          f"stitch: {info['seams']}")
    assert info["segments"] == 2 and info["frames"] == N
    assert s.tracks == 5 and s.recall == 1.0 and s.precision == 1.0
    assert s.switches == 0 and info["seams"][0]["id_changes"] == 0 and info["seams"][0]["linked"] == 3
    # ids and masks identical outside the seam (the later segment's background model differs a
    # little until it has settled)
    assert all(abs(f - BORDER) <= 90 for f in frames), frames


def test_short_warm_up_costs_the_hidden_road_user_its_id(video_scene, tmp_path):
    """A 4-frame warm-up (the default is 90 here): the road user hidden across the border
    (frames 115..125) is not seen by the later segment before the border, so its id changes
    there: exactly one ID switch against the uncut run, reported by the stitch as a track not
    continued."""
    sc, single = video_scene
    split = copy_scene(sc, tmp_path / "split")
    info = scene_masks_segmented(split, BORDER, overlap=4, log=lambda s: None)["c0"]
    s, frames = compare(single, split / "masks" / "c0.txt")
    seam = info["seams"][0]
    print(f"\nseam (warm-up 4 frames): {s.switches} ID switches against the uncut run, stitch: {seam}")
    assert s.switches == 1 and s.precision == 1.0
    # the later segment's background model had 4 frames to settle: some masks of the first
    # frames after the border are missing too; the earlier segment's frames are untouched
    assert s.recall > 0.95 and min(frames) >= BORDER
    assert seam["unlinked"] == 1 and seam["id_changes"] == 0 and seam["linked"] == 2
    assert len({int(t) for t in read_mots(split / "masks" / "c0.txt").track_id}) == 6  # 5 + 1


def cli(args):
    from seg2pose.cli import app

    return CliRunner().invoke(app, args)


def test_batch_segments_resume_and_a_failed_segment_leaves_nothing(video_scene, tmp_path, monkeypatch):
    sc, single = video_scene
    st = tmp_path / "st"
    copy_scene(sc, st / "v")
    seg_dir = st / "v" / "batch" / "segments" / "c0"
    # the second segment fails half-way through writing its tracks
    import seg2pose.video.track as track
    from seg2pose.io.atomic import atomic_open
    from seg2pose.io.mots import format_mots_lines

    real = track.write_mots

    def failing(path, tables):
        if "00000120-00000239" not in Path(path).name:
            return real(path, tables)
        with atomic_open(path, "w") as f:
            for i, t in enumerate(tables):
                f.writelines(format_mots_lines(t))
                if i == 20:
                    raise RuntimeError("injected failure")

    monkeypatch.setattr(track, "write_mots", failing)
    r = cli(["batch", str(st), "masks-from-video", "--serial", "--no-progress", "--segment-frames", "120"])
    assert r.exit_code == 1, r.output
    row = json.loads((st / "summary.json").read_text())["scenes"][0]
    assert row["steps"] == {"masks-from-video": "failed"}
    assert "segment c0 00000120-00000239: RuntimeError: injected failure" in row["failures"][0]["error"]
    assert sorted(p.name for p in seg_dir.iterdir()) == ["00000000-00000119.json", "00000000-00000119.txt"]
    assert not (st / "v" / "masks" / "c0.txt").exists()
    first = (seg_dir / "00000000-00000119.json").stat().st_mtime_ns
    # the re-run skips the finished segment and writes what the library's split writes
    monkeypatch.setattr(track, "write_mots", real)
    r = cli(["batch", str(st), "masks-from-video", "--serial", "--no-progress", "--segment-frames", "120"])
    assert r.exit_code == 0, r.output
    assert "v: video in 2 segments; at the seams 0 id changes, 0 tracks not continued" in r.output
    assert (seg_dir / "00000000-00000119.json").stat().st_mtime_ns == first
    row = json.loads((st / "summary.json").read_text())["scenes"][0]
    assert row["segments"] == 2 and row["seam_id_changes"] == 0 and row["frames"] == N
    assert row["seams"]["c0"][0]["border"] == BORDER
    lib = copy_scene(sc, tmp_path / "lib")
    scene_masks_segmented(lib, BORDER, log=lambda s: None)
    assert (st / "v" / "masks" / "c0.txt").read_bytes() == (lib / "masks" / "c0.txt").read_bytes()
    # a third run: the step is complete, nothing runs
    r = cli(["batch", str(st), "masks-from-video", "--serial", "--no-progress", "--segment-frames", "120"])
    row = json.loads((st / "summary.json").read_text())["scenes"][0]
    assert r.exit_code == 0 and row["steps"] == {"masks-from-video": "skipped"}
    # a segment whose file was damaged is redone; what a killed task left beside it is removed
    seg = plan_scene(st / "v", BORDER)["c0"][1]
    p = segment_path(st / "v", seg)
    p.write_text(p.read_text()[:-50])
    dead = 2**22 + 12345  # above Linux's largest pid
    killed = [p.parent / f".{p.name}.partial-{dead}-x1.txt",
              p.parent / f"..{p.name}.partial-{dead}-x1.txt.partial-{dead}-y2.tmp"]
    for k in killed:
        k.write_text("half")
    from seg2pose.batch.segments import run_segment
    assert run_segment(st / "v", seg)["status"] == "done"
    assert not any(k.exists() for k in killed)
    assert run_segment(st / "v", seg)["status"] == "skipped"
