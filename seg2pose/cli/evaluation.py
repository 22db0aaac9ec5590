"""Evaluation commands: ``s2p eval``, ``s2p calibrate-errors``, ``s2p paper-table``,
``s2p bench-accuracy`` (the method's own commands are ``seg2pose.cli.method``'s)."""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Literal

import typer

from seg2pose.cli.common import METHOD, speaks_flags
from seg2pose.cli.method import MODELS_HELP, SMOOTH_HELP, SPARSE_HELP


def register(app: typer.Typer) -> None:
    app.command("eval", rich_help_panel=METHOD)(speaks_flags(eval_cmd))
    app.command("calibrate-errors", rich_help_panel=METHOD)(speaks_flags(calibrate_cmd))
    # the old name, for one release: a new user reads "calibrate" as the camera's calibration
    app.command("calibrate", rich_help_panel=METHOD, hidden=True, deprecated=True)(
        speaks_flags(calibrate_alias_cmd))
    app.command("paper-table", rich_help_panel=METHOD)(speaks_flags(paper_table_cmd))
    app.command("bench-accuracy", rich_help_panel=METHOD)(speaks_flags(bench_accuracy_cmd))


def eval_cmd(
    scene: Path = typer.Argument(..., help="scene folder with ground truth"),
    run: Path | None = typer.Option(None, "--run", help="run folder (made by s2p run)"),
    split: str | None = typer.Option(None, "--split", help="evaluate only this split's frames"),
    as_json: bool = typer.Option(False, "--json/--no-json", help="print JSON instead of a table"),
    match: Literal["auto", "ids", "nearest"] = typer.Option(
        "auto", "--match",
        help="ids: pair estimates with the truth by track id; nearest: per frame by position (for tracks made by s2p "
             "track, masks-from-video or import-detections); auto: nearest when the run's ids are not the truth's, and "
             "says so",
    ),
    gate: float = typer.Option(3.0, "--gate", help="with --match nearest or auto: the farthest pair, metres"),
    track_d0: float = typer.Option(
        2.0, "--track-distance", min=0.01,
        help="tracking metrics of the run's world tracks: similarity max(0, 1 - d / this) for positions d metres "
             "apart, so MOTA and IDF1 match within half of it, HOTA averages thresholds from 0.05 to 0.95 of it",
    ),
    truth_masks: list[Path] | None = typer.Option(
        None, "--truth-masks",
        help="a camera's truth masks (MOTS txt named after the camera, e.g. truth/masks/c1.txt): HOTA, IDF1 and "
             "MOTSA of SCENE/masks/<camera>.txt against them (mask IoU); repeatable",
    ),
    ignore_below: int = typer.Option(
        0, "--ignore-below", min=0,
        help="with --truth-masks: truth masks under this many pixels are ignore regions (neither found nor missed)",
    ),
) -> None:
    """Errors and tracking metrics of a run (and of masks) against the ground truth.

    The run: mean ground-plane error overall, per class and per 5 m of distance from the cameras,
    and the standard tracking metrics of its world tracks (HOTA with DetA, AssA, LocA; IDF1 with
    IDP, IDR; MOTA with MOTP, IDSW, FP, FN; computed as TrackEval does; against the truth whose
    position lies in the image of one of the run's cameras). Masks (--truth-masks):
    the same metrics on mask IoU, with MOTA as MOTS's MOTSA."""
    import json

    from seg2pose.eval.evaluate import format_r90_table, format_table
    from seg2pose.eval.paper_table import evaluate_run
    from seg2pose.eval.tracking_inputs import mots_summary
    from seg2pose.eval.tracking_metrics import format_summary
    from seg2pose.io.scene import load_scene

    if run is None and not truth_masks:
        raise typer.BadParameter("give --run RUN (world tracks) or --truth-masks FILE (masks), or both")
    sc = load_scene(scene)
    out: dict = {}
    if run is not None:
        res = evaluate_run(sc, run, split=split, match=match, gate=gate, track_d0=track_d0)
        _warn_jumps([sc.gt_path, Path(run) / "poses.csv"], sc.fps)
        if res.match_note:
            typer.echo(f"note: {res.match_note} (--match nearest)", err=True)
        out = res.to_dict()
    masks = {}
    for path in truth_masks or []:
        cam = path.stem
        if cam not in sc.cameras:
            raise typer.BadParameter(f"{path}: the file's name names no camera of the scene "
                                     f"({', '.join(sc.cameras)}); name it <camera>.txt")
        masks[cam] = mots_summary(path, sc.masks_path(cam), sc.split_range(split), ignore_below)
    if masks:
        out["masks"] = masks
    if as_json:
        typer.echo(json.dumps(out, indent=1))
        return
    if run is not None:
        typer.echo(format_table({Path(run).name: res}))
        r90 = format_r90_table({Path(run).name: res})
        if r90:
            typer.echo("error bars r90_m (coverage: share of poses within r90_m; the aim is 0.90)")
            typer.echo(r90)
        if res.tracking:
            typer.echo(f"tracking, world ({res.tracking['similarity']}): {format_summary(res.tracking)}")
    for cam, d in masks.items():
        typer.echo(f"tracking, masks of {cam} (mask IoU): {format_summary(d)}")


def _warn_jumps(paths: list[Path], fps: float) -> None:
    """A warning per pose file with a track that moves farther between two of its rows than
    its class can (two road users under one id: identity figures would count them as one)."""
    from seg2pose.io.poses import read_poses
    from seg2pose.safety.gaps import jump_note, jumps
    from seg2pose.safety.tracks import from_poses

    for p in paths:
        if p.exists():
            tr, _ = from_poses(read_poses(p), fps)
            bad = jumps(tr)
            if len(bad):
                typer.echo(f"warning: {p}: {jump_note(tr, bad)}", err=True)


def calibrate_cmd(
    scene: Path = typer.Argument(..., help="scene folder with ground truth"),
    run: list[Path] = typer.Option(
        ..., "--run",
        help="a run of the validation split (s2p run --split val), with the method and --smooth of the runs to "
             "calibrate; repeat for more road users (other splits, or runs of other scenes, each with that scene's own "
             "models and scored against the scene its run.json names: how a zero-annotation scene, which has no truth "
             "of its own, gets error bars)",
    ),
    out: Path | None = typer.Option(
        None, "-o", "--out",
        help="calibration file (default: MODELS/r90.json beside the run's models, or SCENE/r90-baseline.json for a "
             "baseline run: where s2p run looks)",
    ),
    force: bool = typer.Option(False, "--force", help="replace an existing calibration"),
) -> None:
    """Fit the error bars r90_m on a run whose truth is known.

    Per class, the 90th percentile of the error given what the method knows (distance,
    viewing angle, mask cut by the image border, far residual, ensemble spread, views fused,
    their disagreement): a quantile regression. Runs made afterwards carry r90_m in poses.csv
    and views.csv; s2p eval reports its coverage."""
    from seg2pose.io.scene import load_scene
    from seg2pose.method.r90_calibrate import calibrate_run

    path, cal = calibrate_run(load_scene(scene), list(run), out, force)
    cov = cal.meta["coverage_on_fit"]
    typer.echo(f"r90 calibration ({cal.meta.get('method')}, --smooth {cal.meta.get('smooth_frames')}, "
               f"classes {', '.join(k for k in cal.pose.coef if k != '*')}) in {path}; coverage on "
               f"the fitted rows: views {cov['views']:.3f}, poses {cov['poses']:.3f}")


@functools.wraps(calibrate_cmd)
def calibrate_alias_cmd(*args, **kwargs) -> None:
    """Deprecated name of ``s2p calibrate-errors``."""
    typer.secho("note: `s2p calibrate` is now `s2p calibrate-errors` (error bars); cameras are "
                "calibrated with `s2p calibrate-camera`. The old name goes in the next release.",
                fg=typer.colors.YELLOW, err=True)
    return calibrate_cmd(*args, **kwargs)


def paper_table_cmd(
    scene: Path = typer.Argument(..., help="scene folder with ground truth"),
    models: list[Path] | None = typer.Option(None, "--models", help=MODELS_HELP),
    split: str = typer.Option("test", "--split", help="split to evaluate on"),
    out: Path | None = typer.Option(None, "-o", "--out", help="output folder (default: SCENE/out/paper-table)"),
    config: list[str] | None = typer.Option(
        None, "-c", "--config", help="a camera configuration to include (repeatable; default: all)",
    ),
    seg2posenet: bool = typer.Option(
        True, "--seg2posenet/--no-seg2posenet", help="also the rows with Seg2PoseNet (not only the baseline)",
    ),
    sparse: bool = typer.Option(True, "--sparse/--no-sparse", help=SPARSE_HELP),
    smooth: int = typer.Option(0, "--smooth", min=0, help=SMOOTH_HELP + "; applied to the baseline's rows too"),
    force: bool = typer.Option(False, "--force", help="redo a paper table that exists already"),
) -> None:
    """Table 1 and Figure 6 of the paper on this scene.

    Every configuration with and without Seg2PoseNet: mean error overall and per 5 m of
    distance. Writes table.txt, results.json, error_vs_distance.png and the run folders."""
    from seg2pose.eval.paper_table import paper_table
    from seg2pose.io.scene import load_scene
    from seg2pose.method.sparse import set_enabled

    set_enabled(sparse)
    out_dir, text = paper_table(load_scene(scene), models_dir=models, split=split, out_dir=out,
                                configs=config or None, baseline_only=not seg2posenet, force=force,
                                smooth=smooth)
    typer.echo(text)
    typer.echo(f"written to {out_dir}")


def bench_accuracy_cmd(
    root: Path = typer.Argument(
        ...,
        help="folder for the scenes, models and tables (one sub-folder per seed; finished steps are kept and skipped)",
    ),
    seed: list[int] | None = typer.Option(
        None, "--seed", help="a scene seed (repeatable; default 100, 101, 102: settings were chosen on seeds 0-4)",
    ),
    preset: str = typer.Option("bench", "--preset", help="synthetic scene size (see s2p synth --preset)"),
    variant: list[str] | None = typer.Option(
        None, "--variant",
        help="s2pn (annotated, the quick protocol), s2pn-long (annotated, --protocol long), zero (zero-annotation), "
             "zero-random (with randomised rough models), zero-track, zero-fused or zero-views (zero then "
             "self-training, --self-train track / fused / views; they start from the zero variant's models when those "
             "are finished), zero-random-track or zero-random-views (the same from zero-random's models); repeatable; "
             "default s2pn and zero",
    ),
    threads: int = typer.Option(2, "--threads", min=1, help="CPU threads for training"),
    train_arg: list[str] | None = typer.Option(
        None, "--train-arg", help="one more s2p train option (repeatable), e.g. --train-arg=--epochs=40",
    ),
    smooth: int = typer.Option(
        0, "--smooth", min=0,
        help="also every run with positions smoothed along the tracks over this many frames either side (s2p "
             "paper-table --smooth; the baseline's too)",
    ),
) -> None:
    """The accuracy benchmark over several synthetic scenes.

    For each seed: s2p synth, heights, train and paper-table, then the nine configurations'
    error ratios to the baseline, mean (min-max) over the seeds. Writes ROOT/accuracy.json."""
    from seg2pose.cli.accuracy import run_benchmark

    _, text = run_benchmark(root, seed or [100, 101, 102], preset, tuple(variant or ("s2pn", "zero")),
                            threads, tuple(train_arg or ()), log=typer.echo, smooth=smooth)
    typer.echo(text)
