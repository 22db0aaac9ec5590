"""Checks on background-subtraction output, pure functions on images: which "shadow" pixels
are a flat body rather than a shadow (``flat_pixels``), which long-lasting foreground is a
ghost (``ghost_mask``) and which of its pixels held still (``still_pixels``), and how much
brighter the whole frame is than the background model (``exposure_ratio``, ``to_exposure``).
Used by ``seg2pose.video.video_masks`` and ``seg2pose.video.bg_start``.

Images: (H, W, 3) BGR or (H, W) grey uint8; pixels x right, y down.
"""

from __future__ import annotations

import numpy as np

TEX_WIN = 5  # window (pixels) of the shadow texture test
# A ghost's pixels are learnt from the frame only where the frame held still since the previous
# update (the 5x5 grey mean changed by at most GHOST_STILL, and nothing changed within
# GHOST_NEAR px): the rest waits for a later update. Without this a car crossing a ghost's place
# at the update was learnt as empty road (held-out seed 104, c1: a car-shaped ghost that lasted
# 110 frames, reported by four lenses). Sensor noise of the 5x5 mean: 99.9th percentile 4 grey
# levels between frames (seed 104, c1).
GHOST_STILL = 8.0
GHOST_NEAR = 4
EXPOSURE_GRID = 4  # pixels between the samples of the exposure estimate (a 1280 x 720 frame: 57,600)


def exposure_ratio(image: np.ndarray, bg_grey: np.ndarray, hold: np.ndarray | None = None) -> float:
    """How much brighter the whole frame ``image`` (H, W, 3) uint8 is than the background
    ``bg_grey`` (H, W) float32: the median of grey over background grey on a grid of pixels,
    leaving out ``hold`` (H, W, nonzero: the last foreground) and near-black or saturated
    background. 1: the same light; a cloud over the sun, 0.8. Road users and their shadows are
    a minority of the pixels, so the median is the ground's."""
    import cv2

    s = EXPOSURE_GRID
    g = cv2.cvtColor(np.ascontiguousarray(image[::s, ::s]), cv2.COLOR_BGR2GRAY).astype(np.float32)
    b = bg_grey[::s, ::s]
    keep = (b > 20) & (b < 235)
    if hold is not None:
        keep &= hold[::s, ::s] == 0
    if np.count_nonzero(keep) < 100:
        return 1.0
    return float(np.median(g[keep] / b[keep]))


def to_exposure(image: np.ndarray, ratio: float, band: float) -> np.ndarray:
    """``image`` divided by ``ratio`` (``exposure_ratio``) when that is more than ``band`` away
    from 1, else ``image`` itself (the same object, so a caller can tell)."""
    import cv2

    return image if abs(ratio - 1.0) <= band else cv2.convertScaleAbs(image, alpha=1.0 / ratio)


def texture_stats(background: np.ndarray, t: float) -> tuple:
    """What ``flat_pixels`` needs of a background image (H, W, 3) uint8, computed once per
    background: grey (H, W) float32, its TEX_WIN box mean, t^2 times its box variance where it
    has texture (grey-level spread >= 2; elsewhere -1: no test there), and t^2."""
    import cv2

    k = (TEX_WIN, TEX_WIN)
    gb = cv2.cvtColor(background, cv2.COLOR_BGR2GRAY).astype(np.float32)
    mb = cv2.boxFilter(gb, -1, k)
    vb = cv2.sqrBoxFilter(gb, -1, k) - mb * mb
    return gb, mb, np.where(vb >= 4.0, t * t * vb, -1.0).astype(np.float32), t * t


def flat_pixels(image: np.ndarray, raw: np.ndarray, stats: tuple, fg: np.ndarray,
                near_background: bool = False) -> None:
    """Sets ``fg`` (H, W) uint8 to 1 where ``image`` (H, W, 3) uint8 does not carry the
    background's texture although the subtractor's output ``raw`` (H, W) uint8 (0 background,
    127 shadow, 255 foreground) calls the pixel shadow or, with ``near_background``, background
    or shadow next to foreground or shadow. A shadow darkens the road and keeps its texture
    (normalised cross-correlation of frame and background over TEX_WIN x TEX_WIN near 1), and
    so does empty road; the flat grey or dark body of a car that passes MOG2's brightness-and-
    colour tests does not (correlation < t, and less spread of grey levels than the background:
    ``stats``: ``texture_stats(bg, t)``). Looked at box
    by box where shadow (or foreground and shadow) is dense: 8x8 blocks mostly so (and, near
    background, the blocks next to them), not the single noise pixels MOG2 calls shadow all
    over the image."""
    import cv2

    H, W = raw.shape
    sure = ((raw > 0) if near_background else (raw == 127)).view(np.uint8)
    coarse = cv2.resize(sure, (W // 8, H // 8), interpolation=cv2.INTER_AREA)
    if near_background:
        coarse = cv2.dilate(coarse, np.ones((3, 3), np.uint8))
    _, _, boxes, _ = cv2.connectedComponentsWithStats(coarse, connectivity=8)
    k = (TEX_WIN, TEX_WIN)
    t2 = stats[3]
    for x, y, w, h, area in boxes[1:]:
        if area < 2:
            continue
        y0, y1 = max(8 * y - 8, 0), min(8 * (y + h) + 8, H)
        x0, x1 = max(8 * x - 8, 0), min(8 * (x + w) + 8, W)
        gb, mb, tvb = (a[y0:y1, x0:x1] for a in stats[:3])
        gi = cv2.cvtColor(image[y0:y1, x0:x1], cv2.COLOR_BGR2GRAY).astype(np.float32)
        ma = cv2.boxFilter(gi, -1, k)
        va = np.maximum(cv2.sqrBoxFilter(gi, -1, k) - ma * ma, 1.0)  # floored: flat is flat
        cab = cv2.boxFilter(gi * gb, -1, k) - ma * mb
        r = raw[y0:y1, x0:x1]
        cand = (r != 255) if near_background else (r == 127)
        # ncc = cab / sqrt(va * vb) < t, without the square root
        # ... and the frame has less texture than the background there (a body hides it; a
        # window across a shadow's or a road user's edge sees a step, more spread than road)
        flat = ((cab < 0) | (cab * cab < tvb * va)) & (t2 * va < tvb) & cand
        # the majority of a 7x7 window decides: single pixels of a textured road that
        # correlate badly by chance, and the thin bands where a window straddles an edge (a
        # shadow's own, a road user's: a step the background lacks) drop out; bodies, whose
        # correlation is noise around 0 (low for most pixels, not all), fill in
        major = cv2.boxFilter(flat.view(np.uint8), cv2.CV_32F, (7, 7)) > 0.5
        fg[y0:y1, x0:x1] |= (major & cand).view(np.uint8)


def edge_strength(img: np.ndarray) -> np.ndarray:
    """(h, w) float32 gradient strength of a BGR crop: |Sobel| summed over x, y and the
    channels, after a small blur so that the road's fine texture and noise count little."""
    import cv2

    b = cv2.GaussianBlur(img, (5, 5), 1.2).astype(np.float32)
    g = np.abs(cv2.Sobel(b, cv2.CV_32F, 1, 0, ksize=3)) + np.abs(cv2.Sobel(b, cv2.CV_32F, 0, 1, ksize=3))
    return g.sum(axis=2) if g.ndim == 3 else g


def ncc(a: np.ndarray, b: np.ndarray, k: int = 7) -> np.ndarray:
    """(h, w) float32 normalised cross-correlation of two grey or BGR uint8 crops over k x k
    windows (about 0 where either is flat)."""
    import cv2

    if a.ndim == 3:
        a, b = cv2.cvtColor(a, cv2.COLOR_BGR2GRAY), cv2.cvtColor(b, cv2.COLOR_BGR2GRAY)
    a, b = a.astype(np.float32), b.astype(np.float32)
    ma, mb = cv2.boxFilter(a, -1, (k, k)), cv2.boxFilter(b, -1, (k, k))
    va = cv2.boxFilter(a * a, -1, (k, k)) - ma * ma
    vb = cv2.boxFilter(b * b, -1, (k, k)) - mb * mb
    return (cv2.boxFilter(a * b, -1, (k, k)) - ma * mb) / np.sqrt(np.maximum(va, 1.0) * np.maximum(vb, 1.0))


# the colour test of ``ghost_mask``: a pixel is "explained" by a palette when one of its colours
# is within PALETTE_TOL grey levels in every channel (sensor noise 2-5, a road's texture ~10);
# a ghost's inside is explained by the frame's surroundings (FRAME_EXPLAINED of it) and the
# background image's inside is not (at most BG_EXPLAINED). Development seed 107, c1: ghosts on a
# zebra stripe 1.00 / 0.00-0.09, road users 0.005-0.92 / 0.004-1.0 (none both).
PALETTE_TOL = 20
FRAME_EXPLAINED = 0.9
BG_EXPLAINED = 0.2
PALETTE_SIZE = 300


def explained_share(pixels: np.ndarray, palette: np.ndarray, tol: int = PALETTE_TOL) -> float:
    """Share of ``pixels`` (N, C) whose colour is within ``tol`` in every channel of one of
    ``palette`` (M, C) (at most PALETTE_SIZE of them are used, a fixed sample); grey pixels and
    palette may be (N,) and (M,)."""
    if not len(pixels) or not len(palette):
        return 0.0
    pixels, palette = pixels.reshape(len(pixels), -1), palette.reshape(len(palette), -1)
    if len(palette) > PALETTE_SIZE:
        palette = palette[np.random.default_rng(0).choice(len(palette), PALETTE_SIZE, replace=False)]
    if len(pixels) > 4 * PALETTE_SIZE:
        pixels = pixels[np.random.default_rng(1).choice(len(pixels), 4 * PALETTE_SIZE, replace=False)]
    d = np.abs(pixels[:, None, :].astype(np.int16) - palette[None, :, :].astype(np.int16))
    return float((d.max(axis=2).min(axis=1) <= tol).mean())


def ghost_mask(static: np.ndarray, frame: np.ndarray, background: np.ndarray,
               quiet: np.ndarray, min_area: int, ratio: float) -> np.ndarray:
    """(H, W) bool: the components of ``static`` (H, W) bool (long-lasting foreground) that are
    ghosts. A road user that stopped has its outline in the frame and not in the background
    image; a ghost (the background image holds a road user that has left) the other way round.
    A component of at least ``min_area`` pixels is a ghost when at least half of a ring 2-6 px
    around it is ``quiet`` ((H, W) bool: neither foreground nor shadow) and either

    - *edges*: that half has the background's texture (``ncc`` >= 0.3) and the mean edge
      strength (``edge_strength``) along the component's outline (a 5 px band) is ``ratio``
      times larger in ``background`` than in ``frame`` (both (H, W, 3) or (H, W) uint8); or
    - *colours*: the frame inside it (2 px in from its outline) has the colours of the frame's
      quiet ring (``explained_share`` >= FRAME_EXPLAINED) and the background image inside it
      does not (<= BG_EXPLAINED): the empty road continues into it, the road user that was
      there is gone. The edge test alone misses ghosts on flat road markings: where a car of
      the starting background covered a zebra stripe, the ghost is the stripe's part under
      it, whose outline runs partly along the stripe's own edges (in the frame, not in the
      background) and whose flat white ring has no texture to correlate.

    A ghost lies in the empty road; a bright road marking covered by a flat dark car body
    (which MOG2 may take for background or shadow) has the same outline edges but lies inside
    the car (its ring is not quiet). A stopped road user fails the colour test's first half
    (its colours are not the road's) or its second (the road it hides is in the ring).
    """
    import cv2

    out = np.zeros(static.shape, bool)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(static.view(np.uint8), connectivity=8)
    H, W = static.shape
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
    k_ring = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (13, 13))
    for i in range(1, n):
        x, y, w, h, area = stats[i]
        if area < min_area:
            continue
        x0, y0, x1, y1 = max(x - 8, 0), max(y - 8, 0), min(x + w + 8, W), min(y + h + 8, H)
        blob = (lab[y0:y1, x0:x1] == i).view(np.uint8)
        near = cv2.dilate(blob, k)
        ring = (cv2.dilate(blob, k_ring) - near).view(bool)
        calm = quiet[y0:y1, x0:x1][ring]
        if not calm.mean() >= 0.5:
            continue
        fr, bg = frame[y0:y1, x0:x1], background[y0:y1, x0:x1]
        ok = calm & (ncc(fr, bg)[ring] >= 0.3)
        if ok.mean() >= 0.5:
            band = (near - cv2.erode(blob, k)).view(bool)
            e_frame = edge_strength(fr)[band].mean()
            e_bg = edge_strength(bg)[band].mean()
            if e_bg > ratio * max(e_frame, 1e-6):
                out[y0:y1, x0:x1] |= blob.view(bool)
                continue
        core = cv2.erode(blob, k).view(bool)
        palette = fr[ring][calm]
        if (core.any() and explained_share(fr[core], palette) >= FRAME_EXPLAINED
                and explained_share(bg[core], palette) <= BG_EXPLAINED):
            out[y0:y1, x0:x1] |= blob.view(bool)
    return out


def grey_mean(image: np.ndarray) -> np.ndarray:
    """(H, W) float32: the 5x5 box mean of ``image``'s grey values (colour (H, W, 3) BGR or grey)."""
    import cv2

    g = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
    return cv2.blur(g.astype(np.float32), (5, 5))


def still_pixels(ghosts: np.ndarray, grey: np.ndarray, prev: np.ndarray | None) -> np.ndarray:
    """The pixels of ``ghosts`` (H, W) bool that held still since the previous update: farther
    than ``GHOST_NEAR`` px from any pixel whose 5x5 grey mean (``grey``, ``prev``: (H, W)
    float32) changed by more than ``GHOST_STILL`` (the margin covers the flat inside of a
    passing car, which does not change where the car overlaps itself). No previous frame: none."""
    import cv2

    if prev is None or prev.shape != grey.shape:
        return np.zeros_like(ghosts)
    moved = (np.abs(grey - prev) > GHOST_STILL).view(np.uint8)
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * GHOST_NEAR + 1,) * 2)
    return ghosts & ~cv2.dilate(moved, k).view(bool)
