"""Review commands: ``s2p review``, ``s2p export``, ``s2p import-mcap`` and ``s2p screenshot``.

Heavy imports (rerun, mcap, protobuf) happen inside the commands so ``s2p --help`` stays fast.
"""

from __future__ import annotations

from pathlib import Path

import typer

from seg2pose.cli.common import REVIEW, parse_frames, speaks_flags
from seg2pose.core.errors import S2PError

_FLAG = {"masks": "--mask-every 1", "video": "--video-every 1"}


def _notes(notes) -> None:
    """Print the library's notes; a reduced cadence gets the flag that asks for every frame."""
    for note in notes:
        what = note.split(":", 1)[0]
        hint = f"; {_FLAG[what]} for all" if what in _FLAG and "one frame in" in note else ""
        typer.echo(f"note: {note}{hint}")


START_HELP = ("time of the first frame (frame 0), ISO 8601 with a zone, e.g. 2021-06-14T08:00:00Z "
              "(default: the scene's start_time; without one, times count from 0)")
SCALE_HELP = ("store video frames at this fraction of the camera's size (smaller files; the "
              "viewers show them at full size)")


def _start_ns(text: str | None) -> int | None:
    from seg2pose.io.scene import parse_start_time

    return None if text is None else parse_start_time(text, field="--start-time")


def register(app: typer.Typer) -> None:
    app.command("review", rich_help_panel=REVIEW)(speaks_flags(review))
    app.command("export", rich_help_panel=REVIEW)(speaks_flags(export))
    app.command("import-mcap", rich_help_panel=REVIEW)(speaks_flags(import_mcap_cmd))
    app.command("screenshot", rich_help_panel=REVIEW)(speaks_flags(screenshot_cmd))


def review(
    scene: Path = typer.Argument(..., help="scene folder"),
    run: list[Path] = typer.Option([], "--run", help="run folder (made by `s2p run`); repeat to compare runs"),
    save: Path | None = typer.Option(None, "-o", "--out", help="write the recording to this .rrd file"),
    spawn: bool = typer.Option(False, "--spawn/--no-spawn", help="open the native Rerun viewer"),
    connect: str | None = typer.Option(
        None, "--connect", help="stream to a running viewer, e.g. rerun+http://127.0.0.1:9876/proxy",
    ),
    screenshot: Path | None = typer.Option(
        None, "--screenshot", help="run a headless viewer and save a PNG of it here",
    ),
    frames: str | None = typer.Option(None, "--frames", help="frame range A:B (inclusive); default: the runs' frames"),
    frame: int | None = typer.Option(
        None, "--frame",
        help="time cursor for --screenshot (default: middle frame) and for a spawned or connected viewer",
    ),
    follow: bool = typer.Option(
        False, "--follow/--no-follow", help="make a spawned or connected viewer follow the newest frame",
    ),
    camera: list[str] = typer.Option([], "--camera", help="cameras to show (default: the runs' cameras)"),
    mask_every: int | None = typer.Option(
        None, "--mask-every", min=1,
        help="log masks every k-th frame (default: every frame while the masks stay within 160 Mpixel, else the "
             "smallest k that does)",
    ),
    video_every: int | None = typer.Option(
        None, "--video-every", min=1,
        help="with --video-as jpeg: log video frames every k-th frame (default: as for masks)",
    ),
    video_as: str = typer.Option(
        "asset", "--video-as",
        help="asset: every frame, one H.264 video per camera that the viewer decodes (a few MB; encoded once, cached); "
             "jpeg: JPEG images every --video-every frames",
    ),
    masks: bool = typer.Option(
        True, "--masks/--no-masks",
        help="show the instance masks (outlines every frame, filled every --mask-every frames)",
    ),
    video: bool = typer.Option(True, "--video/--no-video", help="show the video frames (when the scene has video)"),
    start_time: str | None = typer.Option(None, "--start-time", help=START_HELP),
    image_scale: float = typer.Option(1.0, "--image-scale", min=0.05, max=1.0, help=SCALE_HELP),
    force: bool = typer.Option(False, "--force", help="overwrite existing output files"),
    conflicts: Path | None = typer.Option(
        None, "--conflicts",
        help="conflicts.csv of the (first) run (made by `s2p conflicts`): events, highlighted pairs, TTC and distance "
             "plots",
    ),
) -> None:
    """Review a scene and its runs in the Rerun viewer.

    Masks, normal positions, residuals, fused road users, ground truth and errors, with a
    layout that opens ready to use."""
    from s2p_review.recording import LogStyle
    from s2p_review.session import RecordOptions, Targets, record
    from seg2pose.io.scene import load_scene

    to = Targets(rrd=save, spawn=spawn, connect=connect, screenshot=screenshot, frame=frame,
                 follow=follow, force=force)
    if not to.any():
        raise S2PError("nothing to do: pass -o FILE.rrd, --spawn, --connect URL or "
                       "--screenshot FILE.png")
    from s2p_review.recording import VIDEO_FORMATS

    if video_as not in VIDEO_FORMATS:
        raise S2PError(f"--video-as {video_as!r}: expected one of {', '.join(VIDEO_FORMATS)}")
    opts = RecordOptions(frames=parse_frames(frames), cameras=list(camera) or None,
                         mask_every=mask_every, video_every=video_every,
                         style=LogStyle(masks=masks, video=video, video_format=video_as,
                                        image_scale=image_scale),
                         start_ns=_start_ns(start_time), conflicts=conflicts)
    res = record(load_scene(scene), list(run), to, opts)
    _notes(res.notes)
    if res.rrd is not None:
        typer.echo(f"wrote {res.rrd} ({res.rrd.stat().st_size / 1e6:.1f} MB); open it with:  rerun {res.rrd}")
    if res.screenshot is not None:
        typer.echo(f"wrote {res.screenshot}")


def export(
    scene: Path = typer.Argument(..., help="scene folder"),
    run: Path = typer.Option(..., "--run", help="run folder (made by `s2p run`)"),
    out: Path = typer.Option(..., "-o", "--out", help="output .mcap file"),
    frames: str | None = typer.Option(None, "--frames", help="frame range A:B (inclusive); default: the run's frames"),
    mask_every: int | None = typer.Option(
        None, "--mask-every", min=1, help="export masks every k-th frame (default: automatic, as for `s2p review`)",
    ),
    video_every: int | None = typer.Option(
        None, "--video-every", min=1, help="export video frames every k-th frame (default: automatic)",
    ),
    video: bool = typer.Option(
        True, "--video/--no-video",
        help="also export the plain video frames (the display images show the video under the masks either way)",
    ),
    start_time: str | None = typer.Option(None, "--start-time", help=START_HELP),
    image_scale: float = typer.Option(1.0, "--image-scale", min=0.05, max=1.0, help=SCALE_HELP),
    force: bool = typer.Option(False, "--force", help="overwrite an existing file and its layout"),
    conflicts: Path | None = typer.Option(
        None, "--conflicts",
        help="conflicts.csv of the run (made by `s2p conflicts`): exported as events on /s2p/conflicts",
    ),
) -> None:
    """Export a scene and a run as MCAP, for Foxglove and archives.

    Foxglove schemas plus lossless s2p records (an exact round trip), with a Foxglove layout
    beside it (NAME.layout.json)."""
    from s2p_review.mcap_export import ExportOptions, export_mcap
    from seg2pose.io.scene import load_scene

    res = export_mcap(load_scene(scene), run, out, ExportOptions(
        frames=parse_frames(frames), mask_every=mask_every, video_every=video_every,
        video=video, start_ns=_start_ns(start_time), image_scale=image_scale,
        conflicts=conflicts), force=force)
    _notes(res.notes)
    p = res.path
    typer.echo(f"wrote {p} ({p.stat().st_size / 1e6:.1f} MB) and its Foxglove layout {res.layout}; "
               f"open both in Foxglove (Layouts > Import from file); for Rerun use `s2p review -o FILE.rrd`")


def import_mcap_cmd(
    file: Path = typer.Argument(..., help=".mcap file written by `s2p export`"),
    out: Path = typer.Option(..., "-o", "--out", help="output folder (becomes a scene folder)"),
    force: bool = typer.Option(False, "--force", help="write into an existing, non-empty folder"),
) -> None:
    """Restore a scene folder and its run from an MCAP file written by s2p export."""
    from s2p_review.mcap_import import import_mcap

    run_dir = import_mcap(file, out, force=force, check_annotations=_check_restored_journal)
    typer.echo(f"restored {out}/scene.json and the run {run_dir} (poses.csv, views.csv, run.json)")


def screenshot_cmd(
    rrd: Path = typer.Argument(
        ...,
        help="recording (.rrd), or MCAP export (.mcap: Rerun lays it out itself and draws its images and cameras, not "
             "its boxes)",
    ),
    out: Path = typer.Option(..., "-o", "--out", help="output .png"),
    frame: int | None = typer.Option(None, "--frame", help="time cursor, a frame number (default: the middle)"),
    force: bool = typer.Option(False, "--force", help="overwrite an existing file"),
) -> None:
    """Save a screenshot of a recording or MCAP export, opened in a headless viewer.

    The README picture: s2p screenshot sample_logs/demo.rrd -o docs/screenshot.png --frame 560
    --force."""
    from s2p_review.viewer import take_screenshot

    typer.echo(f"wrote {take_screenshot(rrd, out, frame=frame, force=force)}")


def _check_restored_journal(folder: Path, mcap: Path) -> None:
    """Open the annotation project restored into ``folder`` (read-only): a journal that does
    not replay is an error naming the MCAP file's attachment, before anything is moved into
    place."""
    from annotate import Project
    from seg2pose.core.errors import InputError, S2PError

    try:
        with Project.open(folder, read_only=True) as p:
            torn = [n for n in p.notes if "torn" in n]
    except S2PError as e:
        raise InputError(f"the annotation journal attachment does not open: "
                         f"{_final_note(e, folder)}", file=mcap, field="attachments annotations/") from None
    if torn:
        raise InputError(f"the annotation journal attachment is damaged: {torn[0]}", file=mcap,
                         field="attachments annotations/")


def _final_note(e: Exception, folder: Path) -> str:
    """The error's text with the temporary folder's path left out."""
    return str(e).replace(str(folder) + "/", "").replace(str(folder), "")
