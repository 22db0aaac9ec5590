"""Inference: masks -> normal positions (3.2) -> Seg2PoseNet residuals (3.3) -> late fusion
(mean over views, 3.3) -> headings from motion (3.4) -> a run folder.

The run folder itself (run.json, poses.csv, views.csv) is read and written by
``seg2pose.io.run``.

Masks are streamed: all cameras of the configuration are read in lockstep, a chunk of frames at
a time, and the network sees batches of crops gathered across the chunk's frames (one batch
per model: models are per camera and class, or per camera with a class input).
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from seg2pose.errors import InputError, S2PError
from seg2pose.io.mots import MaskTable
from seg2pose.io.poses import PoseTable
from seg2pose.io.run import ViewTable, check_run_writable, file_sha256, now_utc, relative_path, write_run_folder
from seg2pose.io.scene import Scene, load_scene
from seg2pose.masks import CROP_SIZE, mask_centers, rle_stats
from seg2pose.normal import DEFAULT_CENTER_METHOD, fuse_views, headings_from_tracks, normal_positions
from seg2pose.say import say, warn_once


def iter_frames(scene: Scene, cameras: list[str], frame_range: tuple[int, int] | None = None
                ) -> Iterator[tuple[int, dict[str, MaskTable]]]:
    """Stream all cameras' masks in lockstep: (frame, {camera: detections of that frame}),
    frames in increasing order; a camera without detections in a frame is absent."""
    its = {}
    for cam in cameras:
        path = scene.masks_path(cam)
        if not path.exists():
            raise InputError(f"no masks for camera {cam!r}", file=path)
        its[cam] = scene.iter_masks(cam, frame_range)
    heap: list[tuple[int, int, str, MaskTable]] = []
    for k, (cam, it) in enumerate(its.items()):
        nxt = next(it, None)
        if nxt is not None:
            heapq.heappush(heap, (nxt[0], k, cam, nxt[1]))
    order = {cam: k for k, cam in enumerate(its)}
    while heap:
        frame = heap[0][0]
        out = {}
        while heap and heap[0][0] == frame:
            _, _, cam, table = heapq.heappop(heap)
            out[cam] = table
            nxt = next(its[cam], None)
            if nxt is not None:
                heapq.heappush(heap, (nxt[0], order[cam], cam, nxt[1]))
        yield frame, out


# ----------------------------------------------------------------------------------------------
# models


def model_filename(camera: str, cls: str) -> str:
    """``<camera>__<class>.safetensors``; ``all`` in place of the camera or the class for a
    model serving all cameras (of one device) or all classes."""
    return f"{'all' if camera == '*' else camera}__{'all' if cls == '*' else cls}.safetensors"


@dataclass(eq=False)
class Ensemble:
    """Checkpoints from several model folders for one (camera, class): their residuals are
    averaged (model averaging; e.g. an annotated and a zero-annotation model, or runs with
    other seeds). ``info`` is the first member's."""

    members: tuple

    @property
    def info(self) -> dict:
        return self.members[0].info


@dataclass
class ModelSet:
    """The checkpoints a run uses, looked up by (camera, class name): a Checkpoint each, or an
    Ensemble when several model folders are given."""

    models: dict[tuple[str, str], object] = field(default_factory=dict)  # -> Checkpoint | Ensemble
    paths: dict[tuple[str, str], Path | list[Path]] = field(default_factory=dict)

    @classmethod
    def load(cls, models_dir: Path | list[Path], cameras: list[str], classes: list[str],
             arch: str | None = None, fingerprint: str | None = None, device=None,
             allow_incomplete: bool = False) -> "ModelSet":
        """The models of one folder, or of several folders as ensembles (residuals averaged).
        A checkpoint whose training did not finish (metadata "complete": false) is refused
        unless ``allow_incomplete``."""
        if isinstance(models_dir, (list, tuple)):
            if len(models_dir) == 1:
                return cls.load(models_dir[0], cameras, classes, arch, fingerprint, device,
                                allow_incomplete)
            sets = [cls.load(d, cameras, classes, arch, fingerprint, device, allow_incomplete)
                    for d in models_dir]
            ms, made = cls(), {}
            for key in sets[0].models:
                members = tuple(s.models[key] for s in sets)
                ids = tuple(map(id, members))  # one Ensemble per distinct member set (shared models)
                ms.models[key] = made.setdefault(ids, Ensemble(members))
                ms.paths[key] = [s.paths[key] for s in sets]
            return ms
        from seg2pose.net import Checkpoint

        models_dir = Path(models_dir)
        ms = cls()
        missing = []
        cache: dict[Path, object] = {}
        for cam in cameras:
            for c in classes:
                for name in (model_filename(cam, c), model_filename(cam, "*"),
                             model_filename("*", c), model_filename("*", "*")):
                    p = models_dir / name
                    if p.exists():
                        if p not in cache:
                            cache[p] = Checkpoint.load(p, arch=arch, camera=cam, device=device or "cpu")
                            ck = cache[p]
                            if ck.info.get("complete") is False:
                                msg = (f"its training did not finish (epoch {ck.info.get('epoch')}, "
                                       f"val loss {ck.info.get('val_loss')})")
                                if not allow_incomplete:
                                    raise InputError(f"{msg}: finish it with `s2p train`, or pass "
                                                     "--allow-incomplete to use it anyway",
                                                     file=p.with_suffix(".json"), field="complete")
                                say(f"{p}: {msg}; used because incomplete models are allowed",
                                    "warning")
                            if fingerprint and ck.scene_fingerprint and ck.scene_fingerprint != fingerprint:
                                say(f"{p} was trained on another scene (fingerprint "
                                    f"{ck.scene_fingerprint}, this scene {fingerprint})", "warning")
                        ms.models[(cam, c)] = cache[p]
                        ms.paths[(cam, c)] = p
                        break
                else:
                    missing.append(f"{cam}/{c}")
        if missing:
            raise S2PError(f"no Seg2PoseNet model in {models_dir} for {', '.join(missing)}; "
                           "train with `s2p train` or run with --baseline")
        return ms


# ----------------------------------------------------------------------------------------------
# per-view estimates


class _Warn:
    """Say a thing once per run."""

    def __init__(self):
        self.said: set[str] = set()

    def __call__(self, key: str, msg: str) -> None:
        warn_once(self.said, key, msg)


def view_estimates(scene: Scene, cam: str, table: MaskTable, center_method: str,
                   models: ModelSet | None, warn: _Warn, batch: int = 64
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For the detections of one camera (any number of frames): class names (N,), mask centres
    (N, 2) pixels, normal positions (N, 3) metres (NaN where the ray misses the ground) and
    residuals (N, 2) metres (zeros for the baseline or a missed ray)."""
    camera = scene.cameras[cam]
    by_id = scene.class_by_id()
    n = len(table)
    names = np.array([by_id[c].name if c in by_id else "" for c in table.class_id], dtype=object)
    heights = np.array([by_id[c].default_height if c in by_id else np.nan for c in table.class_id])
    if (table.class_id == 0).any():
        warn("noclass", f"camera {cam}: detections without a class (class_id 0) are skipped")
    uv = mask_centers(table.rles, table.height, table.width, center_method)
    normal = np.full((n, 3), np.nan)
    ok = np.isfinite(uv[:, 0]) & np.isfinite(heights)
    if ok.any():
        normal[ok], _ = normal_positions(camera, scene.ground, uv[ok], heights[ok])
    residual = np.zeros((n, 2))
    if models is None or n == 0:
        return names, uv, normal, residual
    _, _, box = rle_stats(table.rles, table.height, table.width)
    big = np.nanmax(box[:, 2:] - box[:, :2], axis=1, initial=0) > CROP_SIZE
    if big.any():
        warn("bigmask", f"camera {cam}: masks larger than the {CROP_SIZE}x{CROP_SIZE} crop are "
                        "cropped around their centre")
    usable = np.isfinite(normal[:, 0])
    groups: dict[int, tuple[object, list[str]]] = {}  # one batch per distinct model
    for (mcam, c), ck in models.models.items():
        if mcam == cam:
            groups.setdefault(id(ck), (ck, []))[1].append(c)
    for ck, cls_of_model in groups.values():
        sel = np.flatnonzero(usable & np.isin(names, cls_of_model))
        residual[sel] = predict_residuals(scene, cam, ck, [table.rles[i] for i in sel],
                                          table.height, table.width, uv[sel], normal[sel, :2],
                                          names[sel], batch)
    return names, uv, normal, residual


def predict_residuals(scene: Scene, cam: str, ck, rles: list[bytes], height: int, width: int,
                      uv: np.ndarray, normal_xy: np.ndarray, names: np.ndarray, batch: int = 64
                      ) -> np.ndarray:
    """Seg2PoseNet residuals (N, 2) metres of checkpoint ``ck`` for N masks of camera ``cam``
    with centres uv (N, 2) pixels, normal positions (N, 2) metres and class names (N,): crops
    straight from the RLE runs and, when the model uses them, the mask-geometry features;
    one batch of full-resolution crops at a time (bounded memory). An Ensemble gives the mean
    of its members' residuals."""
    if isinstance(ck, Ensemble):
        return np.mean([predict_residuals(scene, cam, m, rles, height, width, uv, normal_xy, names,
                                          batch) for m in ck.members], axis=0)
    from seg2pose.examples import crop_runs
    from seg2pose.features import scene_geometry

    out = np.zeros((len(rles), 2))
    center = scene.cameras[cam].center[:2]
    for s in range(0, len(rles), batch):
        sl = slice(s, s + batch)
        part = rles[sl]
        crops = crop_runs(part, height, width, uv[sl])
        geo = (scene_geometry(scene, cam, part, height, width, uv[sl], normal_xy[sl], names[sl])
               if ck.net.cfg.n_geo else None)
        out[sl] = ck.predict(crops, uv[sl], normal_xy[sl], names[sl], batch=batch,
                             origin_xy=center, geo=geo)
    return out


# ----------------------------------------------------------------------------------------------
# fusion and the run folder


def fuse(views: ViewTable, scene: Scene) -> PoseTable:
    """Late fusion: per (frame, track_id), the mean over views of normal position + residual;
    z from the ground surface at the fused (x, y); headings from the fused tracks (eq. 2);
    sizes from the class. Detections without a track id (-1) are not fused with anything."""
    frame, tid = views.frame, views.track_id
    est = views.normal[:, :2] + views.residual
    keep = np.isfinite(est).all(axis=1) & (views.cls != "")
    frame, tid, est = frame[keep], tid[keep], est[keep]
    cam, cls = views.camera[keep], views.cls[keep]
    if len(frame) == 0:
        return PoseTable.empty(with_size=True)
    # untracked detections get unique negative keys so that they stay alone
    key_tid = tid.copy()
    lone = tid < 0
    key_tid[lone] = -1 - np.arange(int(lone.sum()))
    keys = np.stack([frame, key_tid], axis=1)
    ukeys, first, inv = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    inv = inv.reshape(-1)
    cams, cam_idx = np.unique(cam, return_inverse=True)
    stack = np.full((len(cams), len(ukeys), 2), np.nan)
    stack[cam_idx, inv] = est       # one detection per (camera, road user, frame)
    xy = fuse_views(stack)
    z = scene.ground.height(xy)
    out_tid = np.where(ukeys[:, 1] < 0, -1, ukeys[:, 1])
    heading = np.full(len(ukeys), np.nan)
    tracked = out_tid >= 0
    heading[tracked] = headings_from_tracks(out_tid[tracked], ukeys[tracked, 0], xy[tracked])
    out_cls = cls[first]
    sizes = scene.class_sizes()
    size = np.array([sizes.get(str(c), (np.nan, np.nan, np.nan)) for c in out_cls], float)
    table = PoseTable(ukeys[:, 0], out_tid, out_cls, np.column_stack([xy, z]), heading, size)
    return table.sorted()


def compute_views(scene: Scene, cams: list[str], frame_range: tuple[int, int] | None,
                  models: ModelSet | None, center_method: str = DEFAULT_CENTER_METHOD, chunk_frames: int = 32,
                  progress: bool = True) -> tuple[ViewTable, int]:
    """Per-view estimates of all detections of ``cams`` (streamed in lockstep, ``chunk_frames``
    frames per network batch group): the rows of views.csv (sorted by frame, track id,
    camera), and the number of frames."""
    from tqdm import tqdm

    warn = _Warn()
    rows: list[ViewTable] = []

    def flush(chunk: dict[str, list[MaskTable]]) -> None:
        for cam, tables in chunk.items():
            if not tables:
                continue
            t = MaskTable.concat(tables)
            names, uv, normal, residual = view_estimates(scene, cam, t, center_method, models, warn)
            rows.append(ViewTable(t.frame, t.track_id, np.full(len(t), cam, dtype=object), names,
                                  uv, normal, residual))

    chunk: dict[str, list[MaskTable]] = {c: [] for c in cams}
    nframes = 0
    bar = tqdm(total=None if frame_range is None else frame_range[1] - frame_range[0] + 1,
               desc=f"s2p run {'baseline' if models is None else 'seg2posenet'}", unit="frame",
               disable=not progress, leave=False)
    for _, tables in iter_frames(scene, cams, frame_range):
        for cam, t in tables.items():
            chunk[cam].append(t)
        nframes += 1
        bar.update(1)
        if nframes % chunk_frames == 0:
            flush(chunk)
            chunk = {c: [] for c in cams}
    flush(chunk)
    bar.close()
    return ViewTable.concat(rows).sorted(), nframes


def run_meta(scene: Scene, run_dir: Path, cams: list[str], config: str | None,
             models: ModelSet | None, split: str | None, center_method: str) -> dict:
    """run.json of a run (paths relative to the run folder; the checkpoints named with their
    sha256, so a run says exactly which models made it)."""
    fr = scene.split_range(split)
    digests: dict[Path, str] = {}

    def model_entry(p: Path) -> dict:
        if p not in digests:
            digests[p] = file_sha256(p)
        return {"path": relative_path(p, run_dir), "file": p.name, "sha256": digests[p]}

    entries = {}
    for (c, k), p in ({} if models is None else models.paths).items():
        if c not in cams:
            continue
        files = [model_entry(Path(x)) for x in (p if isinstance(p, list) else [p])]
        entry = {key: [f[key] for f in files] if isinstance(p, list) else files[0][key]
                 for key in ("path", "file", "sha256")}
        info = models.models[(c, k)].info
        entries[f"{c}/{k}"] = {**entry, **{kk: info.get(kk) for kk in ("val_loss", "epoch", "seed")}}
    return {
        "scene": relative_path(scene.root, run_dir), "scene_fingerprint": scene.fingerprint(),
        "config": config, "cameras": cams, "method": "baseline" if models is None else "seg2posenet",
        "center_method": center_method, "models": entries,
        "split": split, "frame_range": None if fr is None else list(fr), "created": now_utc(),
    }


def write_run(scene: Scene, run_dir: Path, views: ViewTable, cams: list[str],
              config: str | None, models: ModelSet | None, split: str | None,
              center_method: str, n_frames: int, force: bool = False) -> Path:
    """Fuse per-view estimates and write the run folder (poses.csv, views.csv, run.json)."""
    run_dir = Path(run_dir)
    poses = fuse(views, scene)
    meta = {**run_meta(scene, run_dir, cams, config, models, split, center_method),
            "n_frames": n_frames, "n_views": len(views), "n_poses": len(poses)}
    return write_run_folder(run_dir, poses, views, meta, force=force)


def model_dirs(scene: Scene, models_dir) -> list[Path]:
    """The model folder(s) a run uses: one path, a list of them (averaged), or None for
    SCENE/models."""
    dirs = models_dir if isinstance(models_dir, (list, tuple)) else [models_dir] if models_dir else []
    return [Path(d) for d in dirs] or [scene.root / "models"]


def _load_models(scene: Scene, cams: list[str], models_dir, arch, device,
                 allow_incomplete: bool = False) -> ModelSet:
    from seg2pose.net import pick_device

    return ModelSet.load(model_dirs(scene, models_dir), cams,
                         [c.name for c in scene.classes], arch=arch,
                         fingerprint=scene.fingerprint(), device=pick_device(device),
                         allow_incomplete=allow_incomplete)


def run_scene(scene: Scene | str | Path, run_dir: str | Path, config: str | None = None,
              baseline: bool = False, models_dir: str | Path | None = None,
              split: str | None = None, force: bool = False, center_method: str = DEFAULT_CENTER_METHOD,
              arch: str | None = None, chunk_frames: int = 32, device: str | None = None,
              progress: bool = True, allow_incomplete: bool = False) -> Path:
    """Run the pipeline on a scene and write the run folder ``run_dir`` (see module docstring).

    config: a configuration of the rig (None = all cameras); baseline: normal positions only;
    models_dir: checkpoints (default SCENE/models), or a list of folders whose models are
    averaged (Ensemble); split: a named frame range of the scene; allow_incomplete: use
    checkpoints whose training did not finish (refused otherwise)."""
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    run_dir = Path(run_dir)
    check_run_writable(run_dir, force)  # before the work, not only after it
    cams = [c.name for c in scene.rig.select(config)]
    frame_range = scene.split_range(split)
    models = None if baseline else _load_models(scene, cams, models_dir, arch, device,
                                                allow_incomplete)
    views, nframes = compute_views(scene, cams, frame_range, models, center_method,
                                   chunk_frames, progress)
    return write_run(scene, run_dir, views, cams, config, models, split, center_method,
                     nframes, force=force)
