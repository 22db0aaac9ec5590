"""Assembling the training data of a scene's models (paper 4.1), separate from the training loop.

``model_jobs`` yields one ``ModelJob`` per model still to train: which cameras and classes it
serves, its input normalisation, its annotated training and validation examples (masks matched
to ground truth) and its pool of rough-model examples (3.5). Models finished already (metadata
"complete") are skipped unless the configuration forces retraining.
"""

from __future__ import annotations

import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seg2pose.core.errors import S2PError
from seg2pose.core.say import say
from seg2pose.io.poses import CHECKED_KEYFRAME_SOURCES, TRUSTED_SOURCES, PoseTable
from seg2pose.io.scene import Scene
from seg2pose.method.checkpoint import Checkpoint, model_filename
from seg2pose.method.net import NetConfig, Normalisation
from seg2pose.training import rough_video
from seg2pose.training.config import TrainConfig
from seg2pose.training.examples import ExampleSet, annotated_examples, rough_examples


@dataclass
class ModelJob:
    """One model to train. key: its class name, or '*' for all classes (class one-hot input);
    camera: its camera name, or '*' for all ``cameras`` of the device; train: annotated
    training examples (empty for zero-annotation training); rough: the rough-model pool
    (None when the protocol uses none); val: validation examples."""

    key: str
    camera: str
    cameras: list[str]
    path: Path
    norm: Normalisation
    train: ExampleSet
    rough: ExampleSet | None
    val: ExampleSet


def holdout(ex: ExampleSet, frac: float, rng: np.random.Generator) -> tuple[ExampleSet, ExampleSet]:
    """A random ``frac`` of the examples held out for validation: (rest, held out)."""
    perm = rng.permutation(len(ex))
    k = int(round(frac * len(ex)))
    return ex.take(np.sort(perm[k:])), ex.take(np.sort(perm[:k]))


def camera_groups(scene: Scene, cams: list[str], share_cameras: bool) -> list[tuple[str, list[str]]]:
    """(model camera key, cameras) per model: one for all cameras ('*') or one per camera."""
    if not share_cameras:
        return [(c, [c]) for c in cams]
    sizes = {(scene.cameras[c].width, scene.cameras[c].height) for c in cams}
    if len(sizes) > 1:
        raise S2PError(f"one model for all cameras needs one image size, got {sorted(sizes)}")
    return [("*", cams)]


def _pending(out: Path, gkey: str, keys: list[str], fp: str, force: bool) -> list[tuple[str, Path]]:
    """The (class key, checkpoint path) of the group's models not finished yet (all of them
    with ``force``)."""
    todo = []
    for k in keys:
        path = out / model_filename(gkey, k)
        if path.exists() and not force and not path.with_name(path.name + ".state.pt").exists():
            meta = Checkpoint.load(path)
            if meta.info.get("complete"):
                if meta.scene_fingerprint != fp:
                    say(f"{path} was trained on another scene; retrain it to replace it", "warning")
                say(f"{path.name}: done already (val loss {meta.info.get('val_loss'):.4f}); skipped")
                continue
        todo.append((k, path))
    return todo


def truth_sources(cfg: TrainConfig) -> tuple[str, ...]:
    """The ``source`` values of annotated truth that training uses (never ``occluded``)."""
    if cfg.annotated_rows not in ("interpolated", "keyframes"):
        raise ValueError(f"annotated_rows must be 'interpolated' or 'keyframes', got {cfg.annotated_rows!r}")
    # provenance (io/poses.py): checked keyframes, or those and the rows between them; never
    # unchecked estimates
    return CHECKED_KEYFRAME_SOURCES if cfg.annotated_rows == "keyframes" else TRUSTED_SOURCES


def _annotated(scene: Scene, gcams: list[str], gt: PoseTable | None, cfg: TrainConfig,
               crop: int, factor: int, rng: np.random.Generator) -> tuple[ExampleSet, ExampleSet]:
    """Annotated (training, validation) examples of the cameras ``gcams``: the train and val
    splits, or 15 % of the training examples held out when the scene has no val split."""
    empty = ExampleSet.empty(crop // factor, factor)
    if gt is None:
        return empty, empty
    tr_parts, va_parts = [], []
    for cam in gcams:
        say(f"camera {cam}: building examples from the annotated masks")
        has_splits = "train" in scene.splits
        tr = annotated_examples(scene, cam, gt, "train" if has_splits else None, crop, factor,
                                cfg.center_method, cfg.max_train_per_class, rng=rng,
                                augment=cfg.augment if has_splits else 0,
                                sources=truth_sources(cfg))
        if has_splits and "val" in scene.splits:
            va = annotated_examples(scene, cam, gt, "val", crop, factor, cfg.center_method,
                                    cfg.max_val_per_class, rng=rng, sources=truth_sources(cfg))
        else:
            say(f"camera {cam}: no val split; holding out 15% of the training examples")
            tr, va = holdout(tr, 0.15, rng)
        tr_parts.append(tr)
        va_parts.append(va)
    return ExampleSet.concat(tr_parts), ExampleSet.concat(va_parts)


def films_rough(scene: Scene, cam: str, cfg: TrainConfig) -> bool:
    """Whether the camera's rough models are filmed and background-subtracted
    (``cfg.rough_video``, for cameras with a video)."""
    return bool(cfg.rough_video) and scene.video_path(cam) is not None


def rough_looks(scene: Scene, cams: list[str], cfg: TrainConfig) -> dict:
    """Camera -> ``rough_video.VideoLook`` for the cameras whose rough models are filmed
    (``films_rough``)."""
    out = {}
    for cam in cams:
        if films_rough(scene, cam, cfg):
            say(f"camera {cam}: rough models filmed over the video's background and "
                "background-subtracted like its masks")
            out[cam] = rough_video.video_look(scene, cam)
    return out


def model_jobs(scene: Scene, out: Path, cfg: TrainConfig, net_cfg: NetConfig, group: tuple[str, list[str]],
               classes: list[str], gt: PoseTable | None, force: bool = False) -> Iterator[ModelJob]:
    """The models of one camera group (``camera_groups``) x ``classes`` still to train (all
    of them with ``force``), with
    their examples (built lazily, one model at a time, so memory holds one model's rough pool).
    A group's examples depend on no other group (own random stream), so groups may be trained
    in any order or in parallel."""
    crop, factor = net_cfg.crop, net_cfg.downsample
    fp = scene.fingerprint()
    gkey, gcams = group
    camera = scene.cameras[gcams[0]]
    norm = Normalisation.for_scene(scene.ground_points, camera.width, camera.height,
                                   cfg.residual_scale)
    todo = _pending(out, gkey, ["*"] if cfg.share_classes else classes, fp, force)
    if not todo:
        return
    rng = np.random.default_rng([cfg.seed, sum(map(ord, gkey))])
    train_ex, val_ex = _annotated(scene, gcams, gt, cfg, crop, factor, rng)
    looks = rough_looks(scene, gcams, cfg)

    def rough_pool(classes_: list[str], n: int, rng: np.random.Generator) -> ExampleSet:
        return ExampleSet.concat([rough_examples(scene, cam, c, n, rng, crop, factor,
                                                 cfg.center_method,
                                                 detector_noise=cfg.rough_detector_noise,
                                                 occlusion=cfg.rough_occlusion, look=looks.get(cam),
                                                 random_sizes=cfg.rough_random)
                                  for cam in gcams for c in classes_])

    for k, path in todo:
        kcls = classes if k == "*" else [k]
        # each model's rough pool from its own stream: a resumed training (finished models
        # skipped) draws the same examples as an uninterrupted one
        mrng = np.random.default_rng([cfg.seed, zlib.crc32(gkey.encode()), zlib.crc32(k.encode())])
        tr = train_ex.take(np.flatnonzero(np.isin(train_ex.cls, kcls)))
        va = val_ex.take(np.flatnonzero(np.isin(val_ex.cls, kcls)))
        rough = None
        if cfg.zero_annotation or cfg.rough_every > 0:
            rough = rough_pool(kcls, cfg.rough_per_class, mrng)
        if cfg.zero_annotation or len(va) == 0:
            if not cfg.zero_annotation:
                say(f"{path.stem}: no annotated validation examples; validating on rough models",
                    "warning")
            va = rough_pool(kcls, cfg.rough_val_per_class, mrng)
        if len(tr) == 0 and not cfg.zero_annotation:
            if rough is None or len(rough) == 0:
                say(f"{path.stem}: no training examples at all; skipped", "warning")
                continue
            say(f"{path.stem}: no annotated examples; training on rough models only", "warning")
        if len(va) == 0:
            say(f"{path.stem}: no validation examples; skipped", "warning")
            continue
        yield ModelJob(k, gkey, gcams, path, norm, tr, rough, va)
