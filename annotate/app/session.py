"""One page of the annotation app: the controller, the Rerun notebook viewer, the panel, and
the wiring between them. The marimo app file (notebook.py) only builds a ``Session`` and lays
out its two widgets.

The large camera is a picture made here (frame_image.py) in the page's own image widget
(frame_view.py): the exact frame the panel names, redrawn after every frame move and edit; a
click on it places a keyframe at that pixel. The Rerun viewer shows the 3D world, the other
cameras and the selected track's keyframe timeline.

Frame view -> controller: a click (image pixel, camera, the frame the picture showed).
Viewer -> controller: a click on a camera image (SelectionChangeEvent with a pixel position)
places a keyframe; the time cursor (TimeUpdateEvent) sets the current frame.
Panel -> controller: buttons, shortcut keys, heartbeats.
Controller -> viewer: changed tracks are re-sent (``AnnotationLogger.send_track``), frame
moves set the viewer's time cursor; the frame view gets a new picture when the frame, the
large camera, a track or the selection changed.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("RERUN_NOTEBOOK_ASSET", "serve-local")  # never load the widget from the web

from annotate.app.actions import SHORTCUTS  # noqa: E402
from annotate.app.controller import Controller  # noqa: E402
from annotate.app.frame_image import FrameImages  # noqa: E402
from annotate.app.frame_view import FrameView  # noqa: E402
from annotate.app.panel import Panel, render  # noqa: E402
from annotate.app.viewer_cache import page_frames  # noqa: E402
from s2p_review import layout as L  # noqa: E402
from s2p_review.annotation_log import (  # noqa: E402
    AnnotationLogger,
    Tee,
    TrackColumns,
    app_blueprint,
    camera_of_view,
    log_scene,
    new_recording,
    send_timeline,
)

ARGS_ENV = "S2P_ANNOTATE_ARGS"   # JSON {"scene": ..., "run": ..., "cameras": [...], "native": bool}
VIEWER_HEIGHT = 400  # under the large camera picture: 3D world, the other cameras, the timeline
PENDING_SECONDS = 30.0  # how long the viewer may take to show a frame the page moved it to (a loaded machine lags 20 s)
THUMB_WIDTH = 320  # pixels: the other cameras' small pictures (while the viewer is off)
REPEAT_PX = 2.0  # page pixels: a click this close to the last one that selected is a repeat


def track_columns(project, tid: int) -> TrackColumns:
    """A track's poses as the logger's columns (empty when the track is gone)."""
    import numpy as np

    if tid not in project.tracks:
        z = np.zeros(0)
        return TrackColumns(tid, "", z.astype(np.int64), np.zeros((0, 3)), z, np.zeros((0, 3)),
                            z.astype(object))
    t = project.track_poses(tid)
    return TrackColumns(tid, project.track(tid).cls, t.frame, t.xyz, t.heading, t.size, t.source)


class Session:
    """Everything one page needs (see the module docstring)."""

    def __init__(self, scene, run=None, cameras=None, native: bool = False):
        from rerun.notebook import Viewer

        self.ctl = Controller.open(scene, run=run, cameras=cameras)
        self._runs = [Path(run)] if run is not None else []  # their trails' time range
        self.rec = new_recording()
        # hidden until the page says whether it renders in software (Controller.set_renderer)
        self.viewer = Viewer(width="auto", height=VIEWER_HEIGHT, recording=self.rec)
        target = self.rec
        if native:
            import rerun as rr

            other = rr.RecordingStream("s2p-annotate", recording_id=self.rec.get_recording_id())
            other.spawn()
            target = Tee(self.rec, other)
        self.target = target
        p = self.ctl.project
        self._run_dir, self._logged = run, False
        cams, first, last, video = page_frames(p.scene, run, self.ctl.cameras, self.ctl.frame_range)
        self.notes: list[str] = []
        self.ctl.video_frames = video
        self.pictures = FrameImages(p.scene, cams, first, last)
        self.frame_view = FrameView()
        self._shown: tuple | None = None
        self._cols_version = 0
        self._unsent: dict[int, Any] = {}
        self._unsent_timeline = False
        self._pending: tuple[int, float] | None = None  # a time-cursor move not sent yet
        self._player: Any = None                          # the playback thread
        self.cols = {tid: track_columns(p, tid) for tid in p.tracks}
        self._eye = L.default_eye(p.scene)
        self._send_layout(self.ctl.large_camera)
        self._timeline_span: tuple[int, int] | None = None
        self._ref: Any = None  # the reference PoseTable
        self.logger = AnnotationLogger(target, p.scene, cams)
        self.last_send_ms = 0.0
        self.timeline = "frame"
        self.panel = Panel(shortcuts=SHORTCUTS, hide_viewer=self.ctl.viewer_shown is not True)
        if self.notes:
            self.ctl.message = "; ".join(self.notes)
        self.ctl.on_tracks.append(self._resend)
        self.ctl.on_frame.append(self._move_cursor)
        self.ctl.on_layout.append(self._send_layout)
        self.ctl.on_viewer.append(self._show_viewer)
        self.ctl.on_run.append(self._show_run)
        if native:
            self._log_scene()
        self.viewer.on_event(self._on_viewer_event)
        self.panel.on_msg(self._on_panel_msg)
        self.frame_view.on_msg(self._on_frame_msg)
        self.viewer.set_time_ctrl(sequence=self.ctl.frame, timeline="frame")
        self.refresh_panel()

    def _log_scene(self) -> None:
        """The scene, the tracks and the timeline to the viewer, once, when it is first shown
        (a hidden viewer is sent nothing: the page's first steps are not held up by it)."""
        if self._logged:
            return
        self._logged = True
        p = self.ctl.project
        _, _, _, notes, _ = log_scene(self.target, p.scene, self._run_dir, self.ctl.cameras,
                                      frames=self.ctl.frame_range)
        if notes:
            self.ctl.message = "; ".join(notes)
        for tid, cols in sorted(self.cols.items()):
            self.logger.send_track(cols, selected=tid == self.ctl.selected)
        self._unsent = {}
        self._send_timeline()
        self._unsent_timeline = False
        self.target.flush()

    # --- controller -> viewer / panel ---------------------------------------------------------------
    def _resend(self, ids: set[int], selected: int | None) -> None:
        """Tracks changed: their columns now (the picture draws them); the viewer gets them
        after the picture (``_send_tracks``), so that the page shows the edit first."""
        for tid in sorted(ids):
            cols = track_columns(self.ctl.project, tid)
            if len(cols.frame):
                self.cols[tid] = cols
            else:
                self.cols.pop(tid, None)
            self._unsent[tid] = cols
        self._cols_version += 1
        self._unsent_timeline |= selected in ids or selected is None

    def _send_tracks(self) -> None:
        """Send the changed tracks (and the selected one's timeline) to the viewer."""
        if not self._unsent and not self._unsent_timeline:
            return
        if not self.ctl.viewer_visible or not self._logged:
            return  # kept until the viewer is shown: a hidden viewer costs the page nothing
        t0 = time.perf_counter()
        for tid, cols in sorted(self._unsent.items()):
            self.logger.send_track(cols, selected=tid == self.ctl.selected)
        if self._unsent_timeline:
            self._send_timeline()
        self._unsent, self._unsent_timeline = {}, False
        self.target.flush()
        self.last_send_ms = (time.perf_counter() - t0) * 1e3

    def _show_viewer(self, shown: bool) -> None:
        self.panel.hide_viewer = not shown  # the panel's script hides the viewer's element
        if shown:
            self._log_scene()
            self._send_tracks()
            self._move_cursor(self.ctl.frame)

    def _show_run(self, run: Path) -> None:
        """A new run loaded (train now's, annotate/app/fine_tune_job.py): the viewer logs the
        scene again with it (now when shown, else when it is first shown), its trails named."""
        self._run_dir, self._logged = run, False
        if Path(run) not in self._runs:
            self._runs.append(Path(run))
        self._send_layout(self.ctl.large_camera)
        if self.ctl.viewer_visible:
            self._log_scene()

    def _send_layout(self, large: str | None) -> None:
        bp = app_blueprint(self.ctl.cameras, large, eye=self._eye, fps=self.ctl.project.scene.fps,
                           large_in_page=True, runs=self._runs)
        for r in (self.target.recs if isinstance(self.target, Tee) else [self.rec]):
            r.send_blueprint(bp, make_active=True, make_default=True)

    def _send_timeline(self) -> None:
        """The selected track's keyframes and its distance to the run's estimates (or the
        masks' normal positions) per frame, in the timeline view under the large camera."""
        import numpy as np

        from annotate.review import distance_series, reference

        p, tid = self.ctl.project, self.ctl.selected
        frames = dist = kfs = np.zeros(0, np.int64)
        if tid is not None and tid in p.tracks:
            source = "estimate" if getattr(p, "_run", None) is not None else "normal"
            if self._ref is None:
                self._ref = reference(p, source)
            frames, dist = distance_series(p, tid, source, ref=self._ref)
            kfs = np.asarray(p.track(tid).frames, np.int64)
        self._timeline_span = send_timeline(self.target, p.scene, frames, np.asarray(dist, float),
                                            kfs, previous=self._timeline_span)

    def _move_cursor(self, frame: int) -> None:
        # until the viewer shows this frame, its reports of earlier cursor positions are stale
        self._pending = (int(frame), time.monotonic())
        if not self.ctl.viewer_visible and self.ctl.viewer_state == "ready":
            return  # a hidden viewer's cursor follows when it is shown (it would decode video)
        self.viewer.set_time_ctrl(sequence=int(frame), timeline="frame")

    def refresh_panel(self) -> None:
        """After anything the page did: the panel, the large camera's picture, then the
        viewer's data (in this order: the websocket delivers them in order, and the viewer's
        data keeps the browser busy for a while)."""
        self.panel.html = render(self.ctl.panel())
        self.show_frame()
        self._send_tracks()

    def show_frame(self) -> None:
        """Send the large camera's picture of the current frame, unless it is already shown."""
        cam = self.ctl.large_camera
        key = (cam, self.ctl.frame, self.ctl.selected, self._cols_version, self.ctl.viewer_visible,
               self.ctl.only_selected, self.ctl.play_to is None)
        if cam is None or key == self._shown:
            return
        tracks = [c for t, c in self.cols.items()
                  if not self.ctl.only_selected or t == self.ctl.selected]
        pic = self.pictures.render(cam, self.ctl.frame, tracks, self.ctl.selected)
        extra = ""
        info, tid = self.ctl.selected_info(), self.ctl.selected
        if info is not None and tid is not None:  # (no info without a selection)
            label = f"{self.ctl.project.track(tid).cls} {tid}"
            extra = (f"{label}: {info['distance']:.2f} m from the {info['reference']}"
                     if info["distance"] is not None else label)
        # the other cameras small, unless the viewer shows them (or a playback runs: the large
        # camera alone keeps the scene's frame rate; the small ones stay as they were)
        thumbs = None if self.ctl.play_to is not None else {} if self.ctl.viewer_visible else {
            c: self.pictures.render(c, self.ctl.frame, tracks, self.ctl.selected, width=THUMB_WIDTH).jpeg
            for c in self.ctl.cameras if c != cam}
        self.frame_view.show(cam, self.ctl.frame, pic.jpeg, pic.width, pic.height, pic.note, thumbs,
                             box=self.ctl.box_handles(cam), extra=extra)
        self._shown = key

    # --- events -----------------------------------------------------------------------------------
    def _on_panel_msg(self, _widget, content, _buffers) -> None:
        if not isinstance(content, dict):
            return
        if "action" in content:
            with self.ctl.lock:
                self.ctl.do(str(content["action"]))
                self.refresh_panel()
            if self.ctl.play_to is not None:
                self._start_playback()
        elif "canvas_click" in content:
            self._on_canvas_click(content["canvas_click"], content.get("frame"))
        elif "hello" in content:
            self.ctl.hello(str(content["hello"]))
            if "renderer" in content:
                self.ctl.set_renderer(str(content["renderer"]))
            self.refresh_panel()
        else:
            self.ctl.touch()

    def _on_frame_msg(self, _widget, content, _buffers) -> None:
        """A click on the large camera's picture: a keyframe at that pixel, if the picture
        clicked was of the current frame."""
        if isinstance(content, dict) and content.get("large") in self.ctl.cameras:
            self.ctl.show_large(str(content["large"]))  # a small picture clicked
            self.refresh_panel()
            return
        if not isinstance(content, dict) or not {"click", "drag", "rotate_to"} & set(content):
            return
        try:
            cam, frame = str(content["camera"]), int(content["frame"])
            if "click" in content:
                uv = [(float(content["click"][0]), float(content["click"][1]))]
            elif "drag" in content:
                uv = [(float(a), float(b)) for a, b in content["drag"][:2]]
            else:
                uv = [(float(content["rotate_to"][0]), float(content["rotate_to"][1]))]
        except (TypeError, ValueError, KeyError, IndexError):
            return
        if cam not in self.ctl.cameras:
            return
        with self.ctl.lock:
            self.ctl.play_to = None
            if frame != self.ctl.frame:
                what = "click" if "click" in content else "drag"
                self.ctl.message = (f"{what} ignored: it was made on the picture of frame {frame}, "
                                    f"the page is at frame {self.ctl.frame} now; {what} again")
            elif "click" in content:
                self.ctl.click(cam, uv[0])
            elif "drag" in content and len(uv) == 2:
                self.ctl.drag(cam, uv[0], uv[1])
            elif "rotate_to" in content:
                self.ctl.rotate_to(cam, uv[0])
            self.refresh_panel()

    def _start_playback(self) -> None:
        """Play the selected track at the scene's frame rate (review mode): a thread steps the
        controller one frame per 1/fps and redraws; it ends where ``play_to`` says, or when any
        action clears it. A step that took longer than a frame is not caught up on."""
        if getattr(self, "_player", None) is not None and self._player.is_alive():
            return
        try:
            import marimo as mo
            thread_cls = mo.Thread  # carries the page's context: its widgets can be updated
        except (ImportError, AttributeError):
            import threading
            thread_cls = threading.Thread
        self._player = thread_cls(target=self._play, daemon=True)
        self._player.start()

    def _play(self) -> None:
        dt = 1.0 / max(float(self.ctl.project.scene.fps), 1e-3)
        due = time.monotonic()
        while True:
            due += dt
            wait = due - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            else:
                due = time.monotonic()
            with self.ctl.lock:
                going = self.ctl.play_step()
                self.refresh_panel()
            if not going:
                return

    def _on_viewer_event(self, e) -> None:
        kind = getattr(e, "type", "")
        if os.environ.get("S2P_ANNOTATE_DEBUG"):
            print("viewer event:", e, flush=True)
        if kind == "recording_open" and self.ctl.viewer_state == "loading":
            self.ctl.viewer_state = "open"
            self.refresh_panel()
        if kind == "timeline_change":
            self.timeline = e.timeline
        if kind in ("time_update", "timeline_change") and self.timeline == "frame":
            if self.ctl.viewer_state != "ready":
                # while the scene streams in, the viewer's cursor follows the newest data: the
                # page's frame (restored from the last session) wins until the viewer shows it
                if int(round(e.time)) != self.ctl.frame:
                    self._move_cursor(self.ctl.frame)
                    return
                self.ctl.viewer_state = "ready"
                self._pending = None
                self.refresh_panel()
                return
            f = int(round(e.time))
            pending = getattr(self, "_pending", None)
            if pending is not None:
                if f == pending[0] or time.monotonic() - pending[1] > PENDING_SECONDS:
                    self._pending = None
                else:
                    return  # an echo of an earlier cursor position
            before = self.ctl.frame
            self.ctl.goto(f, from_viewer=True)
            if self.ctl.frame != before:
                self.refresh_panel()
        elif kind == "selection_change":
            items = [it for it in e.items if getattr(it, "type", "") == "entity"]
            if not items:
                return  # a click on empty space, or the selection cleared
            it = items[0]
            self._last_click = (it.view_name, it.entity_path, it.position)
            self._selected_since_click = True
            self._apply_click(*self._last_click)

    def _apply_click(self, view_name, entity_path, position) -> None:
        cam = camera_of_view(view_name, entity_path, self.ctl.cameras)
        if cam is not None:
            self.ctl.click(cam, position)
        elif view_name and (entity_path or "").strip("/").startswith("world"):
            self.ctl.click_world(position, entity_path)  # the 3D view
        else:
            self.ctl.click(None, None, "not in a view")
        self.refresh_panel()

    def _on_canvas_click(self, at, frame=None) -> None:
        """A click on the viewer's canvas at page point ``at`` (reported by the panel after the
        viewer had time to report a selection). Every click is an edit, repeated or not: the
        viewer reports a click only as a selection *change*, so a click that brought none, at
        the page point of the last click that did, is that click again (same camera, same
        pixel, at the frame it was made at). Clicks elsewhere without a selection (the time
        panel, empty space) do nothing; a repeat that arrives after the frame changed is not
        applied to the new frame."""
        try:
            x, y = float(at[0]), float(at[1])
        except (TypeError, ValueError, IndexError):
            return
        if getattr(self, "_selected_since_click", False):
            self._selected_since_click = False
            self._last_click_at = (x, y)
            return
        last = getattr(self, "_last_click_at", None)
        if last is not None and getattr(self, "_last_click", None) is not None and \
                abs(x - last[0]) <= REPEAT_PX and abs(y - last[1]) <= REPEAT_PX:
            if frame is not None and int(frame) != self.ctl.frame:
                self.ctl.message = (f"click ignored: it was made at frame {frame}, the page is at "
                                    f"frame {self.ctl.frame} now; click again")
                self.refresh_panel()
                return
            self._apply_click(*self._last_click)


def session_from_env() -> Session:
    """The Session that ``s2p annotate`` asked for (its arguments travel in S2P_ANNOTATE_ARGS)."""
    args = json.loads(os.environ.get(ARGS_ENV) or "{}")
    if "scene" not in args:
        raise SystemExit(f"{ARGS_ENV} is not set: start the app with `s2p annotate SCENE`")
    return Session(Path(args["scene"]), run=args.get("run"), cameras=args.get("cameras"),
                   native=bool(args.get("native")))
