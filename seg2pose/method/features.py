"""Mask geometry: exact scalar cues of a mask for Seg2PoseNet, beside the crop (an extension).

The paper's network sees a 420x420 crop and the 4-vector (crop centre, normal position). On a
CPU the crop is seen downsampled (``lite``: a third of the resolution), which loses the 1-3 px
cues that place a road user along the viewing ray: where the bottom of the mask is (the feet,
the wheels), how tall the mask is against how tall the class should look at that distance (a
pedestrian behind a car shows only its upper body; an individual's height), and whether the
image border cuts the mask. These are all cheap and exact from the RLE runs (``rle_stats``) and
the calibration, so ``mask_geometry`` computes them and ``NetConfig.n_geo`` appends them to the
network's vector. With ``n_geo = 0`` (the paper arch's default) nothing changes.

The features (``GEO_NAMES``; version ``GEO_VERSION``, recorded in checkpoints), per mask:

- ``box_w``, ``box_h``: bounding-box size / 100 px;
- ``centroid_dx``, ``centroid_dy``: pixel centroid minus the mask centre (the crop centre) / 10 px;
- ``fill``: area / box area, in [0, 1];
- ``foot_dx``, ``foot_dy``: where the ray through the bottom-centre of the box meets the ground
  (height 0), minus the normal position, metres / 2;
- ``top_dx``, ``top_dy``: the ray through the top-centre of the box at twice the class's
  default height (the top of a typical road user), minus the normal position, metres / 2;
- ``h_ratio``: box height / the pixel height of a vertical segment of the class's typical
  height standing at the normal position, minus 1 (negative: shorter than expected, e.g. occluded legs);
- ``cut_left``, ``cut_top``, ``cut_right``, ``cut_bottom``: 1 where the box touches that image
  border (a truncated road user).

Rays that miss the ground give 0 for their two features; every feature is clipped to [-5, 5].
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from seg2pose.geometry.camera import Camera
from seg2pose.geometry.ground import GroundSurface
from seg2pose.geometry.normal import normal_positions
from seg2pose.structures.masks import rle_stats

GEO_VERSION = "geo1"
GEO_NAMES = ("box_w", "box_h", "centroid_dx", "centroid_dy", "fill", "foot_dx", "foot_dy",
             "top_dx", "top_dy", "h_ratio", "cut_left", "cut_top", "cut_right", "cut_bottom")
N_GEO = len(GEO_NAMES)


def mask_geometry(camera: Camera, ground: GroundSurface, rles: Sequence[bytes], height: int,
                  width: int, centers: np.ndarray, normal_xy: np.ndarray,
                  default_heights: np.ndarray, class_heights: np.ndarray) -> np.ndarray:
    """The features of ``GEO_NAMES`` (N, 14) float32 for N masks of one camera.

    rles: N COCO RLE strings of ``height`` x ``width`` images; centers (N, 2) pixels: the mask
    centres the normal positions were computed from; normal_xy (N, 2) metres; default_heights
    (N,) metres: each mask's class default height (paper 3.2); class_heights (N,) metres: the
    typical height of each mask's class (``Scene.class_sizes``)."""
    n = len(rles)
    out = np.zeros((n, N_GEO), np.float64)
    if n == 0:
        return out.astype(np.float32)
    centers = np.asarray(centers, float).reshape(-1, 2)
    normal_xy = np.asarray(normal_xy, float).reshape(-1, 2)
    dh = np.broadcast_to(np.asarray(default_heights, float), (n,))
    ch = np.broadcast_to(np.asarray(class_heights, float), (n,))
    area, centroid, box = rle_stats(rles, height, width)
    bw, bh = box[:, 2] - box[:, 0], box[:, 3] - box[:, 1]
    out[:, 0], out[:, 1] = bw / 100.0, bh / 100.0
    out[:, 2:4] = (centroid - centers) / 10.0
    with np.errstate(invalid="ignore", divide="ignore"):
        out[:, 4] = area / np.maximum(bw * bh, 1.0)
    cu = (box[:, 0] + box[:, 2]) / 2
    ok = np.isfinite(cu)
    if ok.any():
        foot, _ = normal_positions(camera, ground, np.stack([cu, box[:, 3]], 1)[ok], 0.0)
        top, _ = normal_positions(camera, ground, np.stack([cu, box[:, 1]], 1)[ok], 2 * dh[ok])
        out[ok, 5:7] = (foot[:, :2] - normal_xy[ok]) / 2.0
        out[ok, 7:9] = (top[:, :2] - normal_xy[ok]) / 2.0
    # expected pixel height: the image of a vertical segment of the class's typical height
    # standing at the normal position (foreshortened by the view from above)
    z = ground.height(np.nan_to_num(normal_xy))
    foot3 = np.column_stack([normal_xy, z])
    uv0 = camera.project_points(foot3)[0]
    uv1 = camera.project_points(foot3 + np.outer(ch, [0.0, 0.0, 1.0]))[0]
    with np.errstate(invalid="ignore", divide="ignore"):
        out[:, 9] = bh / np.abs(uv0[:, 1] - uv1[:, 1]) - 1.0
    out[:, 10] = box[:, 0] <= 0
    out[:, 11] = box[:, 1] <= 0
    out[:, 12] = box[:, 2] >= width
    out[:, 13] = box[:, 3] >= height
    out = np.clip(np.nan_to_num(out, nan=0.0, posinf=5.0, neginf=-5.0), -5.0, 5.0)
    return out.astype(np.float32)


def scene_geometry(scene, camera: str, rles: Sequence[bytes], height: int, width: int,
                   centers: np.ndarray, normal_xy: np.ndarray, class_names: np.ndarray) -> np.ndarray:
    """``mask_geometry`` for masks of ``scene``'s ``camera`` with class names (N,): the default
    heights and typical class heights are looked up in the scene (unknown classes: NaN, whose
    features become 0)."""
    default = scene.default_heights()
    sizes = scene.class_sizes()
    names = [str(c) for c in np.asarray(class_names, object).reshape(-1)]
    dh = np.array([default.get(c, np.nan) for c in names], float)
    ch = np.array([sizes.get(c, (np.nan,) * 3)[2] for c in names], float)
    return mask_geometry(scene.cameras[camera], scene.ground, rles, height, width, centers,
                         normal_xy, dh, ch)
