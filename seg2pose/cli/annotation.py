"""Annotation commands: the ``s2p annotate`` family.

    s2p annotate SCENE                     the annotation app on SCENE (= s2p annotate open SCENE;
                                           annotate/app/, served by marimo)
    s2p annotate status SCENE              tracks, keyframes and journal of SCENE's annotations
    s2p annotate export SCENE              gt/poses.csv (source column), MCAP set, T-Analyst CSV
    s2p annotate import-tanalyst SCENE CSV T-Analyst tracks as keyframes
    s2p annotate export-tanalyst SCENE -o CSV

A first word that is not a subcommand is the scene (``_SceneOrCommand``); a scene folder that is
named like a subcommand is opened with ``s2p annotate open NAME``.
"""

from __future__ import annotations

from pathlib import Path

import typer
from typer.core import TyperGroup

from seg2pose.cli.common import ANNOTATION, speaks_flags
from seg2pose.core.errors import InputError, S2PError
from seg2pose.io.atomic import check_writable, outputs, replacing

OPEN = "open"


class _SceneOrCommand(TyperGroup):
    """``s2p annotate SCENE ...`` runs ``s2p annotate open SCENE ...``."""

    def parse_args(self, ctx, args: list[str]) -> list[str]:
        if args and not args[0].startswith("-") and args[0] not in self.commands:
            args = [OPEN, *args]
        return super().parse_args(ctx, args)


annotate_app = typer.Typer(
    cls=_SceneOrCommand, no_args_is_help=True, add_completion=False,
    help="Annotate road users by keyframes and interpolation (the T-Analyst replacement).\n\n"
         "`s2p annotate SCENE` opens the annotation app; the subcommands below export the "
         "annotations and bring T-Analyst files in and out.")


def _echo_notes(notes: list[str], limit: int = 5) -> None:
    """The first ``limit`` notes, then how many more (an import can raise hundreds)."""
    for note in notes[:limit]:
        typer.echo(f"note: {note}")
    if len(notes) > limit:
        typer.echo(f"note: ... and {len(notes) - limit} more like these")


def _status(scene: Path) -> None:
    from annotate import Project
    from annotate.export import provenance_line
    from annotate.table import SOURCES, source_counts

    with Project.open(scene, read_only=True) as p:
        _echo_notes(p.notes)
        tracks = list(p.tracks.values())
        by_cls: dict[str, int] = {}
        for t in tracks:
            by_cls[t.cls] = by_cls.get(t.cls, 0) + 1
        kf = sum(len(t.keyframes) for t in tracks)
        typer.echo(f"{p.scene.root}: {len(tracks)} tracks ("
                   + ", ".join(f"{n} {c}" for c, n in sorted(by_cls.items())) + f"), {kf} keyframes, "
                   f"{p.seq} journal records, frames {p.frame_range}")
        table = p.poses()
        counts = source_counts(table)
        typer.echo(f"rows by provenance: {provenance_line(table)}")
        for t in tracks:
            c = counts.get(t.id, {})
            reviewed = sum(b - a + 1 for a, b in t.reviewed)
            typer.echo(f"  {t.cls} {t.id}: " + (", ".join(f"{c[k]} {k}" for k in SOURCES if k in c)
                                                 or "no rows")
                       + (f"; {reviewed} frames reviewed" if reviewed else ""))


def _parse_start(text: str) -> int:
    from seg2pose.io.tanalyst import parse_time

    try:
        return parse_time(text)
    except InputError:
        raise InputError(f"expected HH:MM:SS.mmm, got {text!r}", field="--start") from None


def _parse_types(items: list[str]) -> dict[str, str]:
    out = {}
    for it in items:
        typ, sep, cls = it.partition("=")
        if not sep or not typ.strip() or not cls.strip():
            raise InputError(f"expected TYPE=CLASS, got {it!r}", field="--type")
        out[typ.strip()] = cls.strip()
    return out


START_HELP = ("time stamp of the video's first frame (frame 0) on T-Analyst's clock, "
              "HH:MM:SS.mmm")


@annotate_app.command(OPEN)
@speaks_flags
def open_cmd(
    scene: Path = typer.Argument(..., help="scene folder to annotate (edits go to SCENE/annotations/)"),
    run: Path | None = typer.Option(None, "--run", help="run folder of this scene (from `s2p run`): "
                                       "its estimates are shown, can be accepted as keyframes and "
                                       "drive the suggested keyframes"),
    camera: list[str] = typer.Option([], "--camera", help="cameras to show (repeatable; default: all)"),
    port: int | None = typer.Option(None, "--port", help="local port of the app on 127.0.0.1 (default: "
                                        "a free one; other machines: an SSH tunnel, see below)"),
    browser: bool = typer.Option(True, "--browser/--no-browser", help="open the app in your web browser"),
    native: bool = typer.Option(False, "--native", help="also show the recording in the native Rerun "
                                "viewer (display only; clicks come from the page)"),
) -> None:
    """Open the annotation app on a scene (also: `s2p annotate SCENE`).

    A local web page (no internet, no account): one camera large (exactly the frame the panel
    names, with mask outlines and every track's box; click it to place a keyframe; k: the next
    camera), the Rerun viewer (3D world, the other cameras, the selected track's keyframe
    timeline; hidden at first where the browser renders without a GPU, Shift+V shows it) and a
    panel of tracks, keyframes and actions with their keyboard shortcuts. Prints the URL;
    every edit is journalled at once; stop with Ctrl-C (or SIGTERM).

    The server listens on 127.0.0.1 only and needs the random token in the printed URL
    (page, websocket and API); requests naming another Host or Origin are refused. To annotate
    from another machine, tunnel the port over SSH rather than exposing it: on your machine run
    `ssh -N -L PORT:127.0.0.1:PORT USER@SERVER` and open the printed URL there. The server's log
    is SCENE/annotations/server.log."""
    from annotate.app.serve import run_app

    run_app(scene, run, list(camera) or None, port=port, browser=browser, native=native,
            echo=typer.echo)


@annotate_app.command("status")
@speaks_flags
def status_cmd(scene: Path = typer.Argument(..., help="scene folder")) -> None:
    """Tracks, keyframes and journal of a scene's annotations (reads only; safe while annotating)."""
    _status(scene)


@annotate_app.command("import-tanalyst")
@speaks_flags
def import_tanalyst_cmd(
    scene: Path = typer.Argument(..., help="scene folder"),
    csv: Path = typer.Argument(..., help="T-Analyst tracks CSV (';'-separated, decimal commas)"),
    start: str = typer.Option("00:00:00.000", "--start", help=START_HELP),
    fps: float | None = typer.Option(None, "--fps", help="the video's frame rate "
                                        "(default: the scene's)"),
    types: list[str] = typer.Option([], "--type", help="TYPE=CLASS: the scene class of a "
                                    "T-Analyst road user type the defaults do not know "
                                    "(repeatable), e.g. --type Moped=bicyclist"),
    replace: bool = typer.Option(False, "--replace/--no-replace", help="replace road users imported before"),
) -> None:
    """Import T-Analyst tracks as keyframes.

    One track per road user (ids kept where free), headings from the motion between
    detections; one undoable edit."""
    from annotate import Project
    from annotate.tanalyst_io import import_tanalyst
    from seg2pose.io.tanalyst import read_tanalyst

    table = read_tanalyst(csv)
    with Project.open(scene) as p:
        ch = import_tanalyst(p, table, fps, _parse_start(start), _parse_types(types), file=csv,
                             replace=replace)
        _echo_notes(p.notes)
        kf = sum(len(p.track(t).keyframes) for t in ch.tracks if t in p.tracks)
    typer.echo(f"imported {len(table)} detections of {len(ch.tracks)} road users as {kf} "
               f"keyframes (tracks {', '.join(map(str, sorted(ch.tracks)))})")


def _export_tanalyst(p, out: Path, start: str, fps, keyframes_only: bool, decimal: str,
                     force: bool) -> Path:
    from annotate.tanalyst_io import annotations_to_tanalyst
    from seg2pose.io.tanalyst import write_tanalyst

    if decimal not in (",", "."):
        raise InputError(f"expected ',' or '.', got {decimal!r}", field="--decimal")
    with replacing(out, force, folder=False) as tmp:
        t = annotations_to_tanalyst(p, fps, _parse_start(start), keyframes_only, decimal)
        write_tanalyst(tmp, t)
    typer.echo(f"wrote {out}: {len(t)} detections of {len(set(t.road_user_id.tolist()))} road users")
    return out


@annotate_app.command("export-tanalyst")
@speaks_flags
def export_tanalyst_cmd(
    scene: Path = typer.Argument(..., help="scene folder"),
    out: Path = typer.Option(..., "-o", "--out", help="T-Analyst tracks CSV to write"),
    start: str = typer.Option("00:00:00.000", "--start", help=START_HELP),
    fps: float | None = typer.Option(None, "--fps", help="the video's frame rate "
                                        "(default: the scene's)"),
    keyframes_only: bool = typer.Option(False, "--keyframes-only/--no-keyframes-only",
                                        help="only keyframes, or every annotated frame"),
    decimal: str = typer.Option(",", "--decimal", help="decimal separator: ',' as T-Analyst "
                                "writes, or '.'"),
    force: bool = typer.Option(False, "--force", help="overwrite an existing file"),
) -> None:
    """Write the annotations as a T-Analyst tracks CSV (road user ids and types as imported)."""
    from annotate import Project

    with Project.open(scene, read_only=True) as p:
        _export_tanalyst(p, out, start, fps, keyframes_only, decimal, force)


@annotate_app.command("export")
@speaks_flags
def export_cmd(
    scene: Path = typer.Argument(..., help="scene folder"),
    out: Path | None = typer.Option(None, "-o", "--out", help="folder for the MCAP set and "
                                       "the T-Analyst CSV (default: SCENE/export)"),
    gt: bool = typer.Option(True, "--gt/--no-gt", help="write SCENE/gt/poses.csv (every "
                            "annotated frame, with a source column) for training"),
    mcap: bool = typer.Option(True, "--mcap/--no-mcap", help="write OUT/annotations.mcap: "
                              "video, masks, calibration, annotated tracks and the journal"),
    tanalyst: bool = typer.Option(True, "--tanalyst/--no-tanalyst",
                                  help="write OUT/tanalyst.csv"),
    start: str = typer.Option("00:00:00.000", "--start", help=START_HELP),
    force: bool = typer.Option(False, "--force", help="replace existing outputs (and "
                               "gt/poses.csv that did not come from an annotation export)"),
    allow_unreviewed: bool = typer.Option(False, "--allow-unreviewed", help="also write rows "
                                          "that are unchecked estimates (pre-annotation nobody "
                                          "reviewed), marked estimate-unchecked in the source "
                                          "column; without it such rows refuse the export"),
) -> None:
    """Export the annotations as ground truth, an MCAP set and a T-Analyst CSV.

    Ground truth for `s2p train`, an MCAP set that `s2p import-mcap` turns back into a working
    annotation project (video of every frame, masks, calibration, the journal), and
    T-Analyst's tracks CSV. Every gt row names its provenance (source column: keyframe,
    estimate-accepted, estimate-unchecked, interpolated, reviewed, occluded); the counts are
    printed. Rows that are unchecked estimates refuse the export unless --allow-unreviewed."""
    from annotate import Project
    from annotate.export import UnreviewedError

    out = Path(out) if out is not None else Path(scene) / "export"
    with Project.open(scene, read_only=True) as p:
        try:
            export_set(p, out, gt=gt, mcap=mcap, tanalyst=tanalyst, start=start, force=force,
                       allow_unreviewed=allow_unreviewed)
        except UnreviewedError as e:
            raise S2PError(f"{e} (--allow-unreviewed)") from None


def export_set(p, out: Path, *, gt: bool, mcap: bool, tanalyst: bool, start: str,
               force: bool, allow_unreviewed: bool = False) -> None:
    """gt/poses.csv, OUT/annotations.mcap (+ its layout) and OUT/tanalyst.csv as one set:
    every output checked and locked before anything is written, each built beside its final
    name, all swapped in together at the end (atomic.outputs)."""
    import tempfile

    from annotate.export import gt_replaceable, gt_table, journal_files, provenance_line, write_annotation_run
    from annotate.table import SOURCES, source_counts
    from annotate.tanalyst_io import annotations_to_tanalyst
    from s2p_review.annotated_mcap import export_annotated_mcap
    from s2p_review.foxglove_layout import layout_path
    from s2p_review.mcap_export import ExportOptions
    from seg2pose.io.poses import write_poses
    from seg2pose.io.tanalyst import write_tanalyst

    paths, forced = [], set()
    if gt:
        paths.append(p.scene.gt_path)
        if gt_replaceable(p.scene.gt_path, force):
            forced.add(p.scene.gt_path)
    if mcap:
        paths += [out / "annotations.mcap", layout_path(out / "annotations.mcap")]
    if tanalyst:
        paths.append(out / "tanalyst.csv")
    for q in paths:  # refused up front: nothing is written when one output may not be replaced
        if q not in forced:
            check_writable(q, force)
    t_start = _parse_start(start)
    said = []
    with outputs(paths, force=True) as files:
        truth = None
        if gt:
            truth = gt_table(p, allow_unreviewed)
            write_poses(files.file(p.scene.gt_path), truth)
            said.append(f"wrote {p.scene.gt_path}: {len(truth)} rows ({provenance_line(truth)})")
            for t, c in sorted(source_counts(truth).items()):  # per track, as `annotate status`
                said.append(f"  {p.track(t).cls} {t}: "
                            + ", ".join(f"{c[k]} {k}" for k in SOURCES if k in c))
        if mcap:
            dst = out / "annotations.mcap"
            tmp = files.file(dst)
            # the scratch run inside the MCAP's partial folder: a killed export leaves nothing
            # in /tmp, and the next writer removes the partial folder with it
            with tempfile.TemporaryDirectory(prefix="annotation-run-", dir=tmp.parent) as d:
                run = write_annotation_run(p, Path(d) / "annotations")
                # the MCAP shows the set's own gt, not the gt/poses.csv this set replaces
                res = export_annotated_mcap(p.scene, run, tmp, journal_files(p),
                                            ExportOptions(gt=truth, frames=p.frame_range),
                                            force=True)
            files.adopt(layout_path(dst), res.layout or layout_path(tmp))
            said += [f"note: {n}" for n in res.notes]
            said.append(f"wrote {dst} ({tmp.stat().st_size / 1e6:.1f} MB); `s2p import-mcap` "
                        "restores the scene with its annotation project")
        if tanalyst:
            t = annotations_to_tanalyst(p, None, t_start, False, ",")
            write_tanalyst(files.file(out / "tanalyst.csv"), t)
            said.append(f"wrote {out / 'tanalyst.csv'}: {len(t)} detections of "
                        f"{len(set(t.road_user_id.tolist()))} road users")
    for line in said:
        typer.echo(line)


def register(app: typer.Typer) -> None:
    app.add_typer(annotate_app, name="annotate", rich_help_panel=ANNOTATION)
