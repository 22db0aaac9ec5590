"""The commands tests/system/test_kill.py and benches/bench_faults.py kill
(``kill_harness.Case``), each on small inputs made under a folder: ``build_cases`` (issue 10's
five), ``build_writer_cases`` (issue 24's writers, annotate export's set, batch) and
``build_training_cases`` (s2p train: killed, then resumed)."""

from __future__ import annotations

import json
import shutil
import sys
from collections.abc import Callable
from pathlib import Path

from kill_harness import Case, snapshot


def build_cases(root: Path, frames: int = 40) -> list[Case]:
    """The five commands of issue 10 on small inputs under ``root``: s2p run, synth,
    convert-masks, import-utocs and export, each with an old output to replace."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from hostile_fixtures import write_scene, write_utocs

    from s2p_review.mcap_export import export_mcap
    from seg2pose.io.mask_formats import save_masks
    from seg2pose.io.mots import read_mots
    from seg2pose.io.scene import load_scene
    from seg2pose.io.utocs import import_utocs
    from seg2pose.method.pipeline import RunOptions, run_scene
    from seg2pose.synth.generate import SynthOptions, generate_scene

    root.mkdir(parents=True, exist_ok=True)
    scene = write_scene(root / "scene", frames=frames, users=4)
    other = write_scene(root / "other", frames=5, users=2)
    old = root / "old"
    old.mkdir()
    run_scene(other, old / "run", RunOptions(baseline=True, progress=False))
    run_scene(scene, root / "run", RunOptions(baseline=True, progress=False))
    generate_scene(old / "synth", SynthOptions(frames=3, seed=1, workers=1, progress=False))
    save_masks(old / "png", read_mots(other.masks_path("c0")), "png")
    import_utocs(write_utocs(root / "utocs-a", frames=2), old / "utocs", log=lambda *a: None)
    write_utocs(root / "utocs-b", frames=frames, images=True)
    export_mcap(load_scene(other.root), old / "run", old / "x.mcap")
    out = root / "out"
    out.mkdir()
    return [
        Case("run", ["run", scene.root, "-o", out / "run", "--baseline", "--force"], [out / "run"], [old / "run"]),
        Case("synth", ["synth", "-o", out / "synth", "--frames", "6", "--seed", "2", "--workers", "1", "--no-progress",
                       "--force"], [out / "synth"], [old / "synth"]),
        Case("convert-masks", ["convert-masks", scene.masks_path("c0"), "-o", out / "png", "--format", "png",
                               "--force"], [out / "png"], [old / "png"]),
        Case("import-utocs", ["import-utocs", root / "utocs-b", "-o", out / "utocs", "--force"], [out / "utocs"],
             [old / "utocs"]),
        Case("export", ["export", scene.root, "--run", root / "run", "-o", out / "x.mcap", "--force"],
             [out / "x.mcap"], [old / "x.mcap"]),
    ]


def _state_of(*paths: Path) -> Callable:
    return lambda case: [snapshot(p) for p in paths]


def _project_state(scene_root: Path) -> Callable:
    """The annotation project's tracks and history as a reader sees them (journal bytes hold
    times): None when there is no journal."""
    def state(case):
        from annotate_fixtures import digest

        from annotate import Project

        if not (scene_root / "annotations").exists():
            return [None]
        try:
            with Project.open(scene_root, read_only=True) as p:
                return [digest(p)]
        except Exception as e:  # noqa: BLE001 - a project that does not open is a broken output
            return [f"does not open: {e}"]
    return state


def build_writer_cases(root: Path, frames: int = 16) -> list[Case]:
    """The writing commands of issue 24 on tiny inputs under ``root``: masks-from-video,
    import-detections, track, new-scene, import-tacal, annotate export (gt + MCAP + layout +
    CSV as one set), annotate import-tanalyst, associate (masks/ as a unit), import-mcap --force
    into an existing scene folder (scene.json, ground points, run and journal as one set) and
    batch --serial (killed, then re-run)."""
    import contextlib as _cl

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from review_fixtures import make_scene
    from video_fixtures import calibration, det, rle, write_folder

    from annotate import Project
    from seg2pose.cli.annotation import export_set
    from seg2pose.io.scene import load_scene
    from seg2pose.io.tacal import camera_to_tacal, write_tacal
    from seg2pose.video.video_scene import new_scene, scene_import_detections, scene_masks_from_video

    root.mkdir(parents=True, exist_ok=True)
    old, out = root / "old", root / "out"
    old.mkdir()
    out.mkdir()
    cam = calibration(root)
    calib, ground = root / "calib.json", root / "ground.csv"
    write_folder(root / "frames", frames, [dict(id=1, x=10, y=60, w=10, h=24, vx=2, vy=0),
                                           dict(id=2, x=120, y=30, w=14, h=14, vx=-2, vy=1)])
    write_folder(root / "frames-b", 6, [dict(id=1, x=30, y=40, w=12, h=20, vx=1, vy=0)])
    quiet = dict(log=lambda *a: None)
    bg = ["--set", "min_area=40", "--set", "init_samples=8"]
    bgd = {"min_area": 40, "init_samples": 8}

    def video_scene(name: str) -> Path:
        new_scene(root / name, {"c0": root / "frames"}, calib, ground, fps=10, **quiet)
        return root / name

    # masks-from-video: replaces a detector's masks
    dets = root / "d.json"
    dets.write_text(json.dumps([det(f, 3, rle(20 + 3 * f, 40, 12, 10)) for f in range(frames)]))
    mfv = video_scene("mfv")
    scene_import_detections(mfv, "c0", dets, **quiet)
    shutil.copy2(mfv / "masks" / "c0.txt", old / "mfv-c0.txt")
    # masks-from-video of two cameras (issue 38): both cameras' masks and masks/ids.json
    # replace associated detector masks as one set (a kill after the first camera left its
    # tracker ids beside a record calling them associated, and `s2p run` fused unrelated
    # road users)
    calib2 = root / "calib2.json"
    one = json.loads(calib.read_text())["cameras"][0]
    calib2.write_text(json.dumps({"cameras": [one, dict(one, name="c1")]}))
    mfv2 = root / "mfv2"
    new_scene(mfv2, {"c0": root / "frames", "c1": root / "frames"}, calib2, ground, fps=10, **quiet)
    for c in ("c0", "c1"):
        scene_import_detections(mfv2, c, dets, associate=False, **quiet)
    from seg2pose.video.associate_scene import associate_scene
    associate_scene(mfv2, **quiet)
    for n in ("c0.txt", "c1.txt", "ids.json"):
        shutil.copy2(mfv2 / "masks" / n, old / f"mfv2-{n}")
    # import-detections: replaces background-subtraction masks
    imd = video_scene("imd")
    scene_masks_from_video(imd, bg=bgd, **quiet)
    shutil.copy2(imd / "masks" / "c0.txt", old / "imd-c0.txt")
    # track: masks without ids, tracked in place
    trk = video_scene("trk")
    scene_masks_from_video(trk, bg=bgd, track=False, classify=False, **quiet)
    shutil.copy2(trk / "masks" / "c0.txt", old / "trk-c0.txt")
    # new-scene and import-tacal: replace a scene folder made from other inputs
    new_scene(old / "scene", {"c0": root / "frames-b"}, calib, ground, fps=5, **quiet)
    write_tacal(root / "c0.tacal", camera_to_tacal(cam))
    from seg2pose.io.tacal import scene_from_tacals
    scene_from_tacals([root / "c0.tacal"], ground, old / "tacal", 25.0)
    # annotate export: an older export set of fewer edits
    ann = make_scene(root / "ann", n_frames=20).root
    with Project.open(ann) as p:
        p.create_track("car")
        p.set_keyframe(1, 0, -8.0, -1.5, heading=0.0)
        p.set_keyframe(1, 10, -2.0, -1.5, heading=0.0)
        with _cl.redirect_stdout(None):
            export_set(p, old / "ann-export", gt=False, mcap=True, tanalyst=True,
                       start="00:00:00.000", force=True)
        shutil.copy2(ann / "gt" / "poses.csv", old / "ann-gt-elsewhere.csv")
        from annotate.export import export_gt
        export_gt(p, old / "ann-poses.csv", force=True)
        p.create_track("pedestrian")
        p.set_keyframe(2, 2, 1.0, 2.0, heading=1.0)
        p.set_keyframe(2, 12, 1.0, 4.0)
        with _cl.redirect_stdout(None):  # import-mcap --force: this set over the older one's
            export_set(p, root / "mcap-new", gt=False, mcap=True, tanalyst=False,
                       start="00:00:00.000", force=True)
    from s2p_review.mcap_import import import_mcap
    from seg2pose.cli.review import _check_restored_journal

    import_mcap(old / "ann-export" / "annotations.mcap", old / "restored",
                check_annotations=_check_restored_journal)
    restored = [old / "restored" / n for n in ("scene.json", load_scene(ann).ground_file,
                                               "out/annotations", "annotations")]
    imp = out / "restored"
    (old / "video").mkdir()  # a file of the scene folder that the import does not write
    (old / "video" / "keep.txt").write_text("not an output of import-mcap\n")
    # import-tanalyst: into a project with one track
    tan = make_scene(root / "tan", n_frames=30).root
    with Project.open(tan) as p:
        p.create_track("car")
        p.set_keyframe(1, 0, -8.0, -1.5, heading=0.0)
    shutil.copytree(tan / "annotations", old / "tan-annotations")
    (root / "t.csv").write_text("\n".join([
        "Detection ID;Type of road user;Road user ID;X (m);Y (m);Time Stamp",
        "1;Car;3;-8;-1,5;12:00:00.000", "2;Car;3;-5;-1,5;12:00:00.500",
        "3;Car;3;-2;-1,5;12:00:01.000", "4;Pedestrian;7;1;2;12:00:00.200",
        "5;Pedestrian;7;1;4;12:00:00.600"]) + "\n")
    # associate: two cameras' tracker ids -> one id per road user (masks/ replaced as a unit)
    aso = make_scene(root / "aso", n_frames=12).root
    shutil.copytree(aso / "masks", old / "aso-masks")
    # batch --serial: a study of one video scene, masks-from-video then run
    study = root / "study"
    study.mkdir()
    new_scene(study / "s1", {"c0": root / "frames"}, calib, ground, fps=10, **quiet)
    s1 = load_scene(study / "s1")
    s1.extra["video_masks"] = bgd
    s1.save()
    # batch on a local Ray of its own (one CPU), its driver killed: the same study
    shutil.copytree(study, root / "study-ray")
    sray = root / "study-ray"
    exp = ann / "export"
    return [
        Case("masks-from-video", ["masks-from-video", mfv, "--no-progress", "--force", *bg],
             [mfv / "masks" / "c0.txt"], [old / "mfv-c0.txt"]),
        Case("masks-from-video-2cam", ["masks-from-video", mfv2, "--no-progress", "--force",
                                       "--no-associate", *bg],
             [mfv2 / "masks" / n for n in ("c0.txt", "c1.txt", "ids.json")],
             [old / f"mfv2-{n}" for n in ("c0.txt", "c1.txt", "ids.json")]),
        Case("import-detections", ["import-detections", imd, dets, "--camera", "c0", "--force"],
             [imd / "masks" / "c0.txt"], [old / "imd-c0.txt"]),
        Case("track", ["track", trk, "--no-progress"], [trk / "masks" / "c0.txt"],
             [old / "trk-c0.txt"]),
        Case("new-scene", ["new-scene", "-o", out / "scene", "--video", f"c0={root / 'frames'}",
                           "--calibration", calib, "--ground", ground, "--fps", "10", "--force"],
             [out / "scene"], [old / "scene"]),
        Case("import-tacal", ["import-tacal", root / "c0.tacal", "--ground", ground, "-o",
                              out / "tacal", "--fps", "10", "--force"], [out / "tacal"],
             [old / "tacal"]),
        Case("annotate-export", ["annotate", "export", ann, "--force"],
             [ann / "gt" / "poses.csv", exp / "annotations.mcap", exp / "annotations.layout.json",
              exp / "tanalyst.csv"],
             [old / "ann-poses.csv", old / "ann-export" / "annotations.mcap",
              old / "ann-export" / "annotations.layout.json", old / "ann-export" / "tanalyst.csv"]),
        Case("import-tanalyst", ["annotate", "import-tanalyst", tan, root / "t.csv", "--start",
                                 "12:00:00.000"], [tan / "annotations"],
             [old / "tan-annotations"], state=_project_state(tan)),
        Case("associate", ["associate", aso, "--force"], [aso / "masks"], [old / "aso-masks"]),
        Case("import-mcap", ["import-mcap", root / "mcap-new" / "annotations.mcap", "-o", imp,
                             "--force"],
             [imp / r.relative_to(old / "restored") for r in restored] + [imp / "video"],
             restored + [old / "video"]),
        Case("batch-serial", ["batch", study, "masks-from-video", "run", "--baseline", "--serial",
                              "--no-progress"],
             [study / "s1" / "masks", study / "s1" / "batch", study / "summary.json"],
             [None, None, None],
             state=_state_of(study / "s1" / "masks" / "c0.txt", study / "s1" / "batch" / "baseline"),
             resume=True),
        Case("batch-ray", ["batch", sray, "masks-from-video", "run", "--baseline", "--cpus", "1",
                           "--no-progress"],
             [sray / "s1" / "masks", sray / "s1" / "batch", sray / "summary.json"],
             [None, None, None],
             state=_state_of(sray / "s1" / "masks" / "c0.txt", sray / "s1" / "batch" / "baseline"),
             resume=True, tree=True,
             rerun=["batch", sray, "masks-from-video", "run", "--baseline", "--serial",
                    "--no-progress"]),
    ]


def _models_state(models: Path, stems: list[str]) -> Callable:
    """What a reader of the model folder sees: per expected model, None while it is absent or
    marked incomplete (``ModelSet.load`` refuses those), else the bytes of its checkpoint and
    metadata; last, the files that should not be there (none: a model with unreadable
    metadata, or any file but a model's checkpoint, metadata and resume state)."""
    import hashlib

    from seg2pose.io.atomic_names import is_temporary

    def state(case):
        out, odd = [], []
        for stem in stems:
            meta, ck = models / f"{stem}.json", models / f"{stem}.safetensors"
            try:
                complete = meta.exists() and json.loads(meta.read_text()).get("complete") is True
            except ValueError:
                odd.append(f"{meta.name}: not JSON")
                complete = False
            out.append(hashlib.sha256(meta.read_bytes() + ck.read_bytes()).hexdigest()
                       if complete and ck.exists() else None)
        known = {f"{s}{x}" for s in stems for x in (".json", ".safetensors", ".safetensors.state.pt")}
        if models.is_dir():  # a writer's hidden temporaries are no part of it (cf. snapshot)
            odd += sorted(p.name for p in models.iterdir() if p.name not in known and not is_temporary(p.name))
        return out + [odd or None]
    return state


def build_training_cases(root: Path) -> list[Case]:
    """s2p train (quick protocol, three per-class models, two epochs each) on the tiny scene:
    killed, then run again as after a crash; the re-run must end with the uninterrupted run's
    models, byte for byte (resuming from the per-epoch state)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from review_fixtures import make_scene

    root.mkdir(parents=True, exist_ok=True)
    scene = make_scene(root / "scene", n_frames=30).root
    models = root / "models"
    stems = [f"all__{c}" for c in ("pedestrian", "bicyclist", "car")]
    return [Case("train", ["train", scene, "--protocol", "quick", "--epochs", "2", "--batches", "3",
                           "--threads", "1", "-o", models], [models], [None],
                 state=_models_state(models, stems), resume=True)]
