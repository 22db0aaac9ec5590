"""``s2p demo``: the whole method end to end on a small synthetic junction.

generate a scene -> default heights by bisection (3.2) -> pick the Seg2PoseNet models: the ones
the package ships (``seg2pose.training.demo_models``: the held-out protocol's, trained by the
project on another scene of the same junction and device), or with ``--retrain`` lite models
trained now on this scene's train split -> run the baseline and Seg2PoseNet on the test split
-> evaluate (the table says which models) -> write the sample recording (.rrd) and MCAP export
-> print where it all went.

The demo owns its outputs (the scene folder it made and ``sample_logs/``) and rewrites them on
every run; it never touches anything else.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import typer

from seg2pose.cli.common import METHOD

DEMO_SCENE = Path("demo_scene")
SAMPLE_LOGS = Path("sample_logs")
DEMO_CONFIGS = ("mono-1", "tri-T")
SAMPLE_FRAMES = 160  # frames in the sample recording and MCAP
DEMO_START = "2021-06-14T08:00:00Z"  # the demo scene's clock: frame 0 (the sample files show real times)
# the sample files stay a few MB: video frames at 0.4 of the camera's size, JPEG quality 55,
# video every 4th frame, masks every 4th in the MCAP and every 10th in the recording (which holds
# them twice: by class and by the association's id); a viewer shows the latest; frame 600, the
# README picture's, has both
SAMPLE_IMAGES: dict[str, Any] = {"image_scale": 0.4, "jpeg_quality": 55, "mask_every": 4, "rrd_mask_every": 10,
                 "video_every": 4}


def _step(msg: str) -> float:
    typer.secho(f"==> {msg}", fg=typer.colors.CYAN, bold=True)
    return time.perf_counter()


def run_demo(scene_dir: Path = DEMO_SCENE, logs_dir: Path = SAMPLE_LOGS, seed: int = 0,
             retrain: bool = False, record: bool = True) -> dict:
    """Run the demo; returns a summary dict (paths and mean errors)."""
    from seg2pose.eval.evaluate import evaluate, format_table, seen_truth
    from seg2pose.io.poses import read_poses
    from seg2pose.io.run import read_run_poses
    from seg2pose.io.scene import load_scene
    from seg2pose.method.pipeline import RunOptions, run_scene
    from seg2pose.synth import SynthOptions, generate_scene

    t0 = time.perf_counter()
    if record:  # a linked folder of the recordings: refused before the demo's work, not after
        from seg2pose.io.nofollow import refuse_linked_folder

        refuse_linked_folder(logs_dir)
    summary: dict = {"scene": str(scene_dir)}
    marker = scene_dir / "scene.json"
    made = json.loads(marker.read_text()).get("extra", {}).get("generator", {}) if marker.exists() else {}
    if made.get("seed") == seed and made.get("video"):
        _step(f"reusing the synthetic scene in {scene_dir} (delete it to regenerate)")
    else:
        _step(f"generating a small synthetic junction with video in {scene_dir}")
        generate_scene(scene_dir, SynthOptions(preset="small", seed=seed, video=True, force=True))
    scene = load_scene(scene_dir)
    if scene.start_time is None:  # a clock, so that the sample files show real times
        import dataclasses

        scene = dataclasses.replace(scene, start_time=DEMO_START)
        scene.save()

    _step("default heights by bisection on the training split (paper 3.2)")
    from seg2pose.method.heights import update_default_heights
    update_default_heights(scene, split="train", log=typer.echo)  # saved, and set on scene

    models, used = choose_models(scene, scene_dir / "models", retrain)
    summary["models"], summary["models_dir"] = used, [str(m) for m in models]

    gt = read_poses(scene.gt_path)
    test = scene.split_range("test")
    results = {}
    runs = []
    unseen = {}
    for cfg in DEMO_CONFIGS:
        seen = seen_truth(scene, scene.rig.configs[cfg], gt, test)
        unseen[cfg] = len(gt.in_frames(test)) - len(seen)
        for baseline in (True, False):
            name = f"{cfg} {'baseline' if baseline else 'Seg2PoseNet'}"
            run_dir = scene_dir / "out" / f"run-{cfg}-{'baseline' if baseline else 's2pn'}"
            _step(f"running {name} on the test split -> {run_dir}")
            run_scene(scene, run_dir, RunOptions(config=cfg, baseline=baseline,
                      models_dir=None if baseline else models, split="test", force=True))
            est = read_run_poses(run_dir)
            results[name] = evaluate(est, seen, scene.rig.center[:2], frame_range=test)
            runs.append(run_dir)
    typer.echo("")
    typer.echo(format_table(results))
    typer.echo("gt: the road users a camera of the configuration sees (they have a mask there) in "
               "the test frames; not counted: " + ", ".join(
                   f"{n} seen by no camera of {cfg}" for cfg, n in unseen.items()))
    summary["mean_error"] = {k: r.mean_error for k, r in results.items()}
    summary["ratio"] = {cfg: results[f"{cfg} Seg2PoseNet"].mean_error
                        / results[f"{cfg} baseline"].mean_error for cfg in DEMO_CONFIGS}
    typer.secho("Seg2PoseNet / baseline mean error: " + ", ".join(
        f"{cfg} {r:.2f}x" for cfg, r in summary["ratio"].items()), bold=True)
    typer.echo(f"Seg2PoseNet models: {used}")

    if record:
        from s2p_review.mcap_export import ExportOptions, export_mcap
        from s2p_review.recording import LogStyle
        from s2p_review.session import RecordOptions, Targets
        from s2p_review.session import record as record_rrd

        logs_dir.mkdir(parents=True, exist_ok=True)
        rrd = logs_dir / "demo.rrd"
        mcap = logs_dir / "demo.mcap"
        tri = [r for r in runs if "tri-T" in r.name]
        test = scene.split_range("test")
        assert test is not None  # the synthetic scene has a test split
        first = test[0]
        frames = (first, first + SAMPLE_FRAMES - 1)  # keeps each sample file a few MB
        _step(f"writing the Rerun recording {rrd} (test frames {frames[0]}..{frames[1]})")
        img = SAMPLE_IMAGES
        # the sample keeps JPEG images every few frames (its documented size and its tests);
        # `s2p review` defaults to the video asset of every frame
        style = LogStyle(image_scale=img["image_scale"], jpeg_quality=img["jpeg_quality"],
                         video_format="jpeg")
        record_rrd(scene, tri, Targets(rrd=rrd, force=True),
                   RecordOptions(frames=frames, mask_every=img["rrd_mask_every"],
                                 video_every=img["video_every"], style=style))
        _step(f"writing the MCAP export {mcap} and its Foxglove layout")
        export_mcap(scene, tri[-1], mcap, ExportOptions(
            frames=frames, mask_every=img["mask_every"], video=False,
            image_scale=img["image_scale"], jpeg_quality=img["jpeg_quality"]), force=True)
        summary["rrd"], summary["mcap"] = str(rrd), str(mcap)

    typer.echo("")
    typer.secho(f"demo finished in {time.perf_counter() - t0:.0f} s. Outputs:", bold=True)
    typer.echo(f"  scene folder       {scene_dir}/ (scene.json, masks/, gt/)")
    typer.echo(f"  Seg2PoseNet models {', '.join(f'{m}/' for m in models)}")
    typer.echo(f"  pose tracks        {scene_dir}/out/run-*/poses.csv (+ views.csv per view)")
    if record:
        typer.echo(f"  Rerun recording    {summary['rrd']}   open with:  rerun {summary['rrd']}")
        typer.echo(f"  MCAP export        {summary['mcap']}  open in Foxglove with the layout "
                   f"{Path(summary['mcap']).with_suffix('.layout.json')}")
    return summary


def choose_models(scene, trained_dir: Path, retrain: bool,
                  shipped: Path | None = None) -> tuple[list[Path], str]:
    """The Seg2PoseNet models the demo runs: (model folders, averaged when several; one line
    naming them for the table). By default the shipped ones (``shipped``, default
    ``demo_models.SHIPPED``); when they do not fit the scene (one warning line says why), or
    with ``retrain``, lite models trained on this scene's train split into ``trained_dir``
    (``--protocol demo``: about 2 minutes; an earlier demo's finished ones are reused unless
    ``retrain``)."""
    from seg2pose.training import demo_models
    from seg2pose.training.config import TrainConfig, TrainSettings
    from seg2pose.training.train import train_scene

    shipped = demo_models.SHIPPED if shipped is None else Path(shipped)
    if not retrain:
        problem = demo_models.fit_problem(scene, shipped)
        if problem is None:
            used = demo_models.describe(demo_models.read_manifest(shipped))
            _step(f"using the {used}, from {shipped} (--retrain: train on this scene instead)")
            return demo_models.model_folders(shipped), used
        typer.secho(f"warning: the shipped Seg2PoseNet models do not fit this scene ({problem}); "
                    "training lite models on it instead", fg=typer.colors.YELLOW, err=True)
    _step(f"training lite Seg2PoseNet models on this scene's train split (--protocol demo, "
          f"about 2 minutes) -> {trained_dir}")
    train_scene(scene, trained_dir, TrainConfig.demo(), progress=True,
                settings=TrainSettings(force=retrain))
    return [trained_dir], (f"lite models trained on this scene's train split ({trained_dir}, "
                           "--protocol demo)")


def register(app: typer.Typer) -> None:
    app.command("demo", rich_help_panel=METHOD)(demo)


def demo(
    scene: Path = typer.Option(DEMO_SCENE, "--scene", help="where the demo's synthetic scene goes"),
    out: Path = typer.Option(
        SAMPLE_LOGS, "-o", "--out", help="where the sample recording (demo.rrd) and export (demo.mcap) go",
    ),
    seed: int = typer.Option(0, "--seed", help="seed of the synthetic scene"),
    retrain: bool = typer.Option(False, "--retrain/--no-retrain", help=(
        "instead of the shipped models (the held-out protocol's, trained by the project on "
        "bench seeds 7 and 8; remade by `python -m seg2pose.training.demo_models`), train lite models "
        "afresh on this scene's train split, about 2 minutes (--protocol demo; weaker, about "
        "0.8x the baseline's error)")),
    record: bool = typer.Option(True, "--record/--no-record", help="write the sample recording and export"),
) -> None:
    """Run Seg2Pose end to end on a small synthetic junction.

    Generates a scene, runs the baseline and Seg2PoseNet (the models the package ships, or
    with --retrain lite ones trained on the scene), prints the error table and which models
    it used, and writes a Rerun recording and an MCAP export."""
    run_demo(scene, out, seed=seed, retrain=retrain, record=record)
