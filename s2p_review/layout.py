"""The entity layout of a review recording (DESIGN.md, "Rerun layout"), class colours and the
default blueprint.

One recording may hold several runs of the same scene (e.g. baseline and Seg2PoseNet side by
side), so every run-specific entity has the run's name as one more path level; every road user
of a run is an entity of its own, as in Rerun's tracking examples, so that it can be selected,
hidden and plotted alone. Run and camera names enter paths through Rerun's own escaping
(``entity_part``): names that differ stay apart ("tri T" and "tri_T" are two runs)::

    world/ground/points, world/ground/mesh          ground points and the eq. (1) surface
    world/cameras/<cam>                             Transform3D + Pinhole
    world/cameras/<cam>/image                       video frame (when the scene has video)
    world/cameras/<cam>/masks                       SegmentationImage (pixel = class id)
    world/cameras/<cam>/normal/<run>                Points2D: mask centres of the run's views
    world/cameras/<cam>/poses/<run>                 LineStrips2D: fused boxes projected
    world/cameras/<cam>/gt                          LineStrips2D: true boxes projected
    world/road_users/<run>                          AnnotationContext: class colours in the
                                                    run's look
    world/road_users/<run>/<track id>               Boxes3D (class ids of the run's annotation
                                                    context) + AnyValues road_user (track id,
                                                    class, speed, r90, source) + Scalars: speed
                                                    (m/s) + LineStrips3D: error disc (runs with
                                                    r90) -- one road user of the run
    world/road_users/<run>/<track id>/trail         LineStrips3D: per frame a segment from its
                                                    previous pose, shown over the last
                                                    TRAIL_FRAMES by a visible time range
    world/estimates/<run>/<cam>                     Points3D: normal positions of one view
    world/estimates/<run>/<cam>/residuals           Arrows3D: Seg2PoseNet residuals
    world/gt                                        Boxes3D: ground truth, drawn in grey
    metrics/error/<run>/mean, .../<class>           Scalars: per-frame mean error (metres),
                                                    one plot per run
    metrics/road_users/<run>/<quantity>/<track id>  Scalars per road user: error against the
                                                    truth (m, where there is truth), r90 (m,
                                                    runs with r90); a plot per quantity, and
                                                    one of the speeds (world/road_users/<run>)
"""

from __future__ import annotations

from typing import Any

import numpy as np

TIMELINE = "frame"
TIME = "time"
TRAIL_FRAMES = 30

# class name -> RGB; unknown classes get a colour from PALETTE by class id
CLASS_COLORS = {"pedestrian": (230, 60, 60), "bicyclist": (60, 200, 90), "car": (40, 140, 240),
                "truck": (240, 170, 30), "bus": (180, 90, 230)}
PALETTE = [(230, 60, 60), (60, 200, 90), (40, 140, 240), (240, 170, 30), (180, 90, 230),
           (30, 200, 200), (240, 110, 180), (160, 160, 60)]
GT_COLOR = (200, 200, 200)


def class_color(name: str, class_id: int = 0) -> tuple[int, int, int]:
    return CLASS_COLORS.get(name, PALETTE[class_id % len(PALETTE)])


def class_colors(names: np.ndarray, classes) -> np.ndarray:
    """(N,) class names -> (N, 3) uint8 colours; ``classes``: the scene's ClassSpecs."""
    table = {c.name: class_color(c.name, c.id) for c in classes}
    return np.array([table.get(n, (128, 128, 128)) for n in names], dtype=np.uint8).reshape(-1, 3)


# How a run looks, so that runs compared in one recording tell apart at a glance: a model's
# boxes solid in full class colours with bold projected lines, the baseline's hollow, pale
# (40 % of the way to grey) and thin. alpha: of solid boxes; line: radius of projected lines, pixels.
RUN_LOOKS = {"model": {"solid": True, "pale": 0.0, "alpha": 150, "line": 1.0},
             "baseline": {"solid": False, "pale": 0.4, "alpha": 255, "line": 0.5}}


def run_look(meta: dict) -> str:
    """The look of a run from its run.json: "baseline" for the baseline, else "model"."""
    return "baseline" if str(meta.get("method", "")).lower() == "baseline" else "model"


def run_colors(names: np.ndarray, classes, look: str = "model", solid: bool = False) -> np.ndarray:
    """(N,) class names -> (N, 4) RGBA uint8 colours in the ``look`` of a run; ``solid``: for
    filled boxes (see-through), else for lines (opaque)."""
    spec = RUN_LOOKS[look]
    rgb = class_colors(names, classes).astype(float)
    rgb = (1 - spec["pale"]) * rgb + spec["pale"] * 160.0
    a = np.full((len(rgb), 1), spec["alpha"] if solid and spec["solid"] else 255, float)
    return np.rint(np.c_[rgb, a]).astype(np.uint8).reshape(-1, 4)


def labels(names: np.ndarray, track_ids: np.ndarray) -> list[str]:
    """Short labels such as ``c12`` (first letter of the class, track id)."""
    return [f"{str(n)[:1]}{int(t)}" for n, t in zip(names, track_ids)]


def entity_part(name: str) -> str:
    """A run, camera or class name as one entity path part, losslessly: Rerun's own escaping
    (``rr.escape_entity_path_part``), so that names that differ give parts that differ."""
    import rerun as rr

    return rr.escape_entity_path_part(str(name))


def cam_path(cam: str) -> str:
    return f"world/cameras/{entity_part(cam)}"


def run_path(run: str) -> str:
    """The entity under which a run's road users are (one child per track id)."""
    return f"world/road_users/{entity_part(run)}"


def road_user_path(run: str, track_id: int) -> str:
    return f"{run_path(run)}/{int(track_id)}"


def trail_path(run: str, track_id: int) -> str:
    """A road user's trail: a child of the road user, hidden with it."""
    return f"{road_user_path(run, track_id)}/trail"


ROAD_USER_SERIES = {"speed": "speed (m/s)", "error": "error against the truth (m)",
                    "r90": "r90 error bar (m)"}


def road_user_series_path(run: str, quantity: str, track_id: int | None = None) -> str:
    """metrics/road_users/<run>/<quantity>[/<track id>]: a road user's time series of
    ``quantity`` ("error" or "r90"; the speed is on the road user's own entity), or the folder
    of all road users' series."""
    base = f"metrics/road_users/{entity_part(run)}/{quantity}"
    return base if track_id is None else f"{base}/{int(track_id)}"


def trail_ranges(trail: int, fps: float | None):
    """Visible time ranges that show the last ``trail`` frames up to the time cursor, on both
    timelines (frame numbers and time)."""
    import rerun.blueprint as rrb

    ranges = [rrb.VisibleTimeRange(TIMELINE, start=rrb.TimeRangeBoundary.cursor_relative(seq=-trail),
                                   end=rrb.TimeRangeBoundary.cursor_relative())]
    if fps:
        ranges.append(rrb.VisibleTimeRange(TIME, start=rrb.TimeRangeBoundary.cursor_relative(
            seconds=-trail / float(fps)), end=rrb.TimeRangeBoundary.cursor_relative()))
    return rrb.VisibleTimeRanges(ranges)


def annotation_context(classes, look: str | None = None):
    """Class ids (= mask pixel values) with names and colours; id 0 is transparent background.
    look: the colours in a run's look (``run_colors`` of solid boxes), for the context under
    the run's road users (``run_path``), which then need no colour of their own."""
    import rerun as rr

    colors = [class_color(c.name, c.id) for c in classes] if look is None else \
        [tuple(int(v) for v in row) for row in run_colors(np.array([c.name for c in classes]), classes, look,
                                                          solid=True)]
    infos = [rr.AnnotationInfo(id=0, label="background", color=(0, 0, 0, 0))]
    infos += [rr.AnnotationInfo(id=c.id, label=c.name, color=col) for c, col in zip(classes, colors)]
    return rr.AnnotationContext(infos)


def default_eye(scene) -> tuple[np.ndarray, np.ndarray]:
    """(position, look target) in metres for the 3D view: over the ground points' centre, seen
    from behind the cameras and above, far enough to take in the whole area."""
    g = scene.ground_points
    target = np.r_[g[:, :2].mean(axis=0), g[:, 2].mean()]
    extent = float(max(np.ptp(g[:, 0]), np.ptp(g[:, 1]), 10.0))
    away = scene.rig.center[:2] - target[:2]
    n = np.linalg.norm(away)
    away = away / n if n > 1e-6 else np.array([0.0, -1.0])
    pos = target + np.r_[away * 1.1 * extent, 0.8 * extent]
    return pos, target


def trail_overrides(tracks, trail: int, fps: float | None) -> dict:
    """3D-view overrides that show the road users' trails over the last ``trail`` frames;
    tracks: run name -> its track ids. One override per trail: Rerun's overrides take whole
    paths (no patterns) and do not pass to children, and the road user itself stays at the
    time cursor."""
    ranges = trail_ranges(trail, fps)
    return {trail_path(r, tid): ranges for r, ids in tracks.items() for tid in ids}


def world_defaults() -> list:
    """The 3D view's component defaults: road users' boxes solid without labels (class names
    come from the annotation context; the baseline's wireframe is in its rows) and trails
    4 cm wide without labels (their class names would cover the scene), so that no road
    user's chunk carries them row by row."""
    import rerun as rr

    return [rr.Boxes3D.from_fields(fill_mode=rr.components.FillMode.Solid, show_labels=False),
            rr.LineStrips3D.from_fields(radii=0.04, show_labels=False)]


def blueprint(cameras: list[str], runs: list[str], with_metrics: bool = True, eye=None,
              fps: float | None = None, error_max: float | None = None,
              timeline: str = TIMELINE, more_views=(), series: dict | None = None,
              trail: int = TRAIL_FRAMES, tracks: dict | None = None):
    """The 3D world over the plots (one group per run, side by side) on the left; one 2D view
    per camera on the right. eye: (position, look target) of the 3D view, metres (see
    ``default_eye``); fps: frames per second, so that playback runs in real time; error_max:
    the top of the error plots' common y axis, metres; timeline: the timeline the time panel
    opens on; more_views: more views, in a row under the world (e.g.
    ``s2p_review.conflicts.views()``); trail: the frames of the road users' trails the 3D view
    shows (a visible time range on each trail); tracks: run name -> its track ids (the road
    users whose trails get that range; without, a trail shows its last step); series: run name -> the road-user
    series it has (keys of ROAD_USER_SERIES), each a plot of all its road users, in tabs after
    the run's error plot (``with_metrics``). Rerun's blueprints cannot make a view follow the
    selection: a road user is found in its plot by hovering (the series is named by its
    label, e.g. ``c12``) and selected there or in the 3D view, and its values at the cursor
    are in the selection panel (AnyValues)."""
    import rerun.blueprint as rrb

    cams = [rrb.Spatial2DView(origin=cam_path(c), name=f"camera {c}") for c in cameras]
    extra: dict[str, Any] = {}
    if eye is not None:
        extra["eye_controls"] = rrb.EyeControls3D(position=eye[0], look_target=eye[1], eye_up=(0, 0, 1))
    if tracks and trail > 1:
        extra["overrides"] = trail_overrides(tracks, trail, fps)
    world = rrb.Spatial3DView(origin="world", name="world",
                              contents=["+ world/**"], defaults=world_defaults(),
                              line_grid=rrb.LineGrid3D(visible=False), **extra)
    axis: dict[str, Any] = {} if error_max is None else {
        "axis_y": rrb.ScalarAxis(range=(0.0, float(error_max)), zoom_lock=False)}
    groups = []
    for r in runs:
        views = []
        if with_metrics:
            views.append(rrb.TimeSeriesView(origin=f"metrics/error/{entity_part(r)}", name=f"error (m): {r}",
                                            plot_legend=rrb.PlotLegend(corner="lefttop", visible=True),
                                            **axis))
        for q in (series or {}).get(r, []):
            # speed: Scalars on the road users' own entities (their boxes select their lines)
            views.append(rrb.TimeSeriesView(origin=run_path(r) if q == "speed" else road_user_series_path(r, q),
                                            name=f"{ROAD_USER_SERIES[q]}: {r}",
                                            plot_legend=rrb.PlotLegend(visible=False),
                                            **(axis if q == "error" else {})))
        if views:
            groups.append(views[0] if len(views) == 1 else rrb.Tabs(*views, active_tab=0))
    # left: the world over the plots; right: the cameras stacked (16:9 images use the width of
    # a half screen better stacked than side by side), a grid beyond three
    left: Any = rrb.Vertical(world, rrb.Horizontal(*groups), row_shares=[3, 1]) if groups else world
    if more_views:
        left = rrb.Vertical(left, rrb.Horizontal(*more_views), row_shares=[3, 1])
    if not cams:
        body = left
    else:
        right = rrb.Vertical(*cams) if len(cams) <= 3 else rrb.Grid(*cams, grid_columns=2)
        body = rrb.Horizontal(left, right, column_shares=[1, 1])
    return rrb.Blueprint(body, rrb.TimePanel(state="collapsed", timeline=timeline, fps=fps),
                         rrb.SelectionPanel(state="hidden"),
                         rrb.BlueprintPanel(state="hidden"),
                         auto_views=False, collapse_panels=False)
