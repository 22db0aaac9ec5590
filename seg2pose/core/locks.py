"""Locks: one holder record, one "does that process still run" check and one take-over rule for
every lock of s2p.

A lock file holds its holder's record (``LockHolder``: pid, host, since). A holder on this
machine whose process no longer runs is gone: its lock is taken over with a note. Two ways of
holding a lock file, each where its property is needed:

- ``ExclusiveLock``: the file is created exclusively (``O_EXCL``) and removed on release, so it
  is seen from every host that sees the folder (a study on a shared disk, batch runs on Ray).
  The output lock of seg2pose.io.atomic (``.NAME.lock`` beside each output).
- ``KernelLock``: ``flock`` on a file that stays, released by the kernel however its holder
  dies; the record only names the holder. The annotation journal (annotate.journal), whose
  writer is an interactive session that may hold it for hours and be killed at any time.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import socket
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from seg2pose.core.clock import utc_now
from seg2pose.core.errors import S2PError


def pid_alive(pid: int, since: float | None = None) -> bool:
    """Whether a process ``pid`` runs on this machine. A zombie (ended, not yet collected by
    its parent: e.g. a killed Ray worker whose new parent, a container's first process, is
    slow to collect it) does not run: it holds nothing any more. ``since``: when the process
    was known to run (a lock's time, a file's modification time, seconds since the epoch); a
    process with that pid that started later is another one (pids are reused: 32,768 of them
    on many machines) and does not count."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, another user's
        pass
    except OverflowError:
        return False
    if _zombie(pid):
        return False
    if since is not None:
        started = _start_time(pid)
        if started is not None and started > since + _CLOCK_SLACK:
            return False
    return True


_CLOCK_SLACK = 2.0  # s: lock times are whole seconds, the boot time too


def _start_time(pid: int) -> float | None:
    """Linux: when process ``pid`` started, seconds since the epoch (None elsewhere)."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            ticks = int(f.read().rsplit(b")", 1)[1].split()[19])
        with open("/proc/stat", "rb") as f:
            boot = next(int(line.split()[1]) for line in f if line.startswith(b"btime "))
        return boot + ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError, StopIteration):
        return None


def _zombie(pid: int) -> bool:
    """Linux: the process has ended and waits to be collected (state Z or X in /proc)."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            return f.read().rsplit(b")", 1)[1].split()[0] in (b"Z", b"X")
    except (OSError, IndexError):
        return False


def _epoch(iso: str) -> float | None:
    """An ISO 8601 time (a holder's ``since``) in seconds since the epoch; None when it is not
    one ('?', or without a zone)."""
    import datetime as dt

    try:
        t = dt.datetime.fromisoformat(iso.replace("Z", "+00:00"))
    except (ValueError, AttributeError):
        return None
    return t.timestamp() if t.tzinfo is not None else None


@dataclass(frozen=True)
class LockHolder:
    """Who holds a lock: process ``pid`` on ``host`` since ``since`` (ISO 8601, UTC)."""

    pid: int
    host: str
    since: str = "?"

    @classmethod
    def me(cls, timespec: str = "seconds") -> LockHolder:
        return cls(os.getpid(), socket.gethostname(), utc_now(timespec))

    @classmethod
    def parse(cls, text: str | bytes) -> LockHolder | None:
        """The record of a lock file, or None when it holds none (empty, or cut short by a
        kill between creating and filling it). ``time`` is the older files' name of ``since``."""
        try:
            d = json.loads(text)
            return cls(int(d["pid"]), str(d["host"]), str(d.get("since", d.get("time", "?"))))
        except (ValueError, KeyError, TypeError):
            return None

    def to_json(self) -> str:
        return json.dumps({"pid": self.pid, "host": self.host, "since": self.since})

    @property
    def gone(self) -> bool:
        """A holder on this machine whose process no longer runs (its lock may be taken over)."""
        return self.host == socket.gethostname() and not pid_alive(self.pid, _epoch(self.since))


def _planted_link(path: Path) -> S2PError:
    """A lock's name planted as a link: refused, never read or written through (core sits below
    io, so this is nofollow.link_message's wording for locks)."""
    return S2PError(f"{path} is a symbolic link; s2p does not write through links inside a scene "
                    "or output folder (remove it)")


class ExclusiveLock:
    """Hold the lock file ``path`` (created exclusively, removed on release). A live holder
    makes ``acquire`` raise ``busy(holder)``; a gone one (or a file without a record, from a
    holder killed while writing it) is taken over after ``taken_over(holder)``. OSErrors pass
    through: the caller names its output in them."""

    def __init__(self, path: Path, busy: Callable[[LockHolder], Exception],
                 taken_over: Callable[[LockHolder | None], None] = lambda holder: None):
        self.path, self.busy, self.taken_over = Path(path), busy, taken_over

    def acquire(self) -> bool:
        """Take the lock; False when it was released and re-taken by others three times
        over while this tried."""
        me = LockHolder.me()
        for attempt in range(3):
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY | os.O_NOFOLLOW, 0o644)
            except FileExistsError:
                if self.path.is_symlink():  # planted: never read through it (a FIFO, /dev/zero)
                    raise _planted_link(self.path) from None
                try:
                    text = self.path.read_text(encoding="utf-8", errors="replace")
                except FileNotFoundError:
                    continue  # released meanwhile
                holder = LockHolder.parse(text)
                if (holder is None or holder.gone) and attempt < 2:
                    self.taken_over(holder)
                    with contextlib.suppress(FileNotFoundError):
                        if self.path.read_text(encoding="utf-8", errors="replace") == text:
                            self.path.unlink()
                    continue
                raise self.busy(holder or LockHolder(-1, me.host)) from None
            try:
                with os.fdopen(fd, "w", encoding="utf-8") as f:
                    f.write(me.to_json() + "\n")
            except BaseException:
                with contextlib.suppress(OSError):
                    self.path.unlink()
                raise
            return True
        return False

    def release(self) -> None:
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()


class KernelLock:
    """``flock`` on ``path`` (the file stays: others may wait on it) with the holder's record
    in it. A held lock makes the constructor raise ``busy(holder or None)``; ``previous`` is
    the record a holder left behind without releasing (killed), else None."""

    def __init__(self, path: Path, busy: Callable[[LockHolder | None], Exception],
                 timespec: str = "milliseconds"):
        self.path = Path(path)
        try:  # never through a link planted under the lock's name (it would be truncated)
            self.fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o666)
        except OSError as e:
            if e.errno == errno.ELOOP:
                raise _planted_link(self.path) from None
            raise
        try:
            fcntl.flock(self.fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = self.holder()
            os.close(self.fd)
            self.fd = -1
            raise busy(holder) from None
        self.previous = self.holder()
        os.ftruncate(self.fd, 0)
        os.pwrite(self.fd, LockHolder.me(timespec).to_json().encode(), 0)
        os.fsync(self.fd)

    def holder(self) -> LockHolder | None:
        try:
            with open(self.path, "rb") as f:
                return LockHolder.parse(f.read() or b"{}")
        except OSError:
            return None

    def release(self) -> None:
        """Clear the record and release the lock (idempotent)."""
        if self.fd < 0:
            return
        with contextlib.suppress(OSError):
            os.ftruncate(self.fd, 0)
        fcntl.flock(self.fd, fcntl.LOCK_UN)
        os.close(self.fd)
        self.fd = -1
