"""T-Analyst tracks CSV <-> an annotation project.

Import: every road user of the file becomes a track whose keyframes are its detections (flag
``imported``), in one undoable step. The file has no headings: a keyframe's heading is the
direction of motion to the next detection (the engine's ``motion_headings``), held from the
nearest one that moved where the road user stands still. Track ids are
the file's road user ids where free; the road user id and type are kept in the track's meta so
an export writes them back unchanged.

Export: the annotated poses (every frame, or only keyframes) as detections, road users in id
order, each in time order, detection ids counting from 1.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from annotate.model import EditError, Track
from annotate.place import motion_headings
from seg2pose.core.errors import InputError
from seg2pose.io.tanalyst import CLASS_TO_TYPE, TYPE_TO_CLASS, TAnalystTable, frames_to_times, times_to_frames

META = "tanalyst"  # track.meta key: {"road_user_id": int, "type": str}


def class_of_type(road_user_type: str, known: list[str], type_map: dict[str, str] | None = None
                  ) -> str | None:
    """The scene class of a T-Analyst road user type: ``type_map`` (exact type -> class) first,
    then the class of the same name or the usual T-Analyst names (case-insensitive)."""
    if type_map and road_user_type in type_map:
        return type_map[road_user_type]
    t = road_user_type.strip().lower()
    by_lower = {k.lower(): k for k in known}
    if t in by_lower:
        return by_lower[t]
    c = TYPE_TO_CLASS.get(t)
    return c if c in known else None


def import_tanalyst(project, table: TAnalystTable, fps: float | None = None, start_ms: int = 0,
                    type_map: dict[str, str] | None = None, file: str | Path | None = None,
                    replace: bool = False):
    """Add the road users of a T-Analyst table to ``project`` as tracks of keyframes, one
    undoable step; returns the Change (``change.created``: the new track ids).

    fps: the video's frame rate (default: the scene's); start_ms: the time stamp of frame 0.
    type_map: T-Analyst type -> scene class for types the defaults do not know. Road users
    imported before (same road user id in a track's meta) are refused unless ``replace``, which
    deletes those tracks in the same step. Errors name the file's line."""
    scene = project.scene
    fps = float(scene.fps if fps is None else fps)
    frames = times_to_frames(table, fps, start_ms, file=file)
    known = [c.name for c in scene.classes]
    lo, hi = project.frame_range if project.frame_range is not None else (0, None)
    earlier = {int(t.meta[META]["road_user_id"]): t.id for t in project.tracks.values()
               if isinstance(t.meta.get(META), dict) and "road_user_id" in t.meta[META]}
    ops = []
    taken = set(project.tracks)
    next_id = max(taken, default=0) + 1
    users = np.unique(table.road_user_id)
    for r in users.tolist():
        rows = np.flatnonzero(table.road_user_id == r)
        rows = rows[np.argsort(frames[rows], kind="stable")]
        first_line = int(table.lines[rows[0]]) or None
        typ = str(table.road_user_type[rows[0]])
        cls = class_of_type(typ, known, type_map)
        if cls is None:
            raise InputError(f"road user type {typ!r} is not a class of the scene "
                             f"({', '.join(known)}); map it to one", file=file, line=first_line,
                             field="Type of road user")
        fr = frames[rows]
        dup = np.flatnonzero(np.diff(fr) == 0)
        if len(dup):
            raise InputError(f"road user {r} has two detections in frame {fr[dup[0]]} at {fps:g} "
                             f"fps (lines {table.lines[rows[dup[0]]]} and "
                             f"{table.lines[rows[dup[0] + 1]]})", file=file,
                             line=int(table.lines[rows[dup[0] + 1]]) or None, field="Time Stamp")
        out = np.flatnonzero((fr < lo) | (fr > hi)) if hi is not None else np.flatnonzero(fr < lo)
        if len(out):
            raise InputError(f"frame {fr[out[0]]} is outside the scene's frames "
                             f"{lo}..{hi if hi is not None else ''}", file=file,
                             line=int(table.lines[rows[out[0]]]) or None, field="Time Stamp")
        if r in earlier:
            if not replace:
                raise InputError(f"road user {r} was imported before (track {earlier[r]}); "
                                 "replace it to import again", file=file, line=first_line)
            ops.append({"op": "put_track", "id": earlier[r], "track": None})
            taken.discard(earlier[r])
        tid = r if r >= 1 and r not in taken else next_id
        taken.add(tid)
        next_id = max(next_id, tid + 1)
        while next_id in taken:
            next_id += 1
        xy = table.xy[rows]
        hd = motion_headings(xy, np.full(len(xy), np.nan))
        track = Track(tid, cls, project._size(None, cls), None,
                      meta={META: {"road_user_id": int(r), "type": typ}})
        for i, f, (x, y), h in zip(rows, fr.tolist(), xy.tolist(), hd.tolist()):
            try:  # the engine's checks: finite numbers, on the ground's support
                track.keyframes[f] = project._kf(tid, f, x, y, h, ("imported",))
            except EditError as e:
                raise InputError(str(e), file=file, line=int(table.lines[i]) or None) from None
        ops.append({"op": "put_track", "id": tid, "track": track.to_dict()})
    if not ops:
        raise InputError("no detections to import", file=file)
    return project._commit("import_tanalyst", ops)


def annotations_to_tanalyst(project, fps: float | None = None, start_ms: int = 0,
                            keyframes_only: bool = False, decimal: str = ",") -> TAnalystTable:
    """The project's annotations as a T-Analyst table: every annotated frame (interpolated and
    occluded ones included; none inside outside spans), or only keyframes."""
    fps = float(project.scene.fps if fps is None else fps)
    poses = project.poses()
    if keyframes_only:  # not of_sources("keyframe"): a keyframe in an occluded span is "occluded"
        keep = np.zeros(len(poses), bool)
        for t in np.unique(poses.track_id).tolist():
            sel = poses.track_id == t
            keep[sel] = np.isin(poses.frame[sel], list(project.tracks[t].keyframes))
        poses = poses.take(keep)
    rid = np.empty(len(poses), np.int64)
    typ = np.empty(len(poses), object)
    for t in np.unique(poses.track_id).tolist():
        tr = project.tracks[t]
        m = tr.meta.get(META) if isinstance(tr.meta.get(META), dict) else {}
        sel = poses.track_id == t
        rid[sel] = int(m.get("road_user_id", t))
        typ[sel] = str(m.get("type", CLASS_TO_TYPE.get(tr.cls, tr.cls.capitalize())))
    order = np.lexsort((poses.frame, rid))
    times = frames_to_times(poses.frame[order], fps, start_ms)
    return TAnalystTable(np.arange(1, len(order) + 1), typ[order], rid[order],
                         poses.xyz[order, :2], times, decimal=decimal)
