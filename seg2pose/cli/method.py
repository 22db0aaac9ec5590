"""``s2p train``, ``s2p run``, ``s2p eval``, ``s2p paper-table``: the method's commands."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from seg2pose.cli.common import METHOD
from seg2pose.normal import DEFAULT_CENTER_METHOD


def register(app: typer.Typer) -> None:
    app.command("train", rich_help_panel=METHOD)(train_cmd)
    app.command("run", rich_help_panel=METHOD)(run_cmd)
    app.command("eval", rich_help_panel=METHOD)(eval_cmd)
    app.command("paper-table", rich_help_panel=METHOD)(paper_table_cmd)
    app.command("bench-accuracy", rich_help_panel=METHOD)(bench_accuracy_cmd)


SPARSE_HELP = ("exact sparse inference on the CPU: the network's convolutions only around the "
               "mask (same result, 3-30x faster; seg2pose/sparse.py)")


def run_cmd(
    scene: Path = typer.Argument(..., help="scene folder"),
    out: Path = typer.Option(..., "-o", "--out", help="run folder to write"),
    config: Optional[str] = typer.Option(None, "--config", "-c",
                                         help="camera configuration (default: all cameras)"),
    baseline: bool = typer.Option(False, "--baseline", help="normal positions only, no network"),
    models: Optional[List[Path]] = typer.Option(None, "--models",
                                                help="checkpoint folder (default SCENE/models); repeat it to "
                                                     "average the residuals of several folders' models"),
    split: Optional[str] = typer.Option(None, "--split", help="only this split's frames (train/val/test)"),
    center: str = typer.Option(DEFAULT_CENTER_METHOD, "--center",
                               help="mask centre: bbox (paper section 5) or centroid (3.2); "
                                    "the default was chosen by measurement, docs/NORMAL_POSITIONS.md"),
    arch: Optional[str] = typer.Option(None, "--arch", help="require checkpoints of this arch (lite|paper)"),
    device: Optional[str] = typer.Option(None, "--device", help="torch device (default: cuda if present)"),
    sparse: bool = typer.Option(True, "--sparse/--no-sparse", help=SPARSE_HELP),
    allow_incomplete: bool = typer.Option(False, "--allow-incomplete",
                                          help="use checkpoints whose training was interrupted "
                                               "(refused otherwise)"),
    force: bool = typer.Option(False, "--force", help="replace an existing run folder entirely "
                               "(the new run is written beside it and swapped in when complete)"),
) -> None:
    """Estimate world pose tracks: normal positions, Seg2PoseNet residuals (unless --baseline),
    late fusion over the configuration's views, headings from motion. Writes OUT/run.json,
    OUT/poses.csv and OUT/views.csv."""
    from seg2pose.pipeline import run_scene
    from seg2pose.sparse import set_enabled

    set_enabled(sparse)
    d = run_scene(scene, out, config=config, baseline=baseline, models_dir=models, split=split,
                  force=force, center_method=center, arch=arch, device=device,
                  allow_incomplete=allow_incomplete)
    from seg2pose.io.run import read_run_meta

    meta = read_run_meta(d)
    typer.echo(f"{meta['method']} run of {meta['n_frames']} frames, {meta['n_views']} detections "
               f"-> {meta['n_poses']} poses in {d}")


def train_cmd(
    scene: Path = typer.Argument(..., help="scene folder with ground truth (gt/poses.csv)"),
    out: Optional[Path] = typer.Option(None, "-o", "--out", help="model folder (default SCENE/models)"),
    arch: Optional[str] = typer.Option(None, "--arch",
                                       help="paper (Figure 3, the default), lite (crop /3, CPU; --demo), "
                                            "lite2 (crop /2) or lite-hr (full-resolution 140 px crop; --quick)"),
    quick: bool = typer.Option(False, "--quick", help="short CPU protocol: one lite-hr model with mask geometry per class for all lenses, 30 epochs"),
    demo: bool = typer.Option(False, "--demo", help="the demo's very short protocol"),
    zero_annotation: bool = typer.Option(False, "--zero-annotation",
                                         help="train on rough-model examples only (no ground truth)"),
    rough_noise: Optional[bool] = typer.Option(None, "--rough-noise/--rough-clean",
                                               help="make rough-model masks detector-like (28x28 mask head, 1 px dilation)"),
    cameras: Optional[str] = typer.Option(None, "--cameras", help="comma-separated camera names"),
    classes: Optional[str] = typer.Option(None, "--classes", help="comma-separated class names"),
    epochs: Optional[int] = typer.Option(None, "--epochs"),
    runs: Optional[int] = typer.Option(None, "--runs", help="best-of-N runs (paper: 4)"),
    batches: Optional[int] = typer.Option(None, "--batches", help="batches per epoch (paper: 64)"),
    lr: Optional[float] = typer.Option(None, "--lr"),
    rough: Optional[int] = typer.Option(None, "--rough", help="rough-model examples per camera and class"),
    rough_occlusion: Optional[float] = typer.Option(None, "--rough-occlusion",
                                                    help="share of rough-model examples partly hidden by a rough car "
                                                         "or pedestrian in front of them"),
    rough_every: Optional[int] = typer.Option(None, "--rough-every",
                                              help="every K-th training example is a rough model (paper: 4; 0: none)"),
    share_classes: Optional[bool] = typer.Option(None, "--share-classes/--per-class",
                                                 help="one model per camera with a class input"),
    share_cameras: Optional[bool] = typer.Option(None, "--share-cameras/--per-camera",
                                                 help="one model for all cameras (lenses of one device)"),
    geometry: Optional[bool] = typer.Option(None, "--geometry/--no-geometry",
                                            help="also feed the network exact mask-geometry cues (box size, foot and top "
                                                 "points, expected height, border cuts; seg2pose/features.py)"),
    augment: Optional[int] = typer.Option(None, "--augment",
                                          help="K changed copies of every annotated training mask (occlusion cuts, "
                                               "1 px boundary changes; labels stay exact: seg2pose/augment.py)"),
    device: Optional[str] = typer.Option(None, "--device"),
    threads: Optional[int] = typer.Option(None, "--threads", help="CPU threads for torch (default 2)"),
    seed: Optional[int] = typer.Option(None, "--seed", help="first of the runs' seeds"),
    force: bool = typer.Option(False, "--force", help="retrain models that exist already"),
    parallel: Optional[int] = typer.Option(None, "--parallel", min=1,
                                           help="train the cameras' models in parallel as Ray tasks on "
                                                "this many local CPUs (same seeds, same models)"),
    address: Optional[str] = typer.Option(None, "--address",
                                          help="train the cameras' models as tasks on this Ray cluster"),
) -> None:
    """Train Seg2PoseNet per camera and class (paper 4.1: best of four, Adam 5e-5, batch 16,
    64 batches/epoch, 50 epochs, every 4th example a rough model). Resumes an interrupted
    training from its checkpoints."""
    from seg2pose.batch import ray_map
    from seg2pose.train import TrainConfig, train_scene

    if demo:
        cfg = TrainConfig.demo()
    elif quick:
        cfg = TrainConfig.quick()
    else:
        cfg = TrainConfig.paper()
    if arch is not None:
        cfg = cfg.replace(arch=arch)
    over = {k: v for k, v in dict(epochs=epochs, runs=runs, batches_per_epoch=batches, lr=lr, rough_per_class=rough, rough_every=rough_every, rough_occlusion=rough_occlusion,
                                  share_classes=share_classes, share_cameras=share_cameras, rough_detector_noise=rough_noise, geometry=geometry, augment=augment, device=device, threads=threads,
                                  seed=seed).items()
            if v is not None}
    cfg = cfg.replace(zero_annotation=zero_annotation, force=force, **over)
    out_dir = train_scene(scene, out, cfg,
                          cameras=cameras.split(",") if cameras else None,
                          classes=classes.split(",") if classes else None, progress=True,
                          map_groups=ray_map(address, parallel) if parallel or address else None)
    typer.echo(f"models in {out_dir}")


def eval_cmd(
    scene: Path = typer.Argument(..., help="scene folder with gt/poses.csv"),
    run: Path = typer.Argument(..., help="run folder (from s2p run)"),
    split: Optional[str] = typer.Option(None, "--split", help="evaluate only this split's frames"),
    as_json: bool = typer.Option(False, "--json", help="print JSON instead of a table"),
    match: str = typer.Option("ids", "--match",
                              help="ids: pair estimates with truth by track id; nearest: per frame by "
                                   "position (for tracks made by s2p track / masks-from-video)"),
    gate: float = typer.Option(3.0, "--gate", help="with --match nearest: farthest pair, metres"),
) -> None:
    """Mean ground-plane error of a run against the truth, overall, per class and per 5 m bin
    of distance from the cameras."""
    import json

    from seg2pose.paper_table import evaluate_run
    from seg2pose.evaluate import format_table

    if match not in ("ids", "nearest"):
        raise typer.BadParameter("use ids or nearest", param_hint="--match")
    res = evaluate_run(scene, run, split=split, match=match, gate=gate)
    if as_json:
        typer.echo(json.dumps(res.to_dict(), indent=1))
    else:
        typer.echo(format_table({Path(run).name: res}))


def paper_table_cmd(
    scene: Path = typer.Argument(..., help="scene folder with gt/poses.csv"),
    models: Optional[List[Path]] = typer.Option(None, "--models",
                                                help="checkpoint folder (default SCENE/models); repeat it to "
                                                     "average several folders' models"),
    split: str = typer.Option("test", "--split"),
    out: Optional[Path] = typer.Option(None, "-o", "--out", help="output folder (default SCENE/out/paper-table)"),
    configs: Optional[str] = typer.Option(None, "--configs", help="comma-separated configurations (default all)"),
    baseline_only: bool = typer.Option(False, "--baseline-only", help="skip the Seg2PoseNet rows"),
    sparse: bool = typer.Option(True, "--sparse/--no-sparse", help=SPARSE_HELP),
    force: bool = typer.Option(False, "--force"),
) -> None:
    """Table 1 and Figure 6 of the paper on this scene: every configuration with and without
    Seg2PoseNet, mean error overall and per 5 m bin; writes table.txt, results.json and
    error_vs_distance.png."""
    from seg2pose.paper_table import paper_table
    from seg2pose.sparse import set_enabled

    set_enabled(sparse)
    out_dir, text = paper_table(scene, models_dir=models, split=split, out_dir=out,
                                configs=configs.split(",") if configs else None,
                                baseline_only=baseline_only, force=force)
    typer.echo(text)
    typer.echo(f"written to {out_dir}")


def bench_accuracy_cmd(
    root: Path = typer.Argument(..., help="folder for the scenes, models and tables (one "
                                          "sub-folder per seed; finished steps are kept and skipped)"),
    seeds: str = typer.Option("100,101,102", "--seeds",
                              help="comma-separated scene seeds (choose settings on 0-4, report on 100-102)"),
    preset: str = typer.Option("bench", "--preset", help="synth preset of the scenes"),
    variants: str = typer.Option("s2pn,zero", "--variants",
                                 help="s2pn (annotated, train --quick) and/or zero (zero-annotation, "
                                      "train --quick --zero-annotation --rough 400)"),
    threads: int = typer.Option(2, "--threads", help="CPU threads for training"),
    train_arg: Optional[List[str]] = typer.Option(None, "--train-arg",
                                                  help="one more `s2p train` option (repeatable), "
                                                       "e.g. --train-arg=--epochs=40"),
) -> None:
    """The accuracy benchmark: for each seed s2p synth, heights, train and paper-table, then
    the nine configurations' error ratios to the baseline, mean (min-max) over the seeds.
    Writes ROOT/accuracy.json."""
    from seg2pose.accuracy import run_benchmark

    try:
        seed_list = [int(s) for s in seeds.split(",")]
    except ValueError:
        from seg2pose.errors import InputError
        raise InputError(f"expected comma-separated integers, got {seeds!r}", field="--seeds") from None
    _, text = run_benchmark(root, seed_list, preset, tuple(variants.split(",")), threads,
                            tuple(train_arg or ()), log=typer.echo)
    typer.echo(text)
