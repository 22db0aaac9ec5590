"""Opening files for writing without following links: a scene folder received from a colleague
is untrusted input, and a link planted in it (``annotations/lock -> ~/.bashrc``, a linked
``export/`` folder) must never make s2p write outside it.

- ``open_nofollow(path, flags)``: the folder of ``path`` opened first (``O_DIRECTORY |
  O_NOFOLLOW``: a folder that is a link is refused), then ``path`` relative to that folder's
  handle (``openat``) with ``O_NOFOLLOW`` (a file that is a link is refused). With ``root``
  every folder from ``root`` down is opened that way, so no link between the scene folder and
  the file is followed either. The folder the user named (``root``, or the parent's parent)
  is followed as given: the user chose it.
- ``refuse_links(path)``: the same rule for an output that is swapped in by name (a link at
  the output's own name is replaced as a link, never written through; a linked folder that
  holds it is refused); ``refuse_linked_folder(folder)`` for a folder written file by file.

Refusals are one-line ``S2PError``s naming the link.
"""

from __future__ import annotations

import contextlib
import errno
import os
from collections.abc import Iterator
from pathlib import Path

from seg2pose.core.errors import S2PError

__all__ = ["LinkRefused", "open_nofollow", "fdopen_nofollow", "refuse_links", "refuse_linked_folder",
           "link_message", "write_new_bytes", "write_new_text"]


class LinkRefused(S2PError):
    """A link where s2p writes: refused, nothing written through it."""


def link_message(link: str | Path) -> str:
    return (f"{link} is a symbolic link; s2p does not write through links inside a scene or "
            "output folder (replace it with the folder or file itself)")


def refuse_links(path: str | Path, root: str | Path | None = None) -> None:
    """Raise ``LinkRefused`` when the folder holding ``path`` is a link (or, with ``root``, any
    folder from below ``root`` down to it). ``path`` itself may be a link: outputs replace
    their name as a unit (a link there is replaced as a link)."""
    path = Path(path)
    for d in _folders(path, root):
        if d.is_symlink():
            raise LinkRefused(link_message(d))


def refuse_linked_folder(folder: str | Path, root: str | Path | None = None) -> None:
    """``refuse_links`` for a folder that a command writes file by file (a model folder, a
    paper table, the demo's recordings), checked before its work rather than at its first
    write: the folder itself and the folder holding it (with ``root``, every folder below
    ``root`` down to it) must not be links."""
    refuse_links(folder, root)
    refuse_links(Path(folder) / "_", root)


def _walk(path: Path, root: str | Path | None) -> tuple[Path, tuple[str, ...]]:
    """Where the walk to ``path``'s folder starts (followed as given) and the folder names
    opened from there without following links: the parent's name, or with ``root`` every
    folder below ``root``."""
    parent = path.parent
    if root is not None:
        with contextlib.suppress(ValueError):
            return Path(root), parent.relative_to(root).parts
    if parent.name in ("", ".", ".."):
        return parent, ()
    return parent.parent, (parent.name,)


def _folders(path: Path, root: str | Path | None) -> list[Path]:
    """The folders that must not be links for ``path`` (see ``_walk``)."""
    start, parts = _walk(path, root)
    out = []
    for part in parts:
        start = start / part
        out.append(start)
    return out


@contextlib.contextmanager
def _dir_fd(path: Path, root: str | Path | None) -> Iterator[int]:
    """A handle of the folder of ``path``, every checked folder opened without following a link."""
    start, parts = _walk(path, root)
    fd = os.open(start, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    try:
        d = start
        for part in parts:
            d = d / part
            try:
                nfd = os.open(part, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC,
                              dir_fd=fd)
            except OSError as e:
                if e.errno in (errno.ELOOP, errno.ENOTDIR) and d.is_symlink():
                    raise LinkRefused(link_message(d)) from None
                raise
            os.close(fd)
            fd = nfd
        yield fd
    finally:
        os.close(fd)


def open_nofollow(path: str | Path, flags: int, mode: int = 0o666,
                  root: str | Path | None = None) -> int:
    """``os.open(path, flags | O_NOFOLLOW)`` relative to a handle of its folder, opened without
    following links (see the module docstring). A link at ``path`` or at a folder checked
    raises ``LinkRefused``; other OSErrors pass through."""
    path = Path(path)
    with _dir_fd(path, root) as dfd:
        try:
            return os.open(path.name, flags | os.O_NOFOLLOW | os.O_CLOEXEC, mode, dir_fd=dfd)
        except OSError as e:
            if e.errno == errno.ELOOP or (e.errno == errno.EEXIST and path.is_symlink()):
                raise LinkRefused(link_message(path)) from None
            raise


def fdopen_nofollow(path: str | Path, mode: str = "w", root: str | Path | None = None, **kwargs):
    """A file object of ``open_nofollow`` for the text/binary ``mode`` of ``open`` ('w', 'a',
    'x', 'r+', with or without 'b')."""
    base = mode.replace("b", "").replace("t", "")
    flags = {"w": os.O_WRONLY | os.O_CREAT | os.O_TRUNC, "a": os.O_WRONLY | os.O_CREAT | os.O_APPEND,
             "x": os.O_WRONLY | os.O_CREAT | os.O_EXCL, "r+": os.O_RDWR, "a+": os.O_RDWR | os.O_CREAT | os.O_APPEND,
             "w+": os.O_RDWR | os.O_CREAT | os.O_TRUNC}[base]
    return os.fdopen(open_nofollow(path, flags, root=root), mode, **kwargs)


def write_new_text(path: str | Path, text: str) -> None:
    """Write ``text`` to the new file ``path`` (in a build folder of this process: created,
    never an existing file or link), made durable."""
    with fdopen_nofollow(path, "x", encoding="utf-8", newline="") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())


def write_new_bytes(path: str | Path, data: bytes) -> None:
    """``write_new_text`` for bytes."""
    with fdopen_nofollow(path, "xb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
