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

The names of the temporaries are ``seg2pose.io.atomic_names``'s; the swaps, and the commit
record of a set and its recovery, ``seg2pose.io.atomic_set``'s. Their public names are
importable from here too (``__all__``).
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO

from seg2pose.core.errors import S2PError
from seg2pose.core.locks import ExclusiveLock, LockHolder
from seg2pose.core.say import say
from seg2pose.io.atomic_names import clean_stale_partials, final_name, is_temporary, lock_path, partial_prefix
from seg2pose.io.atomic_set import commit_set, finish_commits, fsync_dir, remove_partial_folder, remove_path, swap_in
from seg2pose.io.kill_points import commit_entry, commit_step
from seg2pose.io.nofollow import refuse_links

__all__ = ["atomic_open", "atomic_path", "atomic_write_bytes", "atomic_write_text",
           "check_writable", "clean_stale_partials", "final_name", "finish_commits", "fsync_dir",
           "is_temporary", "lock_path", "os_error_message", "os_errors", "output_lock",
           "OutputSet", "outputs", "replacing", "swap_in", "temp_sibling_dir", "rename", "link_or_copy",
           "unfinished_outputs", "copy_tree", "holding"]


# ----------------------------------------------------------------------------------------------
# temporary siblings


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _temp_sibling(path: Path, suffix: str) -> tuple[int, str]:
    """mkstemp in the target's folder, with the permissions a plain open() would give
    (mkstemp makes 0600 files, which other users of a shared scene folder could not read)."""
    fd, tmp = tempfile.mkstemp(prefix=partial_prefix(path), suffix=suffix, dir=path.parent)
    os.chmod(tmp, 0o666 & ~_umask())
    return fd, tmp


def temp_sibling_dir(path: str | Path) -> Path:
    """A new empty folder beside ``path`` to build a whole output folder in before renaming
    it into place (mkdtemp's 0700 widened to what mkdir would give). Stale ones of killed
    processes are removed first."""
    path = Path(path)
    refuse_links(path)  # a linked folder: the file would land where the link points
    with os_errors(path):
        path.parent.mkdir(parents=True, exist_ok=True)
        clean_stale_partials(path)
        tmp = Path(tempfile.mkdtemp(prefix=partial_prefix(path), dir=path.parent))
        os.chmod(tmp, 0o777 & ~_umask())
    return tmp


def check_writable(path: str | Path, force: bool) -> Path:
    """Refuse to replace an existing file or non-empty folder unless ``force``, and an output
    in a folder that is a link (``nofollow.refuse_links``)."""
    path = Path(path)
    refuse_links(path)
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


def os_error_message(e: OSError, path: str | Path | None = None) -> str:
    """One line: the output, the cause in words, and the file the system named."""
    cause = _OS_CAUSES.get(e.errno or 0, e.strerror or type(e).__name__)
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
    refuse_links(path)  # a linked folder: the file would land where the link points
    with os_errors(path):
        path.parent.mkdir(parents=True, exist_ok=True)
        clean_stale_partials(path)  # a killed writer's, left for good before
        fd, tmp = _temp_sibling(path, ".tmp")
    try:
        with os_errors(path), os.fdopen(fd, mode, **kwargs) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        with os_errors(path):
            _replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _replace(tmp: str, path: Path) -> None:
    """Put the finished file ``tmp`` at ``path`` in one step (the kill tests' commit steps
    around it: io/kill_points.py)."""
    commit_entry([("built", 1), ("swapped", 1)], [Path(tmp)], [path])
    commit_step("built")
    os.replace(tmp, path)
    commit_step("swapped")
    commit_step("done")


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
    refuse_links(path)  # a linked folder: the file would land where the link points
    with os_errors(path):
        path.parent.mkdir(parents=True, exist_ok=True)
        clean_stale_partials(path)  # a killed writer's (.r.rrd.partial-PID-x.rrd), left for good before
        fd, tmp = _temp_sibling(path, path.suffix or ".tmp")
        os.close(fd)
    try:
        with os_errors(path):
            yield Path(tmp)
            # the library may have replaced our file with a private one of its own
            os.chmod(tmp, 0o666 & ~_umask())
            _replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


# ----------------------------------------------------------------------------------------------
# whole outputs: lock, build beside, swap in


@contextlib.contextmanager
def output_lock(path: str | Path, _hold: bool = False) -> Iterator[Path]:
    """Hold ``.NAME.lock`` beside ``path`` while writing it (``seg2pose.core.locks``). A live
    holder makes this raise S2PError naming it (this process too, unless it holds the lock
    through ``holding``); the lock of a process on this machine that no longer runs is taken
    over with a note."""
    path = Path(path)
    refuse_links(path)  # a linked folder: the lock and the output would land where it points
    with os_errors(path):
        path.parent.mkdir(parents=True, exist_ok=True)
    lock = lock_path(path)

    def busy(h: LockHolder) -> S2PError:
        return S2PError(f"{path} is being written by process {h.pid} on {h.host or '?'} since "
                        f"{h.since}; wait for it to finish (or remove {lock} if that process is gone)")

    def taken_over(h: LockHolder | None) -> None:
        say(f"taking over the lock {lock} of process {h.pid if h else -1}, which no longer runs "
            f"(it started writing {path} at {h.since if h else '?'})", kind="note")

    key = os.path.abspath(lock)
    if key in _held:  # held from the command's start (``holding``): the writer it calls at the
        yield lock    # end locks it again
        return
    held = ExclusiveLock(lock, busy, taken_over)
    with os_errors(path):
        if not held.acquire():
            raise S2PError(f"could not take the lock {lock} of {path}")
    if _hold:
        _held.add(key)
    try:
        yield lock
    except BaseException:
        _unfinished.append(path)  # for the command's one line: which output was cut short
        raise
    finally:
        _held.discard(key)
        held.release()


@contextlib.contextmanager
def holding(*paths: str | Path | None) -> Iterator[None]:
    """Lock the outputs ``paths`` (None: skipped) from the start of a command's work, not only
    for its final write: a second writer is refused before it computes anything. The writers
    this process calls inside take the same locks again without waiting on themselves."""
    with contextlib.ExitStack() as stack:
        for p in paths:
            if p is not None:
                stack.enter_context(output_lock(p, _hold=True))
        yield


_held: set[str] = set()  # the output locks this process holds through ``holding``
_unfinished: list[Path] = []


def unfinished_outputs(forget: bool = False) -> list[Path]:
    """The outputs whose writing an error or interruption ended in this process (their old
    state is kept), most recent last: what a command's error line names. ``forget``: start
    afresh (a command's start, in a process that runs several)."""
    out = list(dict.fromkeys(_unfinished))
    if forget:
        _unfinished.clear()
    return out


@contextlib.contextmanager
def replacing(path: str | Path, force: bool = False, folder: bool = True) -> Iterator[Path]:
    """Build the single output ``path`` (a folder, or a file when ``folder`` is False) where
    this yields, then swap it in as a unit (``outputs`` with one output: locked, refused when
    it exists unless ``force``; on any error or interruption ``path`` is as it was)."""
    with outputs([path], force) as out:
        yield out.folder(path) if folder else out.file(path)


# ----------------------------------------------------------------------------------------------
# the outputs of one command, as a set


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
            tmp = Path(tempfile.mkdtemp(prefix=partial_prefix(path), dir=path.parent))
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
                remove_partial_folder(tmp)
                return
            commit_set([self.built.pop(p) for p in todo], todo)

    def discard(self) -> None:
        for tmp in self.parts:
            remove_path(tmp)


@contextlib.contextmanager
def outputs(paths, force: bool = False, records=()) -> Iterator[OutputSet]:
    """The outputs ``paths`` (files or folders) of one command: each locked (``output_lock``)
    and checked (``check_writable``) before anything is written, a killed writer's set
    finished and its partial builds removed; yields an ``OutputSet`` to build them in, swapped
    in as a set when the block ends (those not committed earlier). ``records``: outputs of the
    set that are replaced without ``force`` (a record of the others, such as masks/ids.json,
    which must change together with the masks it describes)."""
    records = [Path(p) for p in records]
    paths = list(dict.fromkeys([*(Path(p) for p in paths), *records]))
    with contextlib.ExitStack() as stack:
        for p in paths:
            refuse_links(p)
        for p in paths:
            stack.enter_context(output_lock(p))
        for p in paths:
            finish_commits(p)
        for p in paths:
            if p not in records:
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


# ----------------------------------------------------------------------------------------------
# moving and copying files of a build (inside a partial folder of a set, or set aside)


def rename(src: str | Path, dst: str | Path) -> None:
    """Rename ``src`` to ``dst`` (replacing it) in one step: a finished file of a build put
    under its name inside the build, or a damaged file set aside beside itself. Neither name's
    folder may be a link."""
    src, dst = Path(src), Path(dst)
    refuse_links(src)
    refuse_links(dst)
    with os_errors(dst):
        os.replace(src, dst)


def link_or_copy(src: str | Path, dst: str | Path) -> None:
    """Put the file ``src`` at the new name ``dst`` inside a build: a hard link (no bytes
    copied; the old output keeps its own name), else a copy."""
    refuse_links(dst)
    with os_errors(dst):
        try:
            os.link(src, dst, follow_symlinks=False)
        except OSError:
            shutil.copy2(src, dst, follow_symlinks=False)


def copy_tree(src: str | Path, dst: str | Path, ignore=None, link: bool = False) -> None:
    """Copy the folder ``src`` to the new folder ``dst`` inside a build (``link``: files hard
    linked where possible); links inside ``src`` are copied as links, never followed."""
    refuse_links(dst)
    with os_errors(dst):
        shutil.copytree(src, dst, symlinks=True, ignore=ignore,
                        copy_function=link_or_copy if link else shutil.copy2)
