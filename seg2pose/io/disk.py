"""A write that a library (OpenCV's video writer) gave up on without an
OSError: one line naming the output the user asked for, and "the disk is full" when the folder
it was written in has (almost) no room left, the usual reason (tests/system/test_full_disk.py
fills a small tmpfs for real)."""

from __future__ import annotations

import os
from pathlib import Path

from seg2pose.core.errors import S2PError
from seg2pose.io.atomic_names import final_name

# less room than this left beside a file a library was writing: its last writes did not fit
# (encoders and file sinks write in buffers of tens of KiB; a frame of video is more)
NEARLY_FULL = 256 * 1024


def room_left(path: str | Path) -> int | None:
    """Bytes free to this user on the file system of ``path`` (its nearest existing folder);
    None when the system cannot say."""
    p = Path(path)
    while not p.exists() and p != p.parent:
        p = p.parent
    try:
        st = os.statvfs(p)
    except OSError:
        return None
    return st.f_bavail * st.f_frsize


def disk_full(path: str | Path) -> bool:
    """Whether the file system of ``path`` has (almost) no room left (``NEARLY_FULL``)."""
    left = room_left(path)
    return left is not None and left < NEARLY_FULL


def write_failed(path: str | Path, why: str) -> S2PError:
    """The error for a library's failed write of ``path`` (a temporary build's name is given
    as the output's own): "the disk is full" when it is, else ``why``."""
    return S2PError(f"cannot write {final_name(path)}: {'the disk is full' if disk_full(path) else why}")
