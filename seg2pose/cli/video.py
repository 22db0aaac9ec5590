"""Video commands: ``s2p new-scene``, ``s2p masks-from-video``, ``s2p track``,
``s2p import-detections`` (from a static camera's video or a detector's output to masks with
track ids and classes)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from seg2pose.cli.common import SCENE, Progress, parse_frames, speaks_flags
from seg2pose.core.errors import InputError


def _settings(what: str, section: str, keys: str):
    """The ``--set KEY=VALUE`` option (the Annotated metadata) of a command whose settings ``what`` (with its article)
    lie in scene.json ``extra.<section>``; ``keys``: the keys, in words."""
    return typer.Option(
        "--set", help=f"{what} setting KEY=VALUE (repeatable), over scene.json extra.{section}: {keys}")


# the options the video commands share
Cameras = Annotated[list[str] | None,
                    typer.Option("--camera", help="only this camera (repeatable; default: all)")]
Associate = Annotated[bool, typer.Option(
    "--associate/--no-associate",
    help="with two or more cameras: one track id per road user in every camera (s2p associate)")]
ReplaceMasks = Annotated[bool, typer.Option("--force", help="replace an existing masks/<camera>.txt")]
BackgroundSettings = Annotated[list[str], _settings(
    "a background-subtraction", "video_masks",
    "method (mog2|knn), history, threshold, shadows, shadow_texture, texture_near (true|false), "
    "init (mode|median|warmup|none), init_frames, init_samples, learning_rate, update "
    "(selective|all|none), update_every, ghost_after, ghost_ratio, clean_start (true|false), "
    "open_px, close_px, min_area, unsettled")]
TrackerSettings = Annotated[list[str], _settings(
    "a tracker", "tracker",
    "iou_min, gate_m, gate_growth, max_gap, min_length, gap_penalty, split_min (default 0.5: "
    "split a mask holding half of two tracks' predicted masks; 0: never)")]
AssociationSettings = Annotated[list[str], _settings(
    "an association", "associate",
    "gate_m, height_sd, gate_sigmas, track_weight, class_cost, min_run, min_votes, "
    "split_blobs (true|false)")]


def _pairs(items: list[str], what: str) -> dict:
    """["min_area=200", ...] -> {"min_area": 200, ...}: numbers where they parse, else text."""
    out = {}
    for it in items:
        key, sep, val = it.partition("=")
        if not sep or not key.strip():
            raise InputError(f"expected KEY=VALUE, got {it!r}", field=what)
        v: object = val.strip()
        for conv in (int, float):
            try:
                v = conv(val)
                break
            except ValueError:
                pass
        if v in ("true", "false"):
            v = v == "true"
        out[key.strip()] = v
    return out


def register(app: typer.Typer) -> None:
    app.command("new-scene", rich_help_panel=SCENE)(speaks_flags(new_scene_cmd))
    app.command("masks-from-video", rich_help_panel=SCENE)(speaks_flags(masks_from_video_cmd))
    app.command("track", rich_help_panel=SCENE)(speaks_flags(track_cmd))
    app.command("associate", rich_help_panel=SCENE)(speaks_flags(associate_cmd))
    app.command("import-detections", rich_help_panel=SCENE)(speaks_flags(import_detections_cmd))


def new_scene_cmd(
    out: Path = typer.Option(..., "-o", "--out", help="scene folder to create"),
    video: list[str] = typer.Option(..., "--video",
                                    help="a camera's video file or image folder, as NAME=PATH "
                                         "(repeat per camera); a single PATH names the camera c0"),
    calibration: Path = typer.Option(..., "--calibration",
                                     help="calibration: JSON {\"cameras\": \\[{name, P or K/R/t, "
                                          "optional width, height, distortion}]} or a text file of "
                                          "12 numbers (one camera's 3x4 P, row by row)"),
    ground: Path = typer.Option(..., "--ground", help="ground points CSV: x,y,z per line, metres"),
    fps: float | None = typer.Option(None, "--fps", help="frames per second (default: the video's)"),
    force: bool = typer.Option(
        False, "--force",
        help="replace an existing scene folder OUT entirely (built beside it, swapped in when complete)",
    ),
) -> None:
    """Make a scene folder from video, calibration and ground points.

    No masks yet: they come next from s2p masks-from-video or s2p import-detections."""
    from seg2pose.video.video_scene import new_scene

    videos = {}
    for v in video:
        name, sep, path = v.partition("=")
        if not sep:
            name, path = "c0", v
        if name in videos:
            raise InputError(f"camera {name!r} given twice", field="--video")
        videos[name] = Path(path)
    new_scene(out, videos, calibration, ground, fps=fps, force=force, log=typer.echo)


def masks_from_video_cmd(
    scene: Path = typer.Argument(..., help="scene folder with video/<camera>.mp4 (or image folders)"),
    camera: Cameras = None,
    setting: BackgroundSettings = [],  # noqa: B006 -- Typer's default for a repeatable option; never mutated
    track: bool = typer.Option(True, "--track/--no-track", help="give the masks track ids (s2p track)"),
    classes: bool = typer.Option(True, "--classes/--no-classes",
                                 help="give each track a class from its world size"),
    frames: str | None = typer.Option(None, "--frames", help="only frames A:B (inclusive)"),
    force: ReplaceMasks = False,
    progress: Progress = True,
    associate: Associate = True,
) -> None:
    """Instance masks from a static camera's video by background subtraction.

    OpenCV MOG2 with shadow removal, clean-up and connected components, then tracks, the
    pieces of one road user joined into one track (touching, moving as one, a better size
    fit together; scene.json extra.tracker join_gain 0 turns it off) and size classes,
    written to masks/<camera>.txt (MOTS); with several cameras, their ids associated (s2p
    associate). A truncated video keeps what was read; a background that
    never settles is reported with its frames."""
    from seg2pose.video.video_scene import scene_masks_from_video

    scene_masks_from_video(scene, camera, bg=_pairs(setting, "--set"), track=track,
                           classify=classes, force=force, frames=parse_frames(frames),
                           progress=progress, associate=associate, log=typer.echo)


def track_cmd(
    scene: Path = typer.Argument(..., help="scene folder whose masks/<camera>.txt lack track ids"),
    camera: Cameras = None,
    setting: TrackerSettings = [],  # noqa: B006 -- Typer's default for a repeatable option; never mutated
    classes: bool = typer.Option(False, "--classes/--no-classes",
                                 help="also give masks without a class one from their track's world size"),
    progress: Progress = True,
    associate: Associate = True,
) -> None:
    """Give track ids to masks that have none.

    Mask IoU + world distance of normal positions, Hungarian assignment, re-identification
    after short gaps; the masks file is rewritten in place (atomically), masks of tracks
    shorter than min_length dropped."""
    from seg2pose.video.video_scene import scene_track

    scene_track(scene, camera, tracker=_pairs(setting, "--set"), classify=classes,
                progress=progress, associate=associate, log=typer.echo)


def associate_cmd(
    scene: Path = typer.Argument(..., help="scene folder with masks/<camera>.txt of several cameras"),
    camera: Cameras = None,
    setting: AssociationSettings = [],  # noqa: B006 -- Typer's default for a repeatable option; never mutated
    force: bool = typer.Option(False, "--force", help="associate masks that are associated already"),
) -> None:
    """Give one road user the same track id in every camera.

    Each camera's tracker numbers its own tracks; fusing cameras needs one id per road
    user. Masks are paired across cameras by their normal positions on the ground (per
    frame, Hungarian, gated by the default heights' uncertainty), tracks cut where one
    camera's tracker swapped road users, and joined so that no camera sees one road user
    twice; a blob that other cameras see as several road users is split. masks/ is
    rewritten as a unit and masks/ids.json records that the ids are associated."""
    from seg2pose.video.associate_scene import associate_scene

    associate_scene(scene, camera, cfg=_pairs(setting, "--set"), force=force, log=typer.echo)


def import_detections_cmd(
    scene: Path = typer.Argument(..., help="scene folder"),
    coco: Path = typer.Argument(..., help="a detector's COCO JSON (results list or dataset) for one camera"),
    camera: str = typer.Option(..., "--camera", help="the camera the detections belong to"),
    score: float = typer.Option(0.5, "--score", help="drop detections scored below this"),
    nms: float = typer.Option(0.5, "--nms", help="drop a mask overlapping a better one of its class by more IoU"),
    lone_bicycles: bool = typer.Option(False, "--lone-bicycles/--no-lone-bicycles",
                                       help="keep a bicycle without a rider as a bicyclist"),
    frame_offset: int = typer.Option(0, "--frame-offset",
                                     help="added to every frame number (e.g. -1 when image ids start at 1)"),
    force: ReplaceMasks = False,
    associate: Associate = True,
) -> None:
    """Masks from a detector's COCO output (Mask R-CNN, Detectron2, YOLO-seg...).

    Score threshold, mask NMS, COCO classes mapped to the scene's, person + bicycle ->
    bicyclist (the paper's Figure 2), then the tracker when the file has no track ids."""
    from seg2pose.video.detections import DetectionConfig
    from seg2pose.video.video_scene import scene_import_detections

    cfg = DetectionConfig(score_min=score, nms_iou=nms, lone_bicycles=lone_bicycles)
    n = scene_import_detections(scene, camera, coco, cfg=cfg, frame_offset=frame_offset,
                                force=force, associate=associate, log=typer.echo)
    typer.echo(f"wrote {n} masks to {Path(scene) / 'masks' / f'{camera}.txt'}")
