"""``Project``: an annotation project = a scene folder + its journal (``SCENE/annotations/``).

    from annotate import Project
    with Project.open("scene") as p:
        ch = p.create_track("car")
        p.set_keyframe(ch.track, 0, x=3.0, y=-1.5, heading=0.0)
        p.set_keyframe(ch.track, 25, x=12.0, y=-1.4)
        p.poses()            # PoseTable: every frame, z on the ground, size, source column
        p.undo(); p.redo()

Every edit method (edits.py) returns a ``Change`` naming the tracks it changed, after the edit
was written and fsync'ed to the journal; subscribers (``subscribe``) get the same ``Change``.
Opening replays the journal (from the latest snapshot). ``read_only=True`` takes no lock and
writes nothing (a second viewer of a scene being annotated); ``refresh()`` picks up new edits.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType

from annotate import history as H
from annotate import journal as J
from annotate.edits import EditsMixin
from annotate.estimates import scene_frames
from annotate.headings import auto_heading_op
from annotate.interpolate import METHODS, default_method
from annotate.model import EditError, Track, apply_ops, check_op, check_op_frames, op_tracks
from annotate.place import PlacementMixin
from annotate.table import empty, track_poses
from seg2pose.core.errors import S2PError
from seg2pose.io.poses import PoseTable
from seg2pose.io.scene import Scene, load_scene

UNDO_LIMIT = H.UNDO_LIMIT
SNAPSHOT_EVERY = 5_000   # records per journal segment before a snapshot compacts it


@dataclass(frozen=True)
class Change:
    """What an edit, undo, redo or refresh changed. kind: "edit", "undo", "redo", "refresh";
    name: the edit's name ("nudge", ...); seq: its journal record number; tracks: ids of
    changed tracks (created and deleted ones included)."""

    kind: str
    name: str
    seq: int
    tracks: frozenset[int] = frozenset()
    created: frozenset[int] = frozenset()
    deleted: frozenset[int] = frozenset()

    @property
    def track(self) -> int | None:
        """The one created track (create_track, split_track), else the one changed track."""
        pick = self.created or self.tracks
        return next(iter(pick)) if len(pick) == 1 else None


class Project(EditsMixin, PlacementMixin):
    """An open annotation project (see the module docstring). Use ``Project.open``."""

    def __init__(self, scene: Scene, read_only: bool, frames: tuple[int, int] | None,
                 run=None, snapshot_every: int = SNAPSHOT_EVERY):
        self.scene = scene
        self.read_only = read_only
        self.folder = scene.root / J.ANNOTATIONS
        self.notes: list[str] = []  # things said on open/refresh: torn lines, lock take-over
        self.frame_range = frames if frames is not None else scene_frames(scene)
        self.fingerprint = scene.fingerprint()
        self.snapshot_every = int(snapshot_every)
        if self.snapshot_every < 1:
            raise EditError(f"snapshot_every must be >= 1 record, got {snapshot_every!r}")
        self._s = H.State()
        self._cache: dict[int, PoseTable] = {}
        self._stale: dict[int, PoseTable] = {}  # tables of changed tracks: z to reuse
        self._subscribers: list[Callable[[Change], None]] = []
        self._snapshot_retry = 0  # after a snapshot that could not be written: the record to retry at
        self._segment: J.Segment | None = None
        self._segment_start = 0
        self._lock: J.Lock | None = None
        self._run = None
        if run is not None:
            self.load_run(run)

    # --- opening and closing ---------------------------------------------------------------------
    @classmethod
    def open(cls, scene: Scene | str | Path, *, read_only: bool = False,
             run: str | Path | None = None, frames: tuple[int, int] | None = None,
             snapshot_every: int = SNAPSHOT_EVERY) -> Project:
        """Open (or start) the annotation project of a scene folder.

        read_only: no lock, no writes (edits raise); run: a run folder whose Seg2Pose estimates
        serve pre-annotation and suggestions; frames: (first, last) frames of the scene
        (default: from its splits, else its masks). Raises LockedError when another process
        writes, JournalError for a damaged journal or one of another scene."""
        if not isinstance(scene, Scene):
            scene = load_scene(scene)
        p = cls(scene, read_only, frames, run, snapshot_every)
        if not read_only:
            try:
                p.folder.mkdir(exist_ok=True)
                p._lock = J.Lock(p.folder, scene.name)
            except OSError as e:
                raise J.JournalError(f"{p.folder}: cannot write annotations here ({e.strerror}); "
                                     "open the project read-only to look at it") from None
            if p._lock.note:
                p.notes.append(p._lock.note)
        try:
            p._load()
            if not read_only:
                p._open_segment()
                if p._lock and p._lock.note:
                    p._write({"kind": "note", "text": p._lock.note})
        except BaseException:
            p.close()
            raise
        return p

    def close(self) -> None:
        """Release the journal and the lock (idempotent)."""
        if self._segment is not None:
            self._segment.close()
            self._segment = None
        if self._lock is not None:
            self._lock.release()
            self._lock = None

    def __enter__(self) -> Project:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # --- reading -----------------------------------------------------------------------------------
    @property
    def tracks(self) -> Mapping[int, Track]:
        """Track id -> Track (read-only view; change tracks only through the edit methods)."""
        return MappingProxyType(self._s.tracks)

    def track(self, track_id: int) -> Track:
        try:
            return self._s.tracks[int(track_id)]
        except KeyError:
            raise EditError(f"no track {track_id}; tracks: {sorted(self._s.tracks)[:20]}") from None

    def interpolation(self, track_id: int) -> str:
        """The interpolation a track uses (its own choice or its class's default)."""
        t = self.track(track_id)
        return t.interp or default_method(t.cls)

    def track_poses(self, track_id: int) -> PoseTable:
        """Every frame's pose of one track (cached until the track changes): a PoseTable with
        size and source (keyframe / interpolated / occluded) columns."""
        tid = int(track_id)
        if tid not in self._cache:
            t = self.track(tid)
            self._cache[tid] = track_poses(t, self.scene.ground, self.interpolation(tid),
                                           previous=self._stale.pop(tid, None))
        return self._cache[tid]

    def poses(self, tracks=None, frames: tuple[int, int] | None = None) -> PoseTable:
        """Per-frame poses of all (or the given) tracks, sorted by frame then track id: a
        PoseTable with size and source columns (write it with seg2pose.io.poses.write_poses)."""
        ids = sorted(self._s.tracks) if tracks is None else [int(t) for t in tracks]
        parts = [self.track_poses(t).in_frames(frames) for t in ids]
        parts = [t for t in parts if len(t)]
        return PoseTable.concat(parts).sorted() if parts else empty()

    @property
    def seq(self) -> int:
        """Number of journal records so far (edits, undos, redos, notes)."""
        return self._s.seq

    @property
    def can_undo(self) -> bool:
        return bool(self._s.undo)

    @property
    def can_redo(self) -> bool:
        return bool(self._s.redo)

    def history(self) -> list[tuple[int, str]]:
        """(seq, name) of the edits that ``undo`` would take back, oldest first."""
        return [(e.seq, e.name) for e in self._s.undo]

    def subscribe(self, callback: Callable[[Change], None]) -> Callable[[], None]:
        """Call ``callback(change)`` after every edit, undo, redo and refresh; returns a function
        that unsubscribes."""
        self._subscribers.append(callback)
        return lambda: self._subscribers.remove(callback)

    # --- changing ------------------------------------------------------------------------------------
    def _write(self, record: dict) -> int:
        if self.read_only:
            raise EditError("this project is open read-only")
        seq = self._s.seq + 1
        assert self._segment is not None  # a writable project has its segment open
        self._segment.append({"seq": seq, **record})
        self._s.seq = seq
        return seq

    def _apply_durably(self, kind: str, ops: list[dict], record: dict
                       ) -> tuple[int, list[dict], list[dict]]:
        """Apply ops to scratch copies of their tracks, journal the record, then swap the copies
        in: an op that fails or a journal write that fails leaves everything as it was. An
        ``edit`` also brings the auto headings of the tracks it touches up to date (headings.py):
        those ops join the edit's. Returns (seq, ops, inverse)."""
        if self.read_only:
            raise EditError("this project is open read-only")
        touched = op_tracks(ops)
        scratch = {t: self._s.tracks[t].copy() for t in touched if t in self._s.tracks}
        inverse = apply_ops(scratch, ops)
        if kind == "edit":
            extra = [op for t in sorted(scratch) if (op := auto_heading_op(scratch[t]))]
            if extra:
                inverse = apply_ops(scratch, extra) + inverse
                ops = ops + extra
                record = {**record, "ops": ops}
        seq = self._write({"kind": kind, **record})
        for t in touched:
            if t in scratch:
                self._s.tracks[t] = scratch[t]
            else:
                self._s.tracks.pop(t, None)
            old = self._cache.pop(t, None)
            if old is not None:
                self._stale[t] = old
        return seq, ops, inverse

    def _commit(self, name: str, ops: list[dict]) -> Change:
        """Journal and apply one edit (a list of primitive ops) as one undoable step."""
        if not ops:
            return Change("edit", name, self._s.seq)
        before = set(self._s.tracks)
        seq, ops, inverse = self._apply_durably("edit", ops,
                                                  {"name": name, "ops": ops, "t": J.now()})
        H.record_edit(self._s, H.Entry(seq, name, ops, inverse))
        return self._changed("edit", name, seq, op_tracks(ops), before)

    def undo(self) -> Change | None:
        """Take back the last edit (None when there is nothing to undo)."""
        return self._step("undo")

    def redo(self) -> Change | None:
        """Do again the last undone edit (None when there is nothing to redo)."""
        return self._step("redo")

    def _step(self, kind: str) -> Change | None:
        src = self._s.undo if kind == "undo" else self._s.redo
        if not src:
            return None
        e = src[-1]
        before = set(self._s.tracks)
        seq, _, _ = self._apply_durably(kind, H.step_ops(e, kind), {"of": e.seq})
        H.swap(self._s, kind, e.seq)
        return self._changed(kind, e.name, seq, op_tracks(e.ops), before)

    def _changed(self, kind: str, name: str, seq: int, tracks: set[int], before: set[int]
                 ) -> Change:
        after = set(self._s.tracks)
        ch = Change(kind, name, seq, frozenset(tracks), frozenset(after - before),
                    frozenset(before - after))
        if (not self.read_only and self._s.seq - self._segment_start >= self.snapshot_every
                and self._s.seq >= self._snapshot_retry):
            try:
                self.snapshot()
            except (S2PError, OSError) as e:
                # the edit is in the journal: saved. A snapshot only compacts the journal, so
                # one that cannot be written (disk full) is a note, tried again later
                self._snapshot_retry = self._s.seq + max(1, self.snapshot_every // 10)
                self.notes.append(f"{e}; the edit is saved in the journal, the snapshot will be "
                                  f"tried again after record {self._snapshot_retry}")
        for cb in list(self._subscribers):
            cb(ch)
        return ch

    # --- journal: replay, snapshots -----------------------------------------------------------------
    def _load(self) -> None:
        """Replay: the latest snapshot, then the records after it."""
        segs, snaps = J.list_files(self.folder)
        start = max(snaps) if snaps else 0
        if snaps:
            self._s = H.state_from_snapshot(J.load_json(snaps[start]), snaps[start], self.fingerprint)
        later = sorted(a for a in segs if a >= start)
        if snaps and start not in segs and later:
            raise J.JournalError(f"{self.folder}: journal after snapshot {start} is missing")
        for a in later:
            self._replay_segment(segs[a], last=(a == later[-1]))
        self._segment_start = later[-1] if later else start

    def _replay_segment(self, path: Path, last: bool) -> None:
        lines, good, torn = J.read_lines(path)
        if torn:
            if not last:
                raise J.JournalError(f"{path}: damaged in the middle of the history ({torn})")
            self.notes.append(torn)
            if not self.read_only:
                keep = J.move_torn(path, good)
                self.notes.append(f"the torn bytes were moved to {keep.name}")
        for lineno, rec in lines:
            try:
                self._replay_record(rec, path)
            except (KeyError, TypeError, ValueError, EditError) as e:
                raise J.JournalError(f"{path}:{lineno}: cannot replay this record: {e}") from None

    def _replay_record(self, rec: dict, path: Path) -> None:
        kind = rec.get("kind")
        if kind == "header":
            J.check_header(rec, path, self.fingerprint)
            return
        s = self._s
        seq = rec["seq"]
        if seq <= s.seq:
            return  # already in the snapshot
        if seq != s.seq + 1:
            raise ValueError(f"record {seq} follows record {s.seq}: records are missing")
        s.seq = seq
        if kind == "edit":
            ops = rec["ops"]
            for op in ops:  # as an edit's frames are checked when it is made
                check_op(op)
                check_op_frames(op, self.frame_range)
            H.record_edit(s, H.Entry(seq, rec["name"], ops, apply_ops(s.tracks, ops)))
        elif kind in ("undo", "redo"):
            apply_ops(s.tracks, H.step_ops(H.swap(s, kind, rec["of"]), kind))
        elif kind != "note":
            raise ValueError(f"unknown record kind {kind!r}")

    def _header(self) -> dict:
        return {"kind": "header", "version": J.VERSION, "scene": self.scene.name,
                "fingerprint": self.fingerprint, "created": J.now()}

    def _open_segment(self) -> None:
        self._segment = J.new_segment(self.folder, self._segment_start, self._header())

    def snapshot(self) -> Path:
        """Compact the journal now: write the state and undo history as a snapshot, start a new
        segment, and remove the segments and snapshots the new snapshot replaces."""
        if self.read_only:
            raise EditError("this project is open read-only")
        seq = self._s.seq
        path = J.write_snapshot(self.folder, seq, H.snapshot_dict(self._s, self.scene.name,
                                                                  self.fingerprint))
        old = self._segment
        assert old is not None  # a writable project has its segment open
        try:
            new = J.new_segment(self.folder, seq, self._header())
        except (S2PError, OSError) as e:
            # without its segment the snapshot would hide the records still appended to the
            # old one: take it back
            path.unlink(missing_ok=True)
            if seq != self._segment_start:
                (self.folder / J.segment_name(seq)).unlink(missing_ok=True)
            J.fsync_dir(self.folder)
            raise J.NotSavedError(f"{path}: snapshot not written: {e}") from None
        self._segment_start = seq
        self._segment = new
        self._snapshot_retry = 0
        old.close()
        segs, snaps = J.list_files(self.folder)
        for a, p in list(segs.items()) + list(snaps.items()):
            if a < seq:
                p.unlink()
        J.fsync_dir(self.folder)
        return path

    def journal_files(self) -> list[Path]:
        """The files that hold this project's history (snapshot and journal segments), for
        archiving it (e.g. as an MCAP attachment); copied into another copy of the scene's
        ``annotations/`` they reopen as the same project."""
        segs, snaps = J.list_files(self.folder)
        return [p for _, p in sorted(snaps.items())] + [p for _, p in sorted(segs.items())]

    def refresh(self) -> Change:
        """Read-only projects: pick up what the writer has journalled since (reloads)."""
        old = {t: tr.to_dict() for t, tr in self._s.tracks.items()}
        self._s = H.State()
        self._cache.clear()
        self._stale.clear()
        self.notes = []
        try:
            self._load()
        except J.JournalError:
            # the writer may have compacted the journal while we listed it: look again once
            self._s, self.notes = H.State(), []
            self._load()
        new = {t: tr.to_dict() for t, tr in self._s.tracks.items()}
        changed = {t for t in old.keys() | new.keys() if old.get(t) != new.get(t)}
        ch = Change("refresh", "refresh", self._s.seq, frozenset(changed),
                    frozenset(new.keys() - old.keys()), frozenset(old.keys() - new.keys()))
        for cb in list(self._subscribers):
            cb(ch)
        return ch

    # --- run estimates (pre-annotation, suggestions) -------------------------------------------------
    def load_run(self, run: str | Path) -> None:
        """Use a run folder's Seg2Pose estimates (poses.csv) for accept_estimate, preannotate and
        suggestions."""
        from annotate.estimates import RunEstimates
        self._run = RunEstimates.load(run, self.scene)
        self._ids_match: bool | None = None  # place.py: whether the masks' ids are this run's

    @property
    def run(self):
        if self._run is None:
            raise EditError("no run loaded: open the project with a run folder (Seg2Pose output)")
        return self._run

    def check_methods(self, method: str | None) -> None:
        if method is not None and method not in METHODS:
            raise EditError(f"unknown interpolation {method!r}; known: {', '.join(METHODS)}")


__all__ = ["Project", "Change", "S2PError", "UNDO_LIMIT"]

