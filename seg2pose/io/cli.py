"""Commands for files in and out: ``s2p import-utocs``, ``s2p heights``, ``s2p convert-masks``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import typer

from seg2pose.errors import InputError, S2PError

MASK_FORMATS = ("mots", "coco", "png")


def detect_mask_format(path: Path) -> str:
    """'png' for a folder, 'coco' for .json, 'mots' otherwise."""
    if path.is_dir():
        return "png"
    return "coco" if path.suffix.lower() == ".json" else "mots"


def read_masks(path: str | Path, fmt: str | None = None, known_classes=None):
    """A masks file/folder in any supported format -> MaskTable."""
    from seg2pose.io.coco import read_coco
    from seg2pose.io.mots import read_mots
    from seg2pose.io.png import read_png_folder

    path = Path(path)
    if not path.exists():
        raise InputError("masks not found", file=path)
    fmt = fmt or detect_mask_format(path)
    if fmt == "mots":
        return read_mots(path, known_classes)
    if fmt == "coco":
        return read_coco(path, known_classes)
    if fmt == "png":
        return read_png_folder(path, known_classes)
    raise InputError(f"unknown mask format {fmt!r}; use one of {', '.join(MASK_FORMATS)}",
                     field="--format")


def write_masks(path: str | Path, table, fmt: str) -> None:
    from seg2pose.io.coco import write_coco
    from seg2pose.io.mots import write_mots
    from seg2pose.io.png import write_png_folder

    if fmt == "mots":
        write_mots(path, table)
    elif fmt == "coco":
        write_coco(path, table)
    elif fmt == "png":
        write_png_folder(path, table)
    else:
        raise InputError(f"unknown mask format {fmt!r}; use one of {', '.join(MASK_FORMATS)}",
                         field="--format")


def collect_height_views(scene, split: str | None = "train", center: str | None = None,
                         chunk: int = 20000) -> dict[str, list]:
    """Per class name, the bisection input of ``default_height_bisection``: a list of
    (camera, mask centres (N, 2) pixels, true ground positions (N, 2) metres), from the split's
    masks matched to ground truth (paper 4.1 matching)."""
    from seg2pose.io.mots import MaskTable
    from seg2pose.io.poses import read_poses
    from seg2pose.masks import mask_centers
    from seg2pose.matching import match_masks_to_truth
    from seg2pose.normal import DEFAULT_CENTER_METHOD

    center = center or DEFAULT_CENTER_METHOD
    if not scene.gt_path.exists():
        raise S2PError(f"{scene.gt_path}: no ground truth; default heights need it (paper 3.2)")
    fr = scene.split_range(split)
    names = {c.id: c.name for c in scene.classes}
    heights = {c.name: c.default_height for c in scene.classes}
    gt = read_poses(scene.gt_path, known_classes=set(names.values())).in_frames(fr)
    views: dict[str, list] = {}
    for cam in scene.cameras.values():
        path = scene.masks_path(cam.name)
        if not path.exists():
            continue
        pending: list = []

        def flush():
            t = MaskTable.concat(pending)
            pending.clear()
            idx = match_masks_to_truth(cam, t, gt, names, heights)
            ok = idx >= 0
            if not ok.any():
                return
            cen = mask_centers([t.rles[i] for i in np.flatnonzero(ok)], t.height, t.width, center)
            g = idx[ok]
            for cname in np.unique(gt.cls[g]):
                sel = gt.cls[g] == cname
                views.setdefault(str(cname), []).append((cam, cen[sel], gt.xyz[g[sel], :2]))

        n = 0
        for _, t in scene.iter_masks(cam.name, fr):
            pending.append(t)
            n += len(t)
            if n >= chunk:
                flush()
                n = 0
        if pending:
            flush()
    return views


def subsample_views(views: list, max_n: int, seed: int = 0) -> list:
    """At most ``max_n`` detections in total, drawn uniformly (the share of 'closer' is a
    median-like statistic: 20,000 detections pin it to about +-0.4 %)."""
    total = sum(len(c) for _, c, _ in views)
    if total <= max_n:
        return views
    rng = np.random.default_rng(seed)
    keep = np.zeros(total, bool)
    keep[rng.choice(total, max_n, replace=False)] = True
    out, a = [], 0
    for cam, cen, txy in views:
        k = keep[a:a + len(cen)]
        a += len(cen)
        if k.any():
            out.append((cam, cen[k], txy[k]))
    return out


def update_default_heights(scene, split: str | None = "train", center: str | None = None,
                           log=typer.echo, write: bool = True, max_per_class: int = 20000
                           ) -> dict[str, dict]:
    """Paper 3.2: per-class default heights by bisection on ``split``, written back into the
    scene's scene.json (atomically; other fields kept as they are). At most
    ``max_per_class`` matched detections per class are used (a uniform sample).

    Returns per class name {"old", "new", "closer_share", "n"}; classes without matched masks
    keep their height (n = 0)."""
    from seg2pose.io.atomic import atomic_write_text
    from seg2pose.io.scene import DEFAULT_CLASSES, SCENE_FILE
    from seg2pose.normal import closer_share, default_height_bisection

    views = {k: subsample_views(v, max_per_class) for k, v in
             collect_height_views(scene, split, center).items()}
    report: dict[str, dict] = {}
    for c in scene.classes:
        v = views.get(c.name, [])
        old = c.default_height
        if not v:
            report[c.name] = {"old": old, "new": old, "closer_share": None, "n": 0}
            log(f"{c.name:>12}: no matched masks in split {split!r}; kept {old:.3f} m")
            continue
        new = default_height_bisection(v, scene.ground)
        share, n = closer_share(v, scene.ground, new)
        c.default_height = float(round(new, 4))
        report[c.name] = {"old": old, "new": c.default_height, "closer_share": share, "n": n}
        log(f"{c.name:>12}: {old:.3f} m -> {c.default_height:.3f} m   closer than truth: "
            f"{100 * share:.1f}% of {n} normal positions")
    if write:
        path = scene.root / SCENE_FILE
        d = json.loads(path.read_text(encoding="utf-8"))
        cls = d.get("classes") or [dict(c) for c in DEFAULT_CLASSES]
        by_name = {c.name: c.default_height for c in scene.classes}
        for c in cls:
            if c.get("name") in by_name:
                c["default_height"] = by_name[c["name"]]
        d["classes"] = cls
        atomic_write_text(path, json.dumps(d, indent=1) + "\n")
        log(f"wrote default heights into {path}")
    return report


def register(app: typer.Typer) -> None:
    @app.command("import-utocs")
    def import_utocs_cmd(
        src: Path = typer.Argument(..., help="UTOCS recording folder (cameras.json, "
                                   "ground_points.txt, positions/)"),
        out: Path = typer.Argument(..., help="scene folder to create"),
        force: bool = typer.Option(False, "--force", help="overwrite an existing scene"),
        fps: float = typer.Option(None, help="frames per second (default 1/0.075 s, the "
                                  "paper's CARLA interval)"),
        size_scale: float = typer.Option(1.0, help="multiply l, w, h (2 if the recording "
                                         "stores CARLA half extents)"),
        frames: bool = typer.Option(True, "--frames/--no-frames",
                                    help="bring images/cam<id>/ or videos into video/"),
    ) -> None:
        """Import a UTOCS (CARLA) recording into a scene folder; CARLA's left-handed world is
        mirrored in y into this project's right-handed one."""
        from seg2pose.io.utocs import import_utocs

        import_utocs(src, out, force=force, fps=fps, size_scale=size_scale, copy_frames=frames,
                     log=typer.echo)

    @app.command("heights")
    def heights_cmd(
        scene: Path = typer.Argument(..., help="scene folder"),
        split: str = typer.Option("train", help="split whose masks and truth are used "
                                  "('all' for every frame)"),
        center: str = typer.Option(None, help="mask centre: bbox or centroid (default: "
                                   "seg2pose.normal.DEFAULT_CENTER_METHOD)"),
        dry_run: bool = typer.Option(False, "--dry-run", help="print, do not write scene.json"),
    ) -> None:
        """Per-class default heights by bisection (paper 3.2): about half of the split's
        normal positions end up closer to the camera than the truth. Writes scene.json."""
        from seg2pose.io.scene import load_scene
        from seg2pose.normal import CENTER_METHODS

        if center is not None and center not in CENTER_METHODS:
            raise InputError(f"unknown centre {center!r}; use {' or '.join(CENTER_METHODS)}",
                             field="--center")
        update_default_heights(load_scene(scene), split, center, write=not dry_run)

    @app.command("convert-masks")
    def convert_masks_cmd(
        src: Path = typer.Argument(..., help="masks: MOTS .txt, COCO RLE .json, or a folder "
                                   "of instance-id PNGs"),
        dst: Path = typer.Argument(..., help="output file (mots, coco) or folder (png)"),
        format: str = typer.Option(..., "--format", "-f", help="output format: mots, coco, png"),
        src_format: str = typer.Option(None, help="input format (default: from SRC)"),
        force: bool = typer.Option(False, "--force", help="overwrite DST"),
    ) -> None:
        """Convert instance masks between MOTS txt, COCO RLE JSON and PNG instance-id images."""
        from seg2pose.io.atomic import check_writable

        if format not in MASK_FORMATS:
            raise InputError(f"unknown format {format!r}; use one of {', '.join(MASK_FORMATS)}",
                             field="--format")
        check_writable(dst, force)
        table = read_masks(src, src_format)
        write_masks(dst, table, format)
        typer.echo(f"{len(table)} masks in {len(np.unique(table.frame))} frames "
                   f"({table.width}x{table.height}) -> {dst} [{format}]")
