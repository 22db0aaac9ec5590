"""Detector outputs (COCO results JSON: Mask R-CNN, Detectron2, YOLO-seg, ...) into a scene's
masks: score threshold, mask non-maximum suppression, COCO categories -> the scene's classes,
the paper's bicyclist logic (Figure 2), then the tracker when the detector gave no ids.

COCO categories (its own numbering, or names from the file's ``categories``): person ->
pedestrian, car -> car, truck/bus -> truck/bus when the scene has those classes (else car),
motorcycle -> motorcyclist/motorbike when the scene has one (else dropped). A person whose mask
overlaps a bicycle's becomes one bicyclist with the union of both masks; a bicycle with no
rider is dropped, or kept as a bicyclist with ``lone_bicycles=True``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seg2pose.core.errors import InputError
from seg2pose.io.coco import coco_categories, read_coco
from seg2pose.io.mots import MaskTable
from seg2pose.io.schemas import DETECTION_SCORE
from seg2pose.structures.masks import iou, merge_bicyclists, rle_stats

COCO_NAMES = {1: "person", 2: "bicycle", 3: "car", 4: "motorcycle", 6: "bus", 8: "truck"}
_TARGETS = {"person": ["pedestrian"], "car": ["car"], "truck": ["truck", "car"],
            "bus": ["bus", "car"], "motorcycle": ["motorcyclist", "motorbike"]}
BICYCLE = -2  # internal class id of bicycle masks before the merge


@dataclass
class DetectionConfig:
    score_min: float = 0.5        # detections below are dropped
    nms_iou: float = 0.5          # a mask overlapping a higher-scored one of its group by more is dropped
    bicycle_overlap: float = 0.1  # least IoU of a person and a bicycle mask to merge them
    lone_bicycles: bool = False   # keep bicycles without a rider (as bicyclists)

    def __post_init__(self) -> None:
        # the COCO file's score schema: --score nan was taken and dropped nothing (nan < nan is
        # false); overlaps are IoUs in [0, 1]
        self.score_min = DETECTION_SCORE.value(self.score_min, field="--score")
        self.nms_iou = DETECTION_SCORE.value(self.nms_iou, field="--nms")
        self.bicycle_overlap = DETECTION_SCORE.value(self.bicycle_overlap, field="bicycle_overlap")


def category_map(names: dict[int, str], scene_classes: dict[str, int]) -> dict[int, int]:
    """COCO category id -> scene class id (BICYCLE for bicycles; 0 = drop)."""
    out = {}
    for cid, name in names.items():
        if name == "bicycle":
            out[cid] = BICYCLE if "bicyclist" in scene_classes else 0
            continue
        targets = _TARGETS.get(name, [name])
        out[cid] = next((scene_classes[t] for t in targets if t in scene_classes), 0)
    return out


def mask_nms(rles: list[bytes], scores: np.ndarray, groups: np.ndarray, height: int, width: int,
             iou_max: float) -> np.ndarray:
    """Indices kept by greedy non-maximum suppression within each group, best score first
    (ties: earlier record). One IoU matrix per frame, from RLE."""
    n = len(rles)
    if n == 0:
        return np.zeros(0, np.int64)
    order = np.lexsort((np.arange(n), -np.nan_to_num(scores, nan=1.0)))
    m = iou([rles[i] for i in order], [rles[i] for i in order], height, width)
    same = groups[order][:, None] == groups[order][None, :]
    clash = (m > iou_max) & same & np.triu(np.ones((n, n), bool), 1)
    keep = np.ones(n, bool)
    for k in range(n):  # sequential by nature; n is a frame's detections
        if keep[k]:
            keep[clash[k]] = False
    return np.sort(order[keep])


def prepare_frame(t: MaskTable, cfg: DetectionConfig, pedestrian: int, bicyclist: int
                  ) -> MaskTable:
    """One frame's detections (class ids already mapped, BICYCLE for bicycles, 0 dropped):
    threshold, NMS within each class, bicyclist merge. pedestrian, bicyclist: the scene's
    class ids."""
    t = t.take((t.class_id != 0) & ~(_scores(t) < cfg.score_min))  # NaN score: kept
    if len(t) == 0:
        return t
    t = t.take(mask_nms(t.rles, _scores(t), t.class_id, t.height, t.width, cfg.nms_iou))
    bikes = np.flatnonzero(t.class_id == BICYCLE)
    if len(bikes) == 0:
        return t
    persons = np.flatnonzero(t.class_id == pedestrian)
    merged, match = merge_bicyclists([t.rles[i] for i in persons], [t.rles[i] for i in bikes],
                                     t.height, t.width, cfg.bicycle_overlap)
    rles, cls = list(t.rles), t.class_id.copy()
    for j, i in enumerate(persons[match >= 0]):
        rles[i] = merged[j]
        cls[i] = bicyclist
    used = np.zeros(len(bikes), bool)
    used[match[match >= 0]] = True
    cls[bikes[~used]] = bicyclist
    drop = bikes[used] if cfg.lone_bicycles else bikes
    out = MaskTable(t.frame, t.track_id, cls, t.height, t.width, rles, t.score)
    return out.take(np.setdiff1d(np.arange(len(t)), drop))


def _scores(t: MaskTable) -> np.ndarray:
    return t.score if t.score is not None else np.full(len(t), np.nan)


def import_detections(path: str | Path, scene_classes: dict[str, int], *,
                      cfg: DetectionConfig | None = None, size: tuple[int, int] | None = None,
                      n_frames: int | None = None, frame_offset: int = 0,
                      log: Callable[[str], None] = print) -> MaskTable:
    """Read a COCO results/dataset JSON of one camera into a MaskTable of the scene's classes
    (track ids as the file gives them, -1 otherwise), after threshold, NMS and the bicyclist
    merge. scene_classes: class name -> id. size: (height, width) of the camera (checked).
    n_frames: frames of the camera (its video, else the scene's splits), when known: a frame
    beyond it is an error. Masks without a pixel inside the image are dropped (counted).
    frame_offset: added to every frame (for a file that numbers its images from 1, say -1)."""
    cfg = cfg or DetectionConfig()
    path = Path(path)
    names = coco_categories(path) or COCO_NAMES
    cmap = category_map(names, scene_classes)
    table = read_coco(path, size=size)
    if len(table) and size is not None and (table.height, table.width) != tuple(size):
        raise InputError(f"masks are {table.width}x{table.height} pixels but the camera "
                         f"calibration is {size[1]}x{size[0]}", file=path, field="segmentation.size")
    keys = np.array(sorted(cmap), np.int64)
    vals = np.array([cmap[k] for k in keys], np.int64)
    pos = np.clip(np.searchsorted(keys, table.class_id), 0, max(len(keys) - 1, 0))
    known = (keys[pos] == table.class_id) if len(keys) else np.zeros(len(table), bool)
    table.class_id = np.where(known, vals[pos] if len(keys) else 0, 0)
    table.frame = table.frame + int(frame_offset)
    if len(table) and (table.frame.min() < 0 or (n_frames is not None and table.frame.max() >= n_frames)):
        bad = int(table.frame.min()) if table.frame.min() < 0 else int(table.frame.max())
        raise InputError(f"frame {bad} matches no video frame (the video has "
                         f"{n_frames if n_frames is not None else '?'} frames; are image ids "
                         "numbered from 1?)", file=path, field="image_id")
    empty, n_read = 0, len(table)
    if len(table):  # a polygon wholly outside the image leaves no pixel: nothing to track
        area = rle_stats(table.rles, table.height, table.width)[0]
        empty = int((area <= 0).sum())
        table = table.take(area > 0)
    ped, bic = scene_classes.get("pedestrian", -99), scene_classes.get("bicyclist", -99)
    parts = [p for _, t in table.frames() if len(p := prepare_frame(t, cfg, ped, bic))]
    out = MaskTable.concat(parts) if parts else MaskTable.empty(table.height, table.width)
    dropped = int((table.class_id == 0).sum())
    log(f"{path.name}: {n_read} detections -> {len(out)} masks "
        f"({int(np.sum(out.class_id == bic))} bicyclists; {dropped} of categories the scene "
        "does not know" + (f"; {empty} empty masks (no pixel inside the image) dropped"
                           if empty else "") + ")")
    return out
