"""The annotation app's actions: the panel's buttons with their keyboard shortcuts (``ACTIONS``)
and what each does to the controller's state (``Actions``, a mixin of ``Controller``: it moves the
time cursor, selects tracks and edits the project through ``Controller._edit``, so read-only
projects and undo work the same for every action)."""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from annotate import EditError
from annotate.edits import NUDGE_STEPS, ROTATE_STEPS

if TYPE_CHECKING:
    from annotate.project import Project

CLICK_MODES = ("centre", "ground", "mask")
CLICK_MODE_HELP = {
    "centre": "click the middle of the road user (the ray meets the world at half its box's height)",
    "ground": "click where the road user touches the ground",
    "mask": "click a mask: its Seg2Pose estimate (with --run) or its normal position",
}


@dataclass(frozen=True)
class Action:
    """A panel button: ``name`` (the controller method's argument), its label, its keyboard
    shortcut (as the page's key handler spells it: modifiers ``Ctrl+``/``Alt+``/``Shift+``
    then the key) and the group it is shown in."""

    name: str
    label: str
    key: str
    group: str


def _nudges() -> list[Action]:
    out = []
    for step, mod in zip(NUDGE_STEPS, ("Alt+", "", "Shift+")):
        cm = round(step * 100)
        for key, (dx, dy), word in (("w", (0, 1), "+y"), ("s", (0, -1), "-y"),
                                    ("d", (1, 0), "+x"), ("a", (-1, 0), "-x")):
            out.append(Action(f"nudge:{dx * step:g}:{dy * step:g}", f"{word} {cm} cm",
                              f"{mod}{key}", "nudge"))
    return out


def _rotations() -> list[Action]:
    out = []
    for deg, mod in zip(ROTATE_STEPS, ("Alt+", "", "Shift+")):
        out.append(Action(f"rotate:{deg:g}", f"⟲ {deg:g}°", f"{mod}q", "rotate"))
        out.append(Action(f"rotate:{-deg:g}", f"⟳ {deg:g}°", f"{mod}e", "rotate"))
    return out


# review mode and box size (annotate/app/review_mode.py does them)
SIZE_STEP = 0.10    # metres per key press (Shift: the other way)
REVIEW_ACTIONS: list[Action] = [
    Action("play", "▶ play to where to look", "p", "review"),
    Action("mark_reviewed", "reviewed up to here", "r", "review"),
    Action("mark_reviewed_all", "whole track reviewed", "Shift+r", "review"),
    Action("next_look", "next frame to look at (all tracks)", "g", "review"),
    Action("only_selected", "hide / show the other tracks", "b", "view"),
    *[Action(f"size:{d}:{s * SIZE_STEP:g}", f"{d} {'+' if s > 0 else '−'}{SIZE_STEP * 100:.0f} cm",
             f"{'' if s > 0 else 'Shift+'}{key}", "size")
      for d, key in (("l", "l"), ("w", "j"), ("h", "h")) for s in (1, -1)],
]

ACTIONS: list[Action] = [
    Action("prev_frame", "◀ frame", "ArrowLeft", "time"),
    Action("next_frame", "frame ▶", "ArrowRight", "time"),
    Action("back10", "◀◀ 10", "Shift+ArrowLeft", "time"),
    Action("fwd10", "10 ▶▶", "Shift+ArrowRight", "time"),
    Action("prev_keyframe", "◀ keyframe", "[", "time"),
    Action("next_keyframe", "keyframe ▶", "]", "time"),
    Action("next_suggestion", "next suggested keyframe", "Shift+g", "time"),
    Action("prev_track", "◀ track", "Shift+t", "track"),
    Action("next_track", "track ▶", "t", "track"),
    Action("new_track", "new track", "n", "track"),
    Action("deselect", "no track (then a mask click makes one)", "Escape", "track"),
    Action("delete_keyframe", "delete keyframe", "Delete", "track"),
    Action("delete_track", "delete track (press twice)", "Shift+Delete", "track"),
    Action("goto_frame", "go to frame…", "f", "time"),
    Action("click_mode", "click mode", "c", "track"),
    Action("large_camera", "next camera large", "k", "view"),
    Action("best_camera", "the selected track's best camera large", "Shift+k", "view"),
    Action("toggle_viewer", "3D viewer and the other cameras on/off", "Shift+v", "view"),
    Action("accept_estimate", "accept estimate", "y", "track"),
    Action("accept_every", "accept estimates every N", "Shift+y", "track"),
    Action("preannotate", "pre-annotate every road user of the run", "Shift+p", "track"),
    Action("occluded", "occluded from here", "o", "span"),
    Action("outside", "outside from here", "x", "span"),
    Action("visible", "visible here", "v", "span"),
    Action("split", "split here", "Shift+x", "span"),
    Action("merge", "merge previous track into this", "m", "span"),
    Action("interpolation", "cycle interpolation", "i", "span"),
    Action("next_queued", "next road user to annotate (scene-wide queue)", "u", "time"),
    Action("train_now", "train now: fine-tune on the annotations (background)", "Shift+u", "track"),
    Action("undo", "undo", "Ctrl+z", "history"),
    Action("redo", "redo", "Ctrl+y", "history"),
    *REVIEW_ACTIONS, *_nudges(), *_rotations(),
    *[Action(f"class_key:{i}", f"class {i}", str(i), "class") for i in range(1, 10)],
]
ACTION_BY_NAME = {a.name: a for a in ACTIONS}
SHORTCUTS = {a.key: a.name for a in ACTIONS}
SHORTCUTS["Ctrl+Shift+z"] = "redo"
PAGE_ACTIONS = {"goto_frame"}  # done by the page itself (focus the frame field), not the server
CONFIRM_SECONDS = 5.0          # a second Shift+Delete within this long deletes the track


class ControllerState:
    """What the mixins of ``Controller`` (``Actions``, ``Clicks``, ``PanelData``) use of it,
    declared for the type checker only; ``annotate.app.controller.Controller`` defines them."""

    if TYPE_CHECKING:
        project: Project
        cameras: list[str]
        frame_range: tuple[int, int]
        read_only_reason: str | None
        frame: int
        selected: int | None
        previous: int | None
        click_mode: str
        new_class: str
        every: int
        message: str
        last_click: dict | None
        clicks: int
        video_frames: dict
        viewer_state: str
        play_to: int | None
        play_reason: str
        review_from: int | None
        only_selected: bool
        panel_lists: dict
        large_camera: str | None
        lock: threading.RLock
        _key: str
        _run: Any
        _confirm: tuple[int, float] | None  # a first Shift+Delete: (track, when)

        @property
        def read_only(self) -> bool: ...
        @property
        def viewer_visible(self) -> bool: ...
        def touch(self) -> None: ...
        def goto(self, frame: int, from_viewer: bool = False) -> None: ...
        def best_camera(self, tid: int) -> str | None: ...
        def suggestions(self, threshold: float = 0.5) -> list[tuple[int, int, float]]: ...
        def _save(self) -> None: ...
        def _select(self, tid: int | None) -> None: ...
        def _set_viewer(self, shown: bool) -> None: ...
        def _show_large(self, cam: str) -> None: ...
        def _tracks_changed(self, ids) -> None: ...
        def _need_track(self) -> int: ...
        def _edit(self, fn, *args, **kw): ...
        def _size_step(self, dim: str, step: float) -> str: ...
        def _reference(self) -> Any: ...
        def looks(self, top: int = 50) -> list[dict]: ...
        def _set_size(self, text: str) -> str: ...


class Actions(ControllerState):
    """The actions of ``ACTIONS`` as methods ``_a_<name>``; ``_do`` dispatches a name (with the
    parametrised ones: ``goto:F``, ``select:T``, ``class:C``, ``every:N``, ``nudge:DX:DY``,
    ``rotate:DEG``). Needs the controller's ``project``, ``frame``, ``selected``, ``goto``,
    ``_select``, ``_edit`` and ``_save``."""

    def _need_track(self) -> int:
        if self.selected is None:
            raise EditError("no track selected: pick one in the list (t / Shift+t) or make one (n)")
        return self.selected

    def _edit(self, fn, *args, **kw):
        if self.read_only:
            raise EditError(self.read_only_reason or "this project is open read-only")
        ch = fn(*args, **kw)
        if ch is not None:
            self._tracks_changed(ch.tracks)
        return ch

    def _do(self, name: str) -> str | None:
        p = self.project
        if name.startswith("goto:"):
            try:
                self.goto(int(name.split(":")[1]))
            except ValueError:
                raise EditError(f"go to frame: {name.split(':')[1]!r} is not a frame number") from None
            return None
        if name.startswith("look:"):  # a row of a list in the panel: that track at that frame
            _, tid, frame = name.split(":")
            if int(tid) in p.tracks:
                self._select(int(tid))
            self.goto(int(frame))
            return None
        if name.startswith("select:"):
            tid = int(name.split(":")[1])
            self._select(tid if tid in p.tracks else None)
            return None
        if name.startswith("class_key:"):
            return self._class_key(int(name.split(":")[1]))
        if name.startswith("class:"):
            cls = name.split(":", 1)[1]
            if cls not in [c.name for c in p.scene.classes]:
                raise EditError(f"unknown class {cls!r}")
            self.new_class = cls
            self._save()
            return f"new tracks are {cls}"
        if name.startswith("every:"):
            self.every = max(1, int(name.split(":")[1]))
            self._save()
            return f"accept estimates every {self.every} frames"
        if name.startswith("nudge:"):
            _, dx, dy = name.split(":")
            self._edit(p.nudge, self._need_track(), self.frame, float(dx), float(dy))
            return f"moved by ({float(dx) * 100:+.0f}, {float(dy) * 100:+.0f}) cm"
        if name.startswith("size:"):
            _, dim, step = name.split(":")
            return self._size_step(dim, float(step))
        if name.startswith("set_size:"):
            return self._set_size(name.split(":", 1)[1])
        if name.startswith("rotate:"):
            deg = float(name.split(":")[1])
            self._edit(p.rotate, self._need_track(), self.frame, deg)
            return f"turned {deg:+g}°"
        if name not in ACTION_BY_NAME:
            raise EditError(f"unknown action {name!r}")
        return getattr(self, "_a_" + name)()

    # time
    def _a_prev_frame(self):
        self.goto(self.frame - 1)

    def _a_next_frame(self):
        self.goto(self.frame + 1)

    def _a_back10(self):
        self.goto(self.frame - 10)

    def _a_fwd10(self):
        self.goto(self.frame + 10)

    def _keyframes(self) -> list[int]:
        return self.project.track(self._need_track()).frames

    def _a_next_keyframe(self):
        later = [f for f in self._keyframes() if f > self.frame]
        if not later:
            return "no keyframe after this frame"
        self.goto(later[0])

    def _a_prev_keyframe(self):
        earlier = [f for f in self._keyframes() if f < self.frame]
        if not earlier:
            return "no keyframe before this frame"
        self.goto(earlier[-1])

    def _a_next_queued(self):  # annotate/app/fine_tune_job.py
        from annotate.app.fine_tune_job import next_queued

        return next_queued(self)

    def _a_train_now(self):
        from annotate.app.fine_tune_job import train_now

        return train_now(self)

    def _a_next_suggestion(self):
        s = self.suggestions()
        if not s:
            return "no suggestions: the annotation agrees with the estimates / masks"
        later = [x for x in s if x[1] > self.frame] or s
        tid, f, d = later[0]
        self._select(tid)
        self.goto(f)
        return f"track {tid}, frame {f}: {d:.2f} m from the estimate"

    # tracks
    def _a_next_track(self, step: int = 1):
        ids = sorted(self.project.tracks)
        if not ids:
            return "no tracks yet: make one with n"
        i = ids.index(self.selected) + step if self.selected in ids else (0 if step > 0 else -1)
        self._select(ids[i % len(ids)])

    def _a_prev_track(self):
        return self._a_next_track(-1)

    def _a_new_track(self):
        ch = self._edit(self.project.create_track, self.new_class)
        self._select(ch.track)
        return f"track {ch.track} ({self.new_class}): click it in a camera view"

    def _a_deselect(self):
        if self.selected is None:
            return "no track selected"
        self._select(None)
        return ("no track selected: n makes one; in mask mode a click on a mask makes the track "
                "of that road user")

    def _a_delete_track(self):
        import time

        tid = self._need_track()
        pending = getattr(self, "_confirm", None)
        if pending is None or pending[0] != tid or time.monotonic() - pending[1] > CONFIRM_SECONDS:
            self._confirm = (tid, time.monotonic())
            n = len(self.project.track(tid).keyframes)
            return (f"delete track {tid} ({self.project.track(tid).cls}, {n} keyframes)? press "
                    f"Shift+Delete again within {CONFIRM_SECONDS:.0f} s (undo brings it back)")
        self._confirm = None
        self._select(None)
        self._edit(self.project.delete_track, tid)
        return f"track {tid} deleted (Ctrl+z brings it back)"

    def _a_goto_frame(self):
        return "type a frame number in the frame field and press Enter"

    def _class_key(self, i: int) -> str:
        classes = [c.name for c in self.project.scene.classes]
        if not 1 <= i <= len(classes):
            raise EditError(f"class key {i}: the scene has {len(classes)} classes "
                            f"({', '.join(classes)})")
        cls = classes[i - 1]
        self.new_class = cls
        self._save()
        if self.selected is None:
            return f"new tracks are {cls}"
        self._edit(self.project.set_class, self.selected, cls, resize=True)
        return f"track {self.selected} is a {cls} (typical size); new tracks are {cls}"

    def _a_preannotate(self):
        ch = self._edit(self.project.preannotate, every=self.every, frames=self.frame_range,
                        skip_annotated=True)
        return (f"pre-annotated {len(ch.created)} road users of the run (keyframes every "
                f"{self.every} frames, flagged estimate); road users already annotated skipped")

    def _a_delete_keyframe(self):
        self._edit(self.project.delete_keyframe, self._need_track(), self.frame)
        return f"keyframe {self.frame} deleted"

    def _a_toggle_viewer(self):
        self._set_viewer(not self.viewer_visible)
        return ("3D viewer on (Shift+V hides it)" if self.viewer_visible else
                "3D viewer off: the large camera and the panel only (Shift+V shows it)")

    def _a_large_camera(self):
        cams = self.cameras
        i = cams.index(self.large_camera) + 1 if self.large_camera in cams else 0
        self._show_large(cams[i % len(cams)])
        return f"camera {self.large_camera} large (k: the next one)"

    def _a_best_camera(self):
        cam = self.best_camera(self._need_track())
        if cam is None:
            return f"track {self.selected} is in no camera's view at frame {self.frame}"
        self._show_large(cam)
        return f"camera {cam} large: it sees track {self.selected} best here"

    def _a_click_mode(self):
        self.click_mode = CLICK_MODES[(CLICK_MODES.index(self.click_mode) + 1) % len(CLICK_MODES)]
        self._save()
        return f"click mode {self.click_mode}: {CLICK_MODE_HELP[self.click_mode]}"

    def _a_accept_estimate(self):
        self._edit(self.project.accept_estimate, self._need_track(), self.frame)
        return f"estimate taken at frame {self.frame}"

    def _a_accept_every(self):
        t = self.project.track(self._need_track())
        self._edit(self.project.accept_estimate, t.id, every=self.every, frames=self.frame_range)
        return f"estimates taken every {self.every} frames"

    # spans
    def _span_end(self) -> int:
        t = self.project.track(self._need_track())
        later = [f for f in t.frames if f > self.frame]
        return later[0] - 1 if later else max(self.frame, t.last if t.last is not None else self.frame)

    def _a_occluded(self):
        a, b = self.frame, self._span_end()
        self._edit(self.project.mark, self.selected, a, b, "occluded")
        return f"frames {a}..{b} occluded"

    def _a_outside(self):
        a, b = self.frame, self._span_end()
        self._edit(self.project.mark, self.selected, a, b, "outside")
        return f"frames {a}..{b} outside the view"

    def _a_visible(self):
        t = self.project.track(self._need_track())
        span = [(a, b) for a, b, _ in t.spans if a <= self.frame <= b]
        if not span:
            return "this frame is not in an occluded or outside span"
        self._edit(self.project.mark, t.id, span[0][0], span[0][1], "visible")
        return f"frames {span[0][0]}..{span[0][1]} visible again"

    def _a_split(self):
        ch = self._edit(self.project.split_track, self._need_track(), self.frame)
        new = max(ch.created) if ch.created else None
        self._select(new)
        return f"split at frame {self.frame}: the rest is track {new}"

    def _a_merge(self):
        keep = self._need_track()
        if self.previous is None or self.previous not in self.project.tracks:
            return "select the track to merge first, then this one, then merge"
        other = self.previous
        self._edit(self.project.merge_tracks, keep, other)
        self.previous = None
        return f"track {other} merged into {keep}"

    def _a_interpolation(self):
        from annotate import METHODS

        tid = self._need_track()
        cur = self.project.interpolation(tid)
        nxt = METHODS[(list(METHODS).index(cur) + 1) % len(METHODS)]
        self._edit(self.project.set_interpolation, tid, nxt)
        return f"track {tid} interpolates {nxt}"

    def _a_undo(self):
        ch = self._edit(self.project.undo)
        return f"undid {ch.name}" if ch else "nothing to undo"

    def _a_redo(self):
        ch = self._edit(self.project.redo)
        return f"redid {ch.name}" if ch else "nothing to redo"
