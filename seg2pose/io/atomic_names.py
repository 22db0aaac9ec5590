"""The names of what a writer keeps beside an output while it writes (``seg2pose.io.atomic``),
and the removal of those a killed writer left:

- ``.NAME.partial-PID-...``: a build (file or folder) of the output NAME; ``.NAME.old-PID-...``:
  an old output moved aside while the new one is swapped in. Temporaries of temporaries
  (``..NAME.partial-1-x.partial-1-y.tmp``: a library's atomic write of a file that is itself
  being built) belong to NAME too.
- ``.NAME.commit-PID.json``: the record of a set of outputs being swapped in
  (``seg2pose.io.atomic_set``).
- ``.NAME.lock``: the writer's lock (``seg2pose.io.atomic.output_lock``).
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path

from seg2pose.core.locks import pid_alive

_PARTIAL = re.compile(r"^\.(?P<name>.+)\.(?:partial|old)-(?P<pid>\d+)(?:[-.].*)?$")
COMMIT_RECORD = re.compile(r"^\.(?P<name>.+)\.commit-(?P<pid>\d+)\.json$")


def owner(name: str) -> tuple[str, list[int]] | None:
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
    return (owner(name) is not None or COMMIT_RECORD.match(name) is not None
            or (name.startswith(".") and name.endswith(".lock")))


def partial_prefix(path: Path) -> str:
    """How this process's builds of ``path`` begin (``.NAME.partial-PID-``)."""
    return f".{path.name}.partial-{os.getpid()}-"


def commit_record_path(path: Path, pid: int | None = None) -> Path:
    """``.NAME.commit-PID.json`` beside ``path`` (PID: this process's unless given)."""
    return path.parent / f".{path.name}.commit-{os.getpid() if pid is None else pid}.json"


def lock_path(path: str | Path) -> Path:
    path = Path(path)
    return path.with_name(f".{path.name}.lock")


def final_name(path: str | Path) -> str:
    """``path`` with temporary siblings (``.NAME.partial-PID-...``) named by their final
    name: what the user asked for, not where it was being built."""
    out: list[str] = []
    in_partial = False
    for p in Path(path).parts:
        own = owner(p)
        if own is None and in_partial and out[-1] == p:
            in_partial = False
            continue  # NAME built as .NAME.partial-PID-x/NAME (OutputSet.file): the output itself
        in_partial = own is not None
        out.append(own[0] if own else p)
    return str(Path(*out)) if out else str(path)


def dead_writers_leftovers(path: Path,
                           pids_of: Callable[[str], list[int] | None]) -> Iterator[os.DirEntry]:
    """The entries beside ``path`` (in the folder's order, each checked just before it is
    yielded) whose name ``pids_of`` gives the pids of their writers (None: not such a name)
    and none of whose writers runs now: a process that started after the entry was last
    written is not its writer (``pid_alive``)."""
    try:
        entries = list(os.scandir(path.parent))
    except OSError:
        return
    for e in entries:
        pids = pids_of(e.name)
        if pids is None:
            continue
        try:
            written = e.stat(follow_symlinks=False).st_mtime
        except OSError:
            continue
        if not any(pid_alive(p, written) for p in pids):
            yield e


def clean_stale_partials(path: str | Path) -> list[Path]:
    """Remove the temporary siblings ``.NAME.partial-PID...`` / ``.NAME.old-PID...`` of
    ``path`` left by processes that no longer run. Returns what was removed."""
    path = Path(path)

    def builders(name: str) -> list[int] | None:
        own = owner(name)
        return own[1] if own is not None and own[0] == path.name else None

    removed = []
    for e in dead_writers_leftovers(path, builders):
        p = Path(e.path)
        with contextlib.suppress(OSError):
            if e.is_dir(follow_symlinks=False):
                shutil.rmtree(p)
            else:
                p.unlink()
            removed.append(p)
    return removed
