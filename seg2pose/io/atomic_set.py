"""Swapping finished builds in at their final names (``seg2pose.io.atomic`` builds them):
one output exchanged with the old one in one step (``swap_in``), or the outputs of one
command as a set (``commit_set``) with a commit record, so that a writer killed between two
of its swaps is finished by the next writer of any of its outputs (``finish_commits``).

The record ``.NAME.commit-PID.json`` lies in every folder of the set, named after the first
output in that folder; it holds (build, output, build's inode) for every output. A build
still under its partial name with the recorded inode has not been swapped in; one whose name
holds another inode has, and what is under its name is the old output."""

from __future__ import annotations

import contextlib
import ctypes
import errno
import json
import os
import shutil
from pathlib import Path

from seg2pose.io.atomic_names import COMMIT_RECORD, commit_record_path, dead_writers_leftovers, owner
from seg2pose.io.kill_points import commit_entry, commit_step
from seg2pose.io.nofollow import fdopen_nofollow

__all__ = ["commit_step"]  # also annotate.journal's (fault injection: io/kill_points.py)

def fsync_dir(path: str | Path) -> None:
    """Make the creation, rename or removal of a file in folder ``path`` durable (best effort:
    some file systems cannot fsync a folder)."""
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def exchange(a: Path, b: Path) -> bool:
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


def remove_path(p: Path) -> None:
    """Remove the file or folder ``p`` (a folder with all it holds; gone already: nothing)."""
    if p.is_dir() and not p.is_symlink():
        shutil.rmtree(p, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            p.unlink()


def swap_in(tmp: Path, path: Path) -> None:
    """Put the finished ``tmp`` (file or folder) at ``path`` as a unit; an existing ``path``
    is exchanged with it in one step where possible, and removed only afterwards."""
    fsync_dir(tmp if tmp.is_dir() else tmp.parent)
    commit_entry([("built", 1), ("swapped", 1)], [tmp], [path])
    commit_step("built")
    if path.exists() or path.is_symlink():
        if exchange(tmp, path):
            commit_step("swapped")
            remove_path(tmp)  # now the old output
        else:
            old = path.parent / f".{path.name}.old-{os.getpid()}"
            remove_path(old)
            os.replace(path, old)
            os.replace(tmp, path)
            commit_step("swapped")
            remove_path(old)
    else:
        os.replace(tmp, path)
        commit_step("swapped")
    fsync_dir(path.parent)
    commit_step("done")


def remove_partial_folder(tmp: Path) -> None:
    """Remove the partial folder ``tmp`` was built in once ``tmp`` is swapped in."""
    # OutputSet.file builds NAME in .NAME.partial-PID-x/: that folder goes once NAME is in place
    own = owner(tmp.parent.name)
    if own is not None and tmp.parent.exists() and (own[0] == tmp.name or not tmp.exists()):
        remove_path(tmp.parent)


def _record_paths(finals: list[Path], pid: int | None = None) -> list[Path]:
    """Where a set's commit record lies: one copy in every folder of the set's outputs, named
    after the first output in that folder, so that a writer of any one output finds it."""
    first: dict[Path, Path] = {}
    for p in finals:
        first.setdefault(p.parent, p)
    return [commit_record_path(p, pid) for p in first.values()]


def _swap(tmp: Path, path: Path) -> Path | None:
    """Put the build ``tmp`` at ``path``: an existing output is exchanged with it in one step
    (the old one is then under ``tmp``'s name; ``path`` is never absent), else moved aside
    (``.NAME.old-PID-x``) where the system cannot exchange. Returns where the old output now
    is (None: there was none)."""
    if path.exists() or path.is_symlink():
        if exchange(tmp, path):
            return tmp
        old = path.parent / f".{path.name}.old-{os.getpid()}-{os.urandom(3).hex()}"
        os.replace(path, old)
        os.replace(tmp, path)
        return old
    os.replace(tmp, path)
    return None


def commit_set(builds: list[Path], finals: list[Path]) -> None:
    """Swap the finished, durable ``builds`` in at ``finals`` (same order) as one set: recorded
    first (a record in each of their folders), then each exchanged with its old output one
    after another with nothing else between (microseconds: the only time the set is part old,
    part new, each output whole); then the records, the old outputs and the partial folders
    are removed."""
    # the record, beside every output's folder (written in place: a torn one was cut
    # before any swap, so means none), made durable before the first swap
    commit_entry([("recorded", 1), ("set-swap", len(builds)), ("unrecorded", 1)], builds, finals)
    rows = json.dumps([[str(t), str(p), os.lstat(t).st_ino] for t, p in zip(builds, finals)])
    records = _record_paths(finals)
    for record in records:  # never through a link planted under the record's name
        with fdopen_nofollow(record, "w", encoding="utf-8") as f:
            f.write(rows)
            f.flush()
            os.fsync(f.fileno())
    for record in records:
        fsync_dir(record.parent)
    commit_step("recorded")
    # each output exchanged with its build, one after another with nothing between:
    # every output stays whole (old or new); a writer killed among these swaps is
    # finished by the next writer of any output of the set (finish_commits)
    olds = []
    for tmp, p in zip(builds, finals):
        olds.append(_swap(tmp, p))
        commit_step("set-swap")
    for d in dict.fromkeys(p.parent for p in finals):
        fsync_dir(d)
    for record in records:
        os.unlink(record)
    for record in records:
        fsync_dir(record.parent)
    commit_step("unrecorded")
    for old in olds:
        if old is not None:
            remove_path(old)
    for tmp in builds:  # after all swaps: a build may lie in another one's folder
        remove_partial_folder(tmp)
    commit_step("done")


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

    def recorder(name: str) -> list[int] | None:
        m = COMMIT_RECORD.match(name)
        return [int(m.group("pid"))] if m else None

    done = []
    for e in dead_writers_leftovers(path, recorder):
        m = COMMIT_RECORD.match(e.name)
        assert m is not None  # recorder() matched it
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
                remove_path(old)
        for tmp, _, _ in rows:
            remove_partial_folder(tmp)
    return done
