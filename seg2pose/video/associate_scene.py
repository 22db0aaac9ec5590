"""``s2p associate SCENE``: the masks of all cameras read, their tracks associated across
cameras (``seg2pose.video.associate``), merged blobs split by the other cameras' views, one
class per road user, and the masks folder replaced as a unit with ``masks/ids.json`` saying the
ids are associated (``seg2pose.io.track_ids``).

A *merged blob*: one camera sees two road users as one mask (they arrive side by side, or one
behind the other) while another camera sees them apart. After association the second road user
is missing in the first camera although its position, seen by the others, projects into that
camera's blob. The blob is split between the road users: each one's upright box (the class's
size, at its position from the other cameras) projected into the image; a pixel inside several
boxes goes to the road user nearest the camera, a pixel inside none to the nearest box.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seg2pose.core.errors import S2PError
from seg2pose.geometry.normal import normal_positions
from seg2pose.io.atomic import copy_tree, link_or_copy, replacing
from seg2pose.io.mots import MaskTable, write_mots
from seg2pose.io.nofollow import refuse_links, write_new_text
from seg2pose.io.scene import SCENE_FILE, Scene, load_scene
from seg2pose.io.track_ids import entries, ids_path, ids_text, read_ids
from seg2pose.structures.masks import decode, encode, mask_centers, rle_contains
from seg2pose.video.associate import (
    AssociateConfig,
    Association,
    CameraViews,
    associate,
    majority_class,
    position_spread,
)

UNKNOWN_CLASS_HEIGHT = 0.8  # metres: default height of a mask without a class (the tracker's)
MIN_PART = 30               # pixels: a split part smaller than this is dropped


def camera_views(scene: Scene, cam: str, table: MaskTable, cfg: AssociateConfig
                 ) -> tuple[CameraViews, np.ndarray]:
    """Association's view of one camera's masks, and their default heights (N,) metres."""
    by_id = scene.class_by_id()
    heights = np.array([by_id[c].default_height if c in by_id else UNKNOWN_CLASS_HEIGHT
                        for c in table.class_id.tolist()], float)
    uv = mask_centers(table.rles, table.height, table.width, "bbox")
    xyz = np.full((len(table), 3), np.nan)
    ok = np.isfinite(uv[:, 0])
    if ok.any():
        xyz[ok], _ = normal_positions(scene.cameras[cam], scene.ground, uv[ok], heights[ok])
    spread = position_spread(scene.cameras[cam].center, xyz, heights, cfg.height_sd)
    return CameraViews(table.frame, table.track_id, table.class_id, xyz[:, :2], spread), heights


@dataclass
class BlobSplit:
    flagged: int = 0   # masks found holding several road users
    split: int = 0     # of them split into parts
    parts: int = 0     # masks made


def _box_corners(xy: np.ndarray, z: np.ndarray, size: np.ndarray) -> np.ndarray:
    """(N, 8, 3) corners of upright boxes of footprint max(l, w) square (heading unknown) and
    height h standing at xy (N, 2), ground height z (N,), size (N, 3) l, w, h metres."""
    half = np.maximum(size[:, 0], size[:, 1]) / 2
    sx = np.array([-1, 1, 1, -1, -1, 1, 1, -1], float)
    sy = np.array([-1, -1, 1, 1, -1, -1, 1, 1], float)
    sz = np.array([0, 0, 0, 0, 1, 1, 1, 1], float)
    return np.stack([xy[:, None, 0] + half[:, None] * sx, xy[:, None, 1] + half[:, None] * sy,
                     z[:, None] + size[:, None, 2] * sz], axis=2)


def split_merged_blobs(scene: Scene, tables: dict[str, MaskTable], views: dict[str, CameraViews],
                       heights: dict[str, np.ndarray], ids: dict[str, np.ndarray],
                       classes: dict[str, np.ndarray]
                       ) -> tuple[dict[str, MaskTable], BlobSplit]:
    """Masks of one camera that hold a road user the other cameras see apart, split (see the
    module docstring). Returns the cameras' tables with ids and classes set, and counts."""
    names = list(tables)
    stats = BlobSplit()
    # each road user's position per frame, the mean over the cameras that see it
    g = np.concatenate([ids[c] for c in names])
    f = np.concatenate([views[c].frame for c in names])
    xy = np.concatenate([views[c].xy for c in names])
    h = np.concatenate([heights[c] for c in names])
    cl = np.concatenate([classes[c] for c in names])
    bit = np.concatenate([np.full(len(ids[c]), 1 << k, np.int64) for k, c in enumerate(names)])
    ok = np.isfinite(xy[:, 0])
    key = f[ok] * (1 << 31) + g[ok]
    uk, inv = np.unique(key, return_inverse=True)
    n = np.bincount(inv)
    pos = np.stack([np.bincount(inv, xy[ok, 0]), np.bincount(inv, xy[ok, 1])], axis=1) / n[:, None]
    seen = np.zeros(len(uk), np.int64)
    np.bitwise_or.at(seen, inv, bit[ok])
    u_h = np.zeros(len(uk))
    u_h[inv] = h[ok]
    u_cls = np.zeros(len(uk), np.int64)
    u_cls[inv] = cl[ok]
    uf, ug = uk // (1 << 31), uk % (1 << 31)
    by_name = scene.class_names_by_id()
    sizes = scene.class_sizes()
    size = np.array([sizes.get(by_name.get(int(c), ""), (1.0, 1.0, 1.6)) for c in u_cls], float)
    out = {}
    for k, c in enumerate(names):
        t = tables[c]
        t = MaskTable(t.frame, ids[c], classes[c], t.height, t.width, t.rles, t.score)
        cam = scene.cameras[c]
        # road users the others see at a frame this camera has masks of, but not this camera
        cand = np.flatnonzero((seen & (1 << k)) == 0)
        if not len(cand) or not len(t):
            out[c] = t
            continue
        X = np.column_stack([pos[cand], scene.ground.height(pos[cand]) + u_h[cand]])
        uv, _, front = cam.project_points(X)
        inside = front & (uv[:, 0] >= 0) & (uv[:, 0] < t.width) & (uv[:, 1] >= 0) & (uv[:, 1] < t.height)
        cand, uv = cand[inside], uv[inside]
        order = np.argsort(t.frame, kind="stable")
        lo = np.searchsorted(t.frame[order], uf[cand], "left")
        hi = np.searchsorted(t.frame[order], uf[cand], "right")
        rep = hi - lo
        qi = np.repeat(np.arange(len(cand)), rep)
        mi = order[np.repeat(lo, rep) + np.arange(len(qi)) - np.repeat(np.cumsum(rep) - rep, rep)]
        hit = rle_contains(t.rles, t.height, t.width, mi, uv[qi])
        qi, mi = qi[hit], mi[hit]
        # the blob's own road user must be one the other cameras see apart from the missing one
        own = np.searchsorted(uk, t.frame[mi] * (1 << 31) + t.track_id[mi])
        own_ok = (own < len(uk)) & (uk[np.minimum(own, len(uk) - 1)] == t.frame[mi] * (1 << 31) + t.track_id[mi])
        apart = own_ok & ((seen[np.minimum(own, len(uk) - 1)] & seen[cand[qi]] & ~(1 << k)) != 0)
        qi, mi, own = qi[apart], mi[apart], own[apart]
        if not len(mi):
            out[c] = t
            continue
        blobs: dict[int, list[int]] = {}
        for q, m, o in zip(qi.tolist(), mi.tolist(), own.tolist()):
            blobs.setdefault(m, [o]).append(int(cand[q]))
        stats.flagged += len(blobs)
        new_rows, drop = [], []
        for m, users in blobs.items():
            users = list(dict.fromkeys(users))
            parts = _split(t.rles[m], t.height, t.width, cam, scene,
                           pos[users], size[users])
            kept = [(u, p) for u, p in zip(users, parts) if p.sum() >= MIN_PART]
            if len(kept) < 2:
                continue
            stats.split += 1
            drop.append(m)
            for u, p in kept:
                stats.parts += 1
                new_rows.append((int(t.frame[m]), int(ug[u]), int(u_cls[u]) or int(t.class_id[m]),
                                 encode(p)))
        if new_rows:
            keep = np.setdiff1d(np.arange(len(t)), drop)
            extra = MaskTable(np.array([r[0] for r in new_rows], np.int64),
                              np.array([r[1] for r in new_rows], np.int64),
                              np.array([r[2] for r in new_rows], np.int64), t.height, t.width,
                              [r[3] for r in new_rows])
            base = t.take(keep)
            base.score = None
            t = MaskTable.concat([base, extra])
        out[c] = t
    return out, stats


def _split(rle: bytes, height: int, width: int, cam, scene: Scene, xy: np.ndarray,
           size: np.ndarray) -> list[np.ndarray]:
    """The pixels of one mask divided between road users at xy (R, 2) of size (R, 3)."""
    m = decode(rle, height, width).astype(bool)
    z = scene.ground.height(xy)
    corners = _box_corners(xy, z, size)
    uv, depth, _ = cam.project_points(corners.reshape(-1, 3))
    uv = uv.reshape(len(xy), 8, 2)
    lo, hi = uv.min(axis=1), uv.max(axis=1)
    dist = np.linalg.norm(xy - cam.center[:2], axis=1)
    rows, cols = np.nonzero(m)
    px = np.stack([cols + 0.5, rows + 0.5], axis=1)
    inb = ((px[:, None, :] >= lo[None]) & (px[:, None, :] <= hi[None])).all(axis=2)  # (P, R)
    gap = np.maximum(np.maximum(lo[None] - px[:, None], px[:, None] - hi[None]), 0)
    gapd = np.linalg.norm(gap, axis=2)
    # inside several boxes: the road user nearest the camera hides the others
    score = np.where(inb, dist[None, :], 1e6 + gapd)
    owner = np.argmin(score, axis=1)
    parts = []
    for r in range(len(xy)):
        p = np.zeros_like(m)
        sel = owner == r
        p[rows[sel], cols[sel]] = True
        parts.append(p)
    return parts


def associate_scene(scene_dir: str | Path, cameras: list[str] | None = None, *,
                    cfg: dict | AssociateConfig | None = None, force: bool = False,
                    log: Callable[[str], None] = print) -> Association | None:
    """Give the masks of one road user the same track id in every camera of the scene (or of
    ``cameras``); masks/ is replaced as a unit. Refuses masks already associated unless
    ``force``. Settings: ``scene.json`` ``extra.associate``, overridden by ``cfg``."""
    scene = load_scene(scene_dir)
    sj = scene.root / SCENE_FILE
    if not isinstance(cfg, AssociateConfig):
        cfg = AssociateConfig.from_dict({**(scene.extra.get("associate") or {}), **(cfg or {})},
                                        file=sj)
    names = list(cameras) if cameras else list(scene.cameras)
    unknown = [c for c in names if c not in scene.cameras]
    if unknown:
        raise S2PError(f"unknown cameras {unknown}; the scene has {list(scene.cameras)}")
    names = [c for c in names if scene.masks_path(c).exists()]
    if len(names) < 2:
        log("association: fewer than two cameras with masks; ids stay as they are")
        return None
    masks_dir = scene.masks_path(names[0]).parent
    # a linked masks/: refused before reading through it (it would be replaced by a folder
    # holding hard links to the files where it points)
    refuse_links(ids_path(masks_dir))
    done = read_ids(masks_dir)
    if not force and all(done.get(c, {}).get("ids") == "associated"
                         and set(names) <= set(done[c].get("with", [])) for c in names):
        raise S2PError(f"the masks of {', '.join(names)} are associated already ({ids_path(masks_dir)}); "
                       "pass --force to associate them again")
    tables = {c: scene.read_masks(c) for c in names}
    empty = [c for c in names if not len(tables[c])]
    if len(names) - len(empty) < 2:  # nothing to associate with: every file stays as it is
        log(f"association: fewer than two cameras with masks ({', '.join(empty)} without any); "
            "ids stay as they are")
        return None
    views, heights = {}, {}
    for c in names:
        views[c], heights[c] = camera_views(scene, c, tables[c], cfg)
    res = associate(views, cfg)
    classes = majority_class(res.ids, {c: tables[c].class_id for c in names})
    if cfg.split_blobs:
        out, blobs = split_merged_blobs(scene, tables, views, heights, res.ids, classes)
    else:
        out = {c: MaskTable(t.frame, res.ids[c], classes[c], t.height, t.width, t.rles, t.score)
               for c, t in tables.items()}
        blobs = BlobSplit()
    res.blobs = blobs
    with replacing(masks_dir, force=True) as tmp:
        for p in sorted(masks_dir.iterdir()):  # the rest of masks/ goes along, linked
            if p.name.startswith(".") or p.name in {f"{c}.txt" for c in names} | {ids_path(tmp).name}:
                continue
            if p.is_dir() and not p.is_symlink():
                copy_tree(p, tmp / p.name, link=True)
            elif p.is_file() and not p.is_symlink():
                link_or_copy(p, tmp / p.name)
        for c in names:
            t = out[c]
            write_mots(tmp / f"{c}.txt", t.take(np.lexsort((t.track_id, t.frame))))
        cams = {k: v for k, v in done.items() if k not in names}
        cams.update(entries(tmp, {c: "associated" for c in names}, names))
        write_new_text(tmp / ids_path(tmp).name, ids_text(cams))
    s = res.summary()
    log(f"associated {', '.join(names)}: {s['road_users']} road users "
        f"({s['seen_by_several_cameras']} seen by several cameras), {s['cuts']} tracks cut where a "
        f"tracker swapped, {s['joins_refused']} joins refused; {blobs.flagged} merged blobs found, "
        f"{blobs.split} split")
    return res
