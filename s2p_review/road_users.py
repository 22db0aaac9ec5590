"""The road users of a run in a review recording, one entity per road user (``layout``:
``world/road_users/<run>/<track id>``), as Rerun's tracking examples log tracks: a road user
selected or hovered at one frame is the same road user at every other frame, can be hidden
alone, and has time series of its own.

Per road user (track id), each sent with ``send_columns`` over the frames it is seen on, in
one chunk with as few components as it takes (the viewer pays per component of each chunk
when it loads a recording: docs/BENCHMARKS.md, "One entity per road user"):

- its box (Boxes3D with class ids: colour, see-through and class name from the annotation
  context the run gets at ``world/road_users/<run>``, in the run's look; a baseline's
  wireframe in its rows, solid boxes and hidden labels are the 3D view's defaults), one
  ``AnyValues`` struct for the selection panel (``road_user``: track id, class, speed m/s,
  r90 m, source: the row's provenance, else the run's method), its speed as Scalars (so that
  selecting the box selects its line in the run's speed plot) and, with r90, its error disc
  (LineStrips3D on the ground, coloured by size: ``error_discs``);
- its trail, the child entity ``<track id>/trail`` (a segment per frame from its previous
  pose, shown over the last ``LogStyle.trail`` frames by a visible time range on that entity):
  hiding the road user hides its trail, its disc and its speed line;
- series under ``metrics/road_users/<run>/<quantity>/<track id>``: error against the truth
  (rows whose (frame, track id) the truth has: ``seg2pose.eval.evaluate.match_poses``, as the
  run's error plot) and r90.

Where a road user is not seen (a gap, or after its last frame) its box and disc are emptied on
the first frame without it, so nothing lingers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from s2p_review import columns as C
from s2p_review import layout as L
from s2p_review.error_discs import disc_outlines, r90_colors
from seg2pose.io.poses import PoseTable

TRAIL_LIFT_M = 0.05  # trails drawn this far above the ground contact point


@dataclass(frozen=True)
class RoadUsers:
    """A run's rows in (track id, frame) order with what is logged per row: sizes (N, 3)
    l, w, h metres; speed (N,) m/s (NaN for a track of one row); error (N,) metres against the
    truth (NaN without truth); starts (T,) the first row of each track."""

    table: PoseTable
    sizes: np.ndarray
    speed: np.ndarray
    error: np.ndarray
    starts: np.ndarray

    def track_rows(self):
        """(track id, row slice) per track, in track id order."""
        ends = np.r_[self.starts[1:], len(self.table)]
        for a, b in zip(self.starts.tolist(), ends.tolist()):
            yield int(self.table.track_id[a]), slice(a, b)


def speeds(track_id: np.ndarray, frame: np.ndarray, xy: np.ndarray, fps: float,
           half: int | None = None) -> np.ndarray:
    """(N,) ground speed, m/s, of rows sorted by (track id, frame): the least-squares slope of
    the positions xy (N, 2) metres against time over the rows of the same track within
    ``half`` rows either side (default: half a second of frames at ``fps``; fewer at a track's
    ends), its length. A constant velocity is reproduced exactly; position noise sigma leaves
    about sigma * sqrt(12 / m) / (m / fps) m/s over a window of m rows. NaN for a track of one
    row. Each window is summed about its own row, so long tracks lose no precision."""
    n = len(track_id)
    if n == 0:
        return np.zeros(0)
    k = max(1, int(round(fps / 2))) if half is None else max(1, int(half))
    i = np.arange(n)
    new = np.r_[True, track_id[1:] != track_id[:-1]]
    start = np.maximum.accumulate(np.where(new, i, 0))
    last = np.r_[track_id[1:] != track_id[:-1], True]
    end = np.minimum.accumulate(np.where(last, i, n)[::-1])[::-1]
    t = np.asarray(frame, np.float64) / float(fps)
    xy = np.asarray(xy, np.float64)
    m = np.zeros(n)
    st = np.zeros(n)
    stt = np.zeros(n)
    sx = np.zeros((n, 2))
    stx = np.zeros((n, 2))
    for d in range(-k, k + 1):
        j = i + d
        ok = (j >= start) & (j <= end)
        jj = np.where(ok, j, i)
        dt = np.where(ok, t[jj] - t, 0.0)
        dx = np.where(ok[:, None], xy[jj] - xy, 0.0)
        m += ok
        st += dt
        stt += dt * dt
        sx += dx
        stx += dt[:, None] * dx
    den = m * stt - st * st
    with np.errstate(invalid="ignore", divide="ignore"):
        slope = (m[:, None] * stx - st[:, None] * sx) / den[:, None]
    return np.where(den > 0, np.linalg.norm(slope, axis=1), np.nan)


def road_users(poses: PoseTable, sizes: np.ndarray, fps: float, gt: PoseTable | None = None
               ) -> RoadUsers:
    """The rows of ``poses`` with a finite position, in (track id, frame) order, with their
    speeds and (with ``gt``) errors on the ground plane."""
    ok = np.flatnonzero(np.isfinite(poses.xyz).all(axis=1))
    ok = ok[np.lexsort((poses.frame[ok], poses.track_id[ok]))]
    t, sz = poses.take(ok), np.asarray(sizes, float)[ok]
    err = np.full(len(t), np.nan)
    if gt is not None and len(gt) and len(t):
        from seg2pose.eval.evaluate import match_poses

        ie, ig = match_poses(t, gt)
        err[ie] = np.linalg.norm(t.xyz[ie, :2] - gt.xyz[ig, :2], axis=1)
    starts = np.flatnonzero(np.r_[True, t.track_id[1:] != t.track_id[:-1]]) if len(t) else \
        np.zeros(0, np.int64)
    return RoadUsers(t, sz, speeds(t.track_id, t.frame, t.xyz[:, :2], fps), err, starts)


def shown_frames(frame: np.ndarray, last: int) -> tuple[np.ndarray, np.ndarray]:
    """One track's frames (K,) sorted -> the frames to send (the frames it is on, and the first
    frame after each stretch of them, up to ``last``, where it is emptied) and the rows per sent
    frame (0 on the emptying ones)."""
    frames, counts = np.unique(frame, return_counts=True)
    after = frames + 1
    gaps = after[~np.isin(after, frames) & (after <= last)]
    out = np.union1d(frames, gaps)
    lengths = np.zeros(len(out), np.int64)
    lengths[np.searchsorted(out, frames)] = counts
    return out, lengths


def info_column(users: RoadUsers, rows: slice, r90: np.ndarray, src: np.ndarray):
    """The selection panel's values of one road user's rows as one AnyValues column,
    ``road_user``: a struct per row of track_id, class, speed_mps, r90_m and source. One column
    rather than five: Rerun's viewer pays per component of each chunk when it loads a recording
    (docs/BENCHMARKS.md, "One entity per road user"), and a road user is a chunk of its own."""
    import pyarrow as pa

    t = users.table
    n = rows.stop - rows.start
    return pa.StructArray.from_arrays(
        [pa.array(t.track_id[rows].astype(np.int64)), pa.array(t.cls[rows].astype(str).tolist()),
         pa.array(users.speed[rows].astype(np.float32)), pa.array(r90[rows].astype(np.float32)),
         pa.array(src[rows].astype(str).tolist() if n else [], pa.string())],
        names=["track_id", "class", "speed_mps", "r90_m", "source"])


def log_road_users(ctx, run: str, users: RoadUsers, look: str = "model", source: str = "",
                   trail: int = L.TRAIL_FRAMES) -> list[int]:
    """Log every road user of ``run`` (see the module docstring) through ``ctx`` (a
    ``recording.LogContext``); ``source``: what the AnyValues say where rows carry no source
    (the run's method). Returns the track ids logged."""
    import rerun as rr

    t = users.table
    scene = ctx.scene
    class_id = {c.name: c.id for c in scene.classes}
    ids = np.array([class_id.get(str(c), 0) for c in t.cls], np.uint16)
    series_colors = L.class_colors(t.cls, scene.classes)
    line_colors = L.run_colors(t.cls, scene.classes, look)  # opaque, in the run's look
    # the run's look (colours, see-through) by class id, for its road users and their trails
    ctx.static(L.run_path(run), L.annotation_context(scene.classes, look))
    wire = not L.RUN_LOOKS[look]["solid"]  # solid boxes are the 3D view's default (layout)
    fields = C.box_columns(t.xyz, t.heading, users.sizes)
    r90 = t.r90 if t.r90 is not None else np.full(len(t), np.nan)
    src = t.source if t.source is not None else np.full(len(t), source, object)
    ok90 = np.isfinite(r90) & np.isfinite(t.xyz).all(axis=1)
    has_r90 = bool(ok90.any())  # the r90 series too
    has_error = bool(np.isfinite(users.error).any())
    discs = disc_outlines(t.xyz[ok90], r90[ok90])
    disc_row = np.cumsum(ok90) - 1  # row -> its disc
    done = []
    for tid, rows in users.track_rows():
        ent = L.road_user_path(run, tid)
        fr = t.frame[rows]
        frames, lengths = shown_frames(fr, ctx.last)
        # one chunk per road user with as few components as it takes (each costs the viewer
        # time per chunk): geometry and class id (colour and name from the run's annotation
        # context), the selection panel's values, the speed and, with r90, the error disc
        n = len(fr)
        box = rr.Boxes3D.columns(centers=fields["centers"][rows], half_sizes=fields["half_sizes"][rows],
                                 quaternions=fields["quaternions"][rows], class_ids=ids[rows],
                                 fill_mode=[rr.components.FillMode.MajorWireframe] * n if wire else None)
        cols = [*box.partition(lengths), *rr.AnyValues.columns(
            road_user=info_column(users, rows, r90, src)).partition(lengths)]
        # the speed on the road user's own entity: selecting its box picks its line in the plot
        sp = users.speed[rows]
        ok = np.isfinite(sp)
        cols += [*rr.Scalars.columns(scalars=sp[ok]).partition(_per_frame(frames, fr[ok])),
                 *rr.SeriesLines.columns(colors=series_colors[rows][ok]).partition(_per_frame(frames, fr[ok]))]
        mine = ok90[rows]
        if mine.any():
            rings = discs[disc_row[rows][mine]]
            cols += [*rr.LineStrips3D.columns(
                strips=C.segments_arrow(rings, rr.components.LineStrip3DBatch),
                colors=r90_colors(r90[rows][mine])).partition(_per_frame(frames, fr[mine]))]
        ctx.send(ent, frames, cols)
        if trail > 1:
            log_trail(ctx, run, tid, users, rows, line_colors[rows])
        for quantity, column, wanted in (("error", users.error, has_error), ("r90", r90, has_r90)):
            v = column[rows]
            okv = np.isfinite(v)
            if not wanted or not okv.any():
                continue
            ctx.send(L.road_user_series_path(run, quantity, tid), fr[okv], [
                *rr.Scalars.columns(scalars=v[okv]), *rr.SeriesLines.columns(colors=series_colors[rows][okv])])
        done.append(tid)
    return done


def _per_frame(frames: np.ndarray, sub: np.ndarray) -> np.ndarray:
    """Rows per sent frame (``frames``, sorted) of a subset of a road user's rows at ``sub``."""
    out = np.zeros(len(frames), np.int64)
    np.add.at(out, np.searchsorted(frames, sub), 1)
    return out


def log_trail(ctx, run: str, tid: int, users: RoadUsers, rows: slice, colors: np.ndarray) -> None:
    """A road user's trail, ``world/road_users/<run>/<track id>/trail``: at each of its frames
    after the first, one segment from its previous pose, in ``colors`` (N, 4) of its rows
    (colours rather than class ids: the recording has that component already, and each
    component adds columns to every chunk's row of the .rrd's manifest); the blueprint
    shows the last frames of it with a visible time range (``layout.trail_overrides``), so no
    point is sent twice over. A child of the road user: hiding the road user hides its trail."""
    import rerun as rr

    p = users.table.xyz[rows] + [0.0, 0.0, TRAIL_LIFT_M]
    if len(p) < 2:
        return
    segs = np.stack([p[:-1], p[1:]], axis=1)
    ctx.send(L.trail_path(run, tid), users.table.frame[rows][1:], rr.LineStrips3D.columns(
        strips=C.segments_arrow(segs, rr.components.LineStrip3DBatch), colors=colors[1:]))


def series_present(users: RoadUsers) -> list[str]:
    """The road-user series a run has (keys of ``layout.ROAD_USER_SERIES``), for the blueprint."""
    t = users.table
    out = ["speed"] if np.isfinite(users.speed).any() else []
    if np.isfinite(users.error).any():
        out.append("error")
    if t.r90 is not None and np.isfinite(t.r90).any():
        out.append("r90")
    return out


def prepare(scene, sel, gt: PoseTable | None) -> dict[str, RoadUsers]:
    """Run name -> its road users over the selection's frames (``road_users``), sized by the
    scene (``columns.sizes_of``): computed once, before logging, so that the blueprint can name
    every road user's trail and series."""
    out = {}
    for run in sel.runs:
        poses = run.poses.in_frames((sel.first, sel.last))
        out[run.name] = road_users(poses, C.sizes_of(poses, scene), scene.fps, gt)
    return out


def track_ids(users: RoadUsers) -> list[int]:
    return [int(tid) for tid in users.table.track_id[users.starts]]
