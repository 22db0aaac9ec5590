"""Scene commands: ``s2p info``, ``s2p synth``, ``s2p import-utocs``, ``s2p import-tacal``,
``s2p heights``, ``s2p convert-masks``."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np
import typer

from seg2pose.cli.common import SCENE, Progress, speaks_flags
from seg2pose.core.errors import InputError
from seg2pose.io.atomic import check_writable

NOISE_KEYS = ["miss_rate", "min_area", "small_area", "small_miss", "occlusion_miss", "merge_rate",
              "class_confusion",
              "dilate_px", "mask_resolution", "boundary_jitter", "fragment_rate"]


def parse_noise(items: list[str]) -> dict:
    """["miss_rate=0.05", ...] -> {"miss_rate": 0.05, ...} (ints for pixel counts)."""
    out = {}
    for it in items:
        key, sep, val = it.partition("=")
        key = key.strip()
        if not sep or key not in NOISE_KEYS:
            raise InputError(f"expected KEY=VALUE with KEY one of {', '.join(NOISE_KEYS)}, got {it!r}",
                             field="--noise")
        try:
            out[key] = int(val) if key in ("min_area", "small_area", "mask_resolution") else float(val)
        except ValueError:
            raise InputError(f"{key} needs a number, got {val!r}", field="--noise") from None
    return out


def register(app: typer.Typer) -> None:
    app.command("info", rich_help_panel=SCENE)(info)
    app.command("synth", rich_help_panel=SCENE)(speaks_flags(synth))
    app.command("import-utocs", rich_help_panel=SCENE)(speaks_flags(import_utocs_cmd))
    app.command("import-tacal", rich_help_panel=SCENE)(speaks_flags(import_tacal_cmd))
    app.command("heights", rich_help_panel=SCENE)(speaks_flags(heights_cmd))
    app.command("convert-masks", rich_help_panel=SCENE)(speaks_flags(convert_masks_cmd))


def info(scene: Path = typer.Argument(..., help="scene folder")) -> None:
    """Summarise a scene folder: cameras, configurations, classes, splits.

    Prints each camera's image size, focal length, centre and whether it has masks and video;
    the configurations, the classes with their default heights, the splits, and whether
    ground truth exists."""
    from seg2pose.io.scene import load_scene

    s = load_scene(scene)
    typer.echo(f"scene {s.name!r} at {s.root}  fps={s.fps:g}  fingerprint={s.fingerprint()}")
    typer.echo(f"ground: {len(s.ground_points)} points, z in [{s.ground.z_min:.2f}, {s.ground.z_max:.2f}] m")
    for c in s.cameras.values():
        cen = c.center
        typer.echo(f"camera {c.name}: {c.width}x{c.height}  f={c.K[0, 0]:.1f}px  centre=({cen[0]:.2f}, "
                   f"{cen[1]:.2f}, {cen[2]:.2f}) m  masks={'yes' if s.masks_path(c.name).exists() else 'no'}"
                   f"  video={'yes' if s.video_path(c.name) else 'no'}")
    for k, v in s.rig.configs.items():
        typer.echo(f"config {k}: {', '.join(v)}")
    for c in s.classes:
        typer.echo(f"class {c.id} {c.name}: default height {c.default_height:.3f} m")
    for k, (a, b) in s.splits.items():
        typer.echo(f"split {k}: frames {a}..{b}")
    typer.echo(f"ground truth: {'yes' if s.gt_path.exists() else 'no'}")


def synth(
    out: Path = typer.Option(..., "-o", "--out", help="scene folder to create"),
    preset: str = typer.Option(
        "small", "--preset",
        help="small (3 x 240 frames, seconds; tests and the demo), bench (3 x 960 frames, about a minute; the accuracy "
             "benchmark), wide (bench's length with road users of many kinds and sizes -- small cars to buses, "
             "motorcycles, children to tall adults, bags, strollers -- and the pole 6-15 m high, drawn from the seed) "
             "or paper (3 x 7,000 frames, as in the paper's section 4.1)",
    ),
    frames: int | None = typer.Option(
        None, "--frames", help="frames per split (train, val and test each); default from the preset",
    ),
    seed: int = typer.Option(0, "--seed", help="random seed: the same seed gives byte-identical files"),
    rig: str | None = typer.Option(
        None, "--rig",
        help="camera device: device (10 m pole; the default), device-8m, device-12m, or a rig JSON file (default for "
             "--preset wide: the device on a pole 6-15 m high, drawn from the seed)",
    ),
    video: bool = typer.Option(False, "--video/--no-video", help="also render RGB video of every camera"),
    look: str | None = typer.Option(
        None, "--look",
        help="the video's look: flat (flat-shaded plain bodies, constant sun), rich (clouds passing the sun change the "
             "light and soften the shadows, the camera's exposure half follows; striped and patterned clothes, "
             "two-tone paint and decals), or one of the two: light, textured; default: rich for --preset wide, flat "
             "otherwise. Masks and truth are the same either way",
    ),
    groups: float = typer.Option(
        0.0, "--groups", min=0.0, max=1.0,
        help="share of the pedestrians who walk in groups of two or three (friends, a parent and a child: side by "
             "side, stopping and crossing together, the same group every visit; their masks touch and merge as in real "
             "footage); default 0, also for --preset wide, whose published figures are without groups",
    ),
    detector_noise: bool = typer.Option(
        True, "--detector-noise/--no-detector-noise",
        help="masks like a Mask R-CNN detector's (misses, merges, coarse outlines), or perfect silhouettes",
    ),
    noise: list[str] = typer.Option(
        [], "--noise",
        help="set one detector-noise knob, KEY=VALUE (repeatable), e.g. --noise miss_rate=0.05; keys: "
             + ", ".join(NOISE_KEYS),
    ),
    distortion: str | None = typer.Option(
        None, "--distortion", help="radial lens distortion K1,K2 of the device's lenses (none by default)",
    ),
    ids: Literal["road_user", "visit"] = typer.Option(
        "road_user", "--ids",
        help="road_user: a road user keeps its id when it comes back (as in the paper); visit: a new id for every pass",
    ),
    match: Literal["center", "all"] = typer.Option(
        "center", "--match",
        help="center: keep a mask only when the road user's true 3D centre projects inside it (the paper's "
             "association); all: every visible mask",
    ),
    workers: int | None = typer.Option(None, "--workers", help="processes (default: one per core, at most 2)"),
    progress: Progress = True,
    force: bool = typer.Option(
        False, "--force",
        help="replace an existing scene folder entirely "
             "(the new scene is built beside it and swapped in when complete)",
    ),
) -> None:
    """Make a synthetic junction scene with ground truth (the paper's CARLA stand-in).

    A five-lens camera device, ground points, instance masks with detector noise, ground-truth
    poses and optionally video, in the splits train, val and test."""
    import time

    from seg2pose.synth.generate import SynthOptions, generate_scene
    from seg2pose.synth.noise import NoiseConfig

    cfg = NoiseConfig() if detector_noise else NoiseConfig.off()
    if noise:
        cfg = NoiseConfig.from_dict({**cfg.to_dict(), **parse_noise(noise)})
    dist = None
    if distortion:
        try:
            ks = [float(v) for v in distortion.split(",")]
        except ValueError:
            ks = []
        if len(ks) not in (1, 2):  # exactly K1[,K2]: the wide preset's device would drop a third
            raise InputError(f"expected K1,K2 numbers, got {distortion!r}", field="--distortion")
        dist = (ks[0], ks[1] if len(ks) == 2 else 0.0)
    t = time.perf_counter()
    path = generate_scene(out, SynthOptions(preset=preset, frames=frames, seed=seed, rig=rig, video=video,
                          force=force, noise=cfg, progress=progress, workers=workers,
                          ids=ids, distortion=dist, match=match, look=look,
                          groups=groups))
    typer.echo(f"wrote scene {path} in {time.perf_counter() - t:.1f} s")


def import_utocs_cmd(
    src: Path = typer.Argument(..., help="UTOCS recording folder (cameras.json, ground_points.txt, positions/)"),
    out: Path = typer.Option(..., "-o", "--out", help="scene folder to create"),
    fps: float | None = typer.Option(
        None, "--fps", help="frames per second (default 1/0.075 s, the paper's CARLA interval)",
    ),
    size_scale: float = typer.Option(
        1.0, "--size-scale",
        help="multiply lengths, widths and heights by this (2 if the recording stores CARLA's half extents)",
    ),
    frames: bool = typer.Option(True, "--frames/--no-frames", help="bring the recording's images or videos along"),
    start_time: str | None = typer.Option(
        None, "--start-time",
        help="time of frame 0, ISO 8601 with a zone, e.g. 2021-06-14T08:00:00Z (reviews and exports then show real "
             "times)",
    ),
    force: bool = typer.Option(
        False, "--force",
        help="replace an existing scene folder entirely (built beside it, swapped in when complete; nothing of the old "
             "scene is kept)",
    ),
) -> None:
    """Import a UTOCS (CARLA) recording as a scene folder.

    CARLA's left-handed world is mirrored in y into this tool's right-handed one."""
    from seg2pose.io.utocs import import_utocs

    import_utocs(src, out, force=force, fps=fps, size_scale=size_scale, copy_frames=frames,
                 log=typer.echo, start_time=start_time)


def import_tacal_cmd(
    files: list[Path] = typer.Argument(
        ..., help="T-Analyst calibration files (.tacal), one per camera; the camera is named after the file",
    ),
    ground: Path = typer.Option(..., "--ground", help="ground points CSV (x,y,z metres per line, an optional header)"),
    out: Path = typer.Option(..., "-o", "--out", help="scene folder to create"),
    fps: float = typer.Option(..., "--fps", help="the videos' frame rate (frames per second)"),
    size: str | None = typer.Option(
        None, "--size",
        help="image size WIDTHxHEIGHT of every camera, e.g. 1280x720 (default: twice the principal point Cx, Cy of "
             "each file)",
    ),
    force: bool = typer.Option(
        False, "--force", help="replace an existing scene folder entirely (built beside it, swapped in when complete)",
    ),
) -> None:
    """Make a scene from T-Analyst .tacal calibrations and ground points.

    Tsai's camera model; one configuration per camera and 'all'. Add masks (and video) to it
    afterwards."""
    from seg2pose.io.tacal import scene_from_tacals

    wh = None
    if size is not None:
        try:
            w, h = (int(v) for v in size.lower().split("x"))
        except ValueError:
            raise InputError(f"expected WIDTHxHEIGHT, got {size!r}", field="--size") from None
        from seg2pose.core.validate import MAX_IMAGE_SIDE

        if not (0 < w <= MAX_IMAGE_SIDE and 0 < h <= MAX_IMAGE_SIDE):
            raise InputError(f"expected WIDTHxHEIGHT, each in 1..{MAX_IMAGE_SIDE} pixels, got "
                             f"{size!r}", field="--size")
        wh = (w, h)
    s = scene_from_tacals(files, ground, out, fps, wh, force)
    for c in s.cameras.values():
        cen = c.center
        typer.echo(f"camera {c.name}: {c.width}x{c.height}  f={c.K[1, 1]:.1f}px  centre=("
                   f"{cen[0]:.2f}, {cen[1]:.2f}, {cen[2]:.2f}) m  k={c.distortion.k:g}")
    typer.echo(f"wrote scene {out} ({len(s.cameras)} cameras, {len(s.ground_points)} ground "
               "points); configurations: " + ", ".join(s.rig.configs))


def heights_cmd(
    scene: Path = typer.Argument(..., help="scene folder"),
    split: str = typer.Option("train", "--split", help="split whose masks and truth are used ('all' for every frame)"),
    center: Literal["bbox", "centroid"] | None = typer.Option(
        None, "--center", help="mask centre: bbox or centroid (default: the one measured best, bbox)",
    ),
    dry_run: bool = typer.Option(
        False, "--dry-run/--no-dry-run", help="only print the heights; leave scene.json as it is",
    ),
    rough: int = typer.Option(
        0, "--rough", min=0,
        help="use N rough-model renders per class instead of masks matched to ground truth (no annotations needed)",
    ),
    rough_video: bool = typer.Option(
        False, "--rough-video/--no-rough-video",
        help="with --rough: film the rough models over the video's background and use the masks background subtraction "
             "makes of them (measured within 1.2 cm of the clean renders, and minutes slower)",
    ),
    camera: list[str] | None = typer.Option(
        None, "--camera", help="with --rough: render for this camera only (repeatable; default: all)",
    ),
) -> None:
    """Set per-class default heights by bisection on the ground truth (paper 3.2).

    About half of the split's normal positions then end up closer to the camera than the
    truth. Writes the heights into scene.json."""
    from seg2pose.io.scene import load_scene
    from seg2pose.method.heights import update_default_heights

    sc = load_scene(scene)
    views = None
    if rough > 0:
        from seg2pose.training.rough_heights import rough_height_views

        views = rough_height_views(sc, rough, center=center, cameras=camera or None,
                                   video=rough_video)
    update_default_heights(sc, split, center, write=not dry_run, log=typer.echo, views=views)


MaskFormat = Literal["mots", "coco", "png"]


def convert_masks_cmd(
    src: Path = typer.Argument(..., help="masks: MOTS .txt, COCO RLE .json, or a folder of instance-id PNGs"),
    out: Path = typer.Option(..., "-o", "--out", help="output file (mots, coco) or folder (png)"),
    format: MaskFormat = typer.Option(..., "-f", "--format", help="output format: mots, coco or png"),
    src_format: MaskFormat | None = typer.Option(None, "--from", help="input format (default: from the name of SRC)"),
    force: bool = typer.Option(
        False, "--force", help="replace an existing output entirely (a PNG folder keeps none of its old frames)",
    ),
) -> None:
    """Convert instance masks between MOTS text, COCO RLE JSON and PNG instance-id images."""
    from seg2pose.io.mask_formats import read_masks, save_masks

    check_writable(out, force)
    table = read_masks(src, src_format)
    save_masks(out, table, format, force)
    typer.echo(f"{len(table)} masks in {len(np.unique(table.frame))} frames "
               f"({table.width}x{table.height}) -> {out} [{format}]")
