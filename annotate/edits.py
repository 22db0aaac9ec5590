"""The edits of ``Project`` (a mixin): each checks its input, builds primitive operations
(model.py) and commits them as one undoable, journalled step, returning a ``Change``.

Positions are metres in the scene's world frame (the ground contact point, z from the ground
surface), headings radians counter-clockwise from +x, frames ints.

Keyframes off the ground surface's support: more than ``SUPPORT_RADIUS`` from every ground
point, eq. (1) only extrapolates the nearest points' heights, so such keyframes are *kept with
a warning*: flagged ``off_support`` and noted in ``project.notes``. Beyond ``REFUSE_RADIUS``
(far past any camera's useful range: a click at the horizon) they are refused.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.spatial import cKDTree

from annotate.headings import AUTO
from annotate.model import EditError, Keyframe, Track, check_flags, keyframe, keyframe_row, mark_reviewed, mark_spans

SUPPORT_RADIUS = 10.0    # metres from the nearest ground point: beyond, keyframes are flagged
REFUSE_RADIUS = 200.0    # metres: beyond, keyframes are refused
NUDGE_STEPS = (0.02, 0.10, 0.50)   # metres, the app's small / medium / large nudge
ROTATE_STEPS = (1.0, 5.0, 15.0)    # degrees
MAX_SIZE = 30.0          # metres: no road user is longer, wider or taller
CHECKED = {"estimate", "accepted", "normal"}  # flags a correction removes (the pose is now checked)


if TYPE_CHECKING:
    from seg2pose.io.poses import PoseTable
    from seg2pose.io.scene import Scene


class ProjectState:
    """What the mixins of ``Project`` (``EditsMixin``, ``annotate.place.PlacementMixin``) use of
    it and of each other, declared for the type checker only; ``annotate.project.Project`` and
    the mixins define them. (``Change`` is Any here: naming it would be an import cycle.)"""

    if TYPE_CHECKING:
        scene: Scene
        read_only: bool
        notes: list[str]
        frame_range: tuple[int, int] | None
        _run: Any
        _ids_match: bool | None

        @property
        def tracks(self) -> Mapping[int, Track]: ...
        @property
        def run(self) -> Any: ...
        def track(self, track_id: int) -> Track: ...
        def track_poses(self, track_id: int) -> PoseTable: ...
        def poses(self, tracks=None, frames: tuple[int, int] | None = None) -> PoseTable: ...
        def check_methods(self, method: str | None) -> None: ...
        def _commit(self, name: str, ops: list[dict]) -> Any: ...
        def _frame(self, frame) -> int: ...
        def _class(self, cls: str) -> str: ...
        def _size(self, size, cls: str) -> tuple[float, float, float]: ...
        def _kf(self, track: int, frame: int, x, y, heading, flags=()) -> Keyframe: ...
        def _free(self, t: Track, frame: int) -> None: ...
        def _heading(self, track_id: int, frame: int, x: float, y: float, heading, flags
                     ) -> tuple[float, tuple[str, ...]]: ...


class EditsMixin(ProjectState):
    """Edit methods of ``Project``; every one returns a ``Change``."""

    # --- validation ------------------------------------------------------------------------------
    def _frame(self, frame) -> int:
        try:
            f = int(frame)
        except (TypeError, ValueError):
            raise EditError(f"frame must be an integer, got {frame!r}") from None
        if f != frame or f < 0:
            raise EditError(f"frame must be an integer >= 0, got {frame!r}")
        r = self.frame_range
        if r is not None and not (r[0] <= f <= r[1]):
            raise EditError(f"frame {f} is outside the scene's frames {r[0]}..{r[1]}")
        return f

    def _class(self, cls: str) -> str:
        known = [c.name for c in self.scene.classes]
        if cls not in known:
            raise EditError(f"unknown class {cls!r}; the scene knows {', '.join(known)}")
        return cls

    def _size(self, size, cls: str) -> tuple[float, float, float]:
        if size is None:
            size = self.scene.class_sizes().get(cls)
            if size is None:
                raise EditError(f"class {cls!r} has no typical size: give size=(l, w, h)")
        try:
            s = tuple(float(v) for v in size)
        except (TypeError, ValueError):
            raise EditError(f"size must be three numbers l, w, h (metres), got {size!r}") from None
        if len(s) != 3 or not all(math.isfinite(v) and 0 < v <= MAX_SIZE for v in s):
            raise EditError(f"size must be three numbers in (0, {MAX_SIZE}] metres, got {size!r}")
        return s

    def _support(self, x: float, y: float, track: int, frame: int) -> tuple[str, ...]:
        """Flags for a position: () on the ground's support, ("off_support",) off it; refused
        beyond REFUSE_RADIUS."""
        if not hasattr(self, "_kdtree"):
            self._kdtree = cKDTree(self.scene.ground_points[:, :2])
        d = float(self._kdtree.query([x, y])[0])
        if d <= SUPPORT_RADIUS:
            return ()
        where = f"track {track} frame {frame} at ({x:.2f}, {y:.2f})"
        if d > REFUSE_RADIUS:
            raise EditError(f"{where} is {d:.0f} m from the nearest ground point (more than "
                            f"{REFUSE_RADIUS:.0f} m): refused, the ground is unknown there")
        self.notes.append(f"{where} is {d:.1f} m from the nearest ground point: z there is "
                          "extrapolated (keyframe flagged off_support)")
        return ("off_support",)

    def _kf(self, track: int, frame: int, x, y, heading, flags=()) -> Keyframe:
        k = keyframe(x, y, heading, flags)
        extra = self._support(k.x, k.y, track, frame)
        flags = tuple(f for f in k.flags if f != "off_support") + extra
        return Keyframe(k.x, k.y, k.heading, check_flags(flags))

    def _free(self, t: Track, frame: int) -> None:
        if t.span_at(frame) == "outside":
            raise EditError(f"track {t.id}: frame {frame} lies in an outside span; mark it "
                            "visible first")

    def default_heading(self, track_id: int, frame: int, x: float, y: float) -> float:
        """The heading a new keyframe gets when none is given: the interpolated heading inside
        the track, else the direction of motion from the nearest keyframe (if more than 0.3 m
        away), else the nearest keyframe's heading, else 0."""
        t = self.track(track_id)
        if not t.keyframes:
            return 0.0
        tab = self.track_poses(track_id)
        hit = np.flatnonzero(tab.frame == frame)
        if len(hit):
            return float(tab.heading[hit[0]])
        near = min(t.keyframes, key=lambda f: abs(f - frame))
        k = t.keyframes[near]
        d = np.array([x - k.x, y - k.y]) * (1 if frame > near else -1)
        if np.hypot(*d) > 0.3:
            return float(np.arctan2(d[1], d[0]))
        return k.heading

    def _heading(self, track_id: int, frame: int, x: float, y: float, heading, flags
                 ) -> tuple[float, tuple[str, ...]]:
        """(heading, flags) of a keyframe about to be placed: a given heading is set by the
        annotator; None follows the motion (flag AUTO; the project fills it in after the edit)."""
        flags = tuple(fl for fl in flags if fl != AUTO)
        if heading is not None:
            return heading, flags
        old = self.track(track_id).keyframes.get(frame)
        if old is not None and AUTO not in old.flags:  # re-placed: a heading set stays set
            return old.heading, flags
        return self.default_heading(track_id, frame, x, y), flags + (AUTO,)

    def pose_at(self, track_id: int, frame: int) -> tuple[float, float, float]:
        """(x, y, heading) of a track at a frame: the keyframe, or the interpolation."""
        t = self.track(track_id)
        if frame in t.keyframes:
            k = t.keyframes[frame]
            return k.x, k.y, k.heading
        tab = self.track_poses(track_id)
        hit = np.flatnonzero(tab.frame == frame)
        if not len(hit):
            raise EditError(f"track {track_id} has no pose at frame {frame} (keyframes "
                            f"{t.first}..{t.last})")
        i = hit[0]
        return float(tab.xyz[i, 0]), float(tab.xyz[i, 1]), float(tab.heading[i])

    # --- tracks ----------------------------------------------------------------------------------
    def create_track(self, cls: str, size=None, interp: str | None = None, *,
                     track_id: int | None = None, meta: dict | None = None):
        """A new track of class ``cls`` (box size: ``size`` (l, w, h) metres or the class's
        typical size). ``change.track`` is its id."""
        cls = self._class(cls)
        self.check_methods(interp)
        tid = max(self.tracks, default=0) + 1 if track_id is None else int(track_id)
        if tid < 1 or tid in self.tracks:
            raise EditError(f"track id {tid} is taken or not >= 1")
        t = Track(tid, cls, self._size(size, cls), interp, meta=dict(meta or {}))
        return self._commit("create_track", [{"op": "put_track", "id": tid, "track": t.to_dict()}])

    def delete_track(self, track_id: int):
        self.track(track_id)
        return self._commit("delete_track", [{"op": "put_track", "id": int(track_id), "track": None}])

    def set_class(self, track_id: int, cls: str, resize: bool = False):
        """Change a track's class (and, with ``resize``, its size to the class's typical one)."""
        self.track(track_id)
        fields: dict[str, Any] = {"cls": self._class(cls)}
        if resize:
            fields["size"] = list(self._size(None, cls))
        return self._commit("set_class", [{"op": "set_fields", "id": int(track_id), "fields": fields}])

    def set_size(self, track_id: int, size):
        """Set a track's box size (l, w, h) metres."""
        t = self.track(track_id)
        return self._commit("set_size", [{"op": "set_fields", "id": t.id,
                                          "fields": {"size": list(self._size(size, t.cls))}}])

    def set_meta(self, track_id: int, **fields):
        """Set free-form track fields (JSON-able), e.g. run_track=12 links the track to that
        road user of the run (accept_estimate, suggestions)."""
        t = self.track(track_id)
        return self._commit("set_meta", [{"op": "set_fields", "id": t.id,
                                          "fields": {"meta": {**t.meta, **fields}}}])

    def set_interpolation(self, track_id: int, method: str | None):
        """Choose a track's interpolation (linear, hermite, pchip; None = the class default)."""
        self.check_methods(method)
        t = self.track(track_id)
        return self._commit("set_interpolation", [{"op": "set_fields", "id": t.id,
                                                   "fields": {"interp": method}}])

    # --- keyframes -------------------------------------------------------------------------------
    def set_keyframe(self, track_id: int, frame: int, x: float, y: float,
                     heading: float | None = None, flags=()):
        """Add (or replace) the keyframe at ``frame``; heading None: the direction of motion
        (flag auto_heading, kept up to date as the neighbours change: headings.py)."""
        t, f = self.track(track_id), self._frame(frame)
        self._free(t, f)
        heading, flags = self._heading(t.id, f, x, y, heading, flags)
        k = self._kf(t.id, f, x, y, heading, flags)
        return self._commit("set_keyframe", [{"op": "set_keyframes", "id": t.id, "set": [keyframe_row(f, k)]}])

    def move_keyframe(self, track_id: int, frame: int, x: float, y: float,
                      heading: float | None = None, _name: str = "move_keyframe"):
        """Move a keyframe (or the interpolated pose at ``frame``, making it a keyframe) to x, y;
        heading None keeps it (an auto heading, or a new keyframe's, follows the motion). Removes
        the estimate/normal flags: the pose is now checked."""
        t, f = self.track(track_id), self._frame(frame)
        old = t.keyframes.get(f)
        _, _, h0 = self.pose_at(t.id, f)
        flags = tuple(fl for fl in (old.flags if old else (AUTO,)) if fl not in CHECKED)
        if heading is not None:  # the annotator sets it: it no longer follows the motion
            flags = tuple(fl for fl in flags if fl != AUTO)
        k = self._kf(t.id, f, x, y, h0 if heading is None else heading, flags)
        return self._commit(_name, [{"op": "set_keyframes", "id": t.id, "set": [keyframe_row(f, k)]}])

    def delete_keyframe(self, track_id: int, frame: int):
        t = self.track(track_id)
        if int(frame) not in t.keyframes:
            raise EditError(f"track {t.id} has no keyframe at frame {frame}")
        return self._commit("delete_keyframe", [{"op": "set_keyframes", "id": t.id,
                                                 "del": [int(frame)]}])

    def retime_keyframe(self, track_id: int, frame: int, to_frame: int):
        """Move a keyframe to another frame (same pose)."""
        t, to = self.track(track_id), self._frame(to_frame)
        if int(frame) not in t.keyframes:
            raise EditError(f"track {t.id} has no keyframe at frame {frame}")
        if to in t.keyframes and to != frame:
            raise EditError(f"track {t.id} already has a keyframe at frame {to}")
        self._free(t, to)
        k = t.keyframes[int(frame)]
        return self._commit("retime_keyframe", [{"op": "set_keyframes", "id": t.id,
                                                 "del": [int(frame)], "set": [keyframe_row(to, k)]}])

    def nudge(self, track_id: int, frame: int, dx: float, dy: float, relative: bool = False):
        """Shift the pose at ``frame`` by (dx, dy) metres: world axes, or with ``relative`` the
        road user's own (dx forwards, dy to its left). See NUDGE_STEPS."""
        x, y, h = self.pose_at(track_id, self._frame(frame))
        if relative:
            c, s = math.cos(h), math.sin(h)
            dx, dy = c * dx - s * dy, s * dx + c * dy
        return self.move_keyframe(track_id, frame, x + dx, y + dy, _name="nudge")

    def rotate(self, track_id: int, frame: int, degrees: float):
        """Turn the pose at ``frame`` by ``degrees`` (counter-clockwise). See ROTATE_STEPS."""
        x, y, h = self.pose_at(track_id, self._frame(frame))
        return self.move_keyframe(track_id, frame, x, y, h + math.radians(degrees), _name="rotate")

    def mark(self, track_id: int, first: int, last: int, kind: str):
        """Mark frames first..last of a track ``occluded``, ``outside`` (interpolation stops;
        keyframes inside are removed in the same step) or ``visible`` (clears)."""
        t, a, b = self.track(track_id), self._frame(first), self._frame(last)
        spans = mark_spans(t.spans, a, b, kind)
        ops = [{"op": "set_fields", "id": t.id, "fields": {"spans": [list(s) for s in spans]}}]
        inside = [f for f in t.keyframes if a <= f <= b]
        if kind == "outside" and inside:
            ops.insert(0, {"op": "set_keyframes", "id": t.id, "del": sorted(inside)})
        return self._commit(f"mark_{kind}", ops)

    def mark_reviewed(self, track_id: int, first: int, last: int, reviewed: bool = True):
        """Mark frames first..last of a track reviewed (the annotator played them back and
        passed them: estimates there count as accepted, the interpolation as ``reviewed``) or,
        with ``reviewed=False``, not reviewed."""
        t, a, b = self.track(track_id), self._frame(first), self._frame(last)
        if b < a:
            raise EditError(f"frames {a}..{b}: the last frame comes before the first")
        spans = mark_reviewed(t.reviewed, a, b, bool(reviewed))
        return self._commit("mark_reviewed" if reviewed else "unmark_reviewed",
                            [{"op": "set_fields", "id": t.id,
                              "fields": {"reviewed": [list(r) for r in spans]}}])

    # --- several tracks --------------------------------------------------------------------------
    def split_track(self, track_id: int, frame: int):
        """Split a track before ``frame``: keyframes and spans from ``frame`` on go to a new
        track (same class, size, interpolation); ``change.track`` is the new id."""
        t, f = self.track(track_id), self._frame(frame)
        after = [g for g in t.keyframes if g >= f]
        if not after or len(after) == len(t.keyframes):
            raise EditError(f"track {t.id}: splitting at frame {f} leaves one part without "
                            f"keyframes (keyframes {t.first}..{t.last})")
        new = t.copy()
        new.id = max(self.tracks) + 1
        new.keyframes = {g: t.keyframes[g] for g in after}
        new.spans = [s for s in mark_spans(t.spans, 0, f - 1, "visible")] if f > 0 else list(t.spans)
        keep = mark_spans(t.spans, f, max(f, max(b for _, b, _ in t.spans)), "visible") \
            if t.spans else []
        return self._commit("split_track", [
            {"op": "set_keyframes", "id": t.id, "del": sorted(after)},
            {"op": "set_fields", "id": t.id, "fields": {"spans": [list(s) for s in keep]}},
            {"op": "put_track", "id": new.id, "track": new.to_dict()}])

    def merge_tracks(self, keep: int, other: int):
        """Move the keyframes and spans of track ``other`` into ``keep`` (whose class and size
        stay) and delete ``other``. Refused where both have a keyframe in the same frame."""
        a, b = self.track(keep), self.track(other)
        if a.id == b.id:
            raise EditError("cannot merge a track with itself")
        clash = sorted(set(a.keyframes) & set(b.keyframes))
        if clash:
            raise EditError(f"tracks {a.id} and {b.id} both have keyframes at frames {clash[:10]}")
        spans = list(a.spans)
        for s0, s1, kind in b.spans:
            spans = mark_spans(spans, s0, s1, kind)
        return self._commit("merge_tracks", [
            {"op": "set_keyframes", "id": a.id,
             "set": [keyframe_row(f, k) for f, k in sorted(b.keyframes.items())]},
            {"op": "set_fields", "id": a.id, "fields": {"spans": [list(s) for s in spans]}},
            {"op": "put_track", "id": b.id, "track": None}])
