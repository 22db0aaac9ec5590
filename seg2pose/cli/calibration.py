"""``s2p calibrate-camera``: a new site's cameras and ground from clicked image-world pairs (a
pairs CSV, or the page that serves a frame beside an aerial image or a survey table), or from
the traffic itself (``--from-traffic``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from seg2pose.cli.common import SCENE, speaks_flags
from seg2pose.core.errors import InputError


def register(app: typer.Typer) -> None:
    app.command("calibrate-camera", rich_help_panel=SCENE)(speaks_flags(calibrate_camera_cmd))


def parse_sizes(items: list[str] | None) -> dict[str, tuple[int, int]]:
    """["1280x720"] (every camera) or ["c0=1280x720", ...] -> {camera or "*": (w, h)}."""
    out = {}
    for it in items or []:
        cam, sep, size = it.rpartition("=")
        try:
            w, h = (int(v) for v in size.lower().split("x"))
            if not (0 < w <= 100_000 and 0 < h <= 100_000):
                raise ValueError
        except ValueError:
            raise InputError(f"expected WIDTHxHEIGHT or CAMERA=WIDTHxHEIGHT, got {it!r}",
                             field="--image-size") from None
        out[cam if sep else "*"] = (w, h)
    return out


def parse_devices(items: list[str] | None) -> list[list[str]] | None:
    return [[c.strip() for c in it.split(",") if c.strip()] for it in items] if items else None


def source_sizes_frames(source: Path | None, cameras: list[str]) -> tuple[dict, dict, object]:
    """(sizes, first frames (camera -> BGR image), the scene or None) of a scene folder or a
    video / image folder given as SCENE_OR_VIDEO (a video serves every camera named)."""
    if source is None:
        return {}, {}, None
    from seg2pose.io.scene import SCENE_FILE, load_scene
    from seg2pose.io.video import FrameReader, camera_reader

    if (source / SCENE_FILE).exists():
        scene = load_scene(source)
        sizes = {c: (cam.width, cam.height) for c, cam in scene.cameras.items()}
        frames = {}
        for c in scene.cameras:
            if scene.video_path(c) is not None:
                frames[c] = next(iter(camera_reader(scene, c).frames(last=None)), (0, None))[1]
        return sizes, frames, scene
    if not source.exists():
        raise InputError("not found (expected a scene folder, a video or an image folder)", file=source)
    r = FrameReader(source)
    w, h, _ = r.header()
    im = next(iter(r.frames()), (0, None))[1]
    return {c: (w, h) for c in cameras}, {c: im for c in cameras}, None


def calibrate_camera_cmd(
    source: Path | None = typer.Argument(None,
        help="a scene folder (its cameras' image sizes and frames; the result goes in as a new scene version) "
             "or a video / image folder (its frame is shown and drawn on)"),
    points: Path | None = typer.Option(None, "--points",
        help="pairs CSV: camera,u,v,x,y,z[,name] per line (pixel in the camera's frame, world point in metres,"
             " z empty when unknown)"),
    aerial: Path | None = typer.Option(None, "--aerial",
        help="serve the clicking page with this aerial image (PNG/JPEG) beside the frame"),
    world_file: Path | None = typer.Option(None, "--world-file",
        help="the aerial image's world file (.pgw/.jgw; default: beside the image)"),
    reference: list[str] | None = typer.Option(None, "--reference",
        help="instead of a world file: U,V,X,Y, an aerial pixel and its world position (give two)"),
    survey: Path | None = typer.Option(None, "--survey",
        help="surveyed points CSV name,x,y,z: picked on the page, and their elevations go into the ground"),
    camera: list[str] | None = typer.Option(None, "--camera",
        help="the page's camera(s) (default: the scene's, or c0 for a video)"),
    image_size: list[str] | None = typer.Option(None, "--image-size",
        help="WIDTHxHEIGHT of every camera, or CAMERA=WIDTHxHEIGHT (repeatable); default: from the scene or "
             "video"),
    out: Path | None = typer.Option(None, "-o", "--out",
        help="calib.json to write (with NAME.ground.csv, NAME.report.txt, NAME.CAMERA.png beside it); default "
             "for a scene: a new version inside it"),
    device: list[str] | None = typer.Option(None, "--device",
        help="cameras of one device, comma-separated, solved together with shared intrinsics (repeatable)"),
    principal_point: bool = typer.Option(False, "--principal-point/--no-principal-point",
        help="fit the principal point too (else the image centre)"),
    k1: bool = typer.Option(False, "--k1/--no-k1", help="fit one radial distortion term k1"),
    pixel_sigma: float = typer.Option(1.5, "--pixel-sigma", min=0.01, help="click noise in the frame, pixels"),
    world_sigma: float = typer.Option(0.1, "--world-sigma", min=0.001,
        help="noise of the world points' x, y, metres (an aerial image at 5 cm/px clicked within 2 px: 0.1)"),
    focal_prior: float | None = typer.Option(None, "--focal-prior", min=1.0,
        help="the focal's prior centre, pixels (default: a 65 degree horizontal field of view)"),
    force: bool = typer.Option(False, "--force",
        help="replace existing outputs; for a scene: write the new calibration as its next version (the old "
             "scene.json is kept in calibrations/vN/)"),
    from_traffic: bool = typer.Option(False, "--from-traffic/--no-from-traffic",
        help="from the traffic in the scene's masks (after masks-from-video): vanishing points of the road "
             "users' motion, the height from pedestrians and bicyclists; alone it writes cameras in their "
             "own frame (origin below the camera) with their expected error, with --points it is the focal "
             "prior that makes 4 pairs a camera enough"),
    port: int | None = typer.Option(None, "--port", help="the page's port (default: a free one)"),
    browser: bool = typer.Option(True, "--browser/--no-browser", help="open the page in a browser"),
) -> None:
    """Calibrate cameras and the ground of a new site from clicked image-world pairs.

    With --points: solve now (no page). With --aerial or --survey: serve a page with the frame
    on one side and the aerial image (or the survey table) on the other; click a point in the
    frame, then its partner, optionally with an elevation; the pairs are kept crash-safe in
    a journal and solved on the page. Each camera needs 6 pairs spread over the road (fewer
    for the second camera of a --device). Prints per pair the error in pixels and metres on
    the ground, warnings naming pairs that disagree, and the suggested next point; writes
    calib.json (what s2p new-scene --calibration reads), the ground points from the known
    elevations (plane fit; flat where none are known, said so), a report and one picture per
    camera coloured by how far one pixel of error moves a normal position."""
    from seg2pose.geometry.calibrate import SolveOptions

    opts = SolveOptions(pixel_sigma=pixel_sigma, world_sigma=world_sigma, focal_prior_px=focal_prior,
                        principal_point=principal_point, k1=k1)
    traffic_note = None
    if from_traffic:
        opts, traffic_note = traffic_prior(source, camera, opts, points is None, out, force, typer.echo)
        if traffic_note is None:
            return
    if points is None and aerial is None and survey is None:
        raise InputError("give --points pairs.csv, or --aerial IMAGE / --survey points.csv for the page",
                         field="points")
    if points is not None:
        from seg2pose.io.calib_files import read_pairs, read_survey

        pairs = read_pairs(points)
        sizes, frames, scene = source_sizes_frames(source, list(pairs))
        given = parse_sizes(image_size)
        for c in pairs:
            if c in given or "*" in given:
                sizes[c] = given.get(c, given.get("*"))
        surv = read_survey(survey)[1] if survey is not None else None
        solve_and_write(pairs, sizes, frames, scene, out, opts, parse_devices(device), surv, force,
                        typer.echo)
        return
    from annotate.app.calib_serve import PageArgs, run_page

    if out is not None and out.exists() and not force:
        raise InputError(f"{out} exists; pass --force to replace it when saving", field="out")

    run_page(PageArgs(source=source, aerial=aerial, world_file=world_file, reference=list(reference or []),
                      survey=survey, cameras=list(camera or []), sizes=parse_sizes(image_size),
                      out=out, devices=parse_devices(device), opts=opts, force=force, port=port),
             browser=browser, echo=typer.echo)


def solve_and_write(pairs: dict, sizes: dict, frames: dict, scene, out: Path | None, opts,
                    devices, survey: np.ndarray | None, force: bool, echo) -> None:
    """Solve, print the report, write calib.json (or the scene's next version)."""
    from seg2pose.eval.calib_picture import cost_picture
    from seg2pose.geometry.calib_site import SiteInput, calibrate_site
    from seg2pose.io.calib_files import write_result

    res = calibrate_site(SiteInput(pairs, sizes, devices, survey, opts))
    text = res.text()
    echo(text.rstrip())
    pictures = {c: cost_picture(r, frames.get(c)) for c, r in res.cameras.items()}
    for line in write_result(res, text, pictures, out, scene, force):
        echo(line)


def traffic_prior(source: Path | None, cameras: list[str] | None, opts, alone: bool, out: Path | None,
                  force: bool, echo):
    """--from-traffic: the cameras from the scene's traffic. Alone: written to --out (their own
    frames) and (opts, None) returned; else (opts with the traffic's focal as the prior and 4
    pairs a camera, a note)."""
    import dataclasses

    from seg2pose.geometry.ground_fit import ground_from_elevations
    from seg2pose.io.calib_files import write_calibration
    from seg2pose.io.scene import SCENE_FILE, load_scene
    from seg2pose.video.traffic_calib import traffic_calibration

    if source is None or not (source / SCENE_FILE).exists():
        raise InputError("--from-traffic needs a scene folder with masks (s2p masks-from-video)", field="source")
    scene = load_scene(source)
    results = {c: traffic_calibration(scene, c) for c in (cameras or list(scene.cameras))}
    for r in results.values():
        echo(r.text())
    if not alone:
        fs = [r.camera.K[0, 0] for r in results.values()]
        rel = max(float(np.nanmax([r.focal_sd / r.camera.K[0, 0] for r in results.values()])), 0.02)
        return dataclasses.replace(opts, focal_prior_px=float(np.median(fs)), focal_log_sigma=rel,
                                   min_pairs=4), "traffic"
    if out is None:
        raise InputError("give -o calib.json for the cameras from the traffic", field="out")
    report = {"from_traffic": {c: {"focal_px": float(r.camera.K[0, 0]), "focal_sd_px": r.focal_sd,
                                   "height_m": r.height_m, "height_sd_m": r.height_sd,
                                   "segments": r.segments, "upright_road_users": r.people,
                                   "notes": r.notes} for c, r in results.items()}}
    ground = ground_from_elevations(np.empty((0, 3)), np.array([[-30.0, -30.0], [30.0, 30.0]]))
    text = "\n".join(r.text() for r in results.values()) + "\nground: " + ground.summary + "\n"
    names = write_calibration(out, [r.camera.to_dict() for r in results.values()], report, text,
                              ground.points, {}, force)
    echo(f"written: {names['calib']}, {names['ground'].name}, {names['report'].name}")
    return opts, None
