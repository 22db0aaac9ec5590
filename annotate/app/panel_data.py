"""What the annotation app's panel shows (``PanelData``, a mixin of ``Controller``): the track
list with its warnings, the selected track's keyframes, suggested keyframes, and ``panel()``,
all of it as plain data (the page's ``annotate.app.panel`` renders it). Reads the controller's
``project``, ``frame``, ``selected`` and page state; changes nothing."""

from __future__ import annotations

import math

import numpy as np

from annotate.app.actions import ACTIONS, CLICK_MODE_HELP, ControllerState
from annotate.app.fine_tune_job import job_status, queue_rows
from annotate.headings import AUTO


class PanelData(ControllerState):
    """The panel's rows and state (see the module docstring)."""

    def suggestions(self, threshold: float = 0.5) -> list[tuple[int, int, float]]:
        """(track, frame, distance m) where a track's interpolation is more than ``threshold``
        metres from the run's estimates (or, without a run, the masks' normal positions),
        strongest first (annotate.review.suggest_keyframes)."""
        from annotate.review import suggest_keyframes

        source = "estimate" if getattr(self.project, "_run", None) is not None else "normal"
        return [(s.track, s.frame, s.distance)
                for s in suggest_keyframes(self.project, source=source, threshold=threshold)]

    def track_rows(self) -> list[dict]:
        """The track list: id, class, keyframes, span, interpolation, warnings (unchecked
        estimates, keyframes off the ground points, and annotate.review's gaps and implausible
        speeds or accelerations). Cached per journal record and selection: a frame step does
        not recompute it."""
        key = (self.project.seq, self.selected)
        cached = getattr(self, "_rows_cache", None)
        if cached is None or cached[0] != key:
            cached = (key, self._track_rows())
            self._rows_cache = cached
        return cached[1]

    def _track_rows(self) -> list[dict]:
        from annotate.review import plausibility_report

        issues: dict[int, list[str]] = {}
        for i in plausibility_report(self.project):
            issues.setdefault(i.track, []).append(i.message)
        out = []
        for tid, t in sorted(self.project.tracks.items()):
            warn = []
            flags = [f for k in t.keyframes.values() for f in k.flags]
            if "off_support" in flags:
                warn.append(f"{flags.count('off_support')} off the ground points")
            if "estimate" in flags:
                warn.append(f"{flags.count('estimate')} unchecked estimates")
            if len(t.keyframes) == 1:
                warn.append("one keyframe")
            warn += issues.get(tid, [])
            out.append({"id": tid, "cls": t.cls, "keyframes": len(t.keyframes),
                        "span": None if t.first is None else [t.first, t.last],
                        "interp": self.project.interpolation(tid), "warnings": warn,
                        "selected": tid == self.selected})
        return out

    def keyframe_rows(self) -> list[dict]:
        if self.selected is None or self.selected not in self.project.tracks:
            return []
        t = self.project.track(self.selected)
        return [{"frame": f, "x": k.x, "y": k.y, "heading_deg": math.degrees(k.heading),
                 "heading_mode": "auto" if AUTO in k.flags else "set",
                 "flags": [fl for fl in k.flags if fl != AUTO], "current": f == self.frame}
                for f, k in sorted(t.keyframes.items())]

    def review_rows(self) -> list[dict]:
        """The review queue (cached per journal record: a frame step does not recompute it)."""
        key = self.project.seq
        cached = getattr(self, "_looks_cache", None)
        if cached is None or cached[0] != key:
            cached = (key, self.looks(top=12))
            self._looks_cache = cached
        return cached[1]

    def selected_info(self) -> dict | None:
        """The selected track's size, provenance counts, reviewed spans and the distance
        between its pose here and its road user's reference (the run's estimate, else the
        masks' normal position)."""
        from annotate.review import distance_series
        from annotate.review_queue import reference_source
        from annotate.table import source_counts

        tid = self.selected
        if tid is None or tid not in self.project.tracks:
            return None
        t = self.project.track(tid)
        key = (self.project.seq, tid)
        cached = getattr(self, "_dist_cache", None)
        if cached is None or cached[0] != key:
            frames, dist = distance_series(self.project, tid, reference_source(self.project),
                                           ref=self._reference())
            cached = (key, dict(zip(frames.tolist(), dist.tolist())))
            self._dist_cache = cached
        d = cached[1].get(self.frame)
        return {"size": list(t.size), "reviewed": [list(r) for r in t.reviewed],
                "sources": source_counts(self.project.track_poses(tid)).get(tid, {}),
                "distance": None if d is None or not math.isfinite(d) else d,
                "reference": reference_source(self.project)}

    def extra_lists(self) -> dict[str, list[dict]]:
        """The lists others provide (``panel_lists``); one that fails says so in its title."""
        out = {}
        for title, fn in list(self.panel_lists.items()):
            try:
                out[str(title)] = [dict(r) for r in fn()][:20]
            except Exception as e:  # noqa: BLE001 - a helper list never breaks the panel
                out[f"{title} (failed: {type(e).__name__}: {e})"] = []
        return out

    def panel(self) -> dict:
        """Everything the panel shows, as plain data."""
        with self.lock:
            here = None
            sel = self.selected
            if sel is not None and sel in self.project.tracks:
                t = self.project.track(sel)
                src = "keyframe" if self.frame in t.keyframes else None
                if src is None:
                    tab = self.project.track_poses(t.id)
                    hit = np.flatnonzero(tab.frame == self.frame)
                    if len(hit):
                        assert tab.source is not None  # a track's poses say where each row comes from
                        src = str(tab.source[hit[0]])
                    else:
                        src = "not in the track"
                here = src
            no_video = [c for c, fr in sorted(self.video_frames.items()) if self.frame not in fr]
            return {"scene": self.project.scene.name, "frame": self.frame, "no_video": no_video,
                    "frame_range": list(self.frame_range), "selected": self.selected,
                    "here": here, "click_mode": self.click_mode,
                    "click_help": CLICK_MODE_HELP[self.click_mode], "new_class": self.new_class,
                    "classes": [c.name for c in self.project.scene.classes], "every": self.every,
                    "tracks": self.track_rows(), "keyframes": self.keyframe_rows(),
                    "message": self.message, "read_only": self.read_only_reason,
                    "last_click": self.last_click, "seq": self.project.seq,
                    "viewer": self.viewer_state,
                    "can_undo": self.project.can_undo, "can_redo": self.project.can_redo,
                    "has_run": getattr(self.project, "_run", None) is not None,
                    "queue": queue_rows(self), "train_job": job_status(self),
                    "review": self.review_rows(), "info": self.selected_info(),
                    "lists": self.extra_lists(), "playing": self.play_to,
                    "only_selected": self.only_selected,
                    "actions": [a.__dict__ for a in ACTIONS]}
