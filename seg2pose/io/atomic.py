"""Atomic writes: write a temporary file in the same folder, then rename over the final name.

An interrupted run therefore never leaves a half-written file under a final name.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import IO, Iterator

from seg2pose.errors import S2PError


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _temp_sibling(path: Path, suffix: str) -> tuple[int, str]:
    """mkstemp in the target's folder, with the permissions a plain open() would give
    (mkstemp makes 0600 files, which other users of a shared scene folder could not read)."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    os.chmod(tmp, 0o666 & ~_umask())
    return fd, tmp


def temp_sibling_dir(path: str | Path) -> Path:
    """A new empty folder beside ``path`` to build a whole output folder in before renaming
    it into place (mkdtemp's 0700 widened to what mkdir would give)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
    os.chmod(tmp, 0o777 & ~_umask())
    return tmp


def fsync_dir(path: str | Path) -> None:
    """Make a file's creation, rename or removal in the folder ``path`` durable."""
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def check_writable(path: str | Path, force: bool) -> Path:
    """Refuse to overwrite an existing file or folder unless ``force``."""
    path = Path(path)
    if path.exists() and not force:
        raise S2PError(f"{path} exists; pass --force to overwrite it")
    return path


@contextlib.contextmanager
def atomic_open(path: str | Path, mode: str = "w", **kwargs) -> Iterator[IO]:
    """Open a temporary sibling of ``path`` for writing; rename it to ``path`` on success."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = _temp_sibling(path, ".tmp")
    try:
        with os.fdopen(fd, mode, **kwargs) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
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
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = _temp_sibling(path, path.suffix or ".tmp")
    os.close(fd)
    try:
        yield Path(tmp)
        # the library may have replaced our file with a private one of its own
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
