"""``s2p batch STUDY STEP...``: the single-scene commands over every scene of a study folder,
on Ray (local, or a cluster by ``--address``) or serially without it (seg2pose/batch/study.py).

The export and review steps need s2p_review, which only the command layer may import: they are
defined here and handed to the library as Steps."""

from __future__ import annotations

from pathlib import Path

import typer

from seg2pose.batch.steps import LIBRARY_STEPS, run_dir, scene_inputs
from seg2pose.batch.study import BATCH_DIR, BatchOptions, Step, format_summary, run_study
from seg2pose.cli.common import BATCH, Progress, speaks_flags
from seg2pose.core.errors import InputError
from seg2pose.core.ray import ray_available


def mcap_path(scene_dir: Path, opts: BatchOptions) -> Path:
    return scene_dir / BATCH_DIR / f"{opts.run_name}.mcap"


def rrd_path(scene_dir: Path, opts: BatchOptions) -> Path:
    return scene_dir / BATCH_DIR / f"{opts.run_name}.rrd"


def _view_inputs(scene_dir: Path, opts: BatchOptions) -> list[Path]:
    return scene_inputs(scene_dir) + [scene_dir / "video", scene_dir / "gt", run_dir(scene_dir, opts)]


def _export(scene_dir: Path, opts: BatchOptions, force: bool) -> dict:
    """What ``s2p export SCENE --run RUN -o OUT`` does, with its defaults."""
    from s2p_review.mcap_export import ExportOptions, export_mcap
    from seg2pose.io.scene import load_scene

    res = export_mcap(load_scene(scene_dir), run_dir(scene_dir, opts), mcap_path(scene_dir, opts),
                      ExportOptions(), force=force)
    return {"mcap": res.path.name}


def _review(scene_dir: Path, opts: BatchOptions, force: bool) -> dict:
    """What ``s2p review SCENE --run RUN -o OUT`` does, with its defaults."""
    from s2p_review.session import RecordOptions, Targets, record
    from seg2pose.io.scene import load_scene

    res = record(load_scene(scene_dir), [run_dir(scene_dir, opts)],
                 Targets(rrd=rrd_path(scene_dir, opts), force=force), RecordOptions())
    assert res.rrd is not None  # an .rrd was asked for
    return {"rrd": res.rrd.name}


def _layout(p: Path) -> Path:
    return p.with_name(p.name[: -len(".mcap")] + ".layout.json")


EXPORT = Step("export", _view_inputs,
              lambda s, o: [mcap_path(s, o), _layout(mcap_path(s, o))], _export)
REVIEW = Step("review", _view_inputs, lambda s, o: [rrd_path(s, o)], _review)
STEPS = {**LIBRARY_STEPS, "export": EXPORT, "review": REVIEW}
ORDER = ["masks-from-video", "run", "eval", "export", "review"]


def register(app: typer.Typer) -> None:
    app.command("batch", rich_help_panel=BATCH)(speaks_flags(batch_cmd))


def batch_cmd(
    study: Path = typer.Argument(..., help="study folder: one sub-folder per scene (recording), "
                                           "each a scene folder with scene.json"),
    steps: list[str] = typer.Argument(..., help="steps, run in this order over every scene: "
                                                "masks-from-video, run, eval, export, review"),
    baseline: bool = typer.Option(False, "--baseline/--no-baseline", help="run: normal positions only, no network "
                                                            "(results in SCENE/batch/baseline)"),
    models: list[Path] | None = typer.Option(None, "--models",
                                                help="run: checkpoint folder (default each SCENE/models); "
                                                     "results in SCENE/batch/s2pn"),
    address: str | None = typer.Option(None, "--address",
                                          help="a Ray cluster to run on, e.g. ray://head:10001 or auto "
                                               "(default: a local Ray of this command's own, on this "
                                               "machine's cores; it ends with the command)"),
    max_parallel: int | None = typer.Option(None, "--max-parallel", min=1,
                                               help="at most this many tasks (scenes, video segments) at "
                                                    "once (default: all; Ray still runs one per free CPU)"),
    segment_frames: int = typer.Option(36000, "--segment-frames", min=0,
                                       help="masks-from-video: cut videos longer than 1.5 times this "
                                            "many frames into segments of about this length that run "
                                            "in parallel and are stitched back, track ids continued "
                                            "(36000 = 20 min at 30 fps; 0: never cut)"),
    cpus: int | None = typer.Option(None, "--cpus", min=1,
                                       help="the local Ray's CPUs (default: all of this machine's; "
                                            "not with --address)"),
    serial: bool = typer.Option(False, "--serial/--no-serial", help="no Ray: run the scenes one after another here"),
    force: bool = typer.Option(False, "--force", help="masks-from-video: also replace masks the "
                                                      "scenes had before the study ran"),
    progress: Progress = True,
) -> None:
    """Run steps over every scene of a study folder, in parallel with Ray.

    Steps: masks-from-video (long videos cut into segments, --segment-frames), run (--baseline
    or --models), eval, export (MCAP), review (SCENE/batch/RUN.rrd). Each scene's files are
    written as the single-scene command writes them; complete steps are skipped on a re-run; a
    bad scene is reported and the others go on. Writes STUDY/summary.json and prints a table."""
    bad = [s for s in steps if s not in STEPS]
    if bad:
        raise InputError(f"unknown step {bad[0]!r}; expected some of {', '.join(ORDER)}", field="STEP")
    if "run" in steps and not baseline and not models:
        raise InputError("the run step needs --baseline or --models", field="STEP")
    if baseline and models:
        raise InputError("give --baseline or --models, not both", field="--models")
    opts = BatchOptions(baseline=not models, models=tuple(str(m) for m in models or ()), force=force,
                        segment_frames=segment_frames)
    use_ray = not serial and (ray_available() or address is not None)
    if not serial and not use_ray:
        typer.echo("note: Ray is not installed, running the scenes one after another; "
                   "for parallelism: pip install 'seg2pose[scale]'")
    if cpus is not None and address is not None:
        raise InputError("--cpus is for the local Ray; a cluster at --address has its own",
                         field="--cpus")
    res = run_study(study, [STEPS[s] for s in steps], opts, use_ray=use_ray, address=address,
                    max_parallel=max_parallel, cpus=cpus, progress=progress, log=typer.echo)
    typer.echo(format_summary(res.rows))
    for r in res.rows:
        if r.get("seams"):
            typer.echo(f"{r['scene']}: video in {r['segments']} segments; at the seams "
                       f"{r['seam_id_changes']} id changes, {r['seam_unlinked']} tracks not "
                       "continued (a floor of the ID switches there, docs/SCALE.md)")
    typer.echo(f"{len(res.rows)} scenes, {res.n_failed} failed, {res.seconds:.1f} s on {res.backend}; "
               f"summary in {Path(study) / 'summary.json'}")
    if res.n_failed:
        raise typer.Exit(1)
