"""The Foxglove layout shipped next to an MCAP export (``<name>.layout.json``), so that the file
opens in a usable arrangement: the 3D world (road users, ground truth, ground, camera frames)
on the left over a plot of the per-frame errors, one image panel per camera on the right with
its display image (masks over video) and its annotations (projected boxes, outlines, centres).

Load it in Foxglove with Layouts -> Import from file... (see README, "Foxglove").
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from seg2pose.io.atomic import atomic_write_text


def camera_topics(cam: str) -> dict[str, str]:
    """The topics of one camera in an s2p export (see ``mcap_export``)."""
    base = f"/cameras/{cam}"
    return {"calibration": f"{base}/calibration", "transform": f"{base}/transform",
            "masks": f"{base}/masks", "display": f"{base}/display", "image": f"{base}/image",
            "annotations": f"{base}/annotations"}


def _split(direction: str, items: list, shares: Sequence[float] | None = None):
    """A Foxglove mosaic of ``items`` (panel ids or mosaics) along ``direction``, with
    ``shares`` (relative sizes, default equal)."""
    shares = shares or [1.0] * len(items)
    if len(items) == 1:
        return items[0]
    head = shares[0] / sum(shares)
    return {"direction": direction, "first": items[0],
            "second": _split(direction, items[1:], shares[1:]), "splitPercentage": 100 * head}


def layout(cameras: list[str], classes: list[str], image_topic: dict[str, str],
           with_gt: bool, with_errors: bool) -> dict:
    """The layout for an export of ``cameras``; ``image_topic``: camera -> the topic its panel
    shows (the display image, or the video when the camera has no masks)."""
    three_d = "3D!s2p-world"
    topics = {"/road_users/scene": {"visible": True}, "/road_users/poses": {"visible": True},
              "/world/ground": {"visible": True}}
    if with_gt:
        topics["/gt/scene"] = {"visible": True}
    for cam in cameras:
        topics[camera_topics(cam)["calibration"]] = {"visible": True}
    config: dict[str, Any] = {three_d: {"followTf": "world", "topics": topics,
                        "cameraState": {"distance": 60.0, "phi": 55.0, "thetaOffset": 45.0,
                                        "target": [0, 0, 0], "targetOffset": [0, 0, 0],
                                        "targetOrientation": [0, 0, 0, 1], "perspective": True,
                                        "fovy": 45, "near": 0.5, "far": 5000},
                        "scene": {"transforms": {"showLabel": False}}}}
    left = [three_d]
    if with_errors:
        plot = "Plot!s2p-errors"
        config[plot] = {
            "foxglovePanelTitle": "error (m) vs time",
            "paths": [{"value": f"/s2p/errors.{k}", "enabled": True, "timestampMethod": "receiveTime",
                       "label": k} for k in ["mean", *classes]],
            "showLegend": True, "legendDisplay": "top", "showXAxisLabels": True,
            "showYAxisLabels": True, "isSynced": True, "xAxisVal": "timestamp"}
        left.append(plot)
    panels = []
    for cam in cameras:
        t = camera_topics(cam)
        pid = f"Image!s2p-{cam}"
        config[pid] = {"foxglovePanelTitle": f"camera {cam}", "imageMode": {
            "imageTopic": image_topic[cam], "calibrationTopic": t["calibration"],
            "annotations": {t["annotations"]: {"visible": True}}}}
        panels.append(pid)
    body = _split("column", left, [3, 1][:len(left)])
    if panels:
        body = _split("row", [body, _split("column", panels)], [1, 1])
    return {"configById": config, "globalVariables": {}, "userNodes": {},
            "linkedGlobalVariables": [], "playbackConfig": {"speed": 1.0},
            "layout": body}


def layout_topics(doc: dict) -> set[str]:
    """Every topic a layout names (to check it against the file it belongs to)."""
    out: set[str] = set()
    for cfg in doc["configById"].values():
        out |= set(cfg.get("topics", {}))
        im = cfg.get("imageMode", {})
        out |= {v for k, v in im.items() if k in ("imageTopic", "calibrationTopic")}
        out |= set(im.get("annotations", {}))
        out |= {p["value"].split(".", 1)[0] for p in cfg.get("paths", [])}
    return out


def layout_path(mcap_path: Path) -> Path:
    """``x.mcap`` -> ``x.layout.json`` (beside it)."""
    return Path(mcap_path).with_suffix(".layout.json")


def layout_text(doc: dict) -> str:
    return json.dumps(doc, indent=1) + "\n"


def write_layout(path: Path, doc: dict) -> None:
    atomic_write_text(path, layout_text(doc))
