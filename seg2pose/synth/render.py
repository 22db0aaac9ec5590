"""Instance masks of one camera and frame: painter's order into an id buffer, then noise, RLE.

Per frame: all road users' part vertices are projected at once; each part's convex hull is
filled with its road user's index, far road users first, so nearer ones overwrite them
(mutual occlusion); the image border truncates masks by itself. Each road user's visible mask
is then a crop of the buffer around its projected box, so nothing is decoded at full size.
"""

from __future__ import annotations

import numpy as np

from seg2pose.geometry.camera import Camera
from seg2pose.structures.masks import rle_contains
from seg2pose.synth.noise import Det, NoiseConfig, apply_noise
from seg2pose.synth.raster import bbox_of, fill_parts, project_parts, rle_from_crop_t
from seg2pose.synth.world import World

MATCH_RULES = ("all", "center")


class FrameRenderer:
    """Renders one camera's masks frame by frame (reuses its buffer)."""

    def __init__(self, camera: Camera, cam_index: int, world: World, noise: NoiseConfig,
                 seed: int, match: str = "all"):
        if match not in MATCH_RULES:
            raise ValueError(f"match must be one of {MATCH_RULES}, got {match!r}")
        self.match = match
        self.cam = camera
        self.cam_index = cam_index
        self.world = world
        self.noise = noise
        self.seed = seed
        self.W, self.H = camera.width, camera.height
        self.buf_t = np.zeros((self.W, self.H), np.uint16)

    def visible(self, f: int) -> tuple[slice, list[Det]]:
        """Frame f's noise-free visible masks: (row slice, detections with crops)."""
        w = self.world
        r, wv, owner = w.frame_parts(f)
        dets: list[Det] = []
        if len(owner) == 0:
            return r, dets
        uv, ok = project_parts(self.cam, wv)
        centre = w.xyz[r] + np.array([0.0, 0.0, 0.5]) * w.size[w.track[r] - 1][:, 2:3]
        depth = np.linalg.norm(centre - self.cam.center, axis=1)
        # parts that touch the image
        lo, hi = uv.min(axis=1), uv.max(axis=1)
        onimg = ok & (hi[:, 0] >= 0) & (lo[:, 0] < self.W) & (hi[:, 1] >= 0) & (lo[:, 1] < self.H)
        if not onimg.any():
            return r, dets
        sel = np.flatnonzero(onimg)
        sel = sel[np.argsort(-depth[owner[sel]], kind="stable")]  # far first
        buf = self.buf_t
        buf.fill(0)
        fill_parts(buf, uv[sel], owner[sel] + 1)
        solo = self.noise.enabled and self.noise.occlusion_miss > 0
        uv_sel, own_sel = uv[sel], owner[sel]
        for a in np.unique(own_sel):
            mine = own_sel == a
            pts = uv_sel[mine].reshape(-1, 2)
            box = bbox_of(pts, self.W, self.H)
            if box is None:
                continue
            x0, y0, x1, y1 = box
            crop = buf[x0:x1, y0:y1] == a + 1
            n_vis = int(np.count_nonzero(crop))
            if n_vis == 0:
                continue
            vis = 1.0
            if solo:  # the road user drawn alone in its box: how much of it is hidden?
                alone = np.zeros(crop.shape, np.uint8)
                fill_parts(alone, uv_sel[mine] - np.array([x0, y0]), np.ones(int(mine.sum()), np.int64))
                vis = n_vis / max(int(np.count_nonzero(alone)), n_vis)
            dets.append(Det(crop, x0, y0, int(w.ids[r][a]), int(w.cls[r][a]), float(depth[a]), vis))
        return r, dets

    def render(self, f: int) -> list[tuple[int, int, bytes]]:
        """Frame f's detections as (track_id, class_id, RLE), sorted by track id."""
        r, dets = self.visible(f)
        rng = np.random.default_rng([self.seed, 101, self.cam_index, f])
        dets = apply_noise(dets, self.noise, rng, self.W, self.H)
        dets.sort(key=lambda d: d.track_id)
        out = [(d.track_id, d.cls + 1, rle_from_crop_t(d.crop, d.x0, d.y0, self.H, self.W))
               for d in dets]
        if self.match == "center" and out:
            out = self._matched(r, out)
        return out

    def _matched(self, r: slice, out: list[tuple[int, int, bytes]]) -> list[tuple[int, int, bytes]]:
        """Paper 4.1's association: a detection keeps its road user's id only when the
        projection of the road user's true 3D centre (mid-height above the ground contact
        point) falls inside the mask as written (after noise, clipped to the image) and the
        mask has the road user's class; the others would not be matched and are left out.
        A centre projecting outside the image is never covered (a truncated road user whose
        centre is off-image has no matched mask in the paper's protocol either)."""
        w = self.world
        centre = w.xyz[r] + np.outer(0.5 * w.size[w.track[r] - 1, 2], [0.0, 0.0, 1.0])
        uv, _, front = self.cam.project_points(centre)
        uv = np.where(front[:, None], uv, np.nan)
        row = {int(t): k for k, t in enumerate(w.ids[r])}
        k = np.array([row.get(tid, -1) for tid, _, _ in out])
        pts = np.where((k >= 0)[:, None], uv[np.maximum(k, 0)], np.nan)
        same = np.array([kk >= 0 and int(w.cls[r][kk]) + 1 == cid for kk, (_, cid, _) in zip(k, out)])
        cover = rle_contains([o[2] for o in out], self.H, self.W, np.arange(len(out)), pts)
        return [o for o, keep in zip(out, cover & same) if keep]

    def mots_lines(self, f0: int, f1: int) -> tuple[str, int]:
        """MOTS text for frames [f0, f1) and the number of detections."""
        out = []
        for f in range(f0, f1):
            for tid, cid, rle in self.render(f):
                out.append(f"{f} {tid} {cid} {self.H} {self.W} {rle.decode('ascii')}\n")
        return "".join(out), len(out)
