"""One review session: select what to show, log it (``recording``) to the places asked for (an
.rrd file written atomically, a spawned or running viewer, a headless viewer for a screenshot),
then drive the viewers (time cursor, follow). ``record`` is the public entry point.
"""

from __future__ import annotations

import uuid
from dataclasses import dataclass, field
from pathlib import Path

from s2p_review import layout as L
from s2p_review import road_users as RU
from s2p_review.recording import LogStats, LogStyle, log_all
from s2p_review.selection import Selection, select
from s2p_review.timebase import scene_timebase
from seg2pose.core.errors import S2PError
from seg2pose.io.atomic import atomic_open, check_writable, clean_stale_partials, holding
from seg2pose.io.disk import write_failed
from seg2pose.io.pipe_sink import PipeSink
from seg2pose.io.scene import Scene


@dataclass(frozen=True)
class RecordOptions:
    """What to show. frames: (first, last) inclusive (None: the runs' frames); cameras: None =
    the runs' cameras, or all; mask_every / video_every: log masks / video every k-th frame
    only (a viewer shows the latest one, so a smaller file costs some lag; None = automatic,
    see ``selection.resolve_cadence``); style: the look (``recording.LogStyle``); start_ns: UTC
    time of frame 0 in ns since the epoch (None: the scene's, when it has one); conflicts:
    a conflicts.csv to show with the first run's tracks (or the truth's without a run)."""

    frames: tuple[int, int] | None = None
    cameras: list[str] | None = None
    mask_every: int | None = None
    video_every: int | None = None
    style: LogStyle = field(default_factory=LogStyle)
    start_ns: int | None = None
    conflicts: Path | None = None  # a conflicts.csv of the (first) run: see s2p_review.conflicts


@dataclass(frozen=True)
class Targets:
    """Where the recording goes. rrd: write an .rrd there (atomically; refused if it exists
    unless ``force``); spawn: open the native desktop viewer; connect: stream to a running
    viewer (``rerun+http://host:port/proxy``); screenshot: also run a headless viewer and save
    a PNG of it there; frame: the time cursor for the screenshot and for spawned or connected
    viewers (default: the middle frame for screenshots, the viewer's choice otherwise);
    follow: make spawned or connected viewers follow the newest frame instead."""

    rrd: Path | None = None
    spawn: bool = False
    connect: str | None = None
    screenshot: Path | None = None
    frame: int | None = None
    follow: bool = False
    force: bool = False

    def any(self) -> bool:
        return self.rrd is not None or self.spawn or self.connect is not None or self.screenshot is not None


@dataclass(frozen=True)
class RecordResult:
    """What ``record`` did: the .rrd and PNG written (or None), what was shown and logged, and
    notes for the user (automatic cadences, short videos)."""

    rrd: Path | None
    screenshot: Path | None
    selection: Selection
    stats: LogStats
    notes: tuple[str, ...]


def _error_max(scene: Scene, sel: Selection) -> float | None:
    """The top of the runs' common error axis, metres: 2.2 times the largest error, so that the
    lines stay in the lower half and the legend (top left) hides none of them."""
    if not scene.gt_path.exists() or not sel.runs:
        return None
    from s2p_review.recording import error_series
    from seg2pose.io.poses import read_poses

    gt = read_poses(scene.gt_path).in_frames((sel.first, sel.last))
    top = [float(e.max()) for r in sel.runs
           for _, e, _ in error_series(r, gt, scene, sel.first, sel.last).values()]
    return 2.2 * max(top) if top else None


def record(scene: Scene, runs: list[Path], to: Targets | Path,
           options: RecordOptions | None = None) -> RecordResult:
    """Record ``scene`` with ``runs`` (run folders) to Rerun; ``to``: where (a Path is short for
    ``Targets(rrd=path)``). The .rrd file and the screenshot are locked from the start (a
    second writer of either is refused) and a killed writer's partial .rrd files removed."""
    to = Targets(rrd=Path(to)) if isinstance(to, (str, Path)) else to
    with holding(to.rrd, to.screenshot):
        for p in (to.rrd, to.screenshot):
            if p is not None:
                clean_stale_partials(p)
        return _record(scene, runs, to, options)


def _record(scene: Scene, runs: list[Path], to: Targets, options: RecordOptions | None) -> RecordResult:
    import rerun as rr

    from s2p_review import viewer as V

    opts = options or RecordOptions()
    if not to.any():
        raise S2PError("nothing to do: no .rrd file, viewer or screenshot was asked for")
    rrd = check_writable(Path(to.rrd), to.force) if to.rrd is not None else None
    if to.screenshot is not None:
        check_writable(Path(to.screenshot), to.force)
    if to.connect is not None:
        V.check_reachable(to.connect)
    style = opts.style
    sel = select(scene, runs, opts.frames, opts.cameras, opts.mask_every, opts.video_every,
                 style.masks, style.video)
    tb = scene_timebase(scene, opts.start_ns)
    conflicts = None
    if opts.conflicts is not None:
        from s2p_review import conflicts as CF

        conflicts = CF.read_conflicts(opts.conflicts)
    gt = None
    if style.gt and scene.gt_path.exists():
        from seg2pose.io.poses import read_poses

        gt = read_poses(scene.gt_path).in_frames((sel.first, sel.last))
    users = RU.prepare(scene, sel, gt)
    bp = L.blueprint(sel.cameras, [r.name for r in sel.runs],
                     with_metrics=scene.gt_path.exists() and bool(sel.runs),
                     eye=L.default_eye(scene), fps=scene.fps, error_max=_error_max(scene, sel),
                     timeline=L.TIME if tb.start_ns is not None else L.TIMELINE,
                     more_views=CF.views() if conflicts is not None else (),
                     series={k: RU.series_present(u) for k, u in users.items()}, trail=style.trail,
                     tracks={k: RU.track_ids(u) for k, u in users.items()})
    rec = rr.RecordingStream("s2p", recording_id=uuid.uuid4().hex)
    title = f"{scene.name}: " + (", ".join(r.name for r in sel.runs) if sel.runs else "scene")
    shot_viewer = None
    try:
        sinks, live = [], []  # live: viewers to drive after logging (time cursor / follow)
        if to.spawn:
            client = V.spawn_viewer(headless=False)
            live.append(client)
            sinks.append(rr.GrpcSink(client.url))
        if to.connect is not None:
            live.append(V.connect_viewer(to.connect))
            sinks.append(rr.GrpcSink(to.connect))
        if to.screenshot is not None:
            shot_viewer = V.spawn_viewer(headless=True)
            sinks.append(rr.GrpcSink(shot_viewer.url))

        def log(*file_sink):
            rec.set_sinks(*file_sink, *sinks)
            # active, not only default: a viewer that remembers an older s2p layout (other
            # cameras) would otherwise keep showing that one
            rec.send_blueprint(bp, make_active=True, make_default=True)
            rec.send_recording_name(title)
            stats = log_all(rec, scene, sel, tb, style, users)
            if conflicts is not None:
                from seg2pose.io.poses import read_poses

                poses = sel.runs[0].poses if sel.runs else read_poses(scene.gt_path)
                CF.log_conflicts(rec, conflicts, poses, scene.fps, tb, sel.first, sel.last)
            rec.flush()
            return stats

        if rrd is not None:
            # Rerun writes into a pipe and this process into the file (io/pipe_sink.py: a full
            # disk stalls Rerun's own file writer for ever)
            with atomic_open(rrd, "wb") as f:
                pipe = PipeSink(f)
                try:
                    stats = log(rr.FileSink(pipe.path))
                except RuntimeError as e:  # Rerun's file writer stopped (it says no more)
                    raise write_failed(rrd, f"Rerun's file writer stopped ({e})") from e
                finally:
                    rec.disconnect()  # Rerun closes its end: the copy ends
                    pipe.close()  # the copy's OSError: one line naming rrd (atomic_open)
        else:
            stats = log()
        for client in live:
            if to.follow:
                V.wait_loaded(client)
                V.follow(client)
            elif to.frame is not None:
                V.wait_loaded(client, min_end=to.frame)
                V.set_frame(client, to.frame)
        if shot_viewer is not None:
            k = sel.cadence.masks if style.masks else 1  # a frame that has masks, not a stale one
            frame = to.frame if to.frame is not None else sel.first + (sel.n_frames - 1) // 2 // k * k
            V.screenshot_when_loaded(shot_viewer, Path(str(to.screenshot)), frame=frame, force=to.force)
    finally:
        rec.disconnect()  # before the viewers go: no "connection severed" noise
        if shot_viewer is not None:
            V.stop(shot_viewer)
    return RecordResult(rrd, None if to.screenshot is None else Path(to.screenshot), sel, stats,
                        stats.notes)
