"""Label-exact augmentation of annotated masks for training Seg2PoseNet.

A training example is (mask, truth); its target is truth - normal position, and the normal
position comes from the mask (its centre, the class's default height, the ground). So any change
to the mask gives a new, exactly labelled example once the normal position is recomputed from
the changed mask: the truth does not move. Two changes that detectors and traffic produce all
the time, and that a few hundred annotated frames show too rarely for a network to learn:

- **occlusion**: a road user behind another (a pedestrian behind a parked car, a cyclist
  behind a pedestrian) loses the bottom or one side of its mask: a random fraction of the box
  (``cut_min`` .. ``cut_max``) is removed from the bottom (most often) or from the left or right;
- **boundary**: the detector's mask is a pixel too large or too small: dilation or erosion by
  one pixel (3x3 cross).

``augment_masks`` returns the changed masks; ``examples.annotated_examples(augment=K)`` adds K
changed copies of every annotated training mask with recomputed normal positions and targets.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from seg2pose.structures.masks import decode, encode, rle_stats

_CROSS = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))


@dataclass(frozen=True)
class AugmentConfig:
    p_occlude: float = 0.4        # probability of an occlusion cut
    p_bottom: float = 0.7         # share of cuts from the bottom (else left or right)
    cut_min: float = 0.15         # fraction of the box height/width removed
    cut_max: float = 0.6
    p_boundary: float = 0.5       # probability of a 1 px dilation or erosion
    min_area: int = 40            # pixels: smaller results are dropped (a detector misses them)


def augment_masks(rles: Sequence[bytes], height: int, width: int, rng: np.random.Generator,
                  cfg: AugmentConfig = AugmentConfig()) -> tuple[list[bytes], np.ndarray]:
    """One changed copy of each mask. Returns the new RLEs and (N,) bool: which copies are kept
    (non-empty, at least ``min_area`` pixels, and actually changed)."""
    n = len(rles)
    out: list[bytes] = []
    keep = np.zeros(n, bool)
    if n == 0:
        return out, keep
    _, _, box = rle_stats(rles, height, width)
    occl = rng.random(n) < cfg.p_occlude
    bottom = rng.random(n) < cfg.p_bottom
    left = rng.random(n) < 0.5
    frac = rng.uniform(cfg.cut_min, cfg.cut_max, n)
    morph = rng.random(n) < cfg.p_boundary
    dilate = rng.random(n) < 0.5
    for i, r in enumerate(rles):
        if not np.isfinite(box[i, 0]) or not (occl[i] or morph[i]):
            out.append(r)
            continue
        x0, y0, x1, y1 = (int(v) for v in box[i])
        # work on the box plus a 1 px margin (dilation may grow the mask by one pixel)
        px0, py0, px1, py1 = max(x0 - 1, 0), max(y0 - 1, 0), min(x1 + 1, width), min(y1 + 1, height)
        m = decode(r, height, width)
        sub = m[py0:py1, px0:px1].copy()
        if occl[i]:
            if bottom[i]:
                cut = y1 - int(round(frac[i] * (y1 - y0)))
                sub[cut - py0:, :] = 0
            else:
                k = int(round(frac[i] * (x1 - x0)))
                if left[i]:
                    sub[:, :x0 + k - px0] = 0
                else:
                    sub[:, x1 - k - px0:] = 0
        if morph[i]:
            sub = (cv2.dilate if dilate[i] else cv2.erode)(sub, _CROSS)
        if int(sub.sum()) < cfg.min_area:
            out.append(r)
            continue
        m[py0:py1, px0:px1] = sub
        out.append(encode(m))
        keep[i] = True
    return out, keep
