"""Masks as COCO RLE JSON (detector results style).

A file holds a JSON list of records, one per detection::

    {"frame": 12, "image_id": 12, "category_id": 3, "track_id": 7, "score": 0.98,
     "segmentation": {"size": [720, 1280], "counts": "<compressed COCO RLE>"}}

``frame`` (or else ``image_id``) is the frame number; ``track_id`` is optional (-1 = none yet);
``score`` optional. ``counts`` may also be an uncompressed RLE (a list of run lengths, as in
COCO's iscrowd annotations); it is compressed on reading. A full COCO dataset object
(``{"images": [...], "annotations": [...]}``) is read too: an image's ``frame_id`` or ``frame``
gives the frame when present, else its ``id``. ``category_id`` is used as the class id (COCO's
person=1, bicycle=2, car=3 line up with this project's pedestrian=1, bicyclist=2, car=3;
pass ``category_map`` for other numberings). ``segmentation`` may also be COCO polygons
(``[[x0, y0, x1, y1, ...], ...]``, pixel corner coordinates); their image size comes from the
``images`` entry (``height``, ``width``), else from ``size``. With an ``images`` list, an
``image_id`` that is not in it is an error. ``coco_categories`` gives a dataset's
id -> name map (detector results lists carry none: COCO's numbering is assumed).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable
from pathlib import Path

import numpy as np
from pycocotools import mask as mask_util

from seg2pose.core.errors import InputError
from seg2pose.io.atomic import atomic_write_text
from seg2pose.io.mots import MaskTable, check_masks
from seg2pose.io.schemas import DETECTION_SCORE
from seg2pose.io.text import load_json
from seg2pose.structures.masks import decode_counts


def _int(rec: dict, key: str, path: Path, i: int, default=None) -> int:
    v = rec.get(key, default)
    if v is None:
        raise InputError(f"missing '{key}'", file=path, field=f"[{i}].{key}")
    # order matters: bool is an int; inf/huge fail the range test before int() sees them; NaN != NaN
    if (isinstance(v, bool) or not isinstance(v, (int, float)) or not abs(v) < 2**62
            or v != int(v)):
        raise InputError(f"expected an integer, got {v!r}", file=path, field=f"[{i}].{key}")
    return int(v)


def _records(data, path: Path) -> tuple[list, dict, dict]:
    """The annotation list, image_id -> frame and image_id -> (height, width) of a results list
    or a dataset object."""
    if isinstance(data, list):
        return data, {}, {}
    if isinstance(data, dict) and isinstance(data.get("annotations"), list):
        frames, sizes = {}, {}
        for j, im in enumerate(data.get("images") or []):
            if not isinstance(im, dict) or not isinstance(im.get("id"), int) or isinstance(im["id"], bool):
                raise InputError("expected an object with an integer 'id'", file=path,
                                 field=f"images[{j}]")
            fr = im.get("frame_id", im.get("frame", im["id"]))
            if isinstance(fr, bool) or not isinstance(fr, int):
                raise InputError(f"expected an integer frame, got {fr!r}", file=path,
                                 field=f"images[{j}]")
            frames[im["id"]] = fr
            h, w = im.get("height"), im.get("width")
            if isinstance(h, int) and isinstance(w, int) and h > 0 and w > 0:
                sizes[im["id"]] = (h, w)
        return data["annotations"], frames, sizes
    raise InputError("expected a JSON list of detections or a COCO object with 'annotations'",
                     file=path)


def read_coco(path: str | Path, known_classes: Iterable[int] | None = None,
              category_map: dict[int, int] | None = None,
              size: tuple[int, int] | None = None) -> MaskTable:
    """Read COCO RLE JSON into a MaskTable (sorted by frame, stable). ``size`` (height, width)
    is needed only for an empty file; every record must have the same size."""
    path = Path(path)
    data = load_json(path, "masks file")
    recs, image_frames, image_sizes = _records(data, path)
    kc = set(known_classes) if known_classes is not None else None
    frames, tids, cids, rles, scores = [], [], [], [], []
    hw = None
    for i, r in enumerate(recs):
        if not isinstance(r, dict):
            raise InputError("expected an object", file=path, field=f"[{i}]")
        if "frame" in r:
            fr = _int(r, "frame", path, i)
        else:
            img = _int(r, "image_id", path, i)
            if image_frames and img not in image_frames:
                raise InputError(f"image_id {img} matches no entry of 'images'", file=path,
                                 field=f"[{i}].image_id")
            fr = image_frames.get(img, img)
        if not 0 <= fr < 2**62:
            raise InputError(f"expected a frame number >= 0, got {fr}", file=path, field=f"[{i}].frame")
        cid = _int(r, "category_id", path, i)
        if category_map is not None:
            if cid not in category_map:
                raise InputError(f"category_id {cid} not in the category map {sorted(category_map)}",
                                 file=path, field=f"[{i}].category_id")
            cid = category_map[cid]
        if kc is not None and cid != 0 and cid not in kc:
            raise InputError(f"unknown class {cid}; the scene knows {sorted(kc)}", file=path,
                             field=f"[{i}].category_id")
        tid = _int(r, "track_id", path, i, default=-1)
        seg = r.get("segmentation")
        if isinstance(seg, list):
            poly_hw = image_sizes.get(r.get("image_id"), hw or size)
            seg = _polygons(seg, poly_hw, path, i)
        if not isinstance(seg, dict) or "size" not in seg or "counts" not in seg:
            raise InputError("expected an RLE object {'size': [h, w], 'counts': ...}", file=path,
                             field=f"[{i}].segmentation")
        sz = seg["size"]
        if (not isinstance(sz, list) or len(sz) != 2
                or not all(isinstance(v, int) and not isinstance(v, bool) for v in sz)
                or not (0 < sz[0] <= 2**20 and 0 < sz[1] <= 2**20)):
            raise InputError(f"expected [height, width] positive integers, got {sz!r}", file=path,
                             field=f"[{i}].segmentation.size")
        if hw is None:
            hw = (sz[0], sz[1])
        elif tuple(sz) != hw:
            raise InputError(f"size {sz} differs from earlier records ({hw[0]}x{hw[1]})",
                             file=path, field=f"[{i}].segmentation.size")
        counts = seg["counts"]
        if isinstance(counts, list):
            if not all(isinstance(c, int) and not isinstance(c, bool) and 0 <= c < 2**40
                       for c in counts):
                raise InputError("uncompressed counts must be non-negative integers", file=path,
                                 field=f"[{i}].segmentation.counts")
            if sum(counts) != hw[0] * hw[1]:
                raise InputError(f"RLE covers {sum(counts)} pixels but height*width = "
                                 f"{hw[0] * hw[1]}", file=path, field=f"[{i}].segmentation.counts")
            rle = mask_util.frPyObjects({"size": list(hw), "counts": counts}, hw[0], hw[1])["counts"]
        elif isinstance(counts, str):
            try:
                rle = counts.encode("ascii")
            except UnicodeEncodeError:
                raise InputError("RLE string is not ASCII", file=path,
                                 field=f"[{i}].segmentation.counts") from None
            _check_rle(rle, hw, path, i)
        else:
            raise InputError("counts must be a string or a list of integers", file=path,
                             field=f"[{i}].segmentation.counts")
        sc = r.get("score")
        if sc is not None:
            sc = DETECTION_SCORE.value(sc, file=path, field=f"[{i}].score")
        frames.append(fr)
        tids.append(tid)
        cids.append(cid)
        rles.append(rle)
        scores.append(np.nan if sc is None else float(sc))
    if hw is None:
        hw = size if size is not None else (0, 0)
    seen: dict[tuple[int, int], int] = {}
    for i, (fr, tid) in enumerate(zip(frames, tids)):
        if tid >= 0:
            if (fr, tid) in seen:
                raise InputError(f"duplicate detection: track {tid} appears twice in frame {fr} "
                                 f"(also record {seen[fr, tid]})", file=path, field=f"[{i}].track_id")
            seen[fr, tid] = i
    has_score = len(recs) > 0 and not np.isnan(scores).all()
    t = MaskTable(np.array(frames, np.int64), np.array(tids, np.int64), np.array(cids, np.int64),
                  hw[0], hw[1], rles, np.array(scores) if has_score else None)
    return t.take(np.argsort(t.frame, kind="stable"))


def _polygons(seg: list, hw: tuple[int, int] | None, path: Path, i: int) -> dict:
    """COCO polygons -> {'size', 'counts'} (compressed RLE, the union of the polygons)."""
    if hw is None:
        raise InputError("polygon masks need the image size: give 'height' and 'width' in the "
                         "'images' entry", file=path, field=f"[{i}].segmentation")
    if not seg:
        raise InputError("expected at least one polygon [x0, y0, x1, y1, ...]", file=path,
                         field=f"[{i}].segmentation")
    polys = []
    for k, p in enumerate(seg):
        if (not isinstance(p, list) or len(p) < 6 or len(p) % 2
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                           and math.isfinite(v) and abs(v) <= 1e7 for v in p)):
            raise InputError("expected a polygon [x0, y0, x1, y1, ...] of at least 3 points",
                             file=path, field=f"[{i}].segmentation[{k}]")
        polys.append([float(v) for v in p])
    rle = mask_util.merge(mask_util.frPyObjects(polys, hw[0], hw[1]))
    return {"size": [int(hw[0]), int(hw[1])], "counts": rle["counts"].decode("ascii")}


def coco_categories(path: str | Path) -> dict[int, str]:
    """Category id -> lower-case name of a COCO dataset file's ``categories`` list (empty for a
    results list)."""
    path = Path(path)
    data = load_json(path, "masks file")
    out = {}
    cats = data.get("categories") if isinstance(data, dict) else None
    for j, c in enumerate(cats or []):
        if not isinstance(c, dict) or not isinstance(c.get("id"), int) or not isinstance(c.get("name"), str):
            raise InputError("expected {id: int, name: str}", file=path, field=f"categories[{j}]")
        out[c["id"]] = c["name"].strip().lower()
    return out


def _check_rle(rle: bytes, hw: tuple[int, int], path: Path, i: int) -> None:
    try:
        counts, _ = decode_counts([rle])
    except InputError as e:
        raise InputError(e.message, file=path, field=f"[{i}].segmentation.counts") from None
    if int(counts.sum()) != hw[0] * hw[1]:
        raise InputError(f"RLE covers {int(counts.sum())} pixels but height*width = {hw[0] * hw[1]}",
                         file=path, field=f"[{i}].segmentation.counts")


def coco_records(table: MaskTable) -> list[dict]:
    """JSON-ready records of a MaskTable (frame order, stable)."""
    out = []
    size = [int(table.height), int(table.width)]
    for i in np.argsort(table.frame, kind="stable"):
        rec = {"frame": int(table.frame[i]), "image_id": int(table.frame[i]),
               "category_id": int(table.class_id[i]), "track_id": int(table.track_id[i]),
               "segmentation": {"size": size, "counts": table.rles[i].decode("ascii")}}
        if table.score is not None and np.isfinite(table.score[i]):
            rec["score"] = float(table.score[i])
        out.append(rec)
    return out


def write_coco(path: str | Path, table: MaskTable) -> None:
    """Write a MaskTable as COCO RLE JSON (one record per line, atomically)."""
    check_masks(table, file=path)
    recs = coco_records(table)
    text = "[\n" + ",\n".join(json.dumps(r, separators=(",", ":")) for r in recs) + "\n]\n"
    atomic_write_text(path, text)
