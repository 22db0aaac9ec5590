"""From video to a scene's masks, per camera: background-subtraction masks -> tracks -> size
classes, or a detector's COCO file -> tracks; and a new scene from video + calibration +
ground points. The functions here are what ``s2p masks-from-video``, ``s2p import-detections``,
``s2p track`` and ``s2p new-scene`` run.
"""

from __future__ import annotations

import re
import shutil
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np

from seg2pose.core.errors import InputError
from seg2pose.geometry.camera import Camera, Rig
from seg2pose.io.atomic import outputs
from seg2pose.io.calib_files import read_calib_json
from seg2pose.io.mots import write_mots
from seg2pose.io.nofollow import fdopen_nofollow
from seg2pose.io.scene import DEFAULT_CLASSES, SCENE_FILE, ClassSpec, Scene, load_scene, read_ground_points
from seg2pose.io.schemas import frame_limit
from seg2pose.io.text import read_text
from seg2pose.io.track_ids import ids_path, stage_ids
from seg2pose.io.video import VIDEO_EXTS, FrameReader, camera_reader  # noqa: F401 (re-exported)
from seg2pose.io.video_decode import video_index
from seg2pose.video.classify import classify_mots, size_rules
from seg2pose.video.detections import DetectionConfig, import_detections
from seg2pose.video.fragments import join_fragments
from seg2pose.video.track import TrackConfig, track_mots
from seg2pose.video.video_masks import BgConfig, VideoMasksResult, masks_from_video


def _cameras(scene: Scene, cameras: list[str] | None) -> list[str]:
    names = list(cameras) if cameras else list(scene.cameras)
    unknown = [c for c in names if c not in scene.cameras]
    if unknown:
        raise InputError(f"unknown cameras {unknown}; the scene has {list(scene.cameras)}",
                         file=scene.root / SCENE_FILE, field="cameras")
    return names


def masks_outputs(scene: Scene, cameras: list[str], force: bool, ids: bool = True):
    """The output set of masks/<camera>.txt for ``cameras`` and (``ids``) masks/ids.json,
    replaced together (``atomic.outputs``; ids.json without ``force``: it is their record)."""
    paths = [scene.masks_path(c) for c in cameras]
    records = [ids_path(scene.root / "masks")] if ids and cameras else []
    return outputs(paths, force, records=records)


def associate_step(scene: Scene, tracked: list[str], associate: bool, log: Callable[[str], None]
                   ) -> None:
    """After the cameras' tracker ids were written (with their record in masks/ids.json, in the
    same set: ``stage_ids``): when ``associate`` and two or more cameras have masks, associate
    all cameras' ids (``tracked`` is kept for callers that name the cameras tracked)."""
    del tracked
    if not associate:
        return
    with_masks = [c for c in scene.cameras if scene.masks_path(c).exists()]
    if associate and len(with_masks) > 1:
        from seg2pose.video.associate_scene import associate_scene

        associate_scene(scene.root, with_masks, force=True, log=log)


def scene_masks_from_video(scene_dir: str | Path, cameras: list[str] | None = None, *,
                           bg: dict | None = None, tracker: dict | None = None,
                           track: bool = True, classify: bool = True, force: bool = False,
                           frames: tuple[int, int] | None = None, progress: bool = False,
                           associate: bool = True,
                           log: Callable[[str], None] = print) -> dict[str, VideoMasksResult]:
    """masks/<camera>.txt from each camera's video: background subtraction, then the tracker
    and size classes, then (``associate``, with two or more cameras) one id per road user over
    the cameras (``s2p associate``). Settings: ``scene.json`` ``extra.video_masks`` /
    ``extra.tracker`` / ``extra.size_classes`` / ``extra.associate``, overridden by ``bg`` /
    ``tracker``."""
    scene = load_scene(scene_dir)
    sj = scene.root / SCENE_FILE
    cfg = BgConfig.from_dict({**(scene.extra.get("video_masks") or {}), **(bg or {})}, file=sj)
    tcfg = TrackConfig.from_dict({**(scene.extra.get("tracker") or {}), **(tracker or {})}, file=sj)
    rules = size_rules(scene.classes, scene.extra, file=sj) if classify else None
    names = _cameras(scene, cameras)
    out = {}
    # every camera's masks checked and locked first; each built (all stages) in its partial
    # folder and swapped in when complete, never an intermediate stage under the final name
    built = {}
    with masks_outputs(scene, names, force, ids=track) as files:
        for c in names:
            reader = camera_reader(scene, c)
            dst = scene.masks_path(c)
            tmp = files.file(dst)
            res = masks_from_video(reader.path, tmp, cfg, camera=scene.cameras[c],
                                   first_frame=reader.first, frame_step=reader.step, frames=frames,
                                   progress=progress, log=log)
            msg = f"{c}: {res.n_frames} frames -> {res.n_masks} masks"
            if track:
                n_tracks, n_kept = track_mots(tmp, tmp, scene.cameras[c], scene.ground, tcfg,
                                              progress=progress, log=log)
                msg += f" -> {n_tracks} tracks ({n_kept} masks)"
            if rules is not None:
                if track:
                    joins = join_fragments(tmp, tmp, scene.cameras[c], scene.ground, rules,
                                           scene.fps, tcfg, log=lambda m: None)
                    if joins:
                        msg += f", {len(joins)} fragment track(s) joined"
                votes = classify_mots(tmp, tmp, scene.cameras[c], scene.ground, rules,
                                      fps=scene.fps, log=log)
                names_by_id = {k.id: k.name for k in scene.classes}
                if votes:  # untracked masks have no track votes to count
                    counts = np.unique(list(votes.values()), return_counts=True)
                    msg += " (" + ", ".join(f"{n} {names_by_id[int(k)]}"
                                            for k, n in zip(*counts)) + ")"
            built[c] = tmp
            log(msg)
            out[c] = res
        # every camera's masks and their record swapped in as one set when all are done: a
        # kill after the first camera left its tracker ids beside a record of other ids (or
        # none: "given"), and ``s2p run`` fused unrelated road users
        if track:
            stage_ids(files, scene.root / "masks", {c: "tracker" for c in names}, built)
    associate_step(scene, names if track else [], associate and track, log)
    return out


def scene_track(scene_dir: str | Path, cameras: list[str] | None = None, *,
                tracker: dict | None = None, classify: bool = False, force: bool = True,
                progress: bool = False, associate: bool = True,
                log: Callable[[str], None] = print) -> dict[str, int]:
    """Track ids for masks/<camera>.txt in place (and size classes for masks without one),
    then (``associate``) one id per road user over the cameras."""
    scene = load_scene(scene_dir)
    sj = scene.root / SCENE_FILE
    tcfg = TrackConfig.from_dict({**(scene.extra.get("tracker") or {}), **(tracker or {})}, file=sj)
    names = _cameras(scene, cameras)
    for c in names:
        if not scene.masks_path(c).exists():
            raise InputError("no masks for this camera", file=scene.masks_path(c))
    rules = size_rules(scene.classes, scene.extra, file=sj) if classify else None
    out = {}
    built = {}
    with masks_outputs(scene, names, force=True) as files:
        for c in names:
            src = scene.masks_path(c)
            tmp = files.file(src)
            n, kept = track_mots(src, tmp, scene.cameras[c], scene.ground, tcfg,
                                 known_classes=[k.id for k in scene.classes], progress=progress,
                                 log=log)
            if rules is not None:
                classify_mots(tmp, tmp, scene.cameras[c], scene.ground, rules, fps=scene.fps,
                              log=log)
            built[c] = tmp
            log(f"{c}: {n} tracks, {kept} masks")
            out[c] = n
        stage_ids(files, scene.root / "masks", {c: "tracker" for c in names}, built)
    associate_step(scene, list(out), associate, log)
    return out


def scene_frame_count(scene: Scene, camera: str) -> int | None:
    """Frames of a camera: from its video's header (first + step * count), else up to the
    last frame of the scene's splits, else up to the last frame MCAP and Rerun can time
    (``io.schemas.frame_limit``: what ``s2p run`` then accepts)."""
    if scene.video_path(camera) is not None:
        reader = camera_reader(scene, camera)
        _, _, n = reader.header()
        if n:
            return reader.first + reader.step * n
    if scene.splits:
        return max(b for _, b in scene.splits.values()) + 1
    return frame_limit(scene.fps, scene.start_time_ns) + 1


def scene_import_detections(scene_dir: str | Path, camera: str, coco: str | Path, *,
                            cfg: DetectionConfig | None = None, tracker: dict | None = None,
                            frame_offset: int = 0, force: bool = False, associate: bool = True,
                            log: Callable[[str], None] = print) -> int:
    """masks/<camera>.txt from a detector's COCO JSON: threshold, NMS, classes, bicyclists,
    then the tracker when the file has no track ids, then (``associate``, when other cameras
    have masks too) one id per road user over the cameras. Returns the masks written."""
    scene = load_scene(scene_dir)
    _cameras(scene, [camera])
    dst = scene.masks_path(camera)
    cam = scene.cameras[camera]
    n_frames = scene_frame_count(scene, camera)
    with masks_outputs(scene, [camera], force) as files:
        table = import_detections(coco, {k.name: k.id for k in scene.classes}, cfg=cfg,
                                  size=(cam.height, cam.width), n_frames=n_frames,
                                  frame_offset=frame_offset, log=log)
        tmp = files.file(dst)
        write_mots(tmp, table)
        n = len(table)
        if len(table) and (table.track_id < 0).any():
            tcfg = TrackConfig.from_dict({**(scene.extra.get("tracker") or {}), **(tracker or {})},
                                         file=scene.root / SCENE_FILE)
            n_tracks, n = track_mots(tmp, tmp, cam, scene.ground, tcfg, log=log)
            log(f"{camera}: tracked into {n_tracks} tracks ({n} masks)")
        # a detector's own track ids are per camera too; recorded in the same set
        stage_ids(files, scene.root / "masks", {camera: "tracker"}, {camera: tmp})
    associate_step(scene, [camera], associate, log)
    return n


# --- new scene ------------------------------------------------------------------------------------
def read_calibration(path: str | Path, sizes: dict[str, tuple[int, int]]) -> dict[str, Camera]:
    """Cameras from a calibration file: JSON ``{"cameras": [{name, P | K, R, t, [width,
    height], [distortion]}, ...]}`` (or one such object), or a text file of 12 numbers (a 3x4
    P, row by row) for a single camera. Missing image sizes come from ``sizes`` (camera name
    -> (width, height) of its video)."""
    path = Path(path)
    if path.suffix.lower() == ".json":
        cams, unsized = read_calib_json(path, sizes)
        missing = [v for v in sizes if v not in cams]
        if missing and unsized:  # "missing field 'width'" said nothing of the names
            raise InputError(f"no camera named {missing[0]!r} (the video's name) in the calibration; "
                             f"its cameras are {unsized + list(cams)}: name each video after its "
                             "camera (--video NAME=FILE)", file=path)
        return cams
    nums = re.split(r"[\s,;]+", read_text(path, "calibration file").strip())
    try:
        P = np.array([float(v) for v in nums if v], float)
    except ValueError:
        raise InputError("expected 12 numbers (a 3x4 projection matrix P, row by row)",
                         file=path) from None
    if P.size != 12 or not np.isfinite(P).all():
        raise InputError(f"expected 12 finite numbers (P, 3x4), got {P.size}", file=path)
    if len(sizes) != 1:
        raise InputError("a P text file describes one camera; give one video", file=path)
    name, (w, h) = next(iter(sizes.items()))
    return {name: Camera.from_P(name, P.reshape(3, 4), w, h)}


def new_scene(out: str | Path, videos: Mapping[str, str | Path], calibration: str | Path,
              ground_points: str | Path, *, fps: float | None = None, name: str | None = None,
              force: bool = False, log: Callable[[str], None] = print) -> Scene:
    """A scene folder from videos (camera name -> video file or image folder), a calibration
    file (``read_calibration``) and ground points (x,y,z CSV, metres). Videos are copied
    (reflinked where the file system can) to video/<camera>.<ext>, named in scene.json;
    masks come next from ``masks-from-video`` or a detector. The folder is built beside
    ``out`` and swapped in whole: with ``force`` nothing of an old scene there is kept."""
    out = Path(out)
    if not videos:
        raise InputError("no video given", field="videos")
    for src in [*videos.values(), calibration, ground_points]:
        if out.exists() and Path(src).resolve().is_relative_to(out.resolve()):
            raise InputError(f"the input {src} lies inside the scene folder {out}, which is "
                             "replaced as a whole; move the input out of it first", field="--out")
    with outputs([out], force) as files:
        readers = {c: FrameReader(Path(v)) for c, v in videos.items()}
        sizes, counts = {}, {}
        for c, r in readers.items():
            if r.path.suffix.lower() not in VIDEO_EXTS + ("",) and not r.is_folder:
                raise InputError(f"expected a video ({', '.join(VIDEO_EXTS)}) or an image folder",
                                 file=r.path)
            w, h, n = r.header()
            sizes[c], counts[c] = (w, h), n
        cams = read_calibration(calibration, sizes)
        missing = [c for c in videos if c not in cams]
        if missing:
            raise InputError(f"the calibration has no camera {missing[0]!r} (it has {list(cams)})",
                             file=calibration)
        for c, r in readers.items():
            r.check_size(cams[c].width, cams[c].height)
        ground = read_ground_points(ground_points)
        if fps is None:
            fps = _video_fps(next(iter(readers.values())))
        cams = {c: cams[c] for c in videos}
        configs = {f"mono-{c}": [c] for c in cams}
        if len(cams) > 1:
            configs["all"] = list(cams)
        names = {c: "video/" + (c if r.is_folder else f"{c}{r.path.suffix.lower()}")
                 for c, r in readers.items()}
        scene = Scene(root=out, name=name or out.name, fps=float(fps),
                      rig=Rig(cameras=cams, configs=configs, name="rig"), ground_points=ground,
                      classes=[ClassSpec(c["id"], c["name"], c["default_height"]) for c in DEFAULT_CLASSES],
                      videos=names,
                      extra={"source": {"format": "video", "calibration": str(Path(calibration).resolve()),
                                        "videos": {c: str(Path(v).resolve()) for c, v in videos.items()}}})
        scene.check()  # as load_scene reads it, before the videos are copied
        tmp = files.folder(out)
        (tmp / "masks").mkdir()
        for c, r in readers.items():
            copy_video(r.path, tmp / names[c])
        scene.save(tmp)
    each = ', '.join(f'{c} {sizes[c][0]}x{sizes[c][1]}, {counts[c]} frames' for c in cams)
    log(f"new scene {out}: {len(cams)} cameras ({each}), "
        f"{len(ground)} ground points, {fps:g} fps")
    return scene


def _video_fps(reader: FrameReader) -> float:
    """The video stream's mean frame rate (10 for image folders and files that do not say). A
    variable-frame-rate video's frames are numbered by rank (``io/video_decode.py``), so its
    scene time k / fps is its mean pace, not each frame's own timestamp."""
    if reader.is_folder:
        return 10.0
    return video_index(reader.path).fps or 10.0


def copy_video(src: Path, dst: Path) -> None:
    """Copy a video file or image folder to ``dst``: a reflink (shared blocks, copy on write)
    where the file system can, else a plain copy. Never a hard link: editing the scene's video
    in place would edit the original."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    if src.is_dir():
        dst.mkdir()
        for p in sorted(src.iterdir()):
            if p.is_file():
                copy_video(p, dst / p.name)
        return
    with open(src, "rb") as a, fdopen_nofollow(dst, "wb") as b:
        try:
            import fcntl

            fcntl.ioctl(b.fileno(), 0x40049409, a.fileno())  # FICLONE
            return
        except (OSError, ImportError):
            pass
        shutil.copyfileobj(a, b, 1 << 20)
