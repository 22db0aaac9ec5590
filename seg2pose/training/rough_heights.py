"""Default heights without annotations (paper 3.2 + 3.5): the bisection of ``seg2pose.method.heights``
run on rough-model renders instead of masks matched to ground truth.

Rough models (``seg2pose.synth.rough``) are drawn at random positions and headings on the
scene's ground and rasterised into each camera; their true ground positions are known, so the
height that puts about half of their normal positions closer to the camera than the truth can
be found for any calibrated scene, before anyone has annotated a frame.
"""

from __future__ import annotations

import numpy as np

from seg2pose.core.errors import S2PError
from seg2pose.geometry.normal import DEFAULT_CENTER_METHOD
from seg2pose.io.scene import Scene
from seg2pose.structures.masks import mask_centers
from seg2pose.training.rough_video import render_video_examples, video_look

ROUGH_CLASSES = ("pedestrian", "bicyclist", "car")


def rough_height_views(scene: Scene, n_per_class: int = 2000, seed: int = 0,
                       center: str | None = None, cameras: list[str] | None = None,
                       video: bool = False) -> dict[str, list]:
    """Per class name with a rough model, the bisection input of
    ``normal.default_height_bisection``: [(camera, mask centres (N, 2) pixels, true ground
    positions (N, 2) metres)], ``n_per_class`` renders spread over the cameras.

    ``video``: film the rough models over the camera's video background and take the masks the
    background subtraction makes of them (``seg2pose.training.rough_video``): shadow remnants and the
    closing move mask centres (measured on synthetic video: the heights move by at most 1.2 cm,
    docs/RESULTS.md, so it is off by default)."""
    try:
        from seg2pose.synth.rough import render_rough_examples  # lazy: loads OpenCV
    except ImportError as e:  # pragma: no cover - the synth package ships with s2p
        raise S2PError(f"rough 3D models are not available ({e})") from None
    center = center or DEFAULT_CENTER_METHOD
    names = cameras or list(scene.cameras)
    rng = np.random.default_rng(seed)
    views: dict[str, list] = {}
    per_cam = max(n_per_class // max(len(names), 1), 1)

    looks = {n: video_look(scene, n) for n in names if video and scene.video_path(n)}
    for c in scene.classes:
        if c.name not in ROUGH_CLASSES:
            continue
        for name in names:
            cam = scene.cameras[name]
            if name in looks:
                rles, xyz, _, _ = render_video_examples(cam, scene.ground, c.name, per_cam, rng,
                                                     looks[name])
            else:
                rles, xyz, _ = render_rough_examples(cam, scene.ground, c.name, per_cam, rng)
            cen = mask_centers(rles, cam.height, cam.width, center)
            views.setdefault(c.name, []).append((cam, cen, xyz[:, :2]))
    return views
