"""Zero-annotation training's last step (paper 3.5 extended): the radial calibration of a model
trained on rough models alone, from unlabelled masks."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from seg2pose.geometry.normal import DEFAULT_CENTER_METHOD, normal_positions
from seg2pose.io.scene import Scene
from seg2pose.method.checkpoint import Checkpoint, predict_residuals
from seg2pose.structures.masks import mask_centers


def calibrate_radial(scene: Scene, path: Path, split: str | None = "train",
                     max_per_class: int = 1500, center_method: str = DEFAULT_CENTER_METHOD) -> dict[str, float]:
    """Per-class radial offsets of a zero-annotation model from *unlabelled* masks.

    The default heights of 3.2 make the normal positions unbiased along the viewing direction
    (about half closer than the truth, half further). Rough models are not the real road
    users, so a network trained on them alone learns a radial bias that the real ones do not
    have. This finds, per class, the median radial component of the model's residuals over
    the masks of ``split`` (no ground truth used) and stores it in the checkpoint as
    ``radial_offset``; ``Checkpoint.predict`` subtracts it. Returns the offsets (metres)."""
    ck = Checkpoint.load(path)
    ck.info.pop("radial_offset", None)
    cams = ck.info.get("cameras") or [ck.camera]
    heights = scene.default_heights()
    by_id = scene.class_by_id()
    classes = ck.classes or [ck.cls]
    radial: dict[str, list[np.ndarray]] = {c: [] for c in classes}
    rng = np.random.default_rng(0)
    for cam in cams:
        camera = scene.cameras[cam]
        rles, names = [], []
        for _, t in scene.iter_masks(cam, scene.split_range(split)):
            for r, c in zip(t.rles, t.class_id):
                if by_id[int(c)].name in radial:
                    rles.append(r)
                    names.append(by_id[int(c)].name)
        names = np.array(names, object)
        for c in classes:
            sel = np.flatnonzero(names == c)
            if len(sel) > max_per_class // len(cams):
                sel = rng.choice(sel, max_per_class // len(cams), replace=False)
            if not len(sel):
                continue
            rl = [rles[i] for i in sel]
            uv = mask_centers(rl, camera.height, camera.width, center_method)
            n, _ = normal_positions(camera, scene.ground, uv, heights[c])
            ok = np.flatnonzero(np.isfinite(n[:, 0]))
            if not len(ok):
                continue
            res = predict_residuals(scene, cam, ck, [rl[i] for i in ok], camera.height,
                                    camera.width, uv[ok], n[ok, :2], names[sel][ok])
            u = n[ok, :2] - camera.center[:2]
            u /= np.linalg.norm(u, axis=1, keepdims=True)
            radial[c].append(np.sum(res * u, axis=1))
    offsets = {c: float(np.median(np.concatenate(v))) for c, v in radial.items() if v}
    ck.info["radial_offset"] = offsets
    ck.save(path)
    return offsets
