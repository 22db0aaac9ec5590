"""Method commands: ``s2p run``, ``s2p train`` (and fine-tuning); the evaluation commands are
``seg2pose.cli.evaluation``'s."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import typer

from seg2pose.cli.common import METHOD, speaks_flags
from seg2pose.core.ray import ray_map

Arch = Literal["paper", "lite", "lite-hr"]
Center = Literal["bbox", "centroid"]
Protocol = Literal["paper", "quick", "long", "demo"]


def register(app: typer.Typer) -> None:
    app.command("run", rich_help_panel=METHOD)(speaks_flags(run_cmd))
    app.command("train", rich_help_panel=METHOD)(speaks_flags(train_cmd))


SPARSE_HELP = ("exact sparse inference on the CPU: the network's convolutions only around the "
               "mask (the same result, 3-30x faster)")
SMOOTH_HELP = ("smooth each tracked road user's positions over this many frames either side "
               "(a line fitted per window; 0: every frame on its own, the paper's method)")
TRACK_HEIGHTS_HELP = ("fit one height per tracked road user from where the cameras disagree on "
                      "it (positions at the true height coincide: lenses of one device by their "
                      "parallax, cameras on other poles far more) and put its positions there, "
                      "before fusion; one camera keeps the class defaults. Heights in "
                      "RUN/track_heights.csv; docs/RESULTS.md, \"Track consistency\"")
MODELS_HELP = ("folder of trained models (default: SCENE/models); repeat it to average the "
               "models of several folders")


def run_cmd(
    scene: Path = typer.Argument(..., help="scene folder"),
    out: Path = typer.Option(..., "-o", "--out", help="run folder to write"),
    config: str | None = typer.Option(
        None, "-c", "--config", help="camera configuration, e.g. tri-T (default: all cameras)",
    ),
    baseline: bool = typer.Option(
        False, "--baseline/--no-baseline", help="normal positions only, without the network (the paper's baseline)",
    ),
    models: list[Path] | None = typer.Option(None, "--models", help=MODELS_HELP),
    split: str | None = typer.Option(None, "--split", help="only this split's frames (train, val or test)"),
    center: Center = typer.Option(
        "bbox", "--center", help="mask centre: bbox (the paper's section 5, measured best) or centroid (section 3.2)",
    ),
    smooth: int = typer.Option(0, "--smooth", min=0, help=SMOOTH_HELP),
    arch: Arch | None = typer.Option(None, "--arch", help="refuse models of another architecture"),
    device: str | None = typer.Option(
        None, "--device", help="torch device, e.g. cpu or cuda (default: cuda if present)",
    ),
    sparse: bool = typer.Option(True, "--sparse/--no-sparse", help=SPARSE_HELP),
    allow_incomplete: bool = typer.Option(
        False, "--allow-incomplete/--no-allow-incomplete",
        help="use models whose training was interrupted (refused otherwise)",
    ),
    far_residuals: Literal["warn", "fallback", "off"] = typer.Option(
        "warn", "--far-residuals",
        help="when the network moves a position further than it ever did in training (99th percentile of its training "
             "residuals): warn (count them, list them in RUN/flagged.csv), fallback (also keep the normal position for "
             "them) or off",
    ),
    r90: Path | None = typer.Option(
        None, "--r90",
        help="calibration of the error bars r90_m (made by s2p calibrate-errors; default: MODELS/r90.json, or "
             "SCENE/r90-baseline.json for --baseline, where it exists; without one r90_m is nan)",
    ),
    force: bool = typer.Option(
        False, "--force",
        help="replace an existing run folder entirely (the new run is written beside it and swapped in when complete)",
    ),
    confirm: float | None = typer.Option(
        None, "--confirm", min=0.0, max=1.0,
        help="keep a fused pose only when at least this share of the configuration's cameras that see its place report "
             "it (default 0.5 for associated ids, else 0: off)",
    ),
    fuse_unassociated: bool = typer.Option(
        False, "--fuse-unassociated",
        help="fuse cameras whose track ids are each camera's own tracker's "
             "(refused otherwise: run s2p associate first)",
    ),
    track_heights: bool = typer.Option(False, "--track-heights/--no-track-heights", help=TRACK_HEIGHTS_HELP),
    missing: Literal["refuse", "baseline"] = typer.Option(
        "refuse", "--missing",
        help="cameras and classes the models folder has no model for (e.g. after annotating and training only "
             "cars): refuse the run, or run the baseline (normal positions) for them; run.json lists them in "
             "baseline_fallback",
    ),
) -> None:
    """Estimate world pose tracks of a scene's road users.

    Normal positions, Seg2PoseNet residuals (unless --baseline), late fusion over the
    configuration's cameras, headings from motion. Writes a run folder: run.json, poses.csv
    (fused poses) and views.csv (one row per camera view)."""
    from seg2pose.io.run import read_run_meta
    from seg2pose.io.scene import load_scene
    from seg2pose.method.pipeline import RunOptions, run_scene
    from seg2pose.method.sparse import set_enabled

    set_enabled(sparse)
    d = run_scene(load_scene(scene), out, RunOptions(config=config, baseline=baseline, models_dir=models,
                  split=split, force=force, center_method=center, arch=arch, device=device,
                  allow_incomplete=allow_incomplete, smooth=smooth, far_residuals=far_residuals,
                  fuse_unassociated=fuse_unassociated, confirm=confirm, r90=r90,
                  track_heights=track_heights, missing=missing))
    meta = read_run_meta(d)
    typer.echo(f"{meta['method']} run of {meta['n_frames']} frames, {meta['n_views']} detections "
               f"-> {meta['n_poses']} poses in {d}")
    if not (meta.get("r90") or {}).get("calibration"):
        where = "SCENE/r90-baseline.json" if meta["method"] == "baseline" else "MODELS/r90.json"
        typer.echo("note: no r90 calibration, so r90_m (the error bars) is nan; fit one on a run "
                   "of the validation split with s2p calibrate-errors (a scene without truth: on other "
                   f"scenes' val runs, -o {where})", err=True)
    if meta.get("baseline_fallback"):
        typer.echo(f"note: no model for {', '.join(meta['baseline_fallback'])}: the baseline (normal "
                   "positions) there (--missing baseline)", err=True)
    far = meta.get("far_residuals") or {}
    if far.get("flagged_views"):
        what = "kept at their normal positions" if far["policy"] == "fallback" else "listed"
        typer.echo(f"warning: {far['flagged_poses']} poses ({far['flagged_views']} views) were moved further "
                   f"than the network's training residuals; {what} in {d / 'flagged.csv'}", err=True)


FROM_HELP = ("fine-tune these models on the scene's annotations (gt/poses.csv: keyframes placed or "
             "accepted weigh four times an interpolated row, reviewed rows twice, unchecked "
             "estimates are not used; the test split never): rough examples in every batch; per class "
             "the best of the baseline, the start and the fine-tuned model on annotated road users held "
             "out (k-fold by road user), a class that chose the baseline marked so that s2p run uses its "
             "normal positions; a class without annotations keeps its start model. --epochs, --batches, "
             "--lr, --seed, --threads, --device, --camera and --class apply; the protocol's options do "
             "not. Minutes on a CPU for tens of keyframes (docs/guide/fine-tuning.md)")


def train_cmd(
    scene: Path = typer.Argument(..., help="scene folder (with ground truth, unless --zero-annotation)"),
    out: Path | None = typer.Option(None, "-o", "--out", help="model folder (default: SCENE/models)"),
    protocol: Protocol = typer.Option(
        "paper", "--protocol",
        help="paper: best of four, 50 epochs (section 4.1, for a GPU); quick: the measured CPU protocol, minutes; "
             "long: quick for twice as long with a quarter of each batch rough, for a thousand or more annotated "
             "frames per split (bench preset, held out: 0.37x the baseline where quick gives 0.45x; little gain on the "
             "wide preset's vans, trucks and buses; docs/RESULTS.md); demo: the demo's shortest one",
    ),
    arch: Arch | None = typer.Option(
        None, "--arch",
        help="network: paper (Figure 3), lite (crop / 3, for CPUs) or lite-hr (full-resolution 140 px crop)",
    ),
    zero_annotation: bool = typer.Option(
        False, "--zero-annotation/--no-zero-annotation", help="train on rough models only (no ground truth needed)",
    ),
    rough_noise: bool | None = typer.Option(
        None, "--rough-noise/--no-rough-noise",
        help="make rough-model masks detector-like (coarse 28x28 outlines, 1 px wider)",
    ),
    camera: list[str] | None = typer.Option(
        None, "--camera", help="train only for this camera (repeatable; default: all)",
    ),
    cls: list[str] | None = typer.Option(None, "--class", help="train only for this class (repeatable; default: all)"),
    epochs: int | None = typer.Option(None, "--epochs", min=1, help="epochs per run"),
    runs: int | None = typer.Option(None, "--runs", min=1, help="best of this many runs (the paper: 4)"),
    batches: int | None = typer.Option(None, "--batches", min=1, help="batches per epoch (the paper: 64)"),
    lr: float | None = typer.Option(None, "--lr", help="learning rate (the paper: 5e-5)"),
    rough: int | None = typer.Option(None, "--rough", help="rough-model examples per camera and class"),
    rough_video: bool | None = typer.Option(
        None, "--rough-video/--no-rough-video",
        help="film the rough models over the video's background and pass them through the same background subtraction "
             "as the masks (default: off; on synthetic video it measured worse than clean rough models, "
             "docs/RESULTS.md)",
    ),
    rough_occlusion: float | None = typer.Option(
        None, "--rough-occlusion",
        help="share of rough-model examples partly hidden by a rough car or pedestrian in front",
    ),
    rough_random: bool | None = typer.Option(
        None, "--rough-random/--no-rough-random",
        help="randomised rough models: each one's length, width and height drawn from ranges per class (cars 3.5-6 m "
             "long, 1.35-2.4 m high; pedestrians 1.1-2.0 m; bicyclists 1.5-2.3 m long), not one box per class (not "
             "measured yet on this CPU, docs/RESULTS.md)",
    ),
    rough_every: int | None = typer.Option(
        None, "--rough-every", help="every K-th training example is a rough model (the paper: 4; 0: none)",
    ),
    share_classes: bool | None = typer.Option(
        None, "--share-classes/--no-share-classes", help="one model for all classes, with the class as an input",
    ),
    share_cameras: bool | None = typer.Option(
        None, "--share-cameras/--no-share-cameras", help="one model for all cameras (the lenses of one device)",
    ),
    geometry: bool | None = typer.Option(
        None, "--geometry/--no-geometry",
        help="also give the network exact mask-geometry cues: box size, foot and top points, expected height, cuts at "
             "the image border",
    ),
    self_train: str | None = typer.Option(
        None, "--self-train",
        help="with --zero-annotation: after the rough-only models (kept in OUT/rough-stage), make pseudo poses from "
             "the scene's own unlabelled train split and fine-tune on them. track: each lens's estimates smoothed "
             "along its tracks; fused: the lenses' estimates fused and smoothed along the tracks; views: the same at "
             "per-track heights from the lenses' disagreement (docs/RESULTS.md)",
    ),
    self_epochs: int | None = typer.Option(
        None, "--self-epochs", min=1, help="epochs of the self-training's fine-tuning (default 10)",
    ),
    keyframes_only: bool = typer.Option(
        False, "--keyframes-only/--interpolated",
        help="annotated scenes: train only on the annotator's keyframes, or also on the interpolated frames between "
             "them (occluded frames are never used)",
    ),
    augment: int | None = typer.Option(
        None, "--augment",
        help="K changed copies of every annotated training mask (occlusion cuts, 1 px outline changes; labels stay "
             "exact)",
    ),
    device: str | None = typer.Option(
        None, "--device", help="torch device, e.g. cpu or cuda (default: cuda if present)",
    ),
    threads: int | None = typer.Option(None, "--threads", min=1, help="CPU threads for torch (default 2)"),
    seed: int | None = typer.Option(None, "--seed", help="seed of the first run (run r uses seed + r)"),
    force: bool = typer.Option(False, "--force", help="retrain models that exist already"),
    from_models: Path | None = typer.Option(None, "--from", help=FROM_HELP),
    parallel: int | None = typer.Option(
        None, "--parallel", min=1,
        help="train in parallel as Ray tasks on this many local CPUs: every camera x class x run is a task, the best "
             "run picked as in serial (same seeds, same models)",
    ),
    address: str | None = typer.Option(
        None, "--address",
        help="train camera x class x run as tasks on this Ray cluster, e.g. ray://head:10001 or auto",
    ),
) -> None:
    """Train Seg2PoseNet on a scene, per camera and class (paper 4.1).

    The paper's protocol: best of four runs, Adam 5e-5, batch 16, 64 batches per epoch,
    50 epochs, every fourth example a rough model. An interrupted training resumes from its
    checkpoints.

    Without annotation: --zero-annotation trains on rough 3D models only; adding
    --self-train fused (or track, views) then fine-tunes those models on pseudo poses the scene's own
    unlabelled train split gives them.

    From a start: --from MODELS fine-tunes those models (the shipped demo models, a
    zero-annotation run's, another scene's) on this scene's annotations in minutes."""
    from seg2pose.io.nofollow import refuse_linked_folder
    from seg2pose.io.scene import load_scene

    # a linked model folder: refused before the examples are built, not at the first model
    refuse_linked_folder(Path(out) if out is not None else Path(scene) / "models")
    if from_models is not None:
        return _fine_tune(scene, from_models, out, zero_annotation or bool(self_train), epochs,
                          batches, lr, seed, threads, device, camera, cls)
    from seg2pose.training.config import TrainConfig, TrainSettings
    from seg2pose.training.self_training import train_self_trained
    from seg2pose.training.train import train_scene

    cfg = {"paper": TrainConfig.paper, "quick": TrainConfig.quick, "long": TrainConfig.long,
           "demo": TrainConfig.demo}[protocol]()
    over = dict(arch=arch, epochs=epochs, runs=runs, batches_per_epoch=batches, lr=lr,
                rough_per_class=rough, rough_every=rough_every, rough_occlusion=rough_occlusion,
                rough_random=rough_random,
                share_classes=share_classes, share_cameras=share_cameras,
                rough_detector_noise=rough_noise, rough_video=rough_video, geometry=geometry, augment=augment,
                seed=seed, self_train=self_train, self_epochs=self_epochs)
    cfg = cfg.replace(zero_annotation=zero_annotation,
                      annotated_rows="keyframes" if keyframes_only else "interpolated",
                      **{k: v for k, v in over.items() if v is not None})
    settings = TrainSettings(device=device, threads=threads or TrainSettings.threads, force=force)
    # self-training: the rough-only stage (train_scene), then the fine-tuning on pseudo poses
    fit = train_self_trained if cfg.self_train else train_scene
    from seg2pose.io.atomic import holding

    # the model folder locked from the start: two trainings into one folder are refused
    with holding(Path(out) if out is not None else Path(scene) / "models"):
        out_dir = fit(load_scene(scene), out, cfg, cameras=camera or None, classes=cls or None,
                      progress=True, settings=settings,
                      map_groups=ray_map(address, parallel) if parallel or address else None)
    typer.echo(f"models in {out_dir}")


def _fine_tune(scene, start, out, zero, epochs, batches, lr, seed, threads, device, camera, cls) -> None:
    """``s2p train --from``: the fine-tuning of seg2pose.training.fine_tune, its lines echoed."""
    from seg2pose.core.errors import InputError
    from seg2pose.io.scene import load_scene
    from seg2pose.training.fine_tune import FineTuneOptions, fine_tune_scene

    if zero:
        raise InputError("--from fine-tunes on annotations; it does not combine with "
                         "--zero-annotation or --self-train", field="--from")
    d = FineTuneOptions()
    opts = FineTuneOptions(epochs=epochs or d.epochs, batches_per_epoch=batches or d.batches_per_epoch,
                           lr=d.lr if lr is None else lr, seed=seed or 0,
                           threads=threads or d.threads, device=device)
    sc = load_scene(scene)
    res = fine_tune_scene(sc, start, out, opts, cameras=camera or None, classes=cls or None)
    typer.echo(f"fine-tuned from {start} in {res.wall_s:.0f} s:")
    for line in res.lines.values():
        typer.echo(f"  {line}")
    typer.echo(f"models in {out or sc.root / 'models'}")
