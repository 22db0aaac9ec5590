"""An append-only JSON-lines log kept crash-safe, as the annotation journal is: each record is
one ``write`` of one line, fsync'ed before it is acknowledged; a failed write is cut off again;
a torn last line (a crash mid-write) is reported and skipped when read, and cut off (kept
aside in ``<name>.torn-<time>``) before the next append. One writer at a time: a kernel lock
(``<name>.lock``, core/locks.py) held while the log is open.

What the calibration page's clicked pairs are kept in (annotate/app/calib_state.py).
"""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path

from seg2pose.core.clock import utc_stamp
from seg2pose.core.errors import S2PError
from seg2pose.core.locks import KernelLock, LockHolder
from seg2pose.io.atomic_set import fsync_dir


def read_log(path: str | Path) -> tuple[list[dict], int, str | None]:
    """(records, bytes of whole lines, a note about a torn last line or None). A bad line
    before the last one is damage: S2PError naming the file and line."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return [], 0, None
    lines = data.split(b"\n")
    tail = lines.pop()  # b"" when the file ends with a newline
    records, good = [], 0
    for i, line in enumerate(lines):
        try:
            rec = json.loads(line)
            if not isinstance(rec, dict):
                raise ValueError
        except (ValueError, UnicodeDecodeError):
            if i == len(lines) - 1 and not tail:
                tail = line  # a torn write whose newline got through
                break
            raise S2PError(f"{path}:{i + 1}: not a JSON object; the log is damaged before its "
                           "last line") from None
        records.append(rec)
        good += len(line) + 1
    note = None
    if tail.strip():
        note = f"{path.name}:{len(records) + 1}: the last line is torn ({len(tail)} bytes); it is skipped"
    return records, good, note


class AppendLog:
    """The log at ``path`` opened for appending under its lock (``close`` releases both)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)

        def busy(h: LockHolder | None) -> S2PError:
            who = f"process {h.pid} on {h.host or '?'} since {h.since}" if h else "another process"
            return S2PError(f"{self.path} is open in {who}; close that page first")

        self.lock = KernelLock(self.path.with_name(self.path.name + ".lock"), busy)
        self.records, good, self.note = read_log(self.path)
        if self.note is not None:  # keep the torn tail aside, then cut it off
            data = self.path.read_bytes()
            keep = self.path.with_name(f"{self.path.name}.torn-{utc_stamp(microseconds=True)}")
            fd = os.open(keep, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o666)
            try:
                os.write(fd, data[good:])
                os.fsync(fd)
            finally:
                os.close(fd)
            os.truncate(self.path, good)
        self.fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_NOFOLLOW, 0o666)
        self.size = os.fstat(self.fd).st_size
        fsync_dir(self.path.parent)

    def append(self, record: dict) -> None:
        """Write one record durably; on failure the file is cut back and S2PError raised."""
        data = json.dumps(record, separators=(",", ":"), allow_nan=False).encode() + b"\n"
        try:
            n = os.write(self.fd, data)
            while n < len(data):
                n += os.write(self.fd, data[n:])
            os.fsync(self.fd)
        except OSError as e:
            why = "the disk is full" if e.errno in (errno.ENOSPC, errno.EDQUOT) else e.strerror
            try:
                os.ftruncate(self.fd, self.size)
            except OSError:
                pass
            raise S2PError(f"{self.path}: not saved: {why}") from None
        self.size += len(data)
        self.records.append(record)

    def close(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1
            self.lock.release()
