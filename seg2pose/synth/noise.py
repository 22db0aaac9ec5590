"""A detector-noise model that makes rendered silhouettes look like Mask R-CNN output.

Applied per camera and frame to the visible instance masks (crops of the instance buffer):

1. merges: two road users whose boxes overlap are, with ``merge_rate``, detected as one mask
   (the union) that carries the nearer one's id and class; the farther one is lost;
2. missed detections: masks under ``min_area`` pixels always, others with ``miss_rate`` plus
   up to ``small_miss`` more for masks smaller than ``small_area`` pixels, plus up to
   ``occlusion_miss`` more for road users less than half visible (occluded by nearer ones);
3. class confusion: pedestrian <-> bicyclist with ``class_confusion``;
4. shape: dilation/erosion by a random radius (normal, ``dilate_px`` pixels), then the mask is
   resampled through a ``mask_resolution`` x ``mask_resolution`` grid (Mask R-CNN's mask head)
   and thresholded with a smooth random field of amplitude ``boundary_jitter`` added along the
   soft boundary, which rounds corners, loses thin parts and makes the boundary wander;
5. fragments: with ``fragment_rate`` only the part of the mask on one side of a random cut
   through it is detected.

Every knob is recorded in scene.json (extra.generator.noise). ``NoiseConfig.off()`` gives the
perfect silhouettes (tests).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import cv2
import numpy as np

from seg2pose.core.errors import InputError


@dataclass(frozen=True)
class NoiseConfig:
    enabled: bool = True
    miss_rate: float = 0.03
    min_area: int = 40           # pixels
    small_area: int = 600        # pixels
    small_miss: float = 0.25
    occlusion_miss: float = 0.5  # extra miss probability at 0 % visible, falling to 0 at 50 %
    merge_rate: float = 0.15
    class_confusion: float = 0.02
    dilate_px: float = 1.0       # std of the dilation (+) / erosion (-) radius, pixels
    mask_resolution: int = 28
    boundary_jitter: float = 0.25
    fragment_rate: float = 0.02

    @classmethod
    def off(cls) -> NoiseConfig:
        return cls(enabled=False, miss_rate=0.0, min_area=1, small_area=0, small_miss=0.0,
                   occlusion_miss=0.0, merge_rate=0.0, class_confusion=0.0, dilate_px=0.0, mask_resolution=0,
                   boundary_jitter=0.0, fragment_rate=0.0)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> NoiseConfig:
        known = {f.name for f in fields(cls)}
        bad = sorted(set(d) - known)
        if bad:
            raise InputError(f"unknown noise settings {bad}; known: {sorted(known)}", field="noise")
        return cls(**d)

    def validate(self) -> None:
        for name in ("miss_rate", "small_miss", "occlusion_miss", "merge_rate", "class_confusion",
                     "fragment_rate"):
            v = getattr(self, name)
            if not (0.0 <= v <= 1.0):
                raise InputError(f"must be a probability in [0, 1], got {v}", field=f"noise.{name}")
        for name in ("min_area", "small_area", "dilate_px", "mask_resolution", "boundary_jitter"):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise InputError(f"must be >= 0, got {v}", field=f"noise.{name}")
        if self.mask_resolution not in (0,) and self.mask_resolution < 4:
            raise InputError("mask_resolution must be 0 (off) or >= 4 pixels",
                             field="noise.mask_resolution")


@dataclass
class Det:
    """One detection while noise is applied: the transposed crop (w_c, h_c) bool whose
    top-left image pixel is (x0, y0), track id, class index (0 pedestrian, 1 bicyclist,
    2 car), and depth (m) for merge decisions."""

    crop: np.ndarray
    x0: int
    y0: int
    track_id: int
    cls: int
    depth: float
    visible: float = 1.0  # share of the road user's silhouette not hidden by nearer ones


def _union(a: Det, b: Det) -> Det:
    x0, y0 = min(a.x0, b.x0), min(a.y0, b.y0)
    x1 = max(a.x0 + a.crop.shape[0], b.x0 + b.crop.shape[0])
    y1 = max(a.y0 + a.crop.shape[1], b.y0 + b.crop.shape[1])
    m = np.zeros((x1 - x0, y1 - y0), bool)
    for d in (a, b):
        m[d.x0 - x0:d.x0 - x0 + d.crop.shape[0], d.y0 - y0:d.y0 - y0 + d.crop.shape[1]] |= d.crop
    near = a if a.depth <= b.depth else b
    return Det(m, x0, y0, near.track_id, near.cls, near.depth, near.visible)


def _box(d: Det) -> tuple[int, int, int, int]:
    return d.x0, d.y0, d.x0 + d.crop.shape[0], d.y0 + d.crop.shape[1]


def _shape_noise(d: Det, cfg: NoiseConfig, rng: np.random.Generator, width: int, height: int
                 ) -> Det:
    # room for dilation and for the resampled boundary (up to a grid cell) to spill outwards
    cell = max(d.crop.shape) / cfg.mask_resolution if cfg.mask_resolution else 0.0
    pad = int(np.ceil(3 * cfg.dilate_px + cell)) + 3
    # grow the crop by ``pad`` pixels (inside the image) so dilation has room
    x0, y0 = max(d.x0 - pad, 0), max(d.y0 - pad, 0)
    x1 = min(d.x0 + d.crop.shape[0] + pad, width)
    y1 = min(d.y0 + d.crop.shape[1] + pad, height)
    m = np.zeros((x1 - x0, y1 - y0), np.uint8)
    m[d.x0 - x0:d.x0 - x0 + d.crop.shape[0], d.y0 - y0:d.y0 - y0 + d.crop.shape[1]] = d.crop
    r = int(round(rng.normal(0.0, cfg.dilate_px))) if cfg.dilate_px > 0 else 0
    if r != 0:
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * abs(r) + 1, 2 * abs(r) + 1))
        m = cv2.dilate(m, k) if r > 0 else cv2.erode(m, k)
    wc, hc = m.shape
    # the smooth jitter field is added on the coarse grid, so one upsampling does both
    res = cfg.mask_resolution
    small = cv2.resize(m.astype(np.float32), (res, res), interpolation=cv2.INTER_AREA) if res \
        else m.astype(np.float32)
    if cfg.boundary_jitter > 0:
        field = rng.normal(0.0, cfg.boundary_jitter, size=(6, 6)).astype(np.float32)
        field = cv2.resize(field, (small.shape[1], small.shape[0]), interpolation=cv2.INTER_CUBIC)
        # only where the mask is uncertain (its soft boundary): no islands far out, no holes
        small = small + field * (4.0 * small * (1.0 - small))
    soft = cv2.resize(small, (hc, wc), interpolation=cv2.INTER_LINEAR) if res else small
    return Det(soft > 0.5, x0, y0, d.track_id, d.cls, d.depth, d.visible)


def _fragment(d: Det, rng: np.random.Generator) -> Det:
    xs, ys = np.nonzero(d.crop)
    if len(xs) < 2:
        return d
    cx, cy = xs.mean(), ys.mean()
    ang = rng.uniform(0, 2 * np.pi)
    off = rng.uniform(-0.3, 0.3) * np.sqrt(len(xs))
    gx, gy = np.meshgrid(np.arange(d.crop.shape[0]), np.arange(d.crop.shape[1]), indexing="ij")
    side = (gx - cx) * np.cos(ang) + (gy - cy) * np.sin(ang) > off
    keep = d.crop & side
    if not keep.any():
        keep = d.crop & ~side
    return Det(keep, d.x0, d.y0, d.track_id, d.cls, d.depth, d.visible)


def apply_noise(dets: list[Det], cfg: NoiseConfig, rng: np.random.Generator, width: int,
                height: int) -> list[Det]:
    """The detector's view of one camera frame: the noisy detections, in input order."""
    if not cfg.enabled:
        return [d for d in dets if d.crop.any()]
    dets = list(dets)
    # 1. merges of overlapping neighbours
    if cfg.merge_rate > 0 and len(dets) > 1:
        b = np.array([_box(d) for d in dets], float)
        ix = np.clip(np.minimum(b[:, None, 2], b[None, :, 2]) - np.maximum(b[:, None, 0], b[None, :, 0]), 0, None)
        iy = np.clip(np.minimum(b[:, None, 3], b[None, :, 3]) - np.maximum(b[:, None, 1], b[None, :, 1]), 0, None)
        inter = ix * iy
        area = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
        iou = inter / np.maximum(area[:, None] + area[None, :] - inter, 1e-9)
        gone: set[int] = set()
        for i, j in zip(*np.nonzero(np.triu(iou > 0.05, 1))):
            i, j = int(i), int(j)
            if i in gone or j in gone:
                continue
            if rng.random() < cfg.merge_rate:
                u = _union(dets[i], dets[j])
                keep, drop = (i, j) if dets[i].depth <= dets[j].depth else (j, i)
                dets[keep] = u
                gone.add(drop)
        dets = [d for k, d in enumerate(dets) if k not in gone]
    out = []
    for d in dets:
        area = int(d.crop.sum())
        # 2. misses
        p_miss = cfg.miss_rate
        if cfg.small_area > 0:
            p_miss += cfg.small_miss * max(0.0, 1.0 - area / cfg.small_area)
        p_miss += cfg.occlusion_miss * max(0.0, 1.0 - 2.0 * d.visible)
        u = rng.random()
        if area < cfg.min_area or u < p_miss:
            continue
        # 3. class confusion between the two classes a detector mixes up
        if d.cls in (0, 1) and rng.random() < cfg.class_confusion:
            d = Det(d.crop, d.x0, d.y0, d.track_id, 1 - d.cls, d.depth, d.visible)
        # 4. shape
        d = _shape_noise(d, cfg, rng, width, height)
        # 5. fragments
        if cfg.fragment_rate > 0 and rng.random() < cfg.fragment_rate:
            d = _fragment(d, rng)
        if d.crop.any():
            out.append(d)
    return out
