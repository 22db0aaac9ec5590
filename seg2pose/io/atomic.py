"""Atomic outputs: nothing half-written under a final name, nothing replaced without ``force``,
one writer at a time, and the leftovers of killed writers cleaned up.

- ``atomic_open`` / ``atomic_write_text`` / ``atomic_path``: one file, written as a temporary
  sibling and renamed over the final name.
- ``replacing(path, force)``: a whole output (a folder or a file) built beside the final name
  and swapped in as a unit; with ``force`` the old output is exchanged with the new one in one
  step (``renameat2(RENAME_EXCHANGE)`` on Linux; elsewhere: moved aside, new renamed in, old
  removed) and removed only after that. An existing output is never merged with a new one.
- ``output_lock(path)``: ``.NAME.lock`` beside the output holds the writer's pid; a second
  writer is refused; the lock of a process that no longer runs is taken over with a note.
- Temporary siblings are named ``.NAME.partial-PID-...``: ``clean_stale_partials`` removes
  those of processes that no longer run (a killed writer's leftovers), every time a new
  output of that name is started.
- ``outputs(paths, force)``: the outputs of one command as a set (``OutputSet``): every one
  locked and checked before anything is written, each built beside its final name (a file in
  a partial folder of its own, so that a library's own temporaries and a multi-stage build's
  intermediate results stay there too), swapped in at the end; a set swapped in together
  records its swaps first (``.NAME.commit-PID.json`` in every folder of the set), so that a
  writer killed between two swaps is finished by the next writer of any of its outputs.
- ``os_errors(path)``: disk full, a file where a folder should be, a read-only folder: an
  S2PError naming the output and the cause (one line in the CLI) instead of a traceback.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import json
import os
import re
import shutil
import tempfile
from pathlib import Path
from typing import IO, Iterator

from seg2pose.core.errors import S2PError
from seg2pose.core.locks import ExclusiveLock, LockHolder, pid_alive
from seg2pose.core.say import say

_PARTIAL = re.compile(r"^\.(?P<name>.+)\.(?:partial|old)-(?P<pid>\d+)(?:[-.].*)?$")
_COMMIT = re.compile(r"^\.(?P<name>.+)\.commit-(?P<pid>\d+)\.json$")


def _owner(name: str) -> tuple[str, list[int]] | None:
    """The final name a temporary sibling belongs to and the pids in its name, also for the
    temporaries of temporaries (``..NAME.partial-1-x.partial-1-y.tmp``: a library's atomic
    write of a file that is itself being built); None for other names."""
    pids = []
    m = _PARTIAL.match(name)
    while m:
        name = m.group("name")
        pids.append(int(m.group("pid")))
        m = _PARTIAL.match(name)
    return (name, pids) if pids else None


def is_temporary(name: str) -> bool:
    """Whether a file or folder name is one of the hidden things a writer keeps beside an
    output while it writes (``.NAME.partial-PID-...``, ``.NAME.old-PID-...``, ``.NAME.lock``,
    ``.NAME.commit-PID.json``): never part of an output."""
    return (_owner(name) is not None or _COMMIT.match(name) is not None
            or (name.startswith(".") and name.endswith(".lock")))


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _prefix(path: Path) -> str:
    return f".{path.name}.partial-{os.getpid()}-"


def _temp_sibling(path: Path, suffix: str) -> tuple[int, str]:
    """mkstemp in the target's folder, with the permissions a plain open() would give
    (mkstemp makes 0600 files, which other users of a shared scene folder could not read)."""
    fd, tmp = tempfile.mkstemp(prefix=_prefix(path), suffix=suffix, dir=path.parent)
    os.chmod(tmp, 0o666 & ~_umask())
    return fd, tmp


def clean_stale_partials(path: str | Path) -> list[Path]:
    """Remove the temporary siblings ``.NAME.partial-PID...`` / ``.NAME.old-PID...`` of
    ``path`` left by processes that no longer run. Returns what was removed."""
    path = Path(path)
    removed = []
    try:
        entries = list(os.scandir(path.parent))
    except OSError:
        return removed
    for e in entries:
        own = _owner(e.name)
        if own is None or own[0] != path.name:
            continue
        try:  # a process that started after this was last written is not its writer
            written = e.stat(follow_symlinks=False).st_mtime
        except OSError:
            continue
        if any(pid_alive(p, written) for p in own[1]):
            continue
        p = Path(e.path)
        with contextlib.suppress(OSError):
            if e.is_dir(follow_symlinks=False):
                shutil.rmtree(p)
            else:
                p.unlink()
            removed.append(p)
    return removed


def temp_sibling_dir(path: str | Path) -> Path:
    """A new empty folder beside ``path`` to build a whole output folder in before renaming
    it into place (mkdtemp's 0700 widened to what mkdir would give). Stale ones of killed
    processes are removed first."""
    path = Path(path)
    with os_errors(path):
        path.parent.mkdir(parents=True, exist_ok=True)
        clean_stale_partials(path)
        tmp = Path(tempfile.mkdtemp(prefix=_prefix(path), dir=path.parent))
        os.chmod(tmp, 0o777 & ~_umask())
    return tmp


def fsync_dir(path: str | Path) -> None:
    """Make the creation, rename or removal of a file in folder ``path`` durable (best effort:
    some file systems cannot fsync a folder)."""
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def check_writable(path: str | Path, force: bool) -> Path:
    """Refuse to replace an existing file or non-empty folder unless ``force``."""
    path = Path(path)
    if force or not (path.exists() or path.is_symlink()):
        return path
    if path.is_dir() and not path.is_symlink():
        with contextlib.suppress(OSError), os.scandir(path) as it:
            if next(it, None) is None:
                return path  # an empty folder: nothing to lose
    raise S2PError(f"{path} exists; pass --force to replace it")


# ----------------------------------------------------------------------------------------------
# errors of the operating system, as one line


_OS_CAUSES = {
    errno.ENOSPC: "the disk is full",
    errno.EDQUOT: "the disk quota is exceeded",
    errno.EROFS: "the file system is read-only",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.ENOTDIR: "a file is in the way where a folder is needed",
    errno.EEXIST: "a file is in the way where a folder is needed",
    errno.EISDIR: "a folder is in the way where a file is needed",
    errno.ENAMETOOLONG: "the name is too long",
    errno.EIO: "an input/output error of the disk",
}


def final_name(path: str | Path) -> str:
    """``path`` with temporary siblings (``.NAME.partial-PID-...``) named by their final
    name: what the user asked for, not where it was being built."""
    out: list[str] = []
    in_partial = False
    for p in Path(path).parts:
        own = _owner(p)
        if own is None and in_partial and out[-1] == p:
            in_partial = False
            continue  # NAME built as .NAME.partial-PID-x/NAME (OutputSet.file): the output itself
        in_partial = own is not None
        out.append(own[0] if own else p)
    return str(Path(*out)) if out else str(path)


def os_error_message(e: OSError, path: str | Path | None = None) -> str:
    """One line: the output, the cause in words, and the file the system named."""
    cause = _OS_CAUSES.get(e.errno, e.strerror or type(e).__name__)
    fname = final_name(e.filename) if e.filename else None
    if path is None:
        return f"{fname or '?'}: {cause}"
    path = final_name(path)
    where = f" ({fname})" if fname and fname != path else ""
    return f"cannot write {path}: {cause}{where}"


@contextlib.contextmanager
def os_errors(path: str | Path) -> Iterator[None]:
    """Turn an OSError while writing the output ``path`` into an S2PError naming it."""
    try:
        yield
    except S2PError:
        raise
    except OSError as e:
        raise S2PError(os_error_message(e, path)) from e


# ----------------------------------------------------------------------------------------------
# single files


@contextlib.contextmanager
def atomic_open(path: str | Path, mode: str = "w", **kwargs) -> Iterator[IO]:
    """Open a temporary sibling of ``path`` for writing; rename it to ``path`` on success."""
    path = Path(path)
    with os_errors(path):
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = _temp_sibling(path, ".tmp")
    try:
        with os_errors(path), os.fdopen(fd, mode, **kwargs) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        with os_errors(path):
            os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def atomic_write_text(path: str | Path, text: str) -> None:
    with atomic_open(path, "w", encoding="utf-8", newline="") as f:
        f.write(text)


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    with atomic_open(path, "wb") as f:
        f.write(data)


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary sibling path for libraries that write files themselves; renamed on success."""
    path = Path(path)
    with os_errors(path):
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = _temp_sibling(path, path.suffix or ".tmp")
        os.close(fd)
    try:
        with os_errors(path):
            yield Path(tmp)
            # the library may have replaced our file with a private one of its own
            os.chmod(tmp, 0o666 & ~_umask())
            os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


# ----------------------------------------------------------------------------------------------
# whole outputs: lock, build beside, swap in


def lock_path(path: str | Path) -> Path:
    path = Path(path)
    return path.with_name(f".{path.name}.lock")


@contextlib.contextmanager
def output_lock(path: str | Path) -> Iterator[Path]:
    """Hold ``.NAME.lock`` beside ``path`` while writing it (``seg2pose.core.locks``). A live
    holder makes this raise S2PError naming it; the lock of a process on this machine that no
    longer runs is taken over with a note."""
    path = Path(path)
    with os_errors(path):
        path.parent.mkdir(parents=True, exist_ok=True)
    lock = lock_path(path)

    def busy(h: LockHolder) -> S2PError:
        return S2PError(f"{path} is being written by process {h.pid} on {h.host or '?'} since "
                        f"{h.since}; wait for it to finish (or remove {lock} if that process is gone)")

    def taken_over(h: LockHolder | None) -> None:
        say(f"taking over the lock {lock} of process {h.pid if h else -1}, which no longer runs "
            f"(it started writing {path} at {h.since if h else '?'})", kind="note")

    held = ExclusiveLock(lock, busy, taken_over)
    with os_errors(path):
        if not held.acquire():
            raise S2PError(f"could not take the lock {lock} of {path}")
    try:
        yield lock
    finally:
        held.release()


def _exchange(a: Path, b: Path) -> bool:
    """Swap the names ``a`` and ``b`` in one step (Linux renameat2 RENAME_EXCHANGE); False
    where the system cannot."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    AT_FDCWD, RENAME_EXCHANGE = -100, 2
    renameat2.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    if renameat2(AT_FDCWD, os.fsencode(a), AT_FDCWD, os.fsencode(b), RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP):
        return False
    raise OSError(err, os.strerror(err), str(a))


def _remove(p: Path) -> None:
    if p.is_dir() and not p.is_symlink():
        shutil.rmtree(p, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            p.unlink()


def swap_in(tmp: Path, path: Path) -> None:
    """Put the finished ``tmp`` (file or folder) at ``path`` as a unit; an existing ``path``
    is exchanged with it in one step where possible, and removed only afterwards."""
    fsync_dir(tmp if tmp.is_dir() else tmp.parent)
    if path.exists() or path.is_symlink():
        if _exchange(tmp, path):
            _remove(tmp)  # now the old output
        else:
            old = path.parent / f".{path.name}.old-{os.getpid()}"
            _remove(old)
            os.replace(path, old)
            os.replace(tmp, path)
            _remove(old)
    else:
        os.replace(tmp, path)
    fsync_dir(path.parent)


@contextlib.contextmanager
def replacing(path: str | Path, force: bool = False, folder: bool = True) -> Iterator[Path]:
    """Build the single output ``path`` (a folder, or a file when ``folder`` is False) where
    this yields, then swap it in as a unit (``outputs`` with one output: locked, refused when
    it exists unless ``force``; on any error or interruption ``path`` is as it was)."""
    with outputs([path], force) as out:
        yield out.folder(path) if folder else out.file(path)


# ----------------------------------------------------------------------------------------------
# the outputs of one command, as a set


def _commit_path(path: Path, pid: int | None = None) -> Path:
    return path.parent / f".{path.name}.commit-{os.getpid() if pid is None else pid}.json"


def _record_paths(finals: list[Path], pid: int | None = None) -> list[Path]:
    """Where a set's commit record lies: one copy in every folder of the set's outputs, named
    after the first output in that folder, so that a writer of any one output finds it."""
    first = {}
    for p in finals:
        first.setdefault(p.parent, p)
    return [_commit_path(p, pid) for p in first.values()]


def _swap(tmp: Path, path: Path) -> Path | None:
    """Put the build ``tmp`` at ``path``: an existing output is exchanged with it in one step
    (the old one is then under ``tmp``'s name; ``path`` is never absent), else moved aside
    (``.NAME.old-PID-x``) where the system cannot exchange. Returns where the old output now
    is (None: there was none)."""
    if path.exists() or path.is_symlink():
        if _exchange(tmp, path):
            return tmp
        old = path.parent / f".{path.name}.old-{os.getpid()}-{os.urandom(3).hex()}"
        os.replace(path, old)
        os.replace(tmp, path)
        return old
    os.replace(tmp, path)
    return None


def _read_record(path: Path) -> list[tuple[Path, Path, int | None]] | None:
    """A commit record's (build, output, build's inode) triples; None when torn (cut by a kill
    while it was written: before any swap, so none was done)."""
    try:
        rows = json.loads(path.read_text(encoding="utf-8"))
        return [(Path(r[0]), Path(r[1]), int(r[2]) if len(r) > 2 else None) for r in rows]
    except (OSError, ValueError, TypeError, IndexError):
        return None


def finish_commits(path: str | Path) -> list[Path]:
    """Finish the set commits that writers killed among their swaps recorded
    (``.NAME.commit-PID.json`` beside ``path``, of any set that ``path`` is an output of):
    every build still under its partial name (the inode the record names) is swapped in, so
    the set is the new one as a whole; the old outputs and the records are removed. A set
    whose records are not all there and whole was killed before its first swap or after its
    last: its records are removed (its builds are dead partials). Returns the outputs
    swapped in now."""
    path = Path(path)
    done = []
    try:
        entries = list(os.scandir(path.parent))
    except OSError:
        return done
    for e in entries:
        m = _COMMIT.match(e.name)
        if not m:
            continue
        try:
            written = e.stat(follow_symlinks=False).st_mtime
        except OSError:
            continue
        if pid_alive(int(m.group("pid")), written):
            continue
        rows = _read_record(Path(e.path))
        if rows is None:
            with contextlib.suppress(OSError):
                os.unlink(e.path)
            continue
        finals = [final for _, final, _ in rows]
        if path not in finals:
            continue  # another set's, finished by a writer of its outputs
        records = _record_paths(finals, int(m.group("pid")))
        if rows[0][2] is not None and any(_read_record(r) != rows for r in records):
            # a copy missing or torn: the writer died while recording (no swap was done yet)
            # or after its swaps, while removing the records: nothing to finish either way
            for r in records:
                with contextlib.suppress(OSError):
                    os.unlink(r)
            continue
        olds = []
        for tmp, final, ino in rows:
            try:
                built = os.lstat(tmp).st_ino == ino or ino is None
            except OSError:
                continue  # swapped in, and its old output removed
            if built:  # not swapped in yet
                try:
                    olds.append(_swap(tmp, final))
                except FileNotFoundError:
                    continue  # another writer of the set finished it meanwhile
                done.append(final)
            else:  # swapped in: what is under the build's name is the old output
                olds.append(tmp)
        for d in dict.fromkeys(final.parent for _, final, _ in rows):
            fsync_dir(d)
        for r in records:
            with contextlib.suppress(OSError):
                os.unlink(r)
        for old in olds:
            if old is not None:
                _remove(old)
        for tmp, _, _ in rows:
            _remove_partial_folder(tmp)
    return done


def _remove_partial_folder(tmp: Path) -> None:
    # OutputSet.file builds NAME in .NAME.partial-PID-x/: that folder goes once NAME is in place
    own = _owner(tmp.parent.name)
    if own is not None and tmp.parent.exists() and (own[0] == tmp.name or not tmp.exists()):
        _remove(tmp.parent)


class OutputSet:
    """The outputs of one command (``outputs``): ``file(path)`` / ``folder(path)`` give where
    to build each one; ``commit(path)`` swaps one in as soon as it is complete, and leaving
    the ``with`` block swaps in all the rest together. Anything not committed when an error
    or interruption ends the block is removed; the old outputs are then as they were."""

    def __init__(self, paths: list[Path]):
        self.paths = paths
        self.built: dict[Path, Path] = {}  # final -> where it is being built
        self.parts: list[Path] = []        # temporary siblings to remove on failure

    def _check(self, path) -> Path:
        path = Path(path)
        if path not in self.paths:
            raise ValueError(f"{path} is not one of this command's outputs {self.paths}")
        return path

    def file(self, path: str | Path) -> Path:
        """A path named like ``path`` inside a new partial folder beside it: stages and
        libraries may write and rewrite it (their own temporaries stay in that folder)."""
        path = self._check(path)
        with os_errors(path):
            tmp = Path(tempfile.mkdtemp(prefix=_prefix(path), dir=path.parent))
            os.chmod(tmp, 0o777 & ~_umask())
        self.parts.append(tmp)
        self.built[path] = tmp / path.name
        return self.built[path]

    def folder(self, path: str | Path) -> Path:
        """A new empty folder beside ``path`` to build the output folder in."""
        path = self._check(path)
        tmp = temp_sibling_dir(path)
        self.parts.append(tmp)
        self.built[path] = tmp
        return tmp

    def adopt(self, path: str | Path, built: str | Path) -> None:
        """Take ``built`` (a file a library wrote inside one of this set's partial folders,
        e.g. a layout beside an export) as the build of the output ``path``."""
        path, built = self._check(path), Path(built)
        if not any(t in built.parents for t in self.parts):
            raise ValueError(f"{built} is not inside a partial folder of this set")
        self.built[path] = built

    def commit(self, *paths: str | Path) -> None:
        """Swap in ``paths`` (default: every output built and not yet swapped in). One output
        is exchanged with the old one in one step (``swap_in``). Several are made durable
        first, then recorded (a record in each of their folders), then each exchanged with its
        old output one after another with nothing else between (microseconds: the only time
        the set is part old, part new, each output whole); a writer killed among those swaps
        is finished by the next writer of any output of the set (``finish_commits``)."""
        todo = [self._check(p) for p in paths] if paths else list(self.built)
        todo = [p for p in todo if p in self.built]
        if not todo:
            return
        with os_errors(todo[0]):
            for p in todo:
                tmp = self.built[p]
                if not (tmp.exists() or tmp.is_symlink()):
                    raise S2PError(f"{p} was not written")
                if tmp.is_file():
                    with open(tmp, "rb") as f:
                        os.fsync(f.fileno())
                fsync_dir(tmp if tmp.is_dir() else tmp.parent)
            if len(todo) == 1:
                tmp = self.built.pop(todo[0])
                swap_in(tmp, todo[0])
                _remove_partial_folder(tmp)
                return
            # the record, beside every output's folder (written in place: a torn one was cut
            # before any swap, so means none), made durable before the first swap
            builds = [self.built.pop(p) for p in todo]
            rows = json.dumps([[str(t), str(p), os.lstat(t).st_ino] for t, p in zip(builds, todo)])
            records = _record_paths(todo)
            for record in records:
                with open(record, "w", encoding="utf-8") as f:
                    f.write(rows)
                    f.flush()
                    os.fsync(f.fileno())
            for record in records:
                fsync_dir(record.parent)
            # each output exchanged with its build, one after another with nothing between:
            # every output stays whole (old or new); a writer killed among these swaps is
            # finished by the next writer of any output of the set (finish_commits)
            olds = [_swap(tmp, p) for tmp, p in zip(builds, todo)]
            for d in dict.fromkeys(p.parent for p in todo):
                fsync_dir(d)
            for record in records:
                os.unlink(record)
            for record in records:
                fsync_dir(record.parent)
            for old in olds:
                if old is not None:
                    _remove(old)
            for tmp in builds:  # after all swaps: a build may lie in another one's folder
                _remove_partial_folder(tmp)

    def discard(self) -> None:
        for tmp in self.parts:
            _remove(tmp)


@contextlib.contextmanager
def outputs(paths, force: bool = False) -> Iterator[OutputSet]:
    """The outputs ``paths`` (files or folders) of one command: each locked (``output_lock``)
    and checked (``check_writable``) before anything is written, a killed writer's set
    finished and its partial builds removed; yields an ``OutputSet`` to build them in, swapped
    in as a set when the block ends (those not committed earlier)."""
    paths = list(dict.fromkeys(Path(p) for p in paths))
    with contextlib.ExitStack() as stack:
        for p in paths:
            stack.enter_context(output_lock(p))
        for p in paths:
            finish_commits(p)
        for p in paths:
            check_writable(p, force)
        for p in paths:
            clean_stale_partials(p)
        out = OutputSet(paths)
        try:
            yield out
            out.commit()
            out.discard()  # partial folders of outputs swapped in: empty by now
        except BaseException:
            out.discard()
            raise
