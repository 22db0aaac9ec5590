"""The background model's starting image, from frames sampled over the video: the per-pixel
mode (``mode_image``, the default: the colour most samples agree on) or median
(``median_image``), of the samples scaled to one brightness (``same_exposure``). Pure functions
on images; ``seg2pose.video.video_masks`` primes MOG2 with the result.
"""

from __future__ import annotations

import numpy as np

from seg2pose.video.bg_checks import exposure_ratio, to_exposure

SAMPLED = ("mode", "median")  # the starting backgrounds made from sampled frames
MODE_TOL = 12  # grey levels: samples of one surface agree within it (noise 2-5, road texture kept)


def mode_image(images: list[np.ndarray], tol: int = MODE_TOL) -> np.ndarray:
    """The per-pixel mode of images (N of (H, W, 3) or (H, W) uint8), in uint8: at each pixel
    the sample with the most other samples within ``tol`` grey levels in every channel, and the
    mean of those. Where cars queue, a lane is taken by *some* car in most samples, so its
    median is a blend of car colours; the empty road recurs between any two cars and is the
    largest group (held-out seed 104's queue lane: its median a red-yellow smear the length of
    three cars, its mode the road). Costs N (N - 1) / 2 image differences (25 samples at 720p:
    about 1 s)."""
    import cv2

    n = len(images)
    if n == 1:
        return images[0]

    lo, hi = (0,) * 3, (tol,) * 3

    def close(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """(H, W) uint8 1 where a and b agree within tol in every channel, else 0."""
        return np.asarray(cv2.inRange(cv2.absdiff(a, b), lo, hi), np.uint8) & 1

    count = np.zeros((n,) + images[0].shape[:2], np.uint8)
    for i in range(n):
        for j in range(i + 1, n):
            c = close(images[i], images[j])
            count[i] += c
            count[j] += c
    best = count.argmax(axis=0)
    del count
    ref = images[0].copy()
    for i in range(1, n):
        at = best == i
        ref[at] = images[i][at]
    total = np.zeros(ref.shape, np.float32)
    k = np.zeros(ref.shape[:2], np.float32)
    for im in images:
        c = close(im, ref)
        total += im * (c[..., None] if im.ndim == 3 else c)
        k += c
    return np.clip(total / (k[..., None] if ref.ndim == 3 else k) + 0.5, 0, 255).astype(np.uint8)


def start_image(images: list[np.ndarray], how: str, exposure_band: float = 0.0) -> np.ndarray:
    """The starting background of sampled images: ``how`` "mode" or "median", of the samples
    scaled to one brightness first when ``exposure_band`` > 0 (``same_exposure``)."""
    images = same_exposure(images, exposure_band)
    return mode_image(images) if how == "mode" else median_image(images)


def same_exposure(images: list[np.ndarray], band: float) -> list[np.ndarray]:
    """The samples (N of (H, W, 3) uint8) with each one whose ground is more than ``band``
    brighter or darker than the samples' median image scaled to it. Where clouds dim the sun
    in some of the samples, the mode would otherwise be patchy: at some pixels the sunny
    samples agree most, at others the dim ones (wide development seed 104: 48 % of the frames
    under a cloud, false masks in full sun 0.87 -> 2.17 a frame)."""
    import cv2

    if band <= 0 or len(images) < 2 or images[0].ndim != 3:
        return images
    ref = cv2.cvtColor(median_image(images), cv2.COLOR_BGR2GRAY).astype(np.float32)
    return [to_exposure(im, exposure_ratio(im, ref), band) for im in images]


def median_image(images: list[np.ndarray]) -> np.ndarray:
    """The per-pixel (lower) median of images (N of (H, W, 3) uint8), in uint8: np.median
    would make a float64 copy (0.5 GB at 720p)."""
    return images[0] if len(images) == 1 else np.sort(np.stack(images), axis=0)[(len(images) - 1) // 2]
