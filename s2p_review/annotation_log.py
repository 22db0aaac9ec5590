"""Rerun logging for the annotation app: the scene once, then annotation tracks one at a time.

Entities (beside those of ``layout``)::

    world/annotation/t<id>                  Boxes3D: the track's box in every frame of its span
                                            (class ids of the AnnotationContext) + AnyValues:
                                            track id, class, source
    world/annotation/t<id>/trail            LineStrips3D: its last TRAIL_FRAMES positions
    world/cameras/<cam>/annotation/t<id>    LineStrips2D: the box projected into the camera

Each track has its own entities so that an edit re-sends only that track (``send_track``:
one ``send_columns`` per entity over the frames the track covers now *and* covered before, so
frames it left are emptied). Keyframes are drawn with thick lines, interpolated frames thin,
occluded frames dim; the selected track in a highlight colour.

Takes plain columns (frame, xyz, heading, size, source, cls), not the annotation engine's
types: s2p_review does not import annotate.
"""

from __future__ import annotations

import functools
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from s2p_review import columns as C
from s2p_review import layout as L
from s2p_review.timebase import scene_timebase

SELECTED_COLOR = (255, 215, 0)
OCCLUDED_SHADE = 0.45
RADII_3D = {"keyframe": 0.07, "interpolated": 0.025, "occluded": 0.02}
RADII_2D = {"keyframe": 2.0, "interpolated": 0.8, "occluded": 0.6}
VIEW_PREFIX = "camera "  # view names are "camera <cam>" (layout.blueprint)


def track_path(track_id: int) -> str:
    return f"world/annotation/t{int(track_id)}"


def camera_track_path(cam: str, track_id: int) -> str:
    return f"{L.cam_path(cam)}/annotation/t{int(track_id)}"


def camera_of_view(view_name: str | None, entity_path: str | None, cameras) -> str | None:
    """The camera a click landed in, from the view's name ("camera c1") or, failing that, the
    clicked entity's path (world/cameras/<cam>/...); None for the 3D view or anything else."""
    names = {L.entity_part(c): c for c in cameras}
    if view_name and view_name.startswith(VIEW_PREFIX) and view_name[len(VIEW_PREFIX):] in cameras:
        return view_name[len(VIEW_PREFIX):]
    parts = (entity_path or "").strip("/").split("/")
    if view_name is None and len(parts) >= 3 and parts[:2] == ["world", "cameras"]:
        return names.get(parts[2])
    return None


@dataclass
class TrackColumns:
    """One track's poses over its span. frame (N,) int; xyz (N, 3) metres (ground contact
    point); heading (N,) radians; size (N, 3) l, w, h metres; source (N,) str (keyframe,
    interpolated, occluded); cls: the class name."""

    track_id: int
    cls: str
    frame: np.ndarray
    xyz: np.ndarray
    heading: np.ndarray
    size: np.ndarray
    source: np.ndarray


@dataclass
class AnnotationLogger:
    """Sends annotation tracks to a recording (anything with ``log``/``send_columns``/
    ``flush``, e.g. a RecordingStream or ``Tee``). Remembers each track's last sent span."""

    rec: Any
    scene: Any
    cameras: list[str]
    trail: int = L.TRAIL_FRAMES
    sent: dict[int, tuple[int, int]] = field(default_factory=dict)

    def _times(self, frames: np.ndarray):
        return scene_timebase(self.scene).rerun_columns(frames)

    def _colors(self, t: TrackColumns, selected: bool) -> np.ndarray:
        base = np.array(SELECTED_COLOR if selected else L.class_colors(np.array([t.cls]),
                                                                       self.scene.classes)[0],
                        dtype=float)
        shade = np.where(t.source == "occluded", OCCLUDED_SHADE, 1.0)[:, None]
        return np.clip(base[None] * shade, 0, 255).astype(np.uint8).reshape(-1, 3)

    def send_track(self, t: TrackColumns, selected: bool = False) -> int:
        """(Re)send one track; frames it covered before but not now are emptied. Returns the
        number of frames sent."""
        import rerun as rr

        old = self.sent.get(t.track_id)
        if len(t.frame):
            lo, hi = int(t.frame.min()), int(t.frame.max())
            if old:
                lo, hi = min(lo, old[0]), max(hi, old[1])
        elif old:
            lo, hi = old
        else:
            return 0
        order = np.argsort(t.frame, kind="stable")
        t = TrackColumns(t.track_id, t.cls, t.frame[order], t.xyz[order], t.heading[order],
                         t.size[order], t.source[order])
        frames = np.arange(lo, hi + 1)
        times = self._times(frames)
        lengths = C.frame_lengths(t.frame, lo, hi)
        colors = self._colors(t, selected)
        label = f"{t.cls[:1]}{t.track_id}"
        labels = [f"{label} key" if s == "keyframe" else label for s in t.source]
        r3 = np.array([RADII_3D.get(s, 0.03) for s in t.source], np.float32)
        ent = track_path(t.track_id)
        n = len(t.frame)
        cid = {c.name: c.id for c in self.scene.classes}.get(t.cls, 0)
        # class ids through the AnnotationContext; AnyValues for the selection panel
        values: dict[str, Any] = {"track_id": np.full(n, t.track_id, np.int64), "class": [t.cls] * n,
                                  "source": t.source.astype(str)}
        info = rr.AnyValues.columns(**values)
        self.rec.send_columns(ent, indexes=times, columns=[*rr.Boxes3D.columns(
            **C.box_columns(t.xyz, t.heading, t.size), colors=colors, radii=r3, labels=labels,
            class_ids=np.full(n, cid, np.uint16), fill_mode=["majorwireframe"] * n).partition(lengths),
            *info.partition(lengths)])
        if self.trail > 1:
            pts, offs = C.trail_points(np.full(len(t.frame), t.track_id), t.frame,
                                       t.xyz + [0, 0, 0.05], self.trail)
            self.rec.send_columns(ent + "/trail", indexes=times, columns=rr.LineStrips3D.columns(
                strips=C.strips_arrow(pts, offs, rr.components.LineStrip3DBatch),
                colors=colors, radii=np.full(len(t.frame), 0.04, np.float32)).partition(lengths))
        r2 = np.array([RADII_2D.get(s, 1.0) for s in t.source], np.float32)
        for cam in self.cameras:
            segs, idx = C.projected_paths(self.scene.cameras[cam], t.xyz, t.heading, t.size)
            self.rec.send_columns(
                camera_track_path(cam, t.track_id), indexes=times,
                columns=rr.LineStrips2D.columns(
                    strips=C.segments_arrow(segs, rr.components.LineStrip2DBatch),
                    colors=colors[idx], radii=r2[idx],
                    draw_order=np.full(len(idx), 3.0, np.float32))
                .partition(C.frame_lengths(t.frame[idx], lo, hi)))
        if len(t.frame):
            self.sent[t.track_id] = (int(t.frame.min()), int(t.frame.max()))
        else:
            self.sent.pop(t.track_id, None)
        return len(frames)


class Tee:
    """Log to several recording streams at once (the notebook viewer and a native viewer)."""

    def __init__(self, *recs):
        self.recs = recs

    def log(self, *a, **k):
        for r in self.recs:
            r.log(*a, **k)

    def send_columns(self, *a, **k):
        for r in self.recs:
            r.send_columns(*a, **k)

    def flush(self):
        for r in self.recs:
            r.flush()


def new_recording():
    """A recording stream of its own (a fresh id: two app sessions never mix)."""
    import rerun as rr

    return rr.RecordingStream("s2p-annotate", recording_id=uuid.uuid4().hex)


def log_scene(rec, scene, run: Path | None, cameras: list[str] | None,
              frames: tuple[int, int] | None = None, *, video: bool = True, masks: bool = True):
    """Log the scene (cameras, ground, video frames under masks) and the run's estimates for
    comparison, as ``s2p review`` does but without ground truth (annotators must not see it).
    Returns (blueprint, cameras shown, (first, last) frames, notes for the user, camera ->
    scene frames that have video)."""
    from s2p_review.recording import LogStyle, log_all
    from s2p_review.selection import select

    sel = select(scene, [run] if run is not None else [], frames, cameras, masks=masks,
                 video=video)
    # masks as outlines only: every frame at a few kB, where fills cost 0.9 MB a frame each
    stats = log_all(rec, scene, sel, scene_timebase(scene), LogStyle(masks=masks, video=video,
                                                                     gt=False, mask_fills=False))
    bp = L.blueprint(sel.cameras, [r.name for r in sel.runs], with_metrics=False,
                     eye=L.default_eye(scene), fps=scene.fps)
    return bp, sel.cameras, (sel.first, sel.last), list(stats.notes), stats.video_frames


def run_tracks(run: Path) -> list[int]:
    """The track ids of a run folder's poses with a position: the road users ``log_scene``
    logs, whose trails ``app_blueprint`` names (read once per version of the file)."""
    path = Path(run) / "poses.csv"
    return list(_track_ids(path, path.stat().st_mtime_ns))


@functools.lru_cache(maxsize=16)
def _track_ids(path: Path, mtime_ns: int) -> tuple[int, ...]:
    from seg2pose.io.poses import read_poses

    poses = read_poses(path)
    return tuple(sorted(set(poses.track_id[np.isfinite(poses.xyz).all(axis=1)].tolist())))


TIMELINE_PATH = "timeline/selected"   # the selected track's keyframe timeline (send_timeline)


def app_blueprint(cameras: list[str], large: str | None, eye=None, fps: float | None = None,
                  timeline: str = L.TIMELINE, large_in_page: bool = False,
                  runs=()):
    """The annotation app's layout: camera ``large`` big on the left over the selected track's
    keyframe timeline; the 3D world and the other cameras small on the right.
    ``large_in_page``: the page shows camera ``large`` itself (annotate.app.frame_view), so
    the viewer shows the 3D world and the other cameras over the timeline. runs: the folders
    of the runs shown, whose road users' trails (``run_tracks``) the 3D view then shows over the
    last TRAIL_FRAMES frames (without: each road user's last step)."""
    import rerun.blueprint as rrb

    large = large if large in cameras else (cameras[0] if cameras else None)
    extra: dict = {}
    if eye is not None:
        extra["eye_controls"] = rrb.EyeControls3D(position=eye[0], look_target=eye[1], eye_up=(0, 0, 1))
    if runs:
        extra["overrides"] = L.trail_overrides({Path(r).name: run_tracks(Path(r)) for r in runs},
                                               L.TRAIL_FRAMES, fps)
    world = rrb.Spatial3DView(origin="world", name="world", contents=["+ world/**"],
                              line_grid=rrb.LineGrid3D(visible=False), **extra)
    small = [rrb.Spatial2DView(origin=L.cam_path(c), name=f"{VIEW_PREFIX}{c}")
             for c in cameras if c != large]
    plot = rrb.TimeSeriesView(origin=TIMELINE_PATH, name="selected track: keyframes, distance "
                              "to the estimates (m)",
                              plot_legend=rrb.PlotLegend(corner="lefttop", visible=True))
    if large_in_page and large is not None:
        top = [world] + ([rrb.Grid(*small, grid_columns=2)] if len(small) > 1 else small)
        body: Any = rrb.Vertical(rrb.Horizontal(*top), plot, row_shares=[2, 1])
    elif large is None:
        body = rrb.Vertical(world, plot, row_shares=[4, 1])
    else:
        left = rrb.Vertical(rrb.Spatial2DView(origin=L.cam_path(large), name=f"{VIEW_PREFIX}{large}"),
                            plot, row_shares=[4, 1])
        right = rrb.Vertical(world, *small) if len(small) <= 3 else \
            rrb.Vertical(world, rrb.Grid(*small, grid_columns=2), row_shares=[1, 2])
        body = rrb.Horizontal(left, right, column_shares=[3, 1])
    return rrb.Blueprint(body, rrb.TimePanel(state="collapsed", timeline=timeline, fps=fps),
                         rrb.SelectionPanel(state="hidden"), rrb.BlueprintPanel(state="hidden"),
                         auto_views=False, collapse_panels=False)


def send_timeline(rec, scene, frames: np.ndarray, distance: np.ndarray, keyframes: np.ndarray,
                  previous: tuple[int, int] | None = None) -> tuple[int, int] | None:
    """The selected track's timeline: the distance (metres) between its interpolation and the
    run's estimates (or the masks' normal positions) per frame, NaN where there is none, and
    its keyframes as points on the 0 line. ``previous``: the frame span sent last time, emptied
    first. Returns the span sent now."""
    import rerun as rr

    tb = scene_timebase(scene)
    if previous is not None:
        lo, hi = previous
        fr = np.arange(lo, hi + 1)
        for ent in (f"{TIMELINE_PATH}/distance", f"{TIMELINE_PATH}/keyframes"):
            rec.send_columns(ent, indexes=tb.rerun_columns(fr),
                             columns=rr.Clear.columns(is_recursive=[False] * len(fr)))
    rec.log(f"{TIMELINE_PATH}/distance", rr.SeriesLines(colors=[(230, 120, 40)],
                                                        names=["distance to the estimates"]),
            static=True)
    rec.log(f"{TIMELINE_PATH}/keyframes", rr.SeriesPoints(colors=[SELECTED_COLOR],
                                                          names=["keyframes"], marker_sizes=[5.0]),
            static=True)
    ok = np.isfinite(distance)
    C.send_scalars(rec, f"{TIMELINE_PATH}/distance", tb, frames, distance)
    C.send_scalars(rec, f"{TIMELINE_PATH}/keyframes", tb, keyframes, np.zeros(len(keyframes)))
    span = [int(a) for a in (frames[ok] if ok.any() else keyframes)]
    return (min(span), max(span)) if span else None
