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
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from seg2pose.core.clock import utc_now
from seg2pose.core.digest import file_sha256
from seg2pose.core.errors import InputError
from seg2pose.core.say import warn_once
from seg2pose.geometry.normal import DEFAULT_CENTER_METHOD, normal_positions
from seg2pose.io.atomic import holding
from seg2pose.io.mots import MaskTable
from seg2pose.io.run import ViewTable, check_run_writable, relative_path, write_run_folder
from seg2pose.io.scene import Scene
from seg2pose.method.checkpoint import load_models, predict_with_spread
from seg2pose.method.fusion import fuse
from seg2pose.method.ood import POLICIES, flag_far, flagged_poses, format_flagged
from seg2pose.structures.masks import CROP_SIZE, mask_centers, rle_stats

if TYPE_CHECKING:  # torch is imported only when a run uses models
    from seg2pose.method.checkpoint import Checkpoint, Ensemble, ModelSet


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
# per-view estimates


def view_estimates(scene: Scene, cam: str, table: MaskTable, center_method: str,
                   models: ModelSet | None, said: set[str], batch: int = 64,
                   far: FarResiduals | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                              np.ndarray]:
    """For the detections of one camera (any number of frames): class names (N,), mask centres
    (N, 2) pixels, normal positions (N, 3) metres (NaN where the ray misses the ground),
    residuals (N, 2) metres (zeros for the baseline or a missed ray), the error bar's cues
    (N, 3): mask cut by the image border, residual flagged far, ensemble spread (metres), and
    the masks' bounding boxes (N, 4) x0, y0, x1, y1 pixels (NaN for an empty mask).
    ``far``: residuals longer than the model learned (``seg2pose.method.ood``) are recorded there,
    and dropped with its fallback policy."""
    camera = scene.cameras[cam]
    by_id = scene.class_by_id()
    n = len(table)
    names = np.array([by_id[c].name if c in by_id else "" for c in table.class_id], dtype=object)
    heights = np.array([by_id[c].default_height if c in by_id else np.nan for c in table.class_id])
    if (table.class_id == 0).any():
        warn_once(said, "noclass", f"camera {cam}: detections without a class (class_id 0) are skipped")
    uv = mask_centers(table.rles, table.height, table.width, center_method)
    normal = np.full((n, 3), np.nan)
    ok = np.isfinite(uv[:, 0]) & np.isfinite(heights)
    if ok.any():
        normal[ok], _ = normal_positions(camera, scene.ground, uv[ok], heights[ok])
    residual = np.zeros((n, 2))
    cues = np.zeros((n, 3))
    _, _, box = rle_stats(table.rles, table.height, table.width)
    with np.errstate(invalid="ignore"):
        cues[:, 0] = ((box[:, 0] <= 0) | (box[:, 1] <= 0) | (box[:, 2] >= table.width)
                      | (box[:, 3] >= table.height))
    if models is None or n == 0:
        return names, uv, normal, residual, cues, box
    big = np.nanmax(box[:, 2:] - box[:, :2], axis=1, initial=0) > CROP_SIZE
    if big.any():
        warn_once(said, "bigmask", f"camera {cam}: masks larger than the {CROP_SIZE}x{CROP_SIZE} crop are "
                        "cropped around their centre")
    usable = np.isfinite(normal[:, 0])
    groups: dict[int, tuple[Checkpoint | Ensemble, list[str]]] = {}  # one batch per distinct model
    for (mcam, c), ck in models.models.items():
        if mcam == cam:
            groups.setdefault(id(ck), (ck, []))[1].append(c)
    for ck, cls_of_model in groups.values():
        sel = np.flatnonzero(usable & np.isin(names, cls_of_model))

        residual[sel], cues[sel, 2] = predict_with_spread(
            scene, cam, ck, [table.rles[i] for i in sel], table.height, table.width, uv[sel],
            normal[sel, :2], names[sel], batch)
        if far is not None:
            cues[far.check(table, cam, sel, residual, names, ck.info.get("residual_limit")), 1] = 1
    return names, uv, normal, residual, cues, box


@dataclass
class FarResiduals:
    """Views whose residual is longer than their model's training residuals (``seg2pose.method.ood``):
    policy "warn" records them, "fallback" also drops their residual (the normal position
    stays), "off" does nothing."""

    policy: str = "warn"
    rows: list = field(default_factory=list)

    def __post_init__(self) -> None:
        if self.policy not in POLICIES:
            raise InputError(f"unknown policy {self.policy!r} for far residuals; use one of "
                             f"{', '.join(POLICIES)}", field="far_residuals")

    def check(self, table: MaskTable, cam: str, sel: np.ndarray, residual: np.ndarray,
              names: np.ndarray, limits: dict | None) -> np.ndarray:
        """The flagged rows among ``sel`` (indices)."""
        if self.policy == "off" or not len(sel):
            return np.zeros(0, np.int64)
        flag, lim = flag_far(residual[sel], names[sel], limits)
        i = sel[flag]
        if not len(i):
            return i
        self.rows.append((table.frame[i], table.track_id[i], np.full(len(i), cam, object),
                          names[i], residual[i].copy(), lim[flag]))
        if self.policy == "fallback":
            residual[i] = 0.0
        return i

    def summary(self) -> tuple[dict, str | None]:
        """(run.json entry, flagged.csv text or None)."""
        if self.policy == "off":
            return {"policy": "off"}, None
        cols = [np.concatenate(c) for c in zip(*self.rows)] if self.rows else [np.zeros(0)] * 6
        n_poses = flagged_poses(cols[0], cols[1])
        return ({"policy": self.policy, "flagged_views": int(len(cols[0])),
                 "flagged_poses": n_poses, "file": "flagged.csv"},
                format_flagged(*cols))


# ----------------------------------------------------------------------------------------------
# the run folder


def compute_views(scene: Scene, cams: list[str], frame_range: tuple[int, int] | None,
                  models: ModelSet | None, center_method: str = DEFAULT_CENTER_METHOD, chunk_frames: int = 32,
                  progress: bool = True, far: FarResiduals | None = None) -> tuple[ViewTable, int]:
    """Per-view estimates of all detections of ``cams`` (streamed in lockstep, ``chunk_frames``
    frames per network batch group): the rows of views.csv (sorted by frame, track id,
    camera), and the number of frames."""
    from tqdm import tqdm

    said: set[str] = set()  # warnings said once per run
    rows: list[ViewTable] = []

    def flush(chunk: dict[str, list[MaskTable]]) -> None:
        for cam, tables in chunk.items():
            if not tables:
                continue
            t = MaskTable.concat(tables)
            names, uv, normal, residual, cues, box = view_estimates(scene, cam, t, center_method,
                                                                    models, said, far=far)
            rows.append(ViewTable(t.frame, t.track_id, np.full(len(t), cam, dtype=object), names,
                                  uv, normal, residual, cues, box=box))

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
             models: ModelSet | None, split: str | None, center_method: str, smooth: int = 0) -> dict:
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
        if c not in cams or models is None:  # (no paths without models)
            continue
        files = [model_entry(Path(x)) for x in (p if isinstance(p, list) else [p])]
        entry = {key: [f[key] for f in files] if isinstance(p, list) else files[0][key]
                 for key in ("path", "file", "sha256")}
        info = models.models[(c, k)].info
        entries[f"{c}/{k}"] = {**entry, **{kk: info.get(kk) for kk in ("val_loss", "epoch", "seed")}}
    return {
        "scene": relative_path(scene.root, run_dir), "scene_fingerprint": scene.fingerprint(),
        "config": config, "cameras": cams, "method": "baseline" if models is None else "seg2posenet",
        "center_method": center_method, **({"smooth_frames": int(smooth)} if smooth else {}),
        "models": entries,
        **({"baseline_fallback": [f"{c}/{k}" for c, k in models.fallback if c in cams]}
           if models is not None and models.fallback else {}),
        "split": split, "frame_range": None if fr is None else list(fr), "created": utc_now(),
    }


def write_run(scene: Scene, run_dir: Path, views: ViewTable, cams: list[str], models: ModelSet | None,
              n_frames: int, opts: RunOptions, far: FarResiduals | None = None,
              track_ids: dict | None = None, r90_path: Path | None = None) -> Path:
    """Fuse per-view estimates (``opts.smooth``, ``opts.confirm``: see ``fuse``; a confirm of
    None counts as 0) and write the run folder (poses.csv, views.csv, run.json, and flagged.csv
    when the residuals were checked; with ``opts.track_heights`` the views' normal positions are
    first moved to each track's fitted height, and track_heights.csv lists the heights).
    ``track_ids``: how the ids were made
    (``check_track_ids``), recorded in run.json; ``r90_path``: the error bars' calibration
    (``seg2pose.method.uncertainty``; None: r90_m stays NaN)."""
    run_dir = Path(run_dir)
    confirm = opts.confirm or 0.0
    smooth = opts.smooth
    extra = {}
    th_meta = None
    if opts.track_heights:
        from seg2pose.method import track_heights as th

        views, th_meta, extra["track_heights.csv"] = th.apply_track_heights(scene, views,
                                                                            th.DEFAULT_SETTINGS)
    cal, r90_meta = None, {"calibration": None}
    if r90_path is not None and views.cues is not None:
        from seg2pose.method.uncertainty import read_calibration, view_r90

        cal = read_calibration(r90_path)
        method = "baseline" if models is None else "seg2posenet"
        if cal.meta.get("method") not in (None, method):
            raise InputError(f"this r90 calibration was fitted on a {cal.meta['method']} run; "
                             f"this is a {method} run (fit one with s2p calibrate-errors)", file=r90_path)
        if int(cal.meta.get("smooth_frames") or 0) != smooth:
            warn_once(set(), "r90smooth", f"the r90 calibration {r90_path} was fitted on a run "
                      f"with --smooth {cal.meta.get('smooth_frames') or 0}, this one has --smooth "
                      f"{smooth}: its coverage may differ from 90 %")
        views.r90 = view_r90(cal, scene, views)
        r90_meta = {"calibration": relative_path(r90_path, run_dir),
                    "sha256": file_sha256(r90_path)}
    poses = fuse(views, scene, smooth, confirm, cams, r90=cal)
    if poses.r90 is None and views.cues is not None:
        poses.r90 = np.full(len(poses), np.nan)  # the column is always there; NaN: no calibration
    meta = {**run_meta(scene, run_dir, cams, opts.config, models, opts.split, opts.center_method,
                       smooth),
            **({"track_ids": track_ids} if track_ids else {}),
            **({"confirm_share": confirm} if confirm > 0 and len(cams) > 1 else {}),
            **({"track_heights": th_meta} if th_meta is not None else {}),
            "n_frames": n_frames, "n_views": len(views), "n_poses": len(poses), "r90": r90_meta}
    if far is not None and models is not None:
        meta["far_residuals"], text = far.summary()
        if text is not None:
            extra["flagged.csv"] = text
    return write_run_folder(run_dir, poses, views, meta, force=opts.force, extra_files=extra)


def check_tracked(scene: Scene, cameras: list[str]) -> None:
    """Refuse masks files none of whose masks has a track id (``masks-from-video --no-track``,
    a detector without a tracker): headings and the fusion of views need tracks. Reads up to
    the first tracked mask (the first line, usually)."""
    for c in cameras:
        path = scene.masks_path(c)
        if not path.exists():
            continue
        n = 0
        with open(path, "rb") as f:
            for line in f:
                parts = line.split(None, 2)
                if len(parts) < 2:
                    continue
                if parts[1] != b"-1":
                    break
                n += 1
            else:
                if n:
                    raise InputError(f"none of its {n} masks has a track id (all -1); give "
                                     f"them ids first: s2p track {scene.root}", file=path)


# share of the cameras seeing a road user's place that must report it (runs of associated ids);
# chosen on seeds 101-102 (docs/RESULTS.md, "Multi-camera association")
CONFIRM_SHARE = 0.5


def check_track_ids(scene: Scene, cams: list[str], fuse_unassociated: bool = False) -> dict:
    """How the track ids of ``cams`` were made (``seg2pose.io.track_ids``), for run.json.
    Refuses to fuse several cameras whose ids are each camera's own tracker's: late fusion
    would average different road users that happen to share a number."""
    from seg2pose.io.track_ids import ids_status

    masks_dir = scene.masks_path(cams[0]).parent
    source = scene.extra.get("source")
    source = source if isinstance(source, dict) else {}
    kind, why = ids_status(masks_dir, cams, from_video=source.get("format") == "video")
    if kind == "unassociated" and len(cams) > 1:
        if not fuse_unassociated:
            raise InputError(f"the track ids of cameras {', '.join(cams)} are not associated across "
                             f"cameras ({why}); fusing them would average different road users "
                             f"that share a number. Run `s2p associate {scene.root}` first (or "
                             "pass --fuse-unassociated to fuse them anyway)", file=masks_dir)
        return {"ids": "unassociated", "fused_anyway": True, "why": why}
    return {"ids": kind, "why": why}


@dataclass(frozen=True)
class RunOptions:
    """How ``run_scene`` runs the pipeline (the options of ``s2p run``)."""

    config: str | None = None     # a configuration of the rig (None: all cameras)
    baseline: bool = False        # normal positions only (no network)
    # checkpoints (default SCENE/models), or a list of folders whose models are averaged (Ensemble)
    models_dir: str | Path | list | None = None
    split: str | None = None      # a named frame range of the scene (None: all frames)
    force: bool = False           # replace an existing run folder
    center_method: str = DEFAULT_CENTER_METHOD
    arch: str | None = None       # when given, the checkpoints' architecture must match
    chunk_frames: int = 32        # frames per network batch group
    device: str | None = None     # torch device (default: cuda if present)
    progress: bool = True
    allow_incomplete: bool = False  # use checkpoints whose training did not finish
    smooth: int = 0               # fused positions smoothed along each track over this many
                                  # frames either side (0: not; see ``fuse``)
    far_residuals: str = "warn"   # residuals longer than the model was trained on
                                  # (``FarResiduals``: warn, fallback, off)
    # fuse cameras whose ids were never associated (``check_track_ids`` refuses otherwise)
    fuse_unassociated: bool = False
    # see ``fuse``; None: ``CONFIRM_SHARE`` for cameras whose ids were associated, else 0 (off)
    confirm: float | None = None
    # the error bars' calibration (None: the default one, ``default_r90_path``, where it exists)
    r90: str | Path | None = None
    # one height per tracked road user fitted before fusion (``seg2pose.method.track_heights``)
    track_heights: bool = False
    # cameras and classes without a model: "refuse" the run, or run the "baseline" there (said
    # in run.json's baseline_fallback and on the output)
    missing: str = "refuse"


def run_scene(scene: Scene, run_dir: str | Path, opts: RunOptions = RunOptions()) -> Path:
    """Run the pipeline on a scene and write the run folder ``run_dir`` (see module docstring)."""
    run_dir = Path(run_dir)
    with holding(run_dir):  # from the start: two runs into one folder do not both compute
        return _run_scene(scene, run_dir, opts)


def _run_scene(scene: Scene, run_dir: Path, opts: RunOptions) -> Path:
    check_run_writable(run_dir, opts.force)  # before the work, not only after it
    cams = [c.name for c in scene.rig.select(opts.config)]
    check_tracked(scene, cams)
    track_ids = check_track_ids(scene, cams, opts.fuse_unassociated)
    if opts.confirm is None:
        opts = replace(opts, confirm=CONFIRM_SHARE if track_ids["ids"] == "associated" else 0.0)
    frame_range = scene.split_range(opts.split)
    models = None
    if not opts.baseline:
        models = load_models(scene, cams, opts.models_dir, opts.arch, opts.device, opts.allow_incomplete,
                             opts.missing)
    far = None if models is None else FarResiduals(opts.far_residuals)
    r90_path = Path(opts.r90) if opts.r90 is not None else default_r90_path(scene, opts.models_dir,
                                                                            opts.baseline)
    if opts.r90 is not None and not r90_path.is_file():
        raise InputError("r90 calibration not found (make one with s2p calibrate-errors)", file=r90_path)
    views, nframes = compute_views(scene, cams, frame_range, models, opts.center_method,
                                   opts.chunk_frames, opts.progress, far=far)
    check_frames(scene, cams, views.frame)
    return write_run(scene, run_dir, views, cams, models, nframes, opts, far, track_ids,
                     r90_path=r90_path if r90_path.is_file() else None)


def scene_last_frame(scene: Scene, cams: list[str]) -> tuple[int, str]:
    """The last frame the scene has (inclusive) and what says so: the last frame of its splits
    or of its cameras' videos, whichever is later; else the last frame whose time MCAP and
    Rerun can hold (signed 64-bit nanoseconds from 1970, after the scene's start_time)."""
    from seg2pose.io.video import camera_reader

    last = [(b, "its splits in scene.json") for _, b in scene.splits.values()]
    for c in cams:
        if scene.video_path(c) is not None:
            r = camera_reader(scene, c)
            n = r.header()[2]
            if n:
                last.append((r.first + r.step * (n - 1), f"camera {c}'s video"))
    if last:
        return max(last)
    from seg2pose.io.schemas import frame_limit

    return frame_limit(scene.fps, scene.start_time_ns), "the times a recording can hold"


def check_frames(scene: Scene, cams: list[str], frames: np.ndarray) -> None:
    """Refuse masks at frames the scene does not have (a mask at frame 10^15 of a 20-frame
    scene made a run that export and review then failed on): one line naming the frame."""
    if not len(frames):
        return
    last, why = scene_last_frame(scene, cams)
    hi = int(frames.max())
    if int(frames.min()) < 0 or hi > last:
        bad = int(frames.min()) if int(frames.min()) < 0 else hi
        raise InputError(f"a mask at frame {bad}: the scene's frames are 0..{last} ({why})",
                         file=scene.root / "masks")


R90_FILE = "r90.json"
R90_BASELINE_FILE = "r90-baseline.json"


def default_r90_path(scene: Scene, models_dir=None, baseline: bool = False) -> Path:
    """Where a run looks for its error bars' calibration when none is named (and where ``s2p
    calibrate`` writes it): beside the models (the first folder's r90.json) for Seg2PoseNet,
    SCENE/r90-baseline.json for the baseline."""
    if baseline:
        return scene.root / R90_BASELINE_FILE
    from seg2pose.method.checkpoint import model_dirs

    return model_dirs(scene, models_dir)[0] / R90_FILE
