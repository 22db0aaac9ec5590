"""The training configuration, in two parts: the protocol (``TrainConfig``: paper 4.1 and its
CPU presets; what the models depend on) and the run-time settings (``TrainSettings``: device,
threads, force; how this machine trains them). Resuming an interrupted training and skipping
finished models compare the protocol only (``same_protocol``), so a training resumed with
another ``--threads`` or ``--device`` continues.

The presets' reasons and measurements are in ``seg2pose.training.train``'s docstring and
docs/RESULTS.md.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace
from typing import Literal, get_args

from seg2pose.core.errors import InputError
from seg2pose.geometry.normal import CENTER_METHODS, DEFAULT_CENTER_METHOD
from seg2pose.method.net import ARCHS

LrSchedule = Literal["constant", "cosine"]
Loss = Literal["mse", "euclid"]
SELF_TRAIN = ("", "track", "fused", "views")  # self-training flavours (seg2pose.training.self_training)
ROUGH_STAGE = "rough-stage"  # sub-folder of a self-training's rough-only models


@dataclass(frozen=True)
class TrainSettings:
    """How this machine trains (not part of the protocol: the models do not depend on it)."""

    device: str | None = None  # torch device (default: cuda if present)
    threads: int = 2           # CPU threads for torch
    force: bool = False        # retrain finished models; ignore resume states


@dataclass(frozen=True)
class TrainConfig:
    """The training protocol: everything the trained models depend on."""

    arch: str = "paper"
    runs: int = 4                    # best of N
    seed: int = 0                    # run r uses seed + r (the same for every camera)
    lr: float = 5e-5
    lr_schedule: LrSchedule = "constant"  # or "cosine" (decay to 5% over each run)
    batch_size: int = 16
    batches_per_epoch: int = 64
    epochs: int = 50
    rough_every: int = 4             # every 4th example rough (0: none)
    rough_per_class: int = 2048      # size of the pre-rendered rough pool per camera and class
    rough_val_per_class: int = 256   # zero-annotation validation pool
    zero_annotation: bool = False
    radial_calibration: bool = True  # zero-annotation only: see calibrate_radial
    rough_detector_noise: bool = False  # make rough masks detector-like (examples.detector_like)
    rough_occlusion: float = 0.0     # share of rough examples partly hidden by a rough occluder
    rough_random: bool = False       # rough models' sizes drawn per example from ranges per class
    # rough models filmed over the video's background and background-subtracted like its masks
    # (seg2pose.training.rough_video); off: measured worse than clean silhouettes (docs/RESULTS.md)
    rough_video: bool = False
    share_classes: bool = False      # one model per camera with a class one-hot input
    share_cameras: bool = False      # one model for all cameras (lenses of one device)
    geometry: bool = False           # append the mask-geometry features (seg2pose.method.features)
    augment: int = 0                 # changed copies per annotated training mask (seg2pose.training.augment)
    # annotated truth (gt/poses.csv with a source column): "interpolated" trains on keyframes and
    # the frames interpolated between them, "keyframes" on keyframes alone; occluded rows never
    annotated_rows: str = "interpolated"
    max_train_per_class: int | None = None
    max_val_per_class: int | None = 2000
    loss: Loss = "mse"               # "mse" (squared error / 2) or "euclid" (distance, = the metric)
    center_method: str = DEFAULT_CENTER_METHOD
    residual_scale: float = 1.0
    # self-training (zero-annotation only; seg2pose.training.self_training): after the rough-only
    # models and their radial calibration, pseudo poses from the scene's own unlabelled train
    # split -- "track": each lens's estimates smoothed along its tracks; "views": the lenses'
    # estimates at per-track heights, fused and smoothed; "fused": the same at the default
    # heights -- then ``self_epochs`` epochs of fine-tuning on them, starting from the
    # rough-only weights ("": none). Measured in docs/RESULTS.md, "Self-training on the scene's own tracks"
    self_train: str = ""
    self_epochs: int = 10
    self_smooth: int = 4             # half window (frames) of the pseudo poses' smoothing

    def __post_init__(self) -> None:
        for name, allowed in (("arch", ARCHS + ("lite_hr",)), ("lr_schedule", get_args(LrSchedule)),
                              ("loss", get_args(Loss)), ("center_method", CENTER_METHODS)):
            if getattr(self, name) not in allowed:
                raise InputError(f"unknown {name} {getattr(self, name)!r}; use one of "
                                 f"{', '.join(a for a in allowed if a != 'lite_hr')}", field=name)
        if self.self_train not in SELF_TRAIN:
            raise InputError(f"unknown self_train {self.self_train!r}; use one of "
                             f"{', '.join(repr(a) for a in SELF_TRAIN)}", field="self_train")
        if self.self_train and not self.zero_annotation:
            raise InputError("self-training (--self-train) is a zero-annotation step; add "
                             "--zero-annotation", field="self_train")
        if self.self_smooth < 0:
            raise InputError(f"self_smooth must be 0 or more, got {self.self_smooth}",
                             field="self_smooth")
        for name in ("runs", "epochs", "batch_size", "batches_per_epoch", "self_epochs"):
            if int(getattr(self, name)) < 1:
                raise InputError(f"{name} must be at least 1, got {getattr(self, name)}", field=name)

    def replace(self, **kw) -> TrainConfig:
        return replace(self, **kw)

    def rough_stage(self) -> TrainConfig:
        """The protocol of a self-training's first stage: the rough-only models it starts from
        (the same protocol without the self-training fields)."""
        return replace(self, self_train="", self_epochs=TrainConfig.self_epochs,
                       self_smooth=TrainConfig.self_smooth)

    @classmethod
    def paper(cls, arch: str = "paper") -> TrainConfig:
        return cls(arch=arch)

    @classmethod
    def quick(cls) -> TrainConfig:
        """The CPU protocol of docs/RESULTS.md: one ``lite-hr`` model with the mask-geometry
        features per class (the paper's layout) shared by all lenses of the device, one run of
        30 epochs, half of every batch rough-model examples from a pool of 1,500 per lens and
        class (they regularise: the annotated split is small); about 8 minutes on 2 cores for
        the three classes; the best of the CPU variants measured there."""
        return cls(arch="lite-hr", geometry=True, runs=1, lr=1e-3, lr_schedule="cosine", batch_size=32,
                   batches_per_epoch=64, epochs=30, rough_every=2, rough_per_class=1500,
                   rough_val_per_class=40,
                   share_classes=False, share_cameras=True, max_val_per_class=100)

    @classmethod
    def long(cls) -> TrainConfig:
        """``quick`` trained twice as long (60 epochs), a quarter of every batch rough-model
        examples (the paper's share): for a scene with a thousand or more annotated frames per
        split, where the rough examples matter less; about twice quick's time. Chosen on the
        960-frame tuning scene (docs/RESULTS.md, "Learning curve"), measured held out there."""
        return cls.quick().replace(epochs=60, rough_every=4)

    @classmethod
    def demo(cls) -> TrainConfig:
        """The demo's protocol: lite, one model for all five lenses and three classes, in
        about 2 minutes of training on a 2-core CPU (docs/RESULTS.md)."""
        return cls(arch="lite", runs=1, lr=1.5e-3, lr_schedule="cosine", batch_size=32,
                   batches_per_epoch=64, epochs=18, rough_per_class=100, rough_val_per_class=20,
                   share_classes=True, share_cameras=True, max_train_per_class=1000,
                   max_val_per_class=40)


RUN_TIME = tuple(f.name for f in fields(TrainSettings))


def training_record(cfg: TrainConfig, settings: TrainSettings) -> dict:
    """The protocol and the settings as one record (checkpoints' ``train_config``, resume
    states' ``config``): the protocol's fields, then the settings'."""
    return {**asdict(cfg), **asdict(settings)}


def same_protocol(record: dict | None, cfg: TrainConfig) -> bool:
    """Whether a stored ``training_record`` (or an older whole-config record) is of protocol
    ``cfg``; the run-time settings in it are not compared. Fields added since the record was
    written (``LATER_FIELDS``) count as their defaults, so the self-training fields do not make
    older rough-only trainings another protocol."""
    if not isinstance(record, dict):
        return False
    stored = {k: v for k, v in record.items() if k not in RUN_TIME}
    for f in fields(TrainConfig):
        if f.name in LATER_FIELDS:
            stored.setdefault(f.name, f.default)
    return stored == asdict(cfg)


LATER_FIELDS = ("self_train", "self_epochs", "self_smooth")
