"""The annotation app's review mode and size edits (``ReviewActions``, a mixin of ``Controller``):
play a track from the current frame at the scene's frame rate until the frame that needs a
look (``annotate.review_queue.play_stop``), mark what was watched reviewed, jump to the next
frame that needs a look across all tracks (``review_queue``, worst first), change the box's
length, width and height, and hide the other tracks.

Playback itself is timed by the page (session.py): ``play`` sets ``play_to`` and
``play_step`` moves one frame; any other action stops it.
"""

from __future__ import annotations

from annotate import EditError
from annotate.app.actions import ControllerState

DIMS = {"l": 0, "w": 1, "h": 2}


class ReviewActions(ControllerState):
    """``_a_<name>`` methods of ``REVIEW_ACTIONS`` and the parametrised ``size:D:STEP`` and
    ``set_size:L,W,H`` (see the module docstring)."""

    def _reference(self):
        """The reference poses the review compares with (cached until the tracks change: they
        are the run's estimates or the masks' normal positions, not the annotation)."""
        from annotate.review import reference
        from annotate.review_queue import reference_source

        if getattr(self, "_review_ref", None) is None:
            self._review_ref = reference(self.project, reference_source(self.project))
        return self._review_ref

    def looks(self, top: int = 50) -> list[dict]:
        """The review queue: frames that need a look, worst first (annotate.review_queue)."""
        from annotate.review_queue import review_queue

        if not any(True for _ in self.project.tracks):
            return []
        return [{"track": lk.track, "frame": lk.frame, "score": lk.score, "first": lk.first,
                 "last": lk.last} for lk in review_queue(self.project, ref=self._reference())[:top]]

    def _a_play(self):
        from annotate.review_queue import play_stop

        tid = self._need_track()
        stop, why = play_stop(self.project, tid, self.frame, ref=self._reference())
        if stop <= self.frame:
            self.play_to = None
            return f"nothing to play: {why} (frame {stop})"
        self.review_from = self.frame
        self.play_to = stop
        self.play_reason = f"stopped at frame {stop}: {why}"
        return f"playing track {tid} from frame {self.frame} to {stop}"

    def play_step(self) -> bool:
        """One playback frame; False when the playback is over (or was stopped)."""
        with self.lock:
            if self.play_to is None or self.frame >= self.play_to:
                if self.play_to is not None:
                    self.message = self.play_reason + " (r: reviewed up to here; p: play on)"
                self.play_to = None
                return False
            self.goto(self.frame + 1)
            return True

    def _a_mark_reviewed(self):
        tid = self._need_track()
        rows = self.project.track_poses(tid)
        if not len(rows):
            raise EditError(f"track {tid} has no poses to review")
        first = self.review_from if self.review_from is not None else int(rows.frame[0])
        a, b = sorted((max(first, int(rows.frame[0])), min(self.frame, int(rows.frame[-1]))))
        self._edit(self.project.mark_reviewed, tid, a, b)
        self.review_from = None
        return f"track {tid}: frames {a}..{b} reviewed"

    def _a_mark_reviewed_all(self):
        tid = self._need_track()
        rows = self.project.track_poses(tid)
        if not len(rows):
            raise EditError(f"track {tid} has no poses to review")
        self._edit(self.project.mark_reviewed, tid, int(rows.frame[0]), int(rows.frame[-1]))
        return f"track {tid}: all its frames reviewed"

    def _a_next_look(self):
        looks = self.looks(top=1000)
        if not looks:
            return "nothing needs a look: every unchecked estimate is reviewed"
        here = (self.selected, self.frame)
        after = [lk for lk in looks if (lk["track"], lk["frame"]) != here]
        lk = (after or looks)[0]
        self._select(lk["track"])
        self.goto(lk["frame"])
        self.review_from = lk["first"]
        return (f"track {lk['track']}, frame {lk['frame']}: {lk['score']:.2f} m expected error "
                f"(frames {lk['first']}..{lk['last']} unchecked; p plays, r marks reviewed)")

    def _a_only_selected(self):
        self.only_selected = not self.only_selected
        return "only the selected track is drawn" if self.only_selected else "every track is drawn"

    def _size_step(self, dim: str, step: float) -> str:
        tid = self._need_track()
        size = list(self.project.track(tid).size)
        size[DIMS[dim]] = round(size[DIMS[dim]] + step, 3)
        self._edit(self.project.set_size, tid, size)
        return f"track {tid}: l, w, h = {', '.join(f'{v:.2f}' for v in size)} m"

    def _set_size(self, text: str) -> str:
        tid = self._need_track()
        try:
            size = [float(v) for v in text.replace(" ", "").split(",")]
        except ValueError:
            raise EditError(f"size: expected l,w,h in metres, got {text!r}") from None
        self._edit(self.project.set_size, tid, size)
        return f"track {tid}: l, w, h = {', '.join(f'{v:.2f}' for v in size)} m"
