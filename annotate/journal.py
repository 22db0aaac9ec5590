"""The annotation folder on disk: an append-only JSON-lines journal, snapshots, and a lock file.

``SCENE/annotations/``::

    journal-000000.jsonl   one JSON object per line: a header, then edits / undos / redos / notes
    snapshot-000123.json   tracks + undo/redo history after record 123 (written atomically)
    journal-000123.jsonl   the records after that snapshot
    lock                   who writes: {"pid", "host", "since"}; held with flock while open

Records (``seq`` counts from 1 over the whole history):
``{"kind": "header", "version": 1, "scene": name, "fingerprint": fp, "after": N}``,
``{"seq": n, "kind": "edit", "name": "nudge", "ops": [...], "t": time}`` (ops: see model.py),
``{"seq": n, "kind": "undo"|"redo", "of": seq of the edit}``, ``{"seq": n, "kind": "note", ...}``.

Every record is written with one ``write`` and fsync'ed before the edit is applied and
acknowledged; a failed write is cut off again (the edit is reported as not saved, nothing
earlier is touched). A torn last line (a crash mid-write) is reported and skipped on open; the
writer moves it aside to ``torn-<time>.jsonl`` before appending.
"""

from __future__ import annotations

import errno
import json
import os
import re
from pathlib import Path

from seg2pose.core.clock import utc_now, utc_stamp
from seg2pose.core.errors import S2PError
from seg2pose.core.locks import KernelLock, LockHolder
from seg2pose.io.atomic import atomic_write_text, fsync_dir
from seg2pose.io.atomic_set import commit_step
from seg2pose.io.nofollow import fdopen_nofollow, open_nofollow, refuse_links

VERSION = 1
ANNOTATIONS = "annotations"
_SEGMENT = re.compile(r"^journal-(\d{6,})\.jsonl$")
_SNAPSHOT = re.compile(r"^snapshot-(\d{6,})\.json$")


class JournalError(S2PError):
    """The journal cannot be read or written (names the file and line)."""


class LockedError(S2PError):
    """Another process is annotating this scene."""


class NotSavedError(S2PError):
    """An edit could not be written to the journal (disk full, I/O error): it was not applied."""


def now() -> str:
    """A journal record's time: UTC, ISO 8601 to the millisecond."""
    return utc_now("milliseconds")


def dumps(record: dict) -> bytes:
    """One journal line (compact JSON, floats with repr so replay is bit-exact)."""
    return json.dumps(record, separators=(",", ":"), allow_nan=False).encode() + b"\n"


def segment_name(after: int) -> str:
    return f"journal-{after:06d}.jsonl"


def snapshot_name(after: int) -> str:
    return f"snapshot-{after:06d}.json"


def list_files(folder: Path) -> tuple[dict[int, Path], dict[int, Path]]:
    """Journal segments and snapshots in ``folder``, keyed by the record they start after."""
    segs, snaps = {}, {}
    if folder.is_dir():
        for p in folder.iterdir():
            if m := _SEGMENT.match(p.name):
                segs[int(m.group(1))] = p
            elif m := _SNAPSHOT.match(p.name):
                snaps[int(m.group(1))] = p
    return segs, snaps


def read_lines(path: Path) -> tuple[list[tuple[int, dict]], int, str | None]:
    """Records of a segment with their line numbers, the byte length of its good part, and a
    note when the last line is torn. A bad line that is not the last is an error (a torn line
    can only be the last one written)."""
    try:
        data = path.read_bytes()
    except OSError as e:
        raise JournalError(f"{path}: cannot read the journal: {e.strerror}") from None
    lines = data.split(b"\n")
    tail = lines.pop()  # after the last newline: b"" unless the last write was cut short
    while lines and not lines[-1].strip():
        lines.pop()  # trailing blank lines (never written by s2p, harmless)
    try:  # one parse of the whole segment: much faster than a call per line
        records = json.loads(b"[" + b",".join(lines) + b"]") if lines else []
        ok = all(isinstance(r, dict) for r in records)
    except (ValueError, UnicodeDecodeError):
        ok = False
    if not ok:
        for i, line in enumerate(lines):
            try:
                if not isinstance(json.loads(line), dict):
                    raise ValueError
            except (ValueError, UnicodeDecodeError):
                if i == len(lines) - 1 and not tail.strip():
                    # the last complete line is bad: a torn write whose newline got through
                    lines, tail = lines[:-1], line
                    records = json.loads(b"[" + b",".join(lines) + b"]") if lines else []
                    break
                raise JournalError(f"{path}:{i + 1}: not a JSON object; the journal is damaged "
                                   "before its last line") from None
    good = sum(len(x) + 1 for x in lines)
    note = None
    if tail.strip():
        note = (f"{path.name}:{len(lines) + 1}: the last line is torn (an edit interrupted while "
                f"being written, {len(tail)} bytes); it is skipped")
    return list(zip(range(1, len(records) + 1), records)), good, note


class Segment:
    """An open journal segment for appending records durably."""

    def __init__(self, path: Path):
        self.path = path
        # never through a link planted in the scene folder (its target would take the journal)
        self.fd = open_nofollow(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o666)
        self.size = os.fstat(self.fd).st_size
        self.broken = False

    def append(self, record: dict) -> None:
        """Write one record and fsync it; on failure cut the file back and raise NotSavedError."""
        if self.broken:
            raise NotSavedError(f"{self.path}: an earlier write failed and could not be undone; "
                                "close and reopen the project (nothing saved is lost)")
        data = dumps(record)
        try:
            n = os.write(self.fd, data)
            while n < len(data):
                n += os.write(self.fd, data[n:])
            os.fsync(self.fd)
            commit_step("appended")  # the record is durable: the edit is saved (kill tests)
        except OSError as e:
            why = "the disk is full" if e.errno in (errno.ENOSPC, errno.EDQUOT) else e.strerror
            try:
                os.ftruncate(self.fd, self.size)
                os.fsync(self.fd)
            except OSError:
                self.broken = True
            raise NotSavedError(f"{self.path}: edit not saved: {why}; it was not applied "
                                "(earlier edits are safe)") from None
        self.size += len(data)

    def close(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1


def new_segment(folder: Path, after: int, header: dict) -> Segment:
    """Create ``journal-<after>.jsonl`` with its header line, durably."""
    path = folder / segment_name(after)
    seg = Segment(path)
    if seg.size == 0:
        seg.append({**header, "after": after})
        fsync_dir(folder)
    return seg


def write_snapshot(folder: Path, after: int, state: dict) -> Path:
    """Write ``snapshot-<after>.json`` atomically (fsync'ed, renamed into place)."""
    path = folder / snapshot_name(after)
    try:
        atomic_write_text(path, json.dumps(state, separators=(",", ":"), allow_nan=False))
    except S2PError as e:  # atomic_write_text's one line (disk full, read-only, ...)
        raise NotSavedError(f"{path}: snapshot not written: {e}") from None
    except OSError as e:
        raise NotSavedError(f"{path}: snapshot not written: {e.strerror}") from None
    fsync_dir(folder)
    return path


def move_torn(path: Path, good: int) -> Path:
    """Cut a torn tail off a segment, keeping it in ``torn-<time>.jsonl`` beside it."""
    with fdopen_nofollow(path, "r+b") as f:  # a linked segment is refused, never cut
        data = f.read()
        stamp = utc_stamp(microseconds=True)
        keep = path.parent / f"torn-{stamp}.jsonl"
        with fdopen_nofollow(keep, "xb") as k:
            k.write(data[good:])
            k.flush()
            os.fsync(k.fileno())
        f.truncate(good)
        f.flush()
        os.fsync(f.fileno())
    fsync_dir(path.parent)
    return keep


# --- the lock ---------------------------------------------------------------------------------------
class Lock:
    """The writer's lock: flock on ``annotations/lock`` (released by the kernel when the
    process dies) plus its holder's pid, host and start time for the refusal message
    (``seg2pose.core.locks.KernelLock``)."""

    def __init__(self, folder: Path, scene_name: str):
        self.path = folder / "lock"
        self.note: str | None = None
        refuse_links(self.path)  # annotations/ itself a link: refused, like a linked lock file

        def busy(h: LockHolder | None) -> LockedError:
            who = f"pid {h.pid} on {h.host} since {h.since}" if h else "another process"
            return LockedError(f"scene {scene_name!r} is being annotated by {who} ({self.path}); "
                               "close that session or open the project read-only")

        self._lock = KernelLock(self.path, busy)
        old = self._lock.previous
        if old:
            state = "no longer runs" if old.gone else "holds no lock any more"
            self.note = (f"took over the lock of pid {old.pid} on {old.host} "
                         f"(since {old.since}), which {state}")

    def release(self) -> None:
        """Clear the holder and release the lock (the file stays: others may wait on it)."""
        self._lock.release()


def load_json(path: Path) -> dict:
    try:
        d = json.loads(path.read_bytes())
    except (OSError, ValueError) as e:
        raise JournalError(f"{path}: cannot read the snapshot: {e}") from None
    if not isinstance(d, dict):
        raise JournalError(f"{path}: expected a JSON object")
    return d


def check_header(rec: dict, path: Path, fingerprint: str) -> None:
    """Refuse a journal or snapshot of a newer format or of another scene."""
    version = rec.get("version")
    if version != VERSION:
        raise JournalError(f"{path}: journal version {version!r}; this s2p reads version {VERSION}")
    if rec.get("fingerprint") != fingerprint:
        raise JournalError(
            f"{path}: this journal belongs to scene {rec.get('scene')!r} with calibration and "
            f"ground fingerprint {rec.get('fingerprint')}, but this scene's is {fingerprint}; "
            "annotations of another scene (or of a recalibrated one) are not replayed")
