"""Training examples for Seg2PoseNet (paper 4.1 and 3.5).

An example is one instance mask of one camera with its target: the true ground position minus
the mask's normal position (a residual in metres, x and y). Two sources:

- annotated: masks of a split matched to the ground truth as in 4.1 (project the true 3D
  position into the camera; a mask of the same class covering that point is its match,
  ``seg2pose.method.matching.match_masks_to_truth``);
- rough: rasterised rough 3D models at random positions and headings (3.5,
  ``seg2pose.synth.rough.render_rough_examples``); they need only the calibration and the
  ground points, so they also make a training set without annotations (``--zero-annotation``).
  Optionally made detector-like (``detector_like``: Mask R-CNN's 28x28 mask resolution and a
  one-pixel dilation), since clean silhouettes differ from what a detector delivers.

Crops are stored at the network's resolution (``NetConfig.input_size``) as uint8 counts of
covered pixels per downsampling block, so a few thousand lite examples take tens of MB.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from seg2pose.core.errors import S2PError
from seg2pose.core.say import say
from seg2pose.geometry.normal import DEFAULT_CENTER_METHOD, normal_positions
from seg2pose.io.mots import MaskTable
from seg2pose.io.poses import PoseTable
from seg2pose.io.scene import Scene
from seg2pose.method.features import N_GEO, scene_geometry
from seg2pose.method.matching import match_masks_to_truth
from seg2pose.structures.masks import block_counts, crop_runs, decode, encode, mask_centers, rle_stats
from seg2pose.training.rough_video import render_video_examples


@dataclass
class ExampleSet:
    """N examples of one camera. crops (N, S, S) uint8: covered pixels per factor x factor block;
    centers (N, 2) pixels; normal (N, 2) normal position x, y metres; target (N, 2) residual
    metres (truth - normal); cls (N,) class names; rough (N,) bool (a rough-model example);
    geo (N, N_GEO) float32 mask geometry (``seg2pose.method.features``; used when the net has n_geo)."""

    crops: np.ndarray
    factor: int
    centers: np.ndarray
    normal: np.ndarray
    target: np.ndarray
    cls: np.ndarray
    rough: np.ndarray
    geo: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.geo is None:
            self.geo = np.zeros((len(self.target), N_GEO), np.float32)

    def __len__(self) -> int:
        return len(self.target)

    def take(self, idx) -> ExampleSet:
        assert self.geo is not None  # filled in __post_init__
        return ExampleSet(self.crops[idx], self.factor, self.centers[idx], self.normal[idx],
                          self.target[idx], self.cls[idx], self.rough[idx], self.geo[idx])

    def crops_float(self, idx) -> np.ndarray:
        """(B, 1, S, S) float32 network input in [0, 1] for the examples ``idx``."""
        return (self.crops[idx].astype(np.float32) / float(self.factor ** 2))[:, None]

    @classmethod
    def empty(cls, size: int, factor: int) -> ExampleSet:
        return cls(np.zeros((0, size, size), np.uint8), factor, np.zeros((0, 2)), np.zeros((0, 2)),
                   np.zeros((0, 2)), np.zeros(0, object), np.zeros(0, bool))

    @classmethod
    def concat(cls, sets: list[ExampleSet]) -> ExampleSet:
        sets = [s for s in sets if len(s)] or sets[:1]
        return cls(np.concatenate([s.crops for s in sets]), sets[0].factor,
                   np.concatenate([s.centers for s in sets]), np.concatenate([s.normal for s in sets]),
                   np.concatenate([s.target for s in sets]), np.concatenate([s.cls for s in sets]),
                   np.concatenate([s.rough for s in sets]), np.concatenate([s.geo for s in sets]))


def make_examples(rles: list[bytes], height: int, width: int, centers: np.ndarray,
                  normal_xy: np.ndarray, target: np.ndarray, cls: np.ndarray, rough: bool,
                  crop: int, factor: int, batch: int = 64, geo: np.ndarray | None = None
                  ) -> ExampleSet:
    """Crop and downsample masks (bounded memory: ``batch`` full-resolution crops at a time);
    ``geo`` (N, N_GEO): the masks' geometry features (zeros when None)."""
    n = len(rles)
    m = crop // factor
    out = np.zeros((n, m, m), np.uint8)
    if n:
        _, _, box = rle_stats(rles, height, width)
        big = int((np.nanmax(box[:, 2:] - box[:, :2], axis=1) > crop).sum())
        if big:
            say(f"{big} of {n} masks are larger than the {crop}x{crop} crop; they are "
                "cropped around their centre", "note")
    for s in range(0, n, batch):
        c = crop_runs(rles[s:s + batch], height, width, centers[s:s + batch], size=crop)
        out[s:s + batch] = block_counts(c, factor)
    return ExampleSet(out, factor, np.asarray(centers, float).reshape(-1, 2),
                      np.asarray(normal_xy, float).reshape(-1, 2), np.asarray(target, float).reshape(-1, 2),
                      np.asarray(cls, object).reshape(-1), np.full(n, bool(rough)),
                      None if geo is None else np.asarray(geo, np.float32).reshape(n, N_GEO))


def annotated_examples(scene: Scene, camera: str, gt: PoseTable, split: str | None,
                       crop: int, factor: int, center_method: str = DEFAULT_CENTER_METHOD,
                       max_per_class: int | None = None, max_residual: float = 2.5,
                       rng: np.random.Generator | None = None, augment: int = 0,
                       sources: tuple[str, ...] | None = None) -> ExampleSet:
    """Masks of ``camera`` in ``split`` matched to the truth (4.1), as examples.

    ``sources``: for annotated truth (a ``source`` column), keep only masks whose matched row
    has one of these sources (e.g. keyframe and interpolated, not occluded). Masks are matched
    against every row first, so a skipped row never lends its mask to a neighbour.

    ``augment`` = K adds K changed copies of every mask (occlusion cuts, 1 px boundary changes:
    ``seg2pose.training.augment``) with their normal positions and targets recomputed from the changed
    mask, so they are labelled exactly (the truth does not move).

    Streams the masks a few hundred frames at a time; gt must be sorted by frame (as
    read_poses returns it). ``max_per_class`` keeps a random subset per class (CPU budgets);
    residuals longer than ``max_residual`` metres (beyond the network's 2.5 tanh range, e.g.
    a wrong match) are dropped."""
    by_id = scene.class_by_id()
    fr = scene.split_range(split)
    keep_rles: list[bytes] = []
    keep_cls, keep_xy = [], []
    size = (scene.cameras[camera].height, scene.cameras[camera].width)
    for t, g, match in masks_matched_to_truth(scene, camera, gt.in_frames(fr), fr):
        size = (t.height, t.width)
        use = match >= 0
        if sources is not None and g.source is not None:
            use &= np.isin(g.source[np.maximum(match, 0)], list(sources))
        for i in np.flatnonzero(use):
            keep_rles.append(t.rles[i])
            keep_cls.append(by_id[int(t.class_id[i])].name)
            keep_xy.append(g.xyz[match[i], :2])
    if not keep_rles:
        return ExampleSet.empty(crop // factor, factor)
    cls = np.array(keep_cls, object)
    truth = np.array(keep_xy, float)
    idx = np.arange(len(cls))
    if max_per_class is not None:
        rng = rng or np.random.default_rng(0)
        parts = []
        for c in np.unique(cls):
            sel = np.flatnonzero(cls == c)
            if len(sel) > max_per_class:
                sel = np.sort(rng.choice(sel, max_per_class, replace=False))
            parts.append(sel)
        idx = np.sort(np.concatenate(parts))
    rles = [keep_rles[i] for i in idx]
    cls, truth = cls[idx], truth[idx]
    h, w = size
    if augment:
        from seg2pose.training.augment import augment_masks  # lazy: loads OpenCV

        rng = rng or np.random.default_rng(0)
        extra_rles, extra_cls, extra_truth = [], [], []
        for _ in range(int(augment)):
            new, changed = augment_masks(rles, h, w, rng)
            sel = np.flatnonzero(changed)
            extra_rles += [new[i] for i in sel]
            extra_cls.append(cls[sel])
            extra_truth.append(truth[sel])
        rles = rles + extra_rles
        cls = np.concatenate([cls, *extra_cls])
        truth = np.concatenate([truth, *extra_truth])
    return labelled_examples(scene, camera, rles, h, w, cls, truth, False, crop, factor,
                             center_method, max_residual, where=f"camera {camera}, split {split}")


def masks_matched_to_truth(scene: Scene, camera: str, gt: PoseTable,
                           frames: tuple[int, int] | None, chunk_frames: int = 256
                           ) -> Iterator[tuple[MaskTable, PoseTable, np.ndarray]]:
    """``camera``'s masks in ``frames`` (inclusive; None: all) matched to the truth rows ``gt``
    (sorted by frame, as read_poses returns it) as paper 4.1 does (``match_masks_to_truth``),
    streamed ``chunk_frames`` frames at a time (bounded memory): per chunk (masks, the truth
    rows of its frames, match (N,): the row of each mask in those rows, -1 for none)."""
    cam = scene.cameras[camera]
    names, heights = scene.class_names_by_id(), scene.default_heights()
    chunk: list[MaskTable] = []

    def flush() -> tuple[MaskTable, PoseTable, np.ndarray]:
        t = MaskTable.concat(chunk)
        chunk.clear()
        lo, hi = np.searchsorted(gt.frame, [t.frame.min(), t.frame.max() + 1])
        g = gt.take(np.arange(lo, hi))
        return t, g, match_masks_to_truth(cam, t, g, names, heights)

    for _, t in scene.iter_masks(camera, frames):
        chunk.append(t)
        if len(chunk) >= chunk_frames:
            yield flush()
    if chunk:
        yield flush()


def labelled_examples(scene: Scene, camera: str, rles: list[bytes], height: int, width: int,
                      cls: np.ndarray, truth_xy: np.ndarray, rough: bool, crop: int, factor: int,
                      center_method: str = DEFAULT_CENTER_METHOD, max_residual: float = 2.5,
                      where: str | None = None) -> ExampleSet:
    """Examples from masks of ``camera`` with known true positions truth_xy (N, 2) metres and
    class names (N,): mask centres, normal positions (class default heights), targets = truth -
    normal, geometry features, crops. Masks whose ray misses the ground or whose residual is
    longer than ``max_residual`` metres are dropped (said on stderr when ``where`` is given)."""
    heights = scene.default_heights()
    centers = mask_centers(rles, height, width, center_method)
    hts = np.array([heights.get(str(c), 0.9) for c in cls])
    normal, _ = normal_positions(scene.cameras[camera], scene.ground, centers, hts)
    target = np.asarray(truth_xy, float).reshape(-1, 2) - normal[:, :2]
    ok = np.isfinite(target).all(axis=1) & (np.linalg.norm(target, axis=1) <= max_residual)
    dropped = int((~ok).sum())
    if dropped and where:
        say(f"{where}: {dropped} of {len(ok)} matched masks dropped "
            f"(normal position missing or residual > {max_residual} m)", "note")
    ok = np.flatnonzero(ok)
    rles = [rles[i] for i in ok]
    cls = np.asarray(cls, object)[ok]
    geo = scene_geometry(scene, camera, rles, height, width, centers[ok], normal[ok, :2], cls)
    return make_examples(rles, height, width, centers[ok], normal[ok, :2], target[ok], cls,
                         rough, crop, factor, geo=geo)


def detector_like(rles: list[bytes], height: int, width: int, rng: np.random.Generator,
                  resolution: int = 28, dilate_p: float = 0.5) -> list[bytes]:
    """Make clean rasterised masks look like Mask R-CNN output: the box content resampled to
    ``resolution`` x ``resolution`` and back (bilinear, threshold 0.5: Mask R-CNN's 28x28 mask
    head), then dilated by one pixel with probability ``dilate_p``. One loop step per mask
    (OpenCV does the pixels)."""
    import cv2

    _, _, box = rle_stats(rles, height, width)
    out = []
    kernel = np.ones((3, 3), np.uint8)
    for r, b in zip(rles, box):
        if not np.isfinite(b[0]):
            out.append(r)
            continue
        x0, y0, x1, y1 = (int(v) for v in b)
        m = decode(r, height, width)
        sub = m[y0:y1, x0:x1].astype(np.float32)
        small = cv2.resize(sub, (resolution, resolution), interpolation=cv2.INTER_AREA)
        back = (cv2.resize(small, (x1 - x0, y1 - y0), interpolation=cv2.INTER_LINEAR) >= 0.5)
        full = np.zeros((height, width), np.uint8)
        full[y0:y1, x0:x1] = back
        if rng.random() < dilate_p:
            py0, py1, px0, px1 = max(y0 - 1, 0), min(y1 + 1, height), max(x0 - 1, 0), min(x1 + 1, width)
            full[py0:py1, px0:px1] = cv2.dilate(full[py0:py1, px0:px1], kernel)
        out.append(encode(full) if full.any() else r)
    return out


def rough_examples(scene: Scene, camera: str, cls: str, n: int, rng: np.random.Generator,
                   crop: int, factor: int, center_method: str = DEFAULT_CENTER_METHOD,
                   max_residual: float = 2.5, detector_noise: bool = False,
                   occlusion: float = 0.0, look=None, random_sizes: bool = False) -> ExampleSet:
    """``n`` rough-model examples (3.5) of class ``cls`` seen by ``camera``: random positions
    and headings on the ground, rasterised; target = true position - normal position.
    ``look`` (a ``seg2pose.training.rough_video.VideoLook``): film them over the video's background and
    segment them as the video path does (``rough_video.render_video_examples``) instead;
    ``random_sizes``: sizes drawn per example from ``rough.RANDOM_SIZES``."""
    try:
        from seg2pose.synth.rough import render_rough_examples  # lazy: loads OpenCV
    except ImportError as e:
        raise S2PError(f"rough 3D models are not available ({e})") from None
    cam = scene.cameras[camera]
    if look is not None:
        rles, xyz, _, _ = render_video_examples(cam, scene.ground, cls, n, rng, look,
                                             occlusion=max(occlusion, 0.2))
    else:
        rles, xyz, _ = render_rough_examples(cam, scene.ground, cls, n, rng, occlusion=occlusion,
                                             **({"random_sizes": True} if random_sizes else {}))
    if detector_noise and len(rles) and look is None:
        rles = detector_like(rles, cam.height, cam.width, rng)
    if len(rles) == 0:
        return ExampleSet.empty(crop // factor, factor)
    return labelled_examples(scene, camera, rles, cam.height, cam.width,
                             np.full(len(rles), cls, object), np.asarray(xyz, float)[:, :2], True,
                             crop, factor, center_method, max_residual)
