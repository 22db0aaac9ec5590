"""The lossless s2p channels of an MCAP export (JSON, one message per frame) and their
inverse, so that ``mcap_import`` restores the run exactly what ``mcap_export`` wrote:

    /s2p/poses   {"frame", "rows": [{frame, track_id, class, x, y, z, heading, l, w, h[, source]
                 [, r90_m]}]}   (r90_m: the pose's error bar, metres; null for NaN)
    /s2p/views   {"frame", "columns": ["row", *VIEW_COLUMNS[, *CUE_COLUMNS[, *BOX_COLUMNS]]],
                  "rows": [[row, ...], ...]}

Floats are written with Python's shortest exact repr; JSON has no NaN, so null stands for it.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np

from seg2pose.core.validate import MAX_ID
from seg2pose.io.poses import PoseTable
from seg2pose.io.run import BOX_COLUMNS, CUE_COLUMNS, VIEW_COLUMNS, ViewTable

POSES_TOPIC = "/s2p/poses"
VIEWS_TOPIC = "/s2p/views"
POSE_SCHEMA = {
    "title": "s2p.PoseFrame", "type": "object",
    "properties": {
        "frame": {"type": "integer"},
        "rows": {"type": "array", "items": {"type": "object", "properties": {
            "frame": {"type": "integer"}, "track_id": {"type": "integer"},
            "class": {"type": "string"}, "x": {"type": "number"}, "y": {"type": "number"},
            "z": {"type": "number"}, "heading": {"type": ["number", "null"]},
            "l": {"type": ["number", "null"]}, "w": {"type": ["number", "null"]},
            "h": {"type": ["number", "null"]}, "r90_m": {"type": ["number", "null"]}}}}}}
VIEW_SCHEMA = {"title": "s2p.ViewFrame", "type": "object",
               "properties": {"frame": {"type": "integer"},
                              "columns": {"type": "array", "items": {"type": "string"}},
                              "rows": {"type": "array", "items": {"type": "array"}}}}


def num(v: float):
    """A float for JSON: null stands for NaN (and comes back as NaN)."""
    v = float(v)
    return v if math.isfinite(v) else None


def unnum(v) -> float:
    return float("nan") if v is None else float(v)


def split_by_frame(frame: np.ndarray) -> Iterator[np.ndarray]:
    """Row indices of each frame, frames ascending, rows of one frame in their file order."""
    order = np.argsort(frame, kind="stable")
    fr = np.asarray(frame)[order]
    if len(fr):
        yield from np.split(order, np.flatnonzero(np.diff(fr)) + 1)


def pose_messages(table: PoseTable) -> Iterator[tuple[int, dict]]:
    """(frame, /s2p/poses message) per frame of ``table``."""
    for idx in split_by_frame(table.frame):
        f = int(table.frame[idx[0]])
        rows = []
        for i in idx:
            r = {"frame": f, "track_id": int(table.track_id[i]), "class": str(table.cls[i]),
                 "x": float(table.xyz[i, 0]), "y": float(table.xyz[i, 1]),
                 "z": float(table.xyz[i, 2]), "heading": num(table.heading[i])}
            if table.size is not None:
                r.update(l=num(table.size[i, 0]), w=num(table.size[i, 1]), h=num(table.size[i, 2]))
            if table.source is not None:  # annotated poses: keyframe / interpolated / occluded
                r["source"] = str(table.source[i])
            if table.r90 is not None:
                r["r90_m"] = num(table.r90[i])
            rows.append(r)
        yield f, {"frame": f, "rows": rows}


def _int(v) -> int:
    """A JSON integer (frames and track ids): 1.5 or true is refused, never rounded."""
    if isinstance(v, bool) or not isinstance(v, int) or abs(v) > MAX_ID:
        raise ValueError(f"expected an integer frame or track id, got {v!r}")
    return v


def pose_table(messages: list[dict], with_size: bool) -> PoseTable:
    """The PoseTable of /s2p/poses messages (inverse of ``pose_messages``)."""
    rows = [r for m in messages for r in m["rows"]]
    if not rows:
        return PoseTable.empty(with_size)
    size = (np.array([[unnum(r.get("l")), unnum(r.get("w")), unnum(r.get("h"))] for r in rows])
            if with_size else None)
    return PoseTable(np.array([_int(r["frame"]) for r in rows], np.int64),
                     np.array([_int(r["track_id"]) for r in rows], np.int64),
                     np.array([r["class"] for r in rows], dtype=object),
                     np.array([[r["x"], r["y"], r["z"]] for r in rows], np.float64),
                     np.array([unnum(r["heading"]) for r in rows], np.float64), size,
                     np.array([r["source"] for r in rows], dtype=object)
                     if all("source" in r for r in rows) else None,
                     np.array([unnum(r["r90_m"]) for r in rows], np.float64)
                     if all("r90_m" in r for r in rows) else None)


def view_messages(v: ViewTable) -> Iterator[tuple[int, dict]]:
    """(frame, /s2p/views message) per frame; each row carries its row number in the table so
    the import restores the file's order."""
    cues = v.cues is not None
    box = v.box is not None
    # the optional columns in file order (cues, r90, box), (N, 0) without them
    more = np.column_stack([v.uv[:, :0]] + [c.reshape(len(v), -1) for c in (v.cues, v.r90, v.box)
                                            if c is not None])
    for idx in split_by_frame(v.frame):
        f = int(v.frame[idx[0]])
        rows = [[int(i), int(v.frame[i]), int(v.track_id[i]), str(v.camera[i]), str(v.cls[i]),
                 *[num(x) for x in (*v.uv[i], *v.normal[i], *v.residual[i], *more[i])]]
                for i in idx]
        yield f, {"frame": f, "columns": ["row"] + VIEW_COLUMNS + (CUE_COLUMNS if cues else [])
                  + (BOX_COLUMNS if box else []), "rows": rows}


def views_table(messages: list[dict]) -> ViewTable:
    """The ViewTable of /s2p/views messages, in the original row order (inverse of
    ``view_messages``)."""
    rows = sorted((r for m in messages for r in m["rows"]), key=lambda r: r[0])
    if not rows:
        return ViewTable.empty()
    n_cols = [len(m.get("columns", ())) - 1 - len(VIEW_COLUMNS) for m in messages]
    cues = all(k >= len(CUE_COLUMNS) for k in n_cols)
    box = all(k == len(CUE_COLUMNS) + len(BOX_COLUMNS) for k in n_cols)
    nums = np.array([[unnum(x) for x in r[5:(20 if box else 16) if cues else 12]] for r in rows],
                    float)
    return ViewTable(np.array([_int(r[1]) for r in rows], np.int64),
                     np.array([_int(r[2]) for r in rows], np.int64),
                     np.array([r[3] for r in rows], dtype=object),
                     np.array([r[4] for r in rows], dtype=object), nums[:, 0:2], nums[:, 2:5], nums[:, 5:7],
                     nums[:, 7:10] if cues else None, nums[:, 10] if cues else None,
                     nums[:, 11:15] if box else None)
