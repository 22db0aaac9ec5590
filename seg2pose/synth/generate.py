"""``generate_scene``: a whole synthetic scene folder (the benchmark stand-in for CARLA).

Output (a scene folder, DESIGN.md): scene.json (rig with the paper's configurations, classes,
splits, generator settings), ground_points.csv (184 points), masks/<camera>.txt (MOTS),
gt/poses.csv (with l, w, h), and video/<camera>.mp4 with ``video=True``.

Everything is written into a temporary sibling folder that is renamed to the final name at the
end, so an interrupted run leaves no half-written scene. The same seed gives byte-identical
files: every random stream is derived from the seed and named (never from time or process).
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from seg2pose.core.errors import InputError, S2PError
from seg2pose.geometry.camera import Rig
from seg2pose.io.atomic import check_writable, replacing
from seg2pose.io.nofollow import fdopen_nofollow
from seg2pose.io.poses import write_poses
from seg2pose.io.scene import DEFAULT_CLASSES, ClassSpec, Scene
from seg2pose.synth import junction as J
from seg2pose.synth.look import LOOKS, look_named
from seg2pose.synth.noise import NoiseConfig
from seg2pose.synth.render import MATCH_RULES, FrameRenderer
from seg2pose.synth.rig import load_rig
from seg2pose.synth.shapes import CLASS_NAMES, TYPICAL_SIZES
from seg2pose.synth.traffic import TrafficConfig, simulate
from seg2pose.synth.video import write_video
from seg2pose.synth.world import build_world

DT = 0.075  # s between frames (paper 4.1)
PRESETS: dict[str, dict[str, Any]] = {
    # frames per split, frames dropped between splits, population, mean pause (s)
    "small": dict(split=240, gap=20,
                  population={"pedestrian": 24, "bicyclist": 6, "car": 14},
                  mean_pause_s={"pedestrian": 40.0, "bicyclist": 30.0, "car": 20.0}),
    # the accuracy benchmark (issue 14): the small junction over 4x the frames; at 960 frames
    # per split --quick reached 0.52x/0.48x and 1,920 frames gave no more (docs/RESULTS.md)
    "bench": dict(split=960, gap=20,
                  population={"pedestrian": 24, "bicyclist": 6, "car": 14},
                  mean_pause_s={"pedestrian": 40.0, "bicyclist": 30.0, "car": 20.0}),
    # beyond the generator's own road users (issue 25): vehicles from small cars to buses,
    # motorcycles, children to tall adults with bags and strollers, bicyclists of several builds
    # (``shapes_wide``), and the device's pole 6-15 m high, drawn per seed; its video (--video)
    # has clouds that change the light and textured bodies (``look``)
    "wide": dict(split=960, gap=20,
                 population={"pedestrian": 28, "bicyclist": 8, "car": 16},
                 mean_pause_s={"pedestrian": 40.0, "bicyclist": 30.0, "car": 20.0},
                 variety="wide", look="rich"),
    "paper": dict(split=7000, gap=150,
                  population={"pedestrian": 43, "bicyclist": 12, "car": 28},
                  mean_pause_s={"pedestrian": 90.0, "bicyclist": 40.0, "car": 30.0}),
}
SPLITS = ("train", "val", "test")
CHUNK = 100  # frames per rendering task


def world_tracks(world, cls_index: int) -> np.ndarray:
    """Track indices (0-based, into world.size) of a class's road users."""
    return np.unique(world.track[world.cls == cls_index]) - 1


def split_ranges(per_split: int, gap: int) -> dict[str, tuple[int, int]]:
    """Inclusive frame ranges of train/val/test, ``gap`` frames dropped between them."""
    out, f = {}, 0
    for name in SPLITS:
        out[name] = (f, f + per_split - 1)
        f += per_split + gap
    return out


def visible_fn(rig: Rig, max_dist: float = 70.0):
    """xy (M, 2) -> (M,) bool: the true ground point is inside some camera's image and at most
    ``max_dist`` metres from it."""
    cams = list(rig.cameras.values())

    def vis(xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, float).reshape(-1, 2)
        X = np.column_stack([xy, J.true_height(xy)])
        out = np.zeros(len(xy), bool)
        for c in cams:
            uv, depth, front = c.project_points(X)
            close = np.linalg.norm(X - c.center, axis=1) <= max_dist
            out |= front & c.in_image(uv) & close
        return out
    return vis


def check_sees_road(rig: Rig) -> None:
    """Refuse a rig none of whose cameras sees the carriageway."""
    a = np.linspace(0.0, J.STAGE, 61)
    b = np.linspace(-J.ROAD_HALF + 0.5, J.ROAD_HALF - 0.5, 7)
    A, B = np.meshgrid(a, b)
    xy = np.concatenate([J.to_world(arm, A.ravel(), B.ravel()) for arm in J.ARM_ANGLES])
    if not visible_fn(rig)(xy).any():
        raise InputError(f"no camera of rig {rig.name!r} sees the road (within 70 m)", field="rig")


# --- worker processes: forked with the world in a module global (copy-on-write) -------------
_STATE: dict = {}


def _mask_task(args: tuple[str, int, int]) -> tuple[str, int, int, str, int]:
    cam_name, f0, f1 = args
    st = _STATE
    r = st["renderers"].get(cam_name)
    if r is None:
        if st.get("forked"):
            import cv2
            cv2.setNumThreads(1)  # one process per core already; no oversubscription
        idx = st["cam_names"].index(cam_name)
        r = FrameRenderer(st["rig"].cameras[cam_name], idx, st["world"], st["noise"], st["seed"],
                          st["match"])
        st["renderers"][cam_name] = r
    text, n = r.mots_lines(f0, f1)
    return cam_name, f0, f1, text, n


def _video_task(cam_name: str) -> str:
    st = _STATE
    idx = st["cam_names"].index(cam_name)
    write_video(st["tmp"] / "video" / f"{cam_name}.mp4", st["rig"].cameras[cam_name], idx,
                st["world"], st["seed"], fps=1.0 / DT, look=st["look"])
    return cam_name


def _run_tasks(fn, tasks: list, workers: int, progress, desc: str, unit: str):
    """Run tasks in order (ordered results), in worker processes when workers > 1."""
    from tqdm import tqdm

    bar = tqdm(total=len(tasks), desc=desc, unit=unit, disable=not progress, leave=False)
    try:
        if workers <= 1 or "fork" not in mp.get_all_start_methods():  # the world is shared by fork
            for t in tasks:
                yield fn(t)
                bar.update(1)
        else:
            ctx = mp.get_context("fork")
            _STATE["forked"] = True
            with ctx.Pool(workers) as pool:
                for res in pool.imap(fn, tasks):
                    yield res
                    bar.update(1)
    finally:
        bar.close()


@contextlib.contextmanager
def _cleared_state():
    """The worker state (world, renderers) is dropped however generation ends."""
    try:
        yield
    finally:
        _STATE.clear()


@dataclass(frozen=True)
class SynthOptions:
    """What ``generate_scene`` makes (the options of ``s2p synth``).

    preset: "small" (3 x 240 frames, seconds) or "paper" (3 x 7,000 frames 0.075 s apart, 150
    dropped between splits, paper 4.1); frames: frames per split (overrides the preset);
    rig: device name (see ``rig.DEVICES``), a rig JSON file or a Rig; noise: detector noise
    (default on, ``NoiseConfig.off()`` for perfect silhouettes); population: class -> number of
    road users (overrides the preset); workers: processes (default: up to 2, one per core);
    ids: "road_user" (a road user keeps its track id and shape each time it comes back, as the
    paper's 83 road users) or "visit" (a new track id for every pass through the scene);
    distortion: optional radial lens distortion (k1, k2) of the named devices (off by default);
    match: "center" (paper 4.1: a detection is kept, with its road user's id, only when the
    projection of the road user's true 3D centre falls inside its mask; truncated or hidden
    road users whose centre is not covered drop out) or "all" (every visible mask); groups:
    share of the pedestrians who walk in groups of two or three (0: none, every preset's default).
    """

    preset: str = "small"
    frames: int | None = None
    seed: int = 0
    rig: str | Path | Rig | None = None
    video: bool = False
    force: bool = False
    noise: NoiseConfig | None = None
    progress: bool = True
    workers: int | None = None
    population: dict | None = None
    ids: str = "road_user"
    distortion: tuple[float, float] | None = None
    match: str = "center"
    look: str | None = None  # the video's look (synth.look.LOOKS); None: the preset's
    groups: float = 0.0  # share of the pedestrians walking in groups of two or three (traffic)


def generate_scene(out: Path, opts: SynthOptions = SynthOptions()) -> Path:
    """Generate a synthetic scene folder at ``out`` (``SynthOptions``) and return its path."""
    preset, frames, seed, rig, video, force = opts.preset, opts.frames, opts.seed, opts.rig, opts.video, opts.force
    noise, progress, workers, population = opts.noise, opts.progress, opts.workers, opts.population
    ids, distortion, match = opts.ids, opts.distortion, opts.match
    out = Path(out)
    # --- validate everything before any work ---------------------------------------------------
    if preset not in PRESETS:
        raise InputError(f"unknown preset {preset!r}; use one of {', '.join(PRESETS)}", field="preset")
    p = PRESETS[preset]
    per_split = p["split"] if frames is None else frames
    if not isinstance(per_split, (int, np.integer)) or per_split <= 0:
        raise InputError(f"frames per split must be a positive integer, got {frames!r}", field="frames")
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"seed must be a non-negative integer, got {seed!r}", field="seed")
    noise = NoiseConfig() if noise is None else noise
    noise.validate()
    pop = dict(p["population"]) if population is None else dict(population)
    for k, v in pop.items():
        if k not in CLASS_NAMES:
            raise InputError(f"unknown class {k!r}; known: {', '.join(CLASS_NAMES)}", field="population")
        if not isinstance(v, (int, np.integer)) or v < 0:
            raise InputError(f"population of {k} must be an integer >= 0, got {v!r}",
                             field=f"population.{k}")
    if match not in MATCH_RULES:
        raise InputError(f"unknown match rule {match!r}; use {' or '.join(MATCH_RULES)}", field="match")
    if ids not in ("road_user", "visit"):
        raise InputError(f"unknown id scheme {ids!r}; use road_user or visit", field="ids")
    if not 0.0 <= float(opts.groups) <= 1.0:
        raise InputError(f"groups must be a share between 0 and 1, got {opts.groups!r}", field="groups")
    if sum(pop.values()) == 0:
        raise InputError("population is empty: no road users to render", field="population")
    look_name = opts.look or p.get("look", "flat")
    look = look_named(look_name)
    wide = p.get("variety") == "wide"
    if wide and rig is None:  # the pole's height drawn from the seed (its own stream)
        from seg2pose.synth.rig import HEIGHT_RANGE, device_at

        pole_m = round(float(np.random.default_rng([int(seed), 43]).uniform(*HEIGHT_RANGE)), 1)
        rig_obj = device_at(pole_m, distortion=distortion)
    else:
        rig_obj = load_rig(rig, distortion)
    check_sees_road(rig_obj)
    check_writable(out, force)
    if out.exists() and not out.is_dir():
        raise S2PError(f"{out} exists and is not a folder")
    seed = int(seed)
    per_split = int(per_split)
    gap = p["gap"] if per_split == p["split"] else min(p["gap"], max(per_split // 10, 1))
    splits = split_ranges(per_split, gap)
    n_frames = splits["test"][1] + 1
    cams = list(rig_obj.cameras)
    workers = min(len(cams), os.cpu_count() or 1, 2) if workers is None else max(int(workers), 1)

    # --- simulate -------------------------------------------------------------------------------
    traffic = TrafficConfig(population=pop, mean_pause_s=dict(p["mean_pause_s"]),
                            group_share=float(opts.groups))
    sim_stats: dict = {}
    visits = simulate(traffic, n_frames, DT, seed, stats=sim_stats)
    if not visits:
        raise S2PError("the simulation produced no road users; use more frames or a larger population")
    if wide:
        from seg2pose.synth.shapes_wide import WIDE_MAKERS

        world = build_world(visits, n_frames, seed, ids=ids, makers=WIDE_MAKERS)
    else:
        world = build_world(visits, n_frames, seed, ids=ids)
    rng = np.random.default_rng([seed, 31])
    ground = J.sample_ground_points(rng, visible_fn(rig_obj))

    # built beside OUT and swapped in as a unit (the old scene, with --force, goes only after
    # the new one is complete); the lock refuses a second writer of OUT
    with replacing(out, force) as tmp, _cleared_state():
        (tmp / "masks").mkdir()
        (tmp / "gt").mkdir()
        classes = [ClassSpec(c["id"], c["name"], c["default_height"]) for c in DEFAULT_CLASSES]
        counts = {n: int(len(np.unique(world.track[world.cls == i]))) for i, n in enumerate(CLASS_NAMES)}
        extra: dict[str, Any] = {
            "generator": {
                "name": "seg2pose.synth", "version": 1, "preset": preset, "seed": seed,
                "frames_per_split": per_split, "gap": gap, "dt": DT, "rig": rig_obj.name,
                "distortion": list(distortion) if distortion else None,
                "video": bool(video), "ids": ids, "match": match, "noise": noise.to_dict(),
                "traffic": traffic.to_dict(),
                "traffic_stats": sim_stats,
                "ground_points": {"n": len(ground), "curb_share": 0.6},
                "surface": {"lane_m": J.LANE, "curb_m": J.CURB, "sidewalk_m": J.SIDEWALK,
                            "corner_radius_m": J.CORNER_R, "slope": J.SLOPE,
                            "slope_start_m": J.SLOPE_START},
            },
            "class_sizes": {k: list(v) for k, v in TYPICAL_SIZES.items()},
            "road_users": counts,
        }
        if wide:  # (a key of its own: the other presets' scene.json stay byte-identical)
            extra["generator"]["variety"] = "wide"
            extra["generator"]["sizes"] = {
                n: {"min": [round(float(v), 2) for v in world.size[world_tracks(world, i)].min(0)],
                    "max": [round(float(v), 2) for v in world.size[world_tracks(world, i)].max(0)]}
                for i, n in enumerate(CLASS_NAMES) if len(world_tracks(world, i))}
        if video and look != LOOKS["flat"]:  # (the flat look's scene.json stays as it was)
            extra["generator"]["look"] = look_name
        scene = Scene(root=tmp, name=out.name, fps=1.0 / DT, rig=rig_obj, ground_points=ground,
                      classes=classes, splits=splits, extra=extra)
        scene.save(tmp)
        write_poses(tmp / "gt" / "poses.csv", world.poses())
        _STATE.clear()
        _STATE.update(world=world, rig=rig_obj, cam_names=cams, noise=noise, seed=seed,
                      renderers={}, tmp=tmp, match=match, look=look)
        tasks = [(c, f0, min(f0 + CHUNK, n_frames)) for c in cams for f0 in range(0, n_frames, CHUNK)]
        files = {}
        with contextlib.ExitStack() as stack:
            for c in cams:
                files[c] = stack.enter_context(fdopen_nofollow(tmp / "masks" / f"{c}.txt", "w",
                                                               encoding="ascii", newline="\n"))
            for cam_name, _, _, text, _ in _run_tasks(_mask_task, tasks, workers, progress,
                                                       "masks", "chunk"):
                files[cam_name].write(text)
        if video:
            (tmp / "video").mkdir()
            for _ in _run_tasks(_video_task, cams, workers, progress, "video", "camera"):
                pass
    return out
