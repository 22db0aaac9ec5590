"""The background-subtraction settings of ``s2p masks-from-video`` (``BgConfig``): what each
knob does, its default and why, and the one-line errors for a bad value in ``scene.json``'s
``extra.video_masks``. The model itself is ``seg2pose.video.video_masks``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

from seg2pose.core.errors import InputError
from seg2pose.io.schema import Num, OneOf, read_settings


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
        """Settings from scene.json's ``extra.video_masks`` merged with ``--set``, each value
        checked against ``BG_LIMITS`` (``io.schema.read_settings``: an unknown key, a value of
        another type, nan or one out of range is one line naming the setting)."""
        out = read_settings(cls(), d, BG_LIMITS, file=file, section="video_masks")
        out.validate(file)
        return out

    def validate(self, file: Path | None = None) -> None:
        """The rules a range cannot say (on top of ``BG_LIMITS``)."""
        if not (self.learning_rate == -1 or 0 <= self.learning_rate <= 1):
            raise InputError("must be in [0, 1], or -1 for 1/history", file=file,
                             field="extra.video_masks.learning_rate")

    def to_dict(self) -> dict:
        return asdict(self)


BG_LIMITS = {"method": OneOf(("mog2", "knn")), "init": OneOf(("mode", "median", "warmup", "none")),
             "update": OneOf(("selective", "all", "none")),
             **{k: Num(1) for k in ("history", "init_samples", "update_every")},
             **{k: Num(0) for k in ("open_px", "close_px", "min_area", "init_frames", "ghost_after")},
             "shadow_texture": Num(0, 1), "ghost_ratio": Num(1, lo_open=True),
             "threshold": Num(0, lo_open=True), "learning_rate": Num(-1, 1),
             "unsettled": Num(0, 1, lo_open=True), "exposure_band": Num(0, 0.999)}
