"""The background-subtraction settings of ``s2p masks-from-video`` (``BgConfig``): what each
knob does, its default and why, and the one-line errors for a bad value in ``scene.json``'s
``extra.video_masks``. The model itself is ``seg2pose.video.video_masks``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from pathlib import Path

from seg2pose.core.errors import InputError


@dataclass
class BgConfig:
    """Background-subtraction settings (``scene.json`` ``extra.video_masks`` overrides them).
    The defaults were chosen on synthetic ``--video`` scenes of seeds 101-102 (docs/RESULTS.md):
    the selective update and a 5 px closing instead of OpenCV's own update and 7 px."""

    method: str = "mog2"          # mog2 | knn
    history: int = 500            # frames the model remembers
    threshold: float = 16.0       # MOG2 varThreshold (squared Mahalanobis); KNN dist2Threshold
    shadows: bool = True          # detect shadows and drop their pixels
    shadow_texture: float = 0.3   # a "shadow" pixel whose 5x5 neighbourhood correlates less
    #                               than this with the background's texture is foreground (a
    #                               dark car body, not a shadow); 0: OpenCV's shadow test only
    texture_near: bool = True     # the masks also take pixels next to foreground that MOG2
    #                               calls background but that lack the background's texture
    init: str = "mode"            # mode | median (background image from samples) | warmup | none
    init_frames: int = 0          # frames the mode / median / warm-up looks at (0: the whole video)
    init_samples: int = 25        # images in the mode / median
    learning_rate: float = -1.0   # how fast the model follows changes after the start; -1: 1/history
    update: str = "selective"     # selective: learn only pixels away from the foreground (road
    #                               users that stop are not absorbed); all: every pixel (OpenCV's
    #                               own update); none: keep the starting background
    update_every: int = 10        # frames between two selective updates (each learns that many)
    ghost_after: int = 30         # foreground this many frames without a break is tested for a
    #                               ghost (a road user of the starting background that left);
    #                               0: never
    clean_start: bool = True      # mode or median start: a first pass over the video (every
    #                               update_every-th frame) learns the empty road where a road user
    #                               of the start leaves; the masks start from that background
    ghost_ratio: float = 2.0      # a ghost's outline has this many times the edge strength in the
    #                               background image as in the frame
    open_px: int = 3              # opening kernel (pixels): removes noise specks
    close_px: int = 5             # closing kernel (pixels): joins fragments of one road user
    min_area: int = 150           # smallest instance, pixels
    unsettled: float = 0.3        # foreground share of the image that means "background not settled"
    exposure_band: float = 0.03   # a frame whose ground is brighter or darker than the model's by
    #                               more than this share (a cloud over the sun, the camera's
    #                               auto-exposure) is scaled to the model's brightness first; 0: never

    @classmethod
    def from_dict(cls, d: dict | None, file: Path | None = None) -> BgConfig:
        d = d or {}
        names = {f.name: f.type for f in fields(cls)}
        out = cls()
        for k, v in d.items():
            if k not in names:
                raise InputError(f"unknown setting {k!r}; known: {', '.join(names)}", file=file,
                                 field=f"extra.video_masks.{k}")
            default = getattr(out, k)
            ok = (isinstance(v, type(default)) or (isinstance(default, float) and isinstance(v, int))) \
                and not (isinstance(v, bool) and not isinstance(default, bool))
            if not ok or (isinstance(v, float) and not math.isfinite(v)):  # nan: every test fails
                raise InputError(f"expected {'a finite ' if ok else ''}{type(default).__name__}, got {v!r}",
                                 file=file, field=f"extra.video_masks.{k}")
            setattr(out, k, type(default)(v))
        out.validate(file)
        return out

    def validate(self, file: Path | None = None) -> None:
        def bad(k, msg):
            raise InputError(msg, file=file, field=f"extra.video_masks.{k}")
        if self.method not in ("mog2", "knn"):
            bad("method", f"expected mog2 or knn, got {self.method!r}")
        if self.init not in ("mode", "median", "warmup", "none"):
            bad("init", f"expected mode, median, warmup or none, got {self.init!r}")
        if self.update not in ("selective", "all", "none"):
            bad("update", f"expected selective, all or none, got {self.update!r}")
        for k in ("history", "init_samples", "update_every"):
            if getattr(self, k) < 1:
                bad(k, "must be >= 1")
        for k in ("open_px", "close_px", "min_area", "init_frames", "ghost_after"):
            if getattr(self, k) < 0:
                bad(k, "must be >= 0")
        if not 0 <= self.shadow_texture <= 1:
            bad("shadow_texture", "must be in [0, 1]")
        if not self.ghost_ratio > 1:
            bad("ghost_ratio", "must be > 1")
        if not self.threshold > 0:
            bad("threshold", "must be > 0")
        if not (self.learning_rate == -1 or 0 <= self.learning_rate <= 1):
            bad("learning_rate", "must be in [0, 1], or -1 for 1/history")
        if not 0 < self.unsettled <= 1:
            bad("unsettled", "must be in (0, 1]")
        if not 0 <= self.exposure_band < 1:
            bad("exposure_band", "must be in [0, 1)")

    def to_dict(self) -> dict:
        return asdict(self)
