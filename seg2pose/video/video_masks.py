"""Instance masks from a static camera's video by background subtraction.

Per frame: OpenCV MOG2 (or KNN) with shadow detection -> foreground without shadow pixels
(OpenCV marks shadows 127, foreground 255), except "shadows" that do not keep the background's
texture (a flat dark car body passes OpenCV's brightness-and-colour test; ``shadow_texture``)
-> morphological opening (speckle) and closing
(joins a road user's fragments) -> connected components of at least ``min_area`` pixels ->
one instance mask per component, as COCO RLE. Track ids (-1) and classes (0) are left for the
tracker and the size classes (``seg2pose.video.track``, ``seg2pose.video.classify``).

The background model starts from the per-pixel mode of frames sampled over the first
``init_frames`` (``bg_start.mode_image``: the colour most samples agree on; road users that pass do not
survive it, parked ones are background, as they should be; ``init="median"``: the per-pixel
median, which a queue of different cars occupying a lane in most samples turns into a smear),
fed to the subtractor before the first real frame, so the first frames are
usable; ``init="warmup"`` instead runs the subtractor over the first frames once and restarts.
Afterwards the model learns selectively (``update="selective"``): every ``update_every``
frames, the frame with the foreground, shadows and a margin around them replaced by the
model's own background image. Lighting that drifts is followed; a road user that stops (at a
red light, a curb) stays foreground instead of being absorbed, as OpenCV's own update does
within a few seconds; a frame that is mostly foreground (a light change) is learnt whole. A
frame whose ground is brighter or darker than the model's (a cloud, auto-exposure) is first
scaled to the model's brightness (``exposure_band``).
Foreground that lasts ``ghost_after`` frames is tested for a *ghost* (the place a road user of
the starting background has left: its outline is in the background image, not in the frame,
and it lies in quiet, textured road) and a ghost's pixels are learnt at once (``ghost_mask``).
Road users standing for most of the video are in the mode; so by default a first pass over
the video (every ``update_every``-th frame, which is all the selective model learns from) finds
the ghosts, and the masks start from the mode with the empty road put back where they were
(``clean_background``, ``clean_start``): the video is read twice, never held.

Frames are streamed (one image in memory, plus the initial samples); a truncated video keeps
what was read and says where it stopped. When the foreground covers more than ``unsettled`` of
the image (a moving camera, a sudden light change), the frame range is reported.

Pixels: x right, y down, origin at the top-left corner of the top-left pixel.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from seg2pose.core.errors import InputError
from seg2pose.io.mots import MaskTable, write_mots
from seg2pose.io.video import FrameReader
from seg2pose.structures.rle_runs import labels_to_rles
from seg2pose.video.bg_checks import (
    exposure_ratio,
    flat_pixels,
    ghost_mask,
    grey_mean,
    still_pixels,
    texture_stats,
    to_exposure,
)
from seg2pose.video.bg_config import BgConfig
from seg2pose.video.bg_start import SAMPLED, start_image

SHADOW = 127  # OpenCV's shadow label in MOG2/KNN output
# ghosts are tested down to min_area / GHOST_AREA pixels: the part of a ghost that has lasted
# (its core) is smaller than the mask the closing and the texture test make of it (seed 104,
# c0: a 140 px core, the start's dark tyre patch, under a mask of over 150 px for 100 frames)
GHOST_AREA = 4


@dataclass
class VideoMasksResult:
    """What ``masks_from_video`` did: frames and masks written, where reading stopped."""

    n_frames: int = 0
    n_masks: int = 0
    first_frame: int | None = None
    last_good: int | None = None
    stopped: str | None = None                     # why reading ended early, else None
    unsettled: list[tuple[int, int]] = field(default_factory=list)  # frame ranges (inclusive)
    n_rescaled: int = 0  # frames scaled to the model's brightness (``BgConfig.exposure_band``)


class BackgroundMasks:
    """Stateful per-frame segmenter: ``apply(image) -> (rles, foreground share)``."""

    def __init__(self, cfg: BgConfig, height: int, width: int):
        import cv2

        self.cfg = cfg
        self.height, self.width = height, width
        if cfg.method == "mog2":
            self.sub = cv2.createBackgroundSubtractorMOG2(cfg.history, cfg.threshold, cfg.shadows)
        else:
            self.sub = cv2.createBackgroundSubtractorKNN(cfg.history, cfg.threshold * 25.0,  # type: ignore[assignment]  # both BackgroundSubtractors
                                                         cfg.shadows)
        self.lr = -1.0
        self.primed = False        # a background to start from (else OpenCV's own learning)
        self.n_applied = 0
        ell = cv2.MORPH_ELLIPSE
        # pixels this close to the foreground are not learnt by a selective update (a road
        # user's blurred edge, the part of its shadow nearest to it)
        self.k_hold = cv2.getStructuringElement(ell, (15, 15))
        self.k_ghost = cv2.getStructuringElement(ell, (7, 7))  # a ghost's blurred edge
        self.fg_age: np.ndarray | None = None  # frames each pixel has been foreground (updates)
        self._bg_tex: tuple | None = None       # background grey, box mean, box variance
        self.n_ghosts = 0                       # ghosts learnt away
        self.ghost_seen: np.ndarray | None = None  # (H, W) bool: pixels a ghost was learnt at
        # (H, W, 3) uint8: each ghost pixel's colour in the frame it was learnt from (the empty
        # road as seen then; see clean_background)
        self.ghost_image: np.ndarray | None = None
        self._prev_grey: np.ndarray | None = None  # the previous update's frame, grey 5x5 mean
        self.n_rescaled = 0                     # frames scaled to the model's brightness
        self._last_fg: np.ndarray | None = None  # (H, W) uint8: the previous frame's foreground
        self.k_open = cv2.getStructuringElement(ell, (cfg.open_px,) * 2) if cfg.open_px > 1 else None
        self.k_close = cv2.getStructuringElement(ell, (cfg.close_px,) * 2) if cfg.close_px > 1 else None

    def prime(self, images: list[np.ndarray]) -> None:
        """Start the model from a median background of ``images`` (or learn them in order)."""
        if not images:
            return
        self.primed = True
        if self.cfg.init in SAMPLED:
            bg = start_image(images, self.cfg.init, self.cfg.exposure_band)
            # enough repetitions for a confident model; afterwards learn at the history's rate
            self.sub.apply(bg, learningRate=1.0)
            self._bg_tex = None
            for _ in range(min(self.cfg.history, 50)):
                self.sub.apply(bg)
            self.lr = self.cfg.learning_rate if self.cfg.learning_rate >= 0 else 1.0 / self.cfg.history
        else:
            self.lr = self.cfg.learning_rate  # warm-up / none: OpenCV's own rate unless set
            for im in images:
                self.sub.apply(im)

    def apply(self, image: np.ndarray) -> tuple[list[bytes], float]:
        import cv2

        cfg = self.cfg
        image = self._exposed(image)
        learn = self.lr if cfg.update == "all" or not self.primed else 0.0
        raw = self.sub.apply(image, learningRate=learn)
        if learn != 0:
            self._bg_tex = None
        self.n_applied += 1
        share = float(np.count_nonzero(raw > SHADOW)) / raw.size
        fg = self._foreground(image, raw)
        self._last_fg = fg
        if self.primed and cfg.update == "selective" and self.n_applied % cfg.update_every == 0:
            # a frame that is mostly foreground is a changed scene (light, a moved camera),
            # not road users: it is learnt whole, so that the model settles again
            self._learn_background(image, fg, whole=share > cfg.unsettled, raw=raw)
        if cfg.texture_near and cfg.shadows and cfg.shadow_texture > 0:
            # output only: with these pixels in the foreground that the model learns from and
            # tests for ghosts, seed 102 lost ghosts (recall 0.779 instead of 0.821)
            near = np.zeros_like(fg)
            flat_pixels(image, raw, self._texture(), near, near_background=True)
            if near.any():
                fg |= near
                if self.k_close is not None:
                    fg = cv2.morphologyEx(fg, cv2.MORPH_CLOSE, self.k_close)
        # labels only, areas by bincount: OpenCV's WithStats variant is several times slower here
        n, labels = cv2.connectedComponents(fg, connectivity=8, ltype=cv2.CV_32S)
        if n <= 1:
            return [], share
        area = np.bincount(labels[fg.view(bool)], minlength=n)  # foreground pixels only
        ids = np.flatnonzero(area >= max(self.cfg.min_area, 1))
        ids = ids[ids > 0]
        return labels_to_rles(labels, ids), share

    def _foreground(self, image: np.ndarray, raw: np.ndarray) -> np.ndarray:
        """(H, W) uint8 0/1 cleaned foreground of the subtractor's output ``raw``: foreground,
        plus the shadow pixels that are not shadows by their texture (``flat_pixels``), then
        opening and closing."""
        import cv2

        fg = (raw > SHADOW).astype(np.uint8)
        if self.cfg.shadows and self.cfg.shadow_texture > 0:
            flat_pixels(image, raw, self._texture(), fg)
        if self.k_open is not None:
            fg = cv2.morphologyEx(fg, cv2.MORPH_OPEN, self.k_open)
        if self.k_close is not None:
            fg = cv2.morphologyEx(fg, cv2.MORPH_CLOSE, self.k_close)
        return fg

    def _exposed(self, image: np.ndarray) -> np.ndarray:
        """``image`` scaled to the model's brightness when its ground is brighter or darker
        than the model's background by more than ``exposure_band`` (a cloud over the sun, the
        camera's auto-exposure: the whole frame changes, and without this the bright road
        markings and pavement turn foreground); otherwise ``image`` itself. The model keeps the
        light it learnt; the selective update follows what the scaling leaves."""
        band = self.cfg.exposure_band
        if band <= 0 or not self.primed:
            return image
        out = to_exposure(image, exposure_ratio(image, self._texture()[0], self._last_fg), band)
        self.n_rescaled += out is not image
        return out

    def _texture(self) -> tuple:
        """``texture_stats`` of the model's background image, kept until the model learns."""
        if self._bg_tex is None:
            self._bg_tex = texture_stats(self.sub.getBackgroundImage(), self.cfg.shadow_texture)
        return self._bg_tex

    def scan(self, image: np.ndarray) -> None:
        """One step of a first pass (``clean_background``): what ``apply`` does on an update
        frame, without the components. Between two updates the model does not change, so a
        first pass only needs every ``update_every``-th frame."""
        image = self._exposed(image)
        raw = self.sub.apply(image, learningRate=0.0)
        share = float(np.count_nonzero(raw > SHADOW)) / raw.size
        fg = self._foreground(image, raw)
        self._last_fg = fg
        self._learn_background(image, fg, whole=share > self.cfg.unsettled, raw=raw)

    def _learn_background(self, image: np.ndarray, fg: np.ndarray, whole: bool = False,
                          raw: np.ndarray | None = None) -> None:
        """One selective update: the frame with every pixel near the cleaned foreground ``fg``
        (H, W) uint8 replaced by the model's background image, learnt at ``update_every``
        frames' worth of the learning rate. Lighting that drifts is followed; road users that
        stop are not. Specks the opening removed are learnt: held back, the pixels that a
        drift turns foreground one by one would hold their neighbours back in turn.

        Foreground that has lasted ``ghost_after`` frames is tested for a ghost (the place a
        road user of the starting background has left: ``ghost_mask``); a ghost's pixels are
        learnt from the frame at once, so the empty road is background again."""
        import cv2

        cfg = self.cfg
        rate = self.lr if self.lr >= 0 else 1.0 / cfg.history
        if rate <= 0:
            return
        frame = image
        ghosts = None
        grey = grey_mean(image)
        prev, self._prev_grey = self._prev_grey, grey
        if whole:
            self.fg_age = None
        else:
            bg = self.sub.getBackgroundImage()
            if cfg.ghost_after > 0:
                age = self.fg_age if self.fg_age is not None else np.zeros(fg.shape, np.int32)
                age = np.where(fg.view(bool), age + cfg.update_every, 0).astype(np.int32)
                static = age >= cfg.ghost_after
                if static.any() and raw is not None:
                    # quiet: neither foreground nor shadow, sensor-noise specks aside (the model
                    # starts from one image, so its variances are small and noise specks are
                    # dense: 14 % of the road on seed 104; they made a ghost's ring "busy")
                    busy = (raw != 0).view(np.uint8)
                    if self.k_open is not None:
                        busy = cv2.morphologyEx(busy, cv2.MORPH_OPEN, self.k_open)
                    ghosts = ghost_mask(static, image, bg, busy == 0, max(cfg.min_area // GHOST_AREA, 1),
                                        cfg.ghost_ratio)
                    if ghosts.any():
                        ghosts = still_pixels(ghosts, grey, prev)
                    if ghosts.any():
                        ghosts = cv2.dilate(ghosts.view(np.uint8), self.k_ghost).view(bool)
                        age[ghosts] = 0
                    else:
                        ghosts = None
                self.fg_age = age
            hold = cv2.dilate(fg, self.k_hold).view(bool)
            frame = image.copy()
            frame[hold] = bg[hold]
        self.sub.apply(frame, learningRate=min(1.0, rate * cfg.update_every))
        self._bg_tex = None
        if ghosts is not None:
            # restart the model from its background image with the ghost's pixels taken from
            # the frame (OpenCV's rate 1). Learning them at a high rate instead would shrink the
            # variances of every other pixel (they would see the noise-free background image
            # several times) and turn sensor noise into foreground
            frame = self.sub.getBackgroundImage()
            frame[ghosts] = image[ghosts]
            self.sub.apply(frame, learningRate=1.0)
            self.ghost_seen = ghosts if self.ghost_seen is None else self.ghost_seen | ghosts
            if self.ghost_image is None:
                self.ghost_image = np.zeros_like(image)
            self.ghost_image[ghosts] = image[ghosts]
            self.n_ghosts += 1


def _ranges(frames: list[int]) -> list[tuple[int, int]]:
    """Consecutive runs of sorted frame numbers as (first, last) pairs."""
    out: list[tuple[int, int]] = []
    for f in frames:
        if out and f - out[-1][1] <= 1:
            out[-1] = (out[-1][0], f)
        else:
            out.append((f, f))
    return out


def clean_background(reader: FrameReader, cfg: BgConfig, background: np.ndarray,
                     first: int | None, last: int | None) -> np.ndarray:
    """The starting background ``background`` (H, W, 3) uint8 with the empty road put back
    where a road user of it leaves: a first pass of the selective model over frames
    first..last (every ``update_every``-th frame; ghosts are learnt away as they show); at
    each ghost's pixels the frame it was learnt from is taken (the last such frame where
    ghosts overlap). Elsewhere the start is unchanged
    (the light at the start of the video, not at its end)."""
    h, w = background.shape[:2]
    seg = BackgroundMasks(cfg, h, w)
    seg.prime([background])
    for _, im in reader.frames(first, last, every=cfg.update_every):
        if im.shape[:2] != (h, w):
            break  # the second pass reports it
        seg.scan(im)
    if seg.ghost_seen is None or seg.ghost_image is None:  # both are set at the first ghost
        return background
    # the empty road as the frame showed it when the ghost was learnt, not the model's image at
    # the end of the pass: a flat grey car that later stands on a white marking passes MOG2's
    # shadow test there (half as bright, same hue, and the marking has no texture to tell), so
    # the selective updates learn it little by little (development seed 107, c1: the stripe
    # 211 grey levels when learnt, 198-202 at the end, 13 above the noise-tight model: a ghost
    # again in the second pass)
    return np.where(seg.ghost_seen[..., None], seg.ghost_image, background)


def iter_video_masks(reader: FrameReader, cfg: BgConfig, result: VideoMasksResult,
                     first: int | None = None, last: int | None = None,
                     progress: bool = False, desc: str = "masks",
                     init_from: int | None = None) -> Iterator[MaskTable]:
    """Stream MaskTables (one per frame with masks) of ``reader``'s frames; ``result`` is filled
    in as frames are read (also when the video stops early). ``init_from``: the scene frame the
    starting background's samples start at (default: the first frame read; a video segment
    passes the video's first frame, so that it starts from the uncut run's background)."""
    from tqdm import tqdm

    w, h, n_header = reader.header()
    seg = BackgroundMasks(cfg, h, w)
    if cfg.init != "none":
        span_lo = init_from if init_from is not None else first if first is not None else reader.first
        # mode / median: samples over the whole video by default; warm-up: one history's worth
        sampled = cfg.init in SAMPLED
        span = cfg.init_frames or (n_header or 300 if sampled else cfg.history)
        want = np.unique(np.linspace(span_lo, span_lo + (span - 1) * reader.step,
                                     cfg.init_samples if sampled else span)
                         .round().astype(np.int64))
        if sampled or reader.is_folder:
            ims = [im for _, im in reader.sample(want)]
            if (sampled and ims and cfg.clean_start and cfg.ghost_after > 0
                    and cfg.update == "selective"):
                bg = start_image(ims, cfg.init, cfg.exposure_band)
                del ims
                ims = [clean_background(reader, cfg, bg, span_lo, int(want[-1]))]
            seg.prime(ims)
        else:
            seg.prime([im for _, im in reader.frames(first=span_lo, last=int(want[-1]))])
    bad: list[int] = []
    total = None
    if n_header and last is None and first is None:
        total = n_header
    bar = tqdm(total=total, desc=desc, unit="frame", disable=not progress, leave=False)
    try:
        for f, im in reader.frames(first, last):
            if im.shape[:2] != (h, w):
                raise InputError(f"frame {f} is {im.shape[1]}x{im.shape[0]}, the video header "
                                 f"says {w}x{h}", file=reader.path)
            rles, share = seg.apply(im)
            if result.first_frame is None:
                result.first_frame = f
            result.n_frames += 1
            result.last_good = f
            if share > cfg.unsettled:
                bad.append(f)
            bar.update(1)
            if rles:
                result.n_masks += len(rles)
                z = np.zeros(len(rles), np.int64)
                yield MaskTable(z + f, z - 1, z, h, w, rles)
    finally:
        bar.close()
        result.stopped = reader.stopped
        result.unsettled = _ranges(bad)
        result.n_rescaled = seg.n_rescaled


def masks_from_video(video: str | Path, out: str | Path, cfg: BgConfig | None = None, *,
                     camera=None, first_frame: int = 0, frame_step: int = 1,
                     frames: tuple[int, int] | None = None, progress: bool = False,
                     log: Callable[[str], None] = print, init_from: int | None = None
                     ) -> VideoMasksResult:
    """Background-subtraction masks of one camera's video (file or image folder) written to the
    MOTS file ``out`` (track id -1, class 0), atomically, as frames stream through.

    camera: its calibration's width/height must match the frames. first_frame, frame_step:
    scene frame of the first video frame and the step. frames: (first, last) scene frames.
    init_from: where the starting background's samples start (``iter_video_masks``).
    Warnings (early end, unsettled background) go to ``log`` and into the result."""
    cfg = cfg or BgConfig()
    cfg.validate()
    reader = FrameReader(Path(video), first=first_frame, step=frame_step)
    if camera is not None:
        reader.check_size(camera.width, camera.height)
    res = VideoMasksResult()
    lo, hi = frames if frames is not None else (None, None)
    write_mots(out, iter_video_masks(reader, cfg, res, lo, hi, progress, desc=Path(video).stem,
                                     init_from=init_from))
    if res.stopped:
        log(f"warning: {reader.path}: {res.stopped}; kept the masks of frames "
            f"{res.first_frame}..{res.last_good}")
    if res.n_rescaled:
        log(f"note: {reader.path}: {res.n_rescaled} of {res.n_frames} frames were brighter or darker "
            f"than the background model by over {cfg.exposure_band:.0%} (a change of light) and "
            f"were scaled to it before the subtraction")
    if res.unsettled:
        spans = ", ".join(f"{a}..{b}" if a != b else f"{a}" for a, b in res.unsettled[:8])
        more = f" and {len(res.unsettled) - 8} more" if len(res.unsettled) > 8 else ""
        log(f"warning: {reader.path}: the background model did not settle in frames {spans}{more} "
            f"(foreground over {cfg.unsettled:.0%} of the image: a moving camera or a light change?)")
    return res

