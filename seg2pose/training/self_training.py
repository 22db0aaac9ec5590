"""Self-training of zero-annotation models on the scene's own unlabelled masks
(``s2p train --zero-annotation --self-train track|views``).

A zero-annotation model (rough models only, then the radial calibration: ``train.py``,
``zero_annotation.py``) is wrong mostly along the line of sight and by an offset nearly
constant per road user (docs/RESULTS.md, "Error budget"). What the scene itself can say about
that needs no annotation:

1. the rough-only models (``ROUGH_STAGE``, a sub-folder of the model folder) run on every lens
   of the *train* split (``seg2pose.method.pipeline``; its views.csv is kept in
   ``ROUGH_STAGE/train-run`` and reused while the models are the same);
2. pseudo poses per view (``pseudo_poses``), in one of two flavours:
   - "track": each lens alone: its estimates fused per frame (one view: as they are) and
     smoothed along its tracks (``fuse(smooth=...)``, a centred line over +-``self_smooth``
     frames). A per-track height from one lens is not fitted: one camera cannot tell a wrong
     height (its track stays similar, ``seg2pose.method.track_heights``), so it would keep the
     default;
   - "views": all lenses together: one height per track from the lenses' disagreement
     (``apply_track_heights``), then fused over the lenses and smoothed along the track;
   - "fused": as "views" without the per-track heights (on the tuning seed the heights made
     the cars' pseudo poses worse, docs/RESULTS.md);
3. the network fine-tuned on them as if they were annotations (``labelled_examples``: the mask,
   its normal position at the class's default height, target = pseudo pose - normal position),
   for ``self_epochs`` epochs, starting from the rough-only weights, the rough-model examples
   kept in every batch (``rough_every`` as in the protocol); validation on the pseudo poses of
   15 % of the tracks, held out.

The fine-tuned models carry no radial offset (their targets include the calibration already)
and record how they were trained (``info["self_training"]``). Ground truth is never read.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seg2pose.core.digest import file_sha256
from seg2pose.core.errors import S2PError
from seg2pose.core.say import say
from seg2pose.io.run import ViewTable, read_run_meta, read_views
from seg2pose.io.scene import Scene
from seg2pose.method.checkpoint import Checkpoint, load_models
from seg2pose.method.features import N_GEO
from seg2pose.method.fusion import fuse
from seg2pose.method.net import NetConfig
from seg2pose.method.pipeline import RunOptions, compute_views, write_run
from seg2pose.training.config import ROUGH_STAGE, TrainConfig, TrainSettings, same_protocol
from seg2pose.training.examples import ExampleSet, labelled_examples
from seg2pose.training.train import TrainData, new_checkpoint, train_model, train_scene
from seg2pose.training.training_data import camera_groups, model_jobs

TRAIN_RUN = "train-run"       # their run on the train split (inside ROUGH_STAGE)
PSEUDO_PER_CLASS = 1500       # pseudo-labelled masks per lens and class (protocol sets no cap)
VAL_SHARE = 0.15              # share of the tracks whose pseudo poses validate


@dataclass
class PseudoLabels:
    """A pseudo pose per view: camera (N,) str, frame (N,) int, track_id (N,) int (>= 0),
    xy (N, 2) metres."""

    camera: np.ndarray
    frame: np.ndarray
    track_id: np.ndarray
    xy: np.ndarray

    def __len__(self) -> int:
        return len(self.frame)

    def lookup(self, camera: str, frame: np.ndarray, track_id: np.ndarray) -> np.ndarray:
        """(M, 2) the pseudo poses of ``camera``'s views (frame, track_id) (M,); NaN where
        there is none."""
        mine = np.flatnonzero(self.camera == camera)
        hit, at = _find(self.frame[mine], self.track_id[mine], frame, track_id)
        hit &= np.asarray(track_id) >= 0
        out = np.full((len(hit), 2), np.nan)
        out[hit] = self.xy[mine[at[hit]]]
        return out


def _keys(frame: np.ndarray, track_id: np.ndarray) -> np.ndarray:
    """One int64 per (frame, track id): frames and ids below 2**31."""
    return np.asarray(frame, np.int64) * (1 << 31) + np.asarray(track_id, np.int64)


def _find(frame: np.ndarray, track_id: np.ndarray, want_frame: np.ndarray,
          want_id: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where each wanted (frame, track id) (M,) is among the rows (frame, track_id) (N,):
    (found (M,) bool, its row (M,) int, meaningful where found)."""
    keys = _keys(frame, track_id)
    order = np.argsort(keys)
    want = _keys(want_frame, want_id)
    if not len(keys):
        return np.zeros(len(want), bool), np.zeros(len(want), np.int64)
    pos = np.clip(np.searchsorted(keys[order], want), 0, len(keys) - 1)
    return keys[order][pos] == want, order[pos]


def pseudo_poses(scene: Scene, views: ViewTable, flavour: str, smooth: int) -> PseudoLabels:
    """Pseudo poses for every tracked view with an estimate (see the module docstring):
    "track": per lens, its estimates smoothed along its tracks over +-``smooth`` frames;
    "views": per-track heights from all lenses, fused over them, smoothed likewise; "fused":
    fused over the lenses at the default heights, smoothed likewise."""
    if flavour == "views":
        from seg2pose.method.track_heights import DEFAULT_SETTINGS, apply_track_heights

        fitted, _, _ = apply_track_heights(scene, views, DEFAULT_SETTINGS)
        parts = [fitted]
    elif flavour == "fused":
        parts = [views]
    elif flavour == "track":
        parts = [views.of_cameras([c]) for c in np.unique(views.camera)]
    else:
        raise S2PError(f"unknown self-training flavour {flavour!r}; use 'track', 'fused' or 'views'")
    cols: list[tuple] = []
    for v in parts:
        poses = fuse(v, scene, smooth=smooth)  # per (frame, track id); confirm off: keep all
        tracked = poses.track_id >= 0
        use = np.flatnonzero((v.track_id >= 0) & np.isfinite(v.normal[:, :2] + v.residual).all(1))
        hit, at = _find(poses.frame[tracked], poses.track_id[tracked], v.frame[use], v.track_id[use])
        xy = poses.xyz[tracked][at[hit], :2]
        i = use[hit]
        cols.append((v.camera[i], v.frame[i], v.track_id[i], xy))
    if not cols:
        return PseudoLabels(np.zeros(0, object), np.zeros(0, np.int64), np.zeros(0, np.int64),
                            np.zeros((0, 2)))
    return PseudoLabels(*(np.concatenate(c) for c in zip(*cols)))


def unlabelled_split(scene: Scene) -> str | None:
    """The frames the pseudo poses come from: the train split, or all frames when the scene
    has no splits (as the radial calibration, ``calibrate_radial``)."""
    return "train" if "train" in scene.splits else None


def rough_stage_views(scene: Scene, stage_dir: Path, cams: list[str], progress: bool) -> ViewTable:
    """The rough-only models' views of ``cams`` on the train split (``unlabelled_split``;
    ``compute_views``), from
    ``stage_dir/train-run`` when that run was made by the same checkpoints and cameras, else
    computed and written there (a run folder: ``s2p eval`` can inspect it)."""
    split = unlabelled_split(scene)
    models = load_models(scene, cams, stage_dir)
    run_dir = stage_dir / TRAIN_RUN
    shas = sorted({file_sha256(Path(f)) for p in models.paths.values()
                   for f in (p if isinstance(p, list) else [p])})
    if (run_dir / "views.csv").exists():
        meta = read_run_meta(run_dir)
        if (sorted({m["sha256"] for m in meta.get("models", {}).values()}) == shas
                and meta.get("cameras") == cams and meta.get("split") == split):
            say(f"self-training: the rough-only models' train-split run {run_dir} reused")
            return read_views(run_dir / "views.csv")
    say(f"self-training: running the rough-only models on the {split or 'whole'} split of "
        f"{', '.join(cams)}")
    views, n = compute_views(scene, cams, scene.split_range(split), models, progress=progress)
    write_run(scene, run_dir, views, cams, models, n,
              RunOptions(models_dir=stage_dir, split=split, force=True, progress=progress))
    return views


def pseudo_examples(scene: Scene, cam: str, labels: PseudoLabels, classes: list[str],
                    val_tracks: np.ndarray, crop: int, factor: int, center_method: str,
                    cap: int, rng: np.random.Generator) -> tuple[ExampleSet, ExampleSet]:
    """(training, validation) examples from ``cam``'s train-split masks of ``classes`` that
    have a pseudo pose: the masks of the tracks ``val_tracks`` validate, at most ``cap`` masks
    per class (a random subset) train."""
    by_id = scene.class_by_id()
    rles, cls, xy, tid = [], [], [], []
    for _, t in scene.iter_masks(cam, scene.split_range(unlabelled_split(scene))):
        names = np.array([by_id[int(c)].name if int(c) in by_id else "" for c in t.class_id], object)
        p = labels.lookup(cam, t.frame, t.track_id)
        for i in np.flatnonzero(np.isfinite(p[:, 0]) & np.isin(names, classes)):
            rles.append(t.rles[i])
            cls.append(names[i])
            xy.append(p[i])
            tid.append(t.track_id[i])
    cam_ = scene.cameras[cam]
    cls_a, xy_a, tid_a = np.array(cls, object), np.array(xy, float).reshape(-1, 2), np.array(tid)
    is_val = np.isin(tid_a, val_tracks)
    parts = []
    for val in (False, True):
        sel = []
        for c in classes:
            s = np.flatnonzero((cls_a == c) & (is_val == val))
            k = cap if not val else max(1, int(round(cap * VAL_SHARE)))
            sel.append(np.sort(rng.choice(s, k, replace=False)) if len(s) > k else s)
        idx = np.sort(np.concatenate(sel)).astype(np.int64) if sel else np.zeros(0, np.int64)
        if not len(idx):  # e.g. a lens that saw no road user of these classes
            parts.append(ExampleSet.empty(crop // factor, factor))
            continue
        parts.append(labelled_examples(scene, cam, [rles[i] for i in idx], cam_.height, cam_.width,
                                       cls_a[idx], xy_a[idx], False, crop, factor, center_method,
                                       where=f"camera {cam}, pseudo poses"))
    return parts[0], parts[1]


def check_rough_stage(path: Path, cfg: TrainConfig) -> Checkpoint:
    """The finished rough-only checkpoint a self-trained model starts from; refused when it
    was trained with another protocol (e.g. copied from another variant's folder)."""
    ck = Checkpoint.load(path)
    if not ck.info.get("complete") or not same_protocol(ck.info.get("train_config"), cfg.rough_stage()):
        raise S2PError(f"{path} is not a finished rough-only model of this protocol; remove it "
                       "(or train with --force) to retrain it")
    return ck


def keep_rough_stage(start: Path, path: Path, classes: list[str], labels: PseudoLabels) -> str:
    """A model with no pseudo-labelled mask to self-train on (e.g. no track of its class in
    the train split): its finished rough-only model is copied into the model folder (marked
    ``self_training: {"skipped": ...}``) so that the other classes' models and ``s2p run``
    go on, and a re-run finds it done; says so in one line and returns it, short."""
    why = (f"no {'/'.join(classes)} track in the unlabelled split"
           if len(labels) else "no pseudo-labelled views at all")
    ck = Checkpoint.load(start)
    ck.info["self_training"] = {"skipped": why, "start": {"file": f"{ROUGH_STAGE}/{path.name}",
                                                           "sha256": file_sha256(start)}}
    ck.save(path)
    say(f"skipped self-training of {path.stem}: {why}; its rough-only model is kept", "warning")
    return f"{path.stem} ({why})"


def self_train_scene(scene: Scene, out: Path, cfg: TrainConfig, settings: TrainSettings,
                     cams: list[str], classes: list[str], progress: bool = True) -> None:
    """Fine-tune the rough-only models of ``out/ROUGH_STAGE`` on pseudo poses into ``out``
    (see the module docstring); finished models are skipped, interrupted ones resume."""
    stage = out / ROUGH_STAGE
    net_cfg = NetConfig.named(cfg.arch, len(scene.class_names) if cfg.share_classes else 0,
                              N_GEO if cfg.geometry else 0)
    ft = cfg.replace(epochs=cfg.self_epochs)  # the fine-tuning's loop (its cosine schedule too)
    cap = cfg.max_train_per_class or PSEUDO_PER_CLASS
    pseudo: tuple[PseudoLabels, np.ndarray] | None = None  # (labels, held-out track ids)
    skipped: list[str] = []
    for group in camera_groups(scene, cams, cfg.share_cameras):
        for job in model_jobs(scene, out, cfg, net_cfg, group, classes, None, settings.force):
            if pseudo is None:  # only when a model is still to train
                views = rough_stage_views(scene, stage, cams, progress)
                labels = pseudo_poses(scene, views, cfg.self_train, cfg.self_smooth)
                tracks = np.unique(labels.track_id)
                rng = np.random.default_rng(cfg.seed)
                val_tracks = rng.choice(tracks, int(round(VAL_SHARE * len(tracks))), replace=False)
                say(f"self-training ({cfg.self_train}): {len(labels)} pseudo-labelled views of "
                    f"{len(tracks)} tracks ({len(val_tracks)} held out for validation)")
                pseudo = (labels, val_tracks)
            labels, val_tracks = pseudo
            rough = job.rough  # self-training is zero-annotation: every job has its rough pool
            assert rough is not None
            start = check_rough_stage(stage / job.path.name, cfg)
            kcls = scene.class_names if job.key == "*" else [job.key]
            rng = np.random.default_rng([cfg.seed, sum(map(ord, job.path.name))])
            tr, va = zip(*(pseudo_examples(scene, c, labels, kcls, val_tracks, net_cfg.crop,
                                           net_cfg.downsample, cfg.center_method, cap, rng)
                           for c in job.cameras))
            job.train, val = ExampleSet.concat(list(tr)), ExampleSet.concat(list(va))
            if len(val):
                job.val = val  # else the rough models validate (as for the rough stage)
            if not len(job.train):
                skipped.append(keep_rough_stage(stage / job.path.name, job.path, kcls, labels))
                continue
            say(f"{job.path.stem}: self-training on {len(job.train)} pseudo-labelled + "
                f"{len(rough)} rough examples, {len(job.val)} validation")
            ck = new_checkpoint(scene, job, cfg, settings, net_cfg, scene.class_names,
                                ExampleSet.concat([job.train, rough]))
            ck.info["self_training"] = {
                "flavour": cfg.self_train, "epochs": cfg.self_epochs, "smooth": cfg.self_smooth,
                "split": unlabelled_split(scene), "n_pseudo": len(job.train),
                "start": {"file": f"{ROUGH_STAGE}/{job.path.name}",
                          "sha256": file_sha256(stage / job.path.name),
                          "radial_offset": start.info.get("radial_offset")}}

            def data(ex: ExampleSet) -> TrainData:
                return TrainData.of(ex, job.norm, scene.class_names, job.key == "*", cfg.geometry)

            init = {k: v.detach().cpu() for k, v in start.net.state_dict().items()}
            train_model(data(job.train), data(rough), data(job.val), net_cfg, ft, ck,
                        job.path, progress, None, settings, init=init)
    if skipped:  # once more at the end of a long run, where the user looks
        say("self-training finished; skipped (rough-only model kept): " + "; ".join(skipped))


def train_self_trained(scene: Scene, out: str | Path | None, cfg: TrainConfig,
                       cameras: list[str] | None = None, classes: list[str] | None = None,
                       progress: bool = True, map_groups=None,
                       settings: TrainSettings | None = None) -> Path:
    """``s2p train --self-train``, with ``train_scene``'s arguments: the rough-only models first
    (``out/ROUGH_STAGE``, by ``train_scene``; skipped when finished), then the fine-tuning on
    pseudo poses of the scene's unlabelled train split (one model after another:
    ``map_groups`` fans out the first stage only). ``out``: default ``scene.root / "models"``.
    Returns ``out``."""
    settings = settings or TrainSettings()
    out = Path(out) if out else scene.root / "models"
    train_scene(scene, out / ROUGH_STAGE, cfg.rough_stage(), cameras, classes, progress,
                map_groups, settings)
    self_train_scene(scene, out, cfg, settings, cameras or list(scene.cameras),
                     classes or scene.class_names, progress)
    return out
