"""``s2p batch`` over a study of 4 tiny synthetic scenes (one with a corrupt masks file) on a
local Ray with 2 CPUs (one Ray instance for the module): outputs equal to the single-scene
commands', the corrupt scene reported and the others complete, a worker killed in the middle of
writing a run and the study still complete with nothing partial, a second run skipping the
work, and the serial fallback without Ray."""

from __future__ import annotations

import json
import os
import shutil
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from seg2pose.batch.steps import EVAL, RUN
from seg2pose.batch.study import BatchOptions, Step, run_study
from seg2pose.synth.generate import SynthOptions, generate_scene

ray = pytest.importorskip("ray", reason="Ray is the optional extra seg2pose[scale] (make test installs it)")

FRAMES = 4  # per split: 14 frames a scene


@pytest.fixture(scope="module")
def ray_local():
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    # the kill step below lives in this module, which Ray's workers cannot import
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    yield
    ray.shutdown()


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """Four scenes a..d (seeds 0..3) made once; studies are copies of them."""
    root = tmp_path_factory.mktemp("scenes")
    for seed, name in enumerate("abcd"):
        generate_scene(root / name, SynthOptions(frames=FRAMES, seed=seed, progress=False, workers=1))
    return root


def make_study(scenes: Path, dst: Path, names="abcd", corrupt="c") -> Path:
    for n in names:
        shutil.copytree(scenes / n, dst / n)
    if corrupt and corrupt in names:
        (dst / corrupt / "masks" / "c1.txt").write_text("0 1 1 not a mask\n")
    return dst


def cli(args: list[str]):
    from seg2pose.cli import app

    return CliRunner().invoke(app, args)


@pytest.fixture(scope="module")
def study(ray_local, scenes, tmp_path_factory):
    st = make_study(scenes, tmp_path_factory.mktemp("study") / "st")
    r = cli(["batch", str(st), "run", "eval", "export", "--baseline", "--no-progress"])
    return st, r


def test_batch_matches_single_scene_commands(study, tmp_path):
    st, r = study
    assert r.exit_code == 1, r.output  # one scene failed
    assert "4 scenes, 1 failed" in r.output and "on ray" in r.output
    a = st / "a"
    single = tmp_path / "a-single"
    assert cli(["run", str(a), "-o", str(single), "--baseline"]).exit_code == 0
    batch_run = a / "batch" / "baseline"
    for f in ("poses.csv", "views.csv"):
        assert (batch_run / f).read_bytes() == (single / f).read_bytes()
    m1, m2 = (json.loads((d / "run.json").read_text()) for d in (batch_run, single))
    for m in (m1, m2):
        del m["created"], m["scene"]  # the time, and the scene's path relative to the run
    assert m1 == m2
    # eval: what `s2p eval --json` prints
    r2 = cli(["eval", str(a), "--run", str(batch_run), "--json"])
    assert json.loads(r2.output) == json.loads((a / "batch" / "baseline.eval.json").read_text())
    # export: the same MCAP, byte for byte
    out = tmp_path / "a.mcap"
    assert cli(["export", str(a), "--run", str(batch_run), "-o", str(out)]).exit_code == 0
    assert out.read_bytes() == (a / "batch" / "baseline.mcap").read_bytes()


def test_corrupt_scene_reported_others_complete(study):
    st, r = study
    summ = json.loads((st / "summary.json").read_text())
    rows = {row["scene"]: row for row in summ["scenes"]}
    assert summ["backend"] == "ray" and summ["steps"] == ["run", "eval", "export"]
    bad = rows["c"]
    assert bad["steps"] == {"run": "failed", "eval": "not run", "export": "not run"}
    assert len(bad["failures"]) == 1 and "c1.txt:1" in bad["failures"][0]["error"]
    assert not (st / "c" / "batch" / "baseline").exists()  # nothing partial of it
    from seg2pose.io.run import read_run_poses

    for n in "abd":
        row = rows[n]
        assert row["failures"] == [] and set(row["steps"].values()) == {"done"}
        poses = read_run_poses(st / n / "batch" / "baseline")
        assert row["frames"] == 3 * FRAMES + 2  # three splits of 4 frames, gaps of one
        assert row["road_users"] == len(set(poses.track_id.tolist())) > 0
        ev = json.loads((st / n / "batch" / "baseline.eval.json").read_text())
        assert row["mean_error_m"] == pytest.approx(ev["mean_error"])
    assert "c1.txt:1" in r.output and r.output.count("\n") >= 6  # the table


def test_second_run_skips_complete_work(study):
    st, _ = study
    outs = sorted(p for p in st.rglob("*") if p.is_file() and p.name != "summary.json")
    before = {p: p.stat().st_mtime_ns for p in outs}
    r = cli(["batch", str(st), "run", "eval", "export", "--baseline", "--no-progress"])
    assert r.exit_code == 1
    summ = json.loads((st / "summary.json").read_text())
    rows = {row["scene"]: row for row in summ["scenes"]}
    for n in "abd":
        assert set(rows[n]["steps"].values()) == {"skipped"}
        assert rows[n]["frames"] == 3 * FRAMES + 2  # the figures come from the records
    assert rows["c"]["steps"]["run"] == "failed"  # a bad scene is tried again, and fails again
    assert {p: p.stat().st_mtime_ns for p in outs} == before  # nothing rewritten
    # a changed input re-runs the steps that read it, and only those
    gt = st / "b" / "gt" / "poses.csv"
    gt.write_text(gt.read_text() + "\n")
    r = cli(["batch", str(st), "run", "eval", "--baseline", "--no-progress"])
    rows = {row["scene"]: row for row in json.loads((st / "summary.json").read_text())["scenes"]}
    assert rows["b"]["steps"] == {"run": "skipped", "eval": "done"}
    assert rows["a"]["steps"] == {"run": "skipped", "eval": "skipped"}


def _run_killed_once(scene_dir: Path, opts: BatchOptions, force: bool) -> dict:
    """The run step, but the first attempt per scene kills its worker process half-way through
    writing the run folder (poses.csv written into the temporary folder, views.csv not)."""
    mark = scene_dir.parent / f".killed-{scene_dir.name}"
    if not mark.exists():
        mark.touch()
        import seg2pose.io.run as run_io

        def die(*args, **kwargs):
            os._exit(1)

        run_io.format_views = die
    return RUN.run(scene_dir, opts, force)


def test_killed_worker_is_retried_nothing_partial(ray_local, scenes, study, tmp_path):
    st = make_study(scenes, tmp_path / "st", names="ab", corrupt="")
    kill_run = Step("run", RUN.inputs, RUN.outputs, _run_killed_once)
    res = run_study(st, [kill_run, EVAL], BatchOptions(), progress=False, log=lambda s: None)
    assert res.backend == "ray"
    assert (st / ".killed-a").exists() and (st / ".killed-b").exists()  # both workers died once
    assert [r["status"] for r in res.results["run"]] == ["done", "done"]
    assert res.n_failed == 0
    left = [p for p in st.rglob("*") if "partial" in p.name or p.name.startswith(".baseline")]
    assert left == []
    # and the result is the one of an undisturbed run
    for n in "ab":
        for f in ("poses.csv", "views.csv"):
            assert ((st / n / "batch" / "baseline" / f).read_bytes()
                    == (study[0] / n / "batch" / "baseline" / f).read_bytes())


def test_serial_without_ray(scenes, study, tmp_path, monkeypatch):
    import seg2pose.cli.batch as cb

    st = make_study(scenes, tmp_path / "st", names="ad")
    monkeypatch.setattr(cb, "ray_available", lambda: False)
    r = cli(["batch", str(st), "run", "--baseline", "--no-progress"])
    assert r.exit_code == 0, r.output
    assert "Ray is not installed" in r.output and "seg2pose[scale]" in r.output and "on serial" in r.output
    for n in "ad":
        assert ((st / n / "batch" / "baseline" / "poses.csv").read_bytes()
                == (study[0] / n / "batch" / "baseline" / "poses.csv").read_bytes())


def test_bad_usage_is_one_clear_error(tmp_path):
    r = cli(["batch", str(tmp_path), "run", "--baseline"])
    assert r.exit_code != 0 and "no scene folders" in str(r.exception)
    (tmp_path / "x").mkdir()
    (tmp_path / "x" / "scene.json").write_text("{}")
    r = cli(["batch", str(tmp_path), "fly"])
    assert "unknown step 'fly'" in str(r.exception)
    r = cli(["batch", str(tmp_path), "run"])
    assert "--baseline or --models" in str(r.exception)


def test_masks_from_video_step_matches_the_command(tmp_path):
    """A study with one video scene and one whose video is missing: the masks written by the
    batch step are the masks `s2p masks-from-video` writes; the other scene is reported."""
    import cv2
    from video_fixtures import calibration, write_folder

    calibration(tmp_path)
    write_folder(tmp_path / "frames", 16, [dict(id=1, x=10, y=60, w=10, h=24, vx=2, vy=0)])
    st = tmp_path / "st"
    for n in ("v1", "v2"):
        r = cli(["new-scene", "-o", str(st / n), "--video", f"c0={tmp_path / 'frames'}", "--calibration",
                 str(tmp_path / "calib.json"), "--ground", str(tmp_path / "ground.csv"), "--fps", "10"])
        assert r.exit_code == 0, r.output
        sj = st / n / "scene.json"
        d = json.loads(sj.read_text())
        d.setdefault("extra", {})["video_masks"] = {"min_area": 40, "init_samples": 8}
        sj.write_text(json.dumps(d))
    single = tmp_path / "single"
    shutil.copytree(st / "v1", single, symlinks=True)
    shutil.rmtree(st / "v2" / "video")  # the bad scene: no video
    n_threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        r = cli(["batch", str(st), "masks-from-video", "--serial", "--no-progress"])
        assert cli(["masks-from-video", str(single), "--no-progress"]).exit_code == 0
    finally:
        cv2.setNumThreads(n_threads)
    assert r.exit_code == 1, r.output
    rows = {row["scene"]: row for row in json.loads((st / "summary.json").read_text())["scenes"]}
    assert rows["v1"]["steps"] == {"masks-from-video": "done"} and rows["v1"]["frames"] == 16
    assert rows["v2"]["steps"] == {"masks-from-video": "failed"}
    got = (st / "v1" / "masks" / "c0.txt").read_bytes()
    assert got == (single / "masks" / "c0.txt").read_bytes() and len(got.splitlines()) == 16
    # a re-run skips it; masks it did not make are not replaced without --force
    r = cli(["batch", str(st), "masks-from-video", "--serial", "--no-progress"])
    rows = {row["scene"]: row for row in json.loads((st / "summary.json").read_text())["scenes"]}
    assert rows["v1"]["steps"] == {"masks-from-video": "skipped"}


def test_train_fan_out_gives_the_serial_models(ray_local, tmp_path):
    """`s2p train --parallel`: camera x class x run as Ray tasks (2 cameras, a model per class,
    best of 2 runs) give the same checkpoints, byte for byte, as the serial protocol (same
    seeds, same examples, the same best run picked); no run files are left."""
    from scene_fixtures import make_tiny_scene, tiny_config

    from seg2pose.core.ray import ray_map
    from seg2pose.training.train import train_scene

    scene = make_tiny_scene(tmp_path / "tiny", frames=30, n_users=6, seed=1)
    cfg = tiny_config(rough_every=0, epochs=2, batches_per_epoch=3, runs=2, share_classes=False)
    cams = ["c0", "c1"]
    ser = train_scene(scene, tmp_path / "serial", cfg, cameras=cams, progress=False)
    par = train_scene(scene, tmp_path / "ray", cfg, cameras=cams, progress=False,
                      map_groups=ray_map())
    files = sorted(p.name for p in ser.iterdir())
    assert files == sorted(p.name for p in par.iterdir())
    models = [f for f in files if f.endswith(".safetensors")]
    assert len(models) >= 4 and not any(".run" in f or ".state" in f for f in files), files
    for f in files:
        assert (ser / f).read_bytes() == (par / f).read_bytes(), f
    runs = [json.loads((ser / f).read_text())["run"] for f in files if f.endswith(".json")]
    print(f"\nbest runs of the {len(models)} models: {runs}")
    assert set(runs) <= {1, 2}


def test_long_video_segments_as_ray_tasks(ray_local, tmp_path):
    """A 200-frame video cut into 2 segments by `s2p batch masks-from-video --segment-frames
    100` on Ray: the segments run as tasks of their own; the masks are those of the library's
    serial split."""
    from video_fixtures import calibration, write_folder

    from seg2pose.batch.segments import scene_masks_segmented

    calibration(tmp_path)
    write_folder(tmp_path / "frames", 200, [dict(id=1, x=-40, y=60, w=12, h=20, vx=2.5, vy=0),
                                            dict(id=2, x=250, y=20, w=14, h=14, vx=-2.2, vy=0)])
    st = tmp_path / "st"
    r = cli(["new-scene", "-o", str(st / "v"), "--video", f"c0={tmp_path / 'frames'}", "--calibration",
             str(tmp_path / "calib.json"), "--ground", str(tmp_path / "ground.csv"), "--fps", "10"])
    assert r.exit_code == 0, r.output
    sj = st / "v" / "scene.json"
    d = json.loads(sj.read_text())
    d.setdefault("extra", {})["video_masks"] = {"min_area": 40, "init_samples": 8, "history": 30}
    sj.write_text(json.dumps(d))
    lib = tmp_path / "lib"
    shutil.copytree(st / "v", lib)
    r = cli(["batch", str(st), "masks-from-video", "--segment-frames", "100", "--no-progress"])
    assert r.exit_code == 0, r.output
    row = json.loads((st / "summary.json").read_text())["scenes"][0]
    assert row["segments"] == 2 and row["frames"] == 200 and row["seam_id_changes"] == 0
    assert len(list((st / "v" / "batch" / "segments" / "c0").glob("*.json"))) == 2
    scene_masks_segmented(lib, 100, log=lambda s: None)
    got = (st / "v" / "masks" / "c0.txt").read_bytes()
    assert got == (lib / "masks" / "c0.txt").read_bytes()
    assert len({ln.split()[1] for ln in got.splitlines()}) == 2, got.decode()[:2000]
