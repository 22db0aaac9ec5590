"""The annotation app's controller: the current frame, the selected track, the click mode and
every action of the panel, on top of the engine (``annotate.Project``). No UI imports: the
marimo page (notebook.py) feeds it clicks, keys and time-cursor moves, and draws what
``panel()`` returns; tests drive it directly. Here: opening and holding the project, the saved
page state, the time cursor and the views; the actions are ``annotate.app.actions``', the
clicks ``annotate.app.clicks``', what the panel shows ``annotate.app.panel_data``'s (mixins).

Listeners: ``on_tracks(ids, selected)`` after anything that changes how tracks look (edits,
undo/redo, selection), ``on_frame(frame)`` when the controller moves the time cursor.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from annotate import LockedError, Project
from annotate.app.actions import CLICK_MODES, Actions
from annotate.app.clicks import Clicks
from annotate.app.panel_data import PanelData
from annotate.app.review_mode import ReviewActions
from seg2pose.core.errors import S2PError
from seg2pose.io.atomic import atomic_write_text

LOG = logging.getLogger("s2p.annotate")
STATE_FILE = "app_state.json"   # in SCENE/annotations/: selection, frame, modes of the last session
HOLD_SECONDS = 15.0             # a tab silent for this long no longer holds the project


@dataclass
class _Holder:
    controller: Controller
    since: str
    seen: float
    tab: str | None = None  # the browser tab's id (kept by the tab across reloads)


_HOLDERS: dict[str, _Holder] = {}
_HOLDERS_LOCK = threading.RLock()  # open() closes a silent holder while holding it


def _log_change(ch) -> None:
    """One line per edit, undo and redo in the server's log."""
    if ch.kind != "refresh":
        LOG.info("%s %s (record %d) tracks %s", ch.kind, ch.name, ch.seq, sorted(ch.tracks)[:10])


def close_all() -> None:
    """Close every project a page of this process holds (the server is stopping): their edit
    locks are released."""
    with _HOLDERS_LOCK:
        for h in list(_HOLDERS.values()):
            h.controller.close()


@dataclass
class Controller(Actions, ReviewActions, Clicks, PanelData):
    """The state of one page of the app (see the module docstring). Build with ``open``."""

    project: Project
    cameras: list[str]
    frame_range: tuple[int, int]
    read_only_reason: str | None = None
    frame: int = 0
    selected: int | None = None
    previous: int | None = None       # the track selected before (merge takes it)
    click_mode: str = "centre"
    new_class: str = ""
    every: int = 25
    message: str = ""
    last_click: dict | None = None
    clicks: int = 0
    video_frames: dict = field(default_factory=dict)  # camera -> frames with video (the viewer's)
    viewer_state: str = "loading"  # loading -> open (recording arrived) -> ready (time cursor seen)
    on_tracks: list[Callable[[set[int], int | None], None]] = field(default_factory=list)
    on_frame: list[Callable[[int], None]] = field(default_factory=list)
    on_layout: list[Callable[[str], None]] = field(default_factory=list)
    large_camera: str | None = None   # the camera shown large (remembered)
    viewer_shown: bool | None = None  # the Rerun viewer on/off as the annotator chose (remembered); None: automatic
    software_rendering: bool = False  # the browser renders WebGL in software (its hello says)
    renderer_known: bool = False      # the page has said how it renders (until then: no viewer)
    on_viewer: list[Callable[[bool], None]] = field(default_factory=list)
    on_run: list[Callable[[Path], None]] = field(default_factory=list)  # a new run loaded (train now)
    play_to: int | None = None        # playing the selected track up to this frame (review mode)
    play_reason: str = ""             # why the playback stops there
    review_from: int | None = None    # where the review of the selected track started
    only_selected: bool = False       # the picture draws the selected track only
    # more lists for the panel: title -> function giving rows {"track", "frame", "text"} (e.g.
    # what to annotate next); each row is a link to its frame
    panel_lists: dict = field(default_factory=dict)
    lock: threading.RLock = field(default_factory=threading.RLock)

    # --- opening, closing, holding -------------------------------------------------------------
    @classmethod
    def open(cls, scene, run=None, cameras: list[str] | None = None) -> Controller:
        """Open the project of ``scene`` for this page. A project that another page of this
        server holds (it was heard from in the last HOLD_SECONDS), or another process writes,
        opens read-only with the reason in ``read_only_reason``."""
        from seg2pose.io.scene import load_scene

        scene = load_scene(scene) if not hasattr(scene, "cameras") else scene
        key = str(Path(scene.root).resolve())
        reason = None
        with _HOLDERS_LOCK:
            h = _HOLDERS.get(key)
            if h is not None and time.monotonic() - h.seen < HOLD_SECONDS:
                reason = (f"read-only: this project is open for editing in another tab (since "
                          f"{h.since}); close that tab, wait {HOLD_SECONDS:.0f} s and reload")
            elif h is not None:  # a tab gone silent: its project is released
                h.controller.close()
            try:
                project = Project.open(scene, run=run, read_only=reason is not None)
            except LockedError as e:
                reason = f"read-only: {e}"
                project = Project.open(scene, run=run, read_only=True)
            cams = list(cameras) if cameras else list(scene.cameras)
            unknown = [c for c in cams if c not in scene.cameras]
            if unknown:
                project.close()
                raise S2PError(f"unknown cameras {unknown}; the scene has {sorted(scene.cameras)}")
            fr = project.frame_range or (0, 0)
            c = cls(project, cams, (int(fr[0]), int(fr[1])), read_only_reason=reason)
            project.subscribe(_log_change)
            LOG.info("page opened %s (%s)", scene.root, reason or "editing")
            c.new_class = scene.classes[0].name if scene.classes else ""
            c.frame = c.frame_range[0]
            c.large_camera = cams[0] if cams else None
            c._restore()
            if reason is None:
                _HOLDERS[key] = _Holder(c, time.strftime("%H:%M:%S"), time.monotonic())
            c._key = key
            c._run = run
            c.message = reason or "ready"
        return c

    def hello(self, tab: str) -> None:
        """The page names its browser tab (an id the tab keeps across reloads). The tab that
        held the project for editing and was reloaded gets it back at once; any other tab
        stays read-only."""
        with _HOLDERS_LOCK:
            h = _HOLDERS.get(getattr(self, "_key", ""))
            if h is not None and h.controller is self:
                h.tab = h.tab or str(tab)
                return
            if not self.read_only or h is None or h.tab != str(tab):
                return
            h.controller.close()  # this tab's page before the reload
            try:
                project = Project.open(self.project.scene, run=self._run)
            except LockedError as e:
                self.read_only_reason = f"read-only: {e}"
                return
            self.project.close()
            self.project = project
            project.subscribe(_log_change)
            self.read_only_reason = None
            _HOLDERS[self._key] = _Holder(self, time.strftime("%H:%M:%S"), time.monotonic(),
                                          str(tab))
            self.message = "ready (this tab edits again after the reload)"

    def touch(self) -> None:
        """The page is alive (any message from it, or its heartbeat)."""
        with _HOLDERS_LOCK:
            h = _HOLDERS.get(getattr(self, "_key", ""))
            if h is not None and h.controller is self:
                h.seen = time.monotonic()

    def close(self) -> None:
        with _HOLDERS_LOCK:
            h = _HOLDERS.get(getattr(self, "_key", ""))
            if h is not None and h.controller is self:
                del _HOLDERS[self._key]
        self.project.close()

    @property
    def read_only(self) -> bool:
        return self.project.read_only

    # --- saved page state -------------------------------------------------------------------------
    @property
    def state_path(self) -> Path:
        return self.project.folder / STATE_FILE

    def _restore(self) -> None:
        try:
            d = json.loads(self.state_path.read_text())
        except (OSError, ValueError):
            return
        if not isinstance(d, dict):
            return
        f = d.get("frame")
        if isinstance(f, int):
            self.frame = min(max(f, self.frame_range[0]), self.frame_range[1])
        if d.get("selected") in self.project.tracks:
            self.selected = int(d["selected"])
        if d.get("click_mode") in CLICK_MODES:
            self.click_mode = d["click_mode"]
        if isinstance(d.get("every"), int) and d["every"] >= 1:
            self.every = d["every"]
        if d.get("new_class") in [c.name for c in self.project.scene.classes]:
            self.new_class = d["new_class"]
        if d.get("large_camera") in self.cameras:
            self.large_camera = d["large_camera"]
        if isinstance(d.get("viewer_shown"), bool):
            self.viewer_shown = d["viewer_shown"]

    def _save(self) -> None:
        if self.read_only:
            return
        d = {"frame": self.frame, "selected": self.selected, "click_mode": self.click_mode,
             "every": self.every, "new_class": self.new_class, "large_camera": self.large_camera,
             "viewer_shown": self.viewer_shown}
        try:
            atomic_write_text(self.state_path, json.dumps(d))
        except OSError:
            pass  # the page state is a convenience; edits are in the journal

    # --- notifications ----------------------------------------------------------------------------
    def _tracks_changed(self, ids) -> None:
        for cb in list(self.on_tracks):
            cb(set(ids), self.selected)

    def _select(self, tid: int | None) -> None:
        if tid == self.selected:
            return
        old, self.selected = self.selected, tid
        if old is not None:
            self.previous = old
        self._save()
        self._tracks_changed({t for t in (old, tid) if t is not None})

    @property
    def viewer_visible(self) -> bool:
        """Whether the page shows the Rerun viewer: the annotator's choice, else on unless the
        browser renders in software (there one repaint of the viewer takes seconds and holds
        up the page: docs/BENCHMARKS.md, "Annotation app"); off until the page has said how it
        renders (the scene is sent to the viewer only once it is shown)."""
        if self.viewer_shown is not None:
            return self.viewer_shown
        return self.renderer_known and not self.software_rendering

    def _set_viewer(self, shown: bool) -> None:
        self.viewer_shown = bool(shown)
        self._save()
        for cb in list(self.on_viewer):
            cb(self.viewer_visible)

    def set_renderer(self, renderer: str) -> None:
        """The browser's WebGL renderer (from the page): software rendering hides the viewer
        unless the annotator chose otherwise."""
        r = str(renderer).lower()
        self.renderer_known = True
        self.software_rendering = any(k in r for k in ("swiftshader", "llvmpipe", "software", "lavapipe"))
        if self.software_rendering and self.viewer_shown is None:
            self.message = ("software rendering in this browser: the 3D viewer is off so that "
                            "every step shows at once (Shift+V shows it)")
        for cb in list(self.on_viewer):
            cb(self.viewer_visible)

    def show_large(self, cam: str) -> None:
        """Show camera ``cam`` large (a click on its small picture)."""
        with self.lock:
            self.touch()
            self._show_large(cam)
            self.message = f"camera {cam} large (k: the next one)"

    def _show_large(self, cam: str) -> None:
        self.large_camera = cam
        self._save()
        for cb in list(self.on_layout):
            cb(cam)

    def best_camera(self, tid: int) -> str | None:
        """The camera that sees track ``tid`` best at the current frame: its box projected
        largest, wholly in front of the camera; None when none sees it."""
        now = self.footprint_now(tid)
        if now is None:
            return None
        _, _, _, z, foot = now
        t = self.project.track(tid)
        corners = np.vstack([np.c_[foot, np.full(4, z)], np.c_[foot, np.full(4, z + t.size[2])]])
        best, area = None, 0.0
        for cam in self.cameras:
            c = self.project.scene.cameras[cam]
            uv, _, front = c.project_points(corners)
            if not front.all():
                continue
            lo = np.clip(uv.min(axis=0), 0, [c.width, c.height])
            hi = np.clip(uv.max(axis=0), 0, [c.width, c.height])
            a = float(np.prod(np.maximum(hi - lo, 0)))
            if a > area:
                best, area = cam, a
        return best

    def goto(self, frame: int, from_viewer: bool = False) -> None:
        """Move to ``frame`` (clamped to the scene); unless the viewer told us, move its cursor."""
        f = int(min(max(int(frame), self.frame_range[0]), self.frame_range[1]))
        changed = f != self.frame
        self.frame = f
        if changed:
            self._save()
        if not from_viewer:
            for cb in list(self.on_frame):
                cb(f)

    # --- the actions ------------------------------------------------------------------------------
    def do(self, name: str) -> str:
        """Run one action (a name from ACTIONS); returns the message shown in the panel. Bad
        requests (no track selected, read-only, an edit the engine refuses) become messages."""
        with self.lock:
            self.touch()
            if name != "play":
                self.play_to = None  # any other action stops a playback
            try:
                self.message = self._do(name) or ""
            except S2PError as e:
                self.message = str(e)
            return self.message
