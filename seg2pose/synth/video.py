"""Simple RGB frames of a synthetic scene, written to ``video/<camera>.mp4``.

A textured static background (asphalt, lane markings, stop lines, zebra crossings, paved
sidewalks with curbs, grass), computed once per camera by casting every pixel's ray onto the
true surface; per frame, the road users' shadows (parts projected onto the ground along the
sun direction) and their Lambert-shaded faces in painter's order, then sensor noise. With a
``look.Look`` (the wide preset's "rich"), clouds change the light over time and the bodies are
textured. Good enough for the background-subtraction path and for review; not photorealistic.

Pixels: x right, y down, origin at the top-left corner of the top-left pixel.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from seg2pose.geometry.camera import Camera
from seg2pose.io.atomic import atomic_path
from seg2pose.io.disk import disk_full, write_failed
from seg2pose.synth import junction as J
from seg2pose.synth.look import (
    AMBIENT,
    BodyTextures,
    Look,
    draw_clouds,
    draw_textures,
    exposure_gain,
    ground_light,
    sun_strength,
    texture_values,
)
from seg2pose.synth.raster import SHIFT, project_parts
from seg2pose.synth.shapes import BODY, FACES, FRAME, GLASS, LEGS, SKIN, TOP, WHEEL
from seg2pose.synth.world import World

SUN = np.array([0.45, 0.3, -1.0]) / np.linalg.norm([0.45, 0.3, -1.0])  # direction of the light
NOISE_SIGMA = 3.0  # grey levels of sensor noise
TEXTURED = (BODY, TOP, FRAME, LEGS)  # parts that carry a pattern (paint, clothes), not glass or skin


def _hash_noise(x: np.ndarray, y: np.ndarray, scale: float) -> np.ndarray:
    """A cheap deterministic texture in [-1, 1] from world coordinates (metres)."""
    a = np.sin(x * 12.9898 * scale + y * 78.233 * scale) * 43758.5453
    return 2.0 * (a - np.floor(a)) - 1.0


def background(camera: Camera) -> np.ndarray:
    """(H, W, 3) uint8 BGR image of the empty junction seen by ``camera``."""
    H, W = camera.height, camera.width
    v, u = np.mgrid[0:H, 0:W]
    uv = np.column_stack([u.ravel() + 0.5, v.ravel() + 0.5])
    X = J.ray_ground_points(camera.center, camera.unproject(uv))
    sky = ~np.isfinite(X[:, 0])
    Xg = np.where(sky[:, None], 0.0, X)
    x, y = Xg[:, 0], Xg[:, 1]
    d = J.curb_distance(Xg[:, :2])
    img = np.empty((len(x), 3), np.float32)
    road = d < 0
    img[:] = (150, 152, 148)                      # sidewalk paving
    tiles = ((np.floor(x / 0.6) + np.floor(y / 0.6)) % 2) == 0
    img[~road & tiles] *= 0.93
    img[road] = (78, 80, 84)                      # asphalt
    grass = d > J.SIDEWALK
    img[grass] = (60, 115, 70)
    curb = np.abs(d) < 0.18
    img[curb] = (185, 185, 182)
    # road markings, per arm in arm coordinates (a along the arm, b across)
    for th in J.ARM_ANGLES.values():
        c, s = np.cos(th), np.sin(th)
        a = x * c + y * s
        b = -x * s + y * c
        on_arm = road & (a > J.ROAD_HALF) & (np.abs(b) < J.ROAD_HALF)
        beyond = a > J.ROAD_HALF + J.CROSSWALK[1] + 1.0
        centre = on_arm & beyond & (np.abs(b) < 0.08)
        lanes = on_arm & beyond & (np.abs(np.abs(b) - J.LANE) < 0.06) & ((a % 6.0) < 3.0)
        stop = on_arm & (np.abs(a - (J.ROAD_HALF + J.CROSSWALK[1] + 1.0)) < 0.2) & (b > 0)
        zebra = on_arm & (a > J.ROAD_HALF + J.CROSSWALK[0]) & (a < J.ROAD_HALF + J.CROSSWALK[1]) \
            & ((b % 1.0) < 0.5)
        img[centre | lanes | stop | zebra] = (215, 215, 215)
    tex = _hash_noise(x, y, 1.0)[:, None] * 9.0
    img += tex
    # farther ground fades towards a haze colour
    dist = np.linalg.norm(Xg - camera.center, axis=1)
    fog = np.clip((dist - 40.0) / 80.0, 0, 0.6)[:, None]
    img = img * (1 - fog) + np.array([200, 195, 190]) * fog
    img[sky] = (225, 200, 170)
    return np.clip(img, 0, 255).astype(np.uint8).reshape(H, W, 3)


def _part_colours(world: World, tracks: np.ndarray, kinds: np.ndarray, owner: np.ndarray
                  ) -> np.ndarray:
    """(P, 3) float BGR base colour of each part."""
    own = world.colour[tracks[owner] - 1].astype(np.float32)
    col = own.copy()
    col[kinds == GLASS] = (70, 55, 45)
    col[kinds == WHEEL] = (25, 25, 25)
    col[kinds == SKIN] = (120, 150, 200)
    # trousers: a darker shade derived from the track id (deterministic)
    legs = kinds == LEGS
    col[legs] = np.stack([40 + (tracks[owner[legs]] * 37) % 60,
                          35 + (tracks[owner[legs]] * 17) % 40,
                          30 + (tracks[owner[legs]] * 23) % 50], 1)
    col[(kinds == BODY) | (kinds == TOP) | (kinds == FRAME)] = own[(kinds == BODY) | (kinds == TOP) | (kinds == FRAME)]
    return col


def render_frame(camera: Camera, world: World, f: int, bg: np.ndarray, sun: float = 1.0,
                 textures: BodyTextures | None = None) -> np.ndarray:
    """One RGB (BGR) frame (H, W, 3) uint8 without sensor noise.

    sun: share of the direct sunlight (``look.sun_strength``; 1: full sun, the flat look);
    textures: each road user's pattern (``look.draw_textures``) or None (plain bodies)."""
    gain = float(exposure_gain(sun))  # 1.0 at full sun, so the flat look's bytes are unchanged
    img = bg.copy() if sun == 1.0 else cv2.convertScaleAbs(bg, alpha=float(ground_light(sun)) * gain)
    r, wv, owner = world.frame_parts(f)
    if len(owner) == 0:
        return img
    tracks = world.track[r]
    kinds = world.part_kinds(f)
    # shadows: every vertex slides along the sun direction down to its road user's ground
    ground_z = world.xyz[r][owner, 2][:, None]
    t = (ground_z - wv[:, :, 2]) / SUN[2]
    sh = wv + t[:, :, None] * SUN
    uv_s, ok_s = project_parts(camera, sh)
    shadow = np.zeros(img.shape[:2], np.uint8)
    pts = np.clip(np.round((uv_s - 0.5) * (1 << SHIFT)), -2**28, 2**28).astype(np.int32)
    for p in pts[ok_s]:
        cv2.fillConvexPoly(shadow, cv2.convexHull(p), 1, cv2.LINE_8, SHIFT)
    m = shadow.astype(bool)
    img[m] = (bg[m] * (AMBIENT * gain)).astype(np.uint8)  # skylight only
    # road users: parts far to near (by part centre), visible faces Lambert-shaded
    uv, ok = project_parts(camera, wv)
    cen = wv.mean(axis=1)
    depth = np.linalg.norm(cen - camera.center, axis=1)
    agent_depth = np.linalg.norm(world.xyz[r] - camera.center, axis=1)
    order = np.lexsort((-depth, -agent_depth[owner]))
    fv = wv[:, FACES]                              # (P, 6, 4, 3)
    n = np.cross(fv[:, :, 1] - fv[:, :, 0], fv[:, :, 3] - fv[:, :, 0])
    fc = fv.mean(axis=2)
    n *= np.sign(np.einsum("pfk,pfk->pf", n, fc - cen[:, None]))[..., None]  # outwards
    nn = np.linalg.norm(n, axis=2, keepdims=True)
    n = n / np.maximum(nn, 1e-12)
    facing = np.einsum("pfk,pfk->pf", n, fc - camera.center) < 0
    # faces: skylight 0.45 + sunlight 0.55 cos (Lambert), the sun's share dimmed by a cloud
    light = 0.45 + (0.55 * sun) * np.clip(-np.einsum("pfk,k->pf", n, SUN), 0, 1)
    col = _part_colours(world, tracks, kinds, owner)
    fpts = np.clip(np.round((uv[:, FACES] - 0.5) * (1 << SHIFT)), -2**28, 2**28).astype(np.int32)
    # which road user (row + 1) shows its pattern at each pixel, 0 where none does
    body = np.zeros(img.shape[:2], np.int32) if textures is not None else None
    for p in order:
        if not ok[p]:
            continue
        for k in np.flatnonzero(facing[p] & (nn[p, :, 0] > 1e-9)):
            c = tuple(float(v) for v in np.clip(col[p] * light[p, k] * gain, 0, 255))
            face = np.ascontiguousarray(fpts[p, k])
            cv2.fillConvexPoly(img, face, c, cv2.LINE_8, SHIFT)
            if body is not None:
                cv2.fillConvexPoly(body, face, int(owner[p]) + 1 if kinds[p] in TEXTURED else 0,
                                   cv2.LINE_8, SHIFT)
    if body is not None and textures is not None:  # one is None when the other is
        _paint_textures(img, body, camera, world, r, textures, gain)
    return img


def _paint_textures(img: np.ndarray, body: np.ndarray, camera: Camera, world: World, r: slice,
                    textures: BodyTextures, gain: float) -> None:
    """Add each road user's pattern to its pixels (``body``: row + 1 per pixel, 0: none), in
    metres on the body measured from its projected centre, so the pattern moves and scales
    with it."""
    vv, uu = np.nonzero(body)
    if len(vv) == 0:
        return
    row = body[vv, uu] - 1
    tracks = world.track[r]
    centre = world.xyz[r] + np.column_stack([np.zeros((len(tracks), 2)),
                                             world.size[tracks - 1, 2] / 2])
    uvc, zc, _ = camera.project_points(centre)
    ppm = camera.K[0, 0] / np.maximum(zc, 0.5)  # pixels per metre at the road user's distance
    x = (uu + 0.5 - uvc[row, 0]) / ppm[row]
    y = (vv + 0.5 - uvc[row, 1]) / ppm[row]
    d = texture_values(textures, tracks[row], x, y) * gain
    img[vv, uu] = np.clip(img[vv, uu] + d[:, None], 0, 255).astype(np.uint8)


def write_video(path: Path, camera: Camera, cam_index: int, world: World, seed: int,
                fps: float, frames: range | None = None, look: Look = Look()) -> None:
    """Render every frame of ``world`` for ``camera`` into an mp4 (mp4v) at ``path``; ``look``
    adds a change of light and textured bodies (the same clouds and patterns in every camera)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    bg = background(camera)
    rng = np.random.default_rng([seed, 201, cam_index])
    bank = [rng.normal(0, NOISE_SIGMA, size=bg.shape) for _ in range(6)]
    pos = [np.clip(b, 0, 255).astype(np.uint8) for b in bank]
    neg = [np.clip(-b, 0, 255).astype(np.uint8) for b in bank]
    sun = (sun_strength(draw_clouds(seed, world.n_frames / fps), np.arange(world.n_frames) / fps)
           if look.light_change else np.ones(world.n_frames))
    textures = None
    if look.textures:
        track_cls = np.zeros(int(world.track.max(initial=0)), np.int8)  # each track's class
        track_cls[world.track - 1] = world.cls
        textures = draw_textures(track_cls, seed)
    level = cv2.utils.logging.getLogLevel()
    # a frame that does not fit is a warning on stderr per frame from OpenCV's writer (no
    # error returned): quiet, and judged by the room left once the video is closed
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
    try:
        with atomic_path(path) as tmp:  # .NAME.partial-PID-x.mp4, renamed when complete
            wr = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), float(fps),  # type: ignore[attr-defined]  # in cv2, not in its stubs
                                 (camera.width, camera.height))
            if not wr.isOpened():
                raise write_failed(path, "OpenCV cannot open an mp4v video there (this OpenCV has no mp4v "
                                   "encoder?)")
            try:
                for f in (frames if frames is not None else range(world.n_frames)):
                    img = render_frame(camera, world, f, bg, float(sun[f]), textures)
                    k = int(rng.integers(len(bank)))
                    img = cv2.subtract(cv2.add(img, pos[k]), neg[k])
                    wr.write(img)
            finally:
                wr.release()
            if disk_full(tmp):  # its last frames did not fit: never swapped in cut short
                raise write_failed(path, "the disk is full")
    finally:
        cv2.utils.logging.setLogLevel(level)
