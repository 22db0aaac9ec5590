"""Rough-model examples that look like background-subtraction masks (paper 3.5 for the video path).

Masks made from video (``seg2pose.video.video_masks``) are not the clean silhouettes that rough models
rasterise to: shadow remnants stick to them, the closing fills and widens them, pixels whose
colour matches the background drop out, neighbours merge into one blob and road users in front
cut them. A network trained on clean rough silhouettes alone learns residuals that do not fit
such masks (issue 13 measured zero-annotation training making a bg-sub baseline worse).

So the rough models are *filmed* instead: drawn in random colours, Lambert-shaded, with a cast
shadow of random strength and sun direction, over the scene's own background image (the median
of its video, the image the subtractor starts from), with sensor noise of the video's measured
strength, and passed through the same background subtraction (``video_masks.BackgroundMasks``:
MOG2/KNN with shadow removal, opening, closing, components, minimum area) with the scene's
settings. Some targets get a neighbour standing 0.8-4 m away (merged blobs) or a road user in
front (``rough.occluder_parts``; partial occlusion). Every component whose road-user pixels
are mostly a target's becomes an example with that target's true position, so a fragment, a
widened blob and a merged blob are examples just as the video path would deliver them; a
target the subtractor misses gives none.

Several targets share one frame when their boxes (with shadows) do not touch, so one
subtractor call serves several examples. Pixels: x right, y down, origin at the top-left
corner of the top-left pixel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pycocotools import mask as mask_util

from seg2pose.core.errors import InputError
from seg2pose.geometry.camera import Camera
from seg2pose.geometry.ground import GroundSurface
from seg2pose.io.scene import Scene
from seg2pose.io.video import camera_reader
from seg2pose.synth.shapes import FACES
from seg2pose.video.video_masks import BackgroundMasks, BgConfig

NEIGHBOUR_CLASSES = (("car", 0.45), ("pedestrian", 0.4), ("bicyclist", 0.15))
MARGIN_PX = 12  # gap kept between targets of one frame (the closing must not join them)
# a target waiting for a frame: its group's parts, contact point xyz, box (pixels), heading
_Queued = tuple[list[np.ndarray], np.ndarray, tuple[int, int, int, int], float]


@dataclass
class VideoLook:
    """What a camera's video looks like to the subtractor: the median background (H, W, 3)
    uint8 BGR, the sensor noise (grey levels, standard deviation) and the scene's
    background-subtraction settings."""

    background: np.ndarray
    noise_sigma: float
    bg: BgConfig


def video_look(scene: Scene, camera: str, samples: int | None = None) -> VideoLook:
    """The camera's ``VideoLook``: the median of ``samples`` frames spread over its video
    (the subtractor's own start, ``BgConfig.init_samples`` by default) and the noise measured
    as the robust spread (1.4826 MAD) of frame minus background."""
    cfg = BgConfig.from_dict(scene.extra.get("video_masks"), file=scene.root / "scene.json")
    reader = camera_reader(scene, camera)
    _, _, n = reader.header()
    n = n or 300
    k = samples or cfg.init_samples
    want = np.unique(np.linspace(reader.first, reader.first + (n - 1) * reader.step, k)
                     .round().astype(np.int64))
    ims = [im for _, im in reader.sample(want)]
    if not ims:
        raise InputError("no frames could be read for the rough-model background",
                         file=reader.path)
    bg = np.sort(np.stack(ims), axis=0)[(len(ims) - 1) // 2]
    spreads = []
    for im in ims[:: max(len(ims) // 5, 1)]:
        d = im.astype(np.int16) - bg.astype(np.int16)
        spreads.append(1.4826 * float(np.median(np.abs(d - np.median(d)))))
    return VideoLook(bg, max(float(np.median(spreads)), 0.5), cfg)


def _segmenter(look: VideoLook, rng: np.random.Generator, noise: list[np.ndarray]
               ) -> BackgroundMasks:
    """A subtractor started as the video path starts it (median background), then settled on
    noisy copies of the background so its variances fit the noise; afterwards frozen
    (learning rate 0), so an example does not depend on the ones before it."""
    H, W = look.background.shape[:2]
    seg = BackgroundMasks(look.bg, H, W)
    seg.prime([look.background])
    seg.lr = 0.05
    for i in range(60):
        seg.apply(_noisy(look.background, noise[i % len(noise)]))
    seg.lr = 0.0
    return seg


def _noisy(img: np.ndarray, noise: np.ndarray) -> np.ndarray:
    return np.clip(img.astype(np.int16) + noise, 0, 255).astype(np.uint8)


def _sun(rng: np.random.Generator) -> np.ndarray:
    """A random light direction (unit, pointing down): azimuth uniform, elevation 40-75 deg."""
    az, el = rng.uniform(-np.pi, np.pi), np.deg2rad(rng.uniform(40, 75))
    return np.array([np.cos(az) * np.cos(el), np.sin(az) * np.cos(el), -np.sin(el)])


def _group(camera: Camera, ground: GroundSurface, cls: str, xyz: np.ndarray, hd: float, sc: float,
           rng: np.random.Generator, neighbours: float, occlusion: float) -> list[np.ndarray]:
    """World parts (P, 8, 3) of one target (first) and its optional neighbour and occluder."""
    from seg2pose.synth.rough import occluder_parts, place, rough_model  # lazy: loads OpenCV

    objs = [place(rough_model(cls) * sc, hd, xyz)]
    if rng.random() < neighbours:
        names, weights = [c for c, _ in NEIGHBOUR_CLASSES], [w for _, w in NEIGHBOUR_CLASSES]
        ncls = names[int(rng.choice(len(names), p=np.array(weights) / sum(weights)))]
        ang, dist = rng.uniform(-np.pi, np.pi), rng.uniform(0.8, 4.0)
        nxy = xyz[:2] + dist * np.array([np.cos(ang), np.sin(ang)])
        nz = float(ground.height(nxy[None])[0])
        objs.append(place(rough_model(ncls) * rng.uniform(0.92, 1.08), rng.uniform(-np.pi, np.pi),
                          [nxy[0], nxy[1], nz]))
    if rng.random() < occlusion:
        objs.append(occluder_parts(camera, ground, xyz[:2], rng))
    return objs


def _shadow_parts(parts: np.ndarray, ground_z: float, sun: np.ndarray) -> np.ndarray:
    """Parts (P, 8, 3) slid along ``sun`` down to the plane z = ground_z (their cast shadow)."""
    t = (ground_z - parts[..., 2]) / sun[2]
    return parts + t[..., None] * sun


def _fill(buf: np.ndarray, uv: np.ndarray, value) -> None:
    """Fill the convex hull of uv (M, 2) pixels into buf (H, W[, 3]) with value."""
    import cv2

    from seg2pose.synth.raster import SHIFT  # lazy: loads OpenCV

    pts = np.clip(np.round((uv - 0.5) * (1 << SHIFT)), -2**28, 2**28).astype(np.int32)
    cv2.fillConvexPoly(buf, cv2.convexHull(pts), value, cv2.LINE_8, SHIFT)


def _film(camera: Camera, groups: list[list[np.ndarray]], ground_z: list[float], look: VideoLook,
          rng: np.random.Generator, noise: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One frame of the groups over the background: (image (H, W, 3) uint8, object label
    image (H, W) int32: 1 + index of the visible object in ``[o for g in groups for o in g]``,
    0 for background and shadow)."""
    from seg2pose.synth.raster import project_parts  # lazy: loads OpenCV

    img = look.background.copy()
    H, W = img.shape[:2]
    lab = np.zeros((H, W), np.int32)
    sun = _sun(rng)
    objs = [(o, z) for g, z in zip(groups, ground_z) for o in g]
    shadow = np.zeros((H, W), np.uint8)
    for o, z in objs:
        uv, ok = project_parts(camera, _shadow_parts(o, z, sun))
        for p in np.flatnonzero(ok):
            _fill(shadow, uv[p], 1)
    m = shadow.astype(bool)
    img[m] = (img[m] * rng.uniform(0.4, 0.8)).astype(np.uint8)
    # road users far to near (painter's order), each part's visible faces Lambert-shaded
    depth = [float(np.linalg.norm(o.reshape(-1, 3).mean(0) - camera.center)) for o, _ in objs]
    for i in np.argsort(depth)[::-1]:
        o = objs[i][0]
        base = rng.uniform(15, 240, 3)
        uv, ok = project_parts(camera, o)
        cen = o.mean(axis=1)
        pd = np.linalg.norm(cen - camera.center, axis=1)
        for p in np.argsort(pd)[::-1]:
            if not ok[p]:
                continue
            col = base if rng.random() < 0.7 else rng.uniform(15, 240, 3)
            fv = o[p][FACES]                                   # (6, 4, 3)
            n = np.cross(fv[:, 1] - fv[:, 0], fv[:, 3] - fv[:, 0])
            fc = fv.mean(axis=1)
            n *= np.sign(np.einsum("fk,fk->f", n, fc - cen[p]))[:, None]
            nn = np.linalg.norm(n, axis=1)
            n = n / np.maximum(nn, 1e-12)[:, None]
            facing = (np.einsum("fk,fk->f", n, fc - camera.center) < 0) & (nn > 1e-9)
            light = 0.45 + 0.55 * np.clip(-n @ sun, 0, 1)
            for f in np.flatnonzero(facing):
                fuv = uv[p][FACES[f]]
                _fill(img, fuv, tuple(float(v) for v in np.clip(col * light[f], 0, 255)))
                _fill(lab, fuv, int(i) + 1)
    return _noisy(img, noise), lab


def render_video_examples(camera: Camera, ground: GroundSurface, cls: str, n: int,
                          rng: np.random.Generator, look: VideoLook, neighbours: float = 0.3,
                          occlusion: float = 0.2, per_frame: int = 8, scale_jitter: float = 0.08
                          ) -> tuple[list[bytes], np.ndarray, np.ndarray, dict]:
    """``n`` rough-model examples of class ``cls`` as the video path would segment them.

    Returns the masks (compressed RLE), the true ground-contact positions (n, 3) metres, the
    headings (n,) radians and counts: frames filmed, targets placed, targets that gave no mask,
    examples from a blob holding another road user too (merged). Sizes vary by
    ``scale_jitter`` (relative), as in ``rough.render_rough_examples``."""
    from seg2pose.synth.raster import project_parts  # lazy: loads OpenCV
    from seg2pose.synth.rough import MAX_DISTANCE, visible_region  # lazy: loads OpenCV

    if n <= 0:
        return [], np.zeros((0, 3)), np.zeros(0), {"frames": 0, "targets": 0, "missed": 0,
                                                   "merged": 0}
    H, W = camera.height, camera.width
    if look.background.shape[:2] != (H, W):
        raise InputError(f"the video is {look.background.shape[1]}x{look.background.shape[0]}, the "
                         f"calibration {W}x{H}", field="background")
    x0r, x1r, y0r, y1r = visible_region(camera, ground, MAX_DISTANCE)
    noise = [rng.normal(0, look.noise_sigma, look.background.shape).astype(np.int16)
             for _ in range(4)]
    seg = _segmenter(look, rng, noise)
    rles: list[bytes] = []
    xyz_out: list[np.ndarray] = []
    hd_out: list[float] = []
    stats = {"frames": 0, "targets": 0, "missed": 0, "merged": 0}
    queue: list[_Queued] = []
    while len(rles) < n:
        if stats["frames"] > 50 + 20 * n:
            raise InputError(f"could not film {n} {cls} rough models that the background "
                             "subtraction sees", field="rough_video")
        # candidates: contact point in (a margin around) the image, within MAX_DISTANCE
        while len(queue) < 4 * per_frame:
            xy = np.array([rng.uniform(x0r, x1r), rng.uniform(y0r, y1r)])
            xyz = np.array([xy[0], xy[1], float(ground.height(xy[None])[0])])
            uv0, d0, front = camera.project_points(xyz[None])
            if not (front[0] and np.linalg.norm(xyz - camera.center) <= MAX_DISTANCE
                    and -0.25 * W < uv0[0, 0] < 1.25 * W and -0.25 * H < uv0[0, 1] < 1.25 * H):
                continue
            hd = rng.uniform(-np.pi, np.pi)
            g = _group(camera, ground, cls, xyz, hd,
                       1.0 + rng.uniform(-scale_jitter, scale_jitter), rng, neighbours, occlusion)
            pts = []
            for o in g:
                for parts in (o, _shadow_parts(o, xyz[2], np.array([0.0, 0.0, -1.0]))):
                    uv, ok = project_parts(camera, parts)
                    if not ok.all():
                        break
                    pts.append(uv.reshape(-1, 2))
            if len(pts) < 2 * len(g):
                continue
            uv = np.concatenate(pts)
            # shadows can fall up to ~1.7 m beside the model: grow the box by a third
            bx0, by0 = uv.min(0)
            bx1, by1 = uv.max(0)
            gx, gy = (bx1 - bx0) / 3 + MARGIN_PX, (by1 - by0) / 3 + MARGIN_PX
            box = (int(bx0 - gx), int(by0 - gy), int(bx1 + gx), int(by1 + gy))
            if box[2] <= 0 or box[3] <= 0 or box[0] >= W or box[1] >= H:
                continue
            queue.append((g, xyz, box, hd))
        # a frame: targets from the queue whose boxes do not overlap (the rest wait)
        chosen: list[_Queued] = []
        rest: list[_Queued] = []
        boxes: list[tuple[int, int, int, int]] = []
        for item in queue:
            b = item[2]
            if len(chosen) < per_frame and all(b[2] <= c[0] or c[2] <= b[0] or b[3] <= c[1]
                                               or c[3] <= b[1] for c in boxes):
                chosen.append(item)
                boxes.append(b)
            else:
                rest.append(item)
        queue = rest
        groups = [c[0] for c in chosen]
        img, lab = _film(camera, groups, [float(c[1][2]) for c in chosen], look, rng,
                         noise[stats["frames"] % len(noise)])
        stats["frames"] += 1
        stats["targets"] += len(chosen)
        target_of = {}  # object label -> chosen index, for the targets (first of each group)
        k = 1
        for j, g in enumerate(groups):
            target_of[k] = j
            k += len(g)
        comps, _ = seg.apply(img)
        got = np.zeros(len(chosen), bool)
        if comps:
            dec = mask_util.decode([{"size": [H, W], "counts": r} for r in comps])
            for c in range(len(comps)):
                cnt = np.bincount(lab[dec[:, :, c].astype(bool)], minlength=k)[1:]
                if not cnt.any():
                    continue  # a shadow remnant or noise alone
                owner = int(np.argmax(cnt)) + 1
                if owner not in target_of or len(rles) >= n:
                    continue
                j = target_of[owner]
                got[j] = True
                stats["merged"] += int(np.count_nonzero(cnt) > 1)
                rles.append(comps[c])
                xyz_out.append(chosen[j][1])
                hd_out.append(chosen[j][3])
        stats["missed"] += int((~got).sum())
    return rles, np.asarray(xyz_out, float).reshape(-1, 3), np.asarray(hd_out, float), stats
