"""Digests of files: the sha256 that run.json, the batch records and the segment records hold."""

from __future__ import annotations

import hashlib
from pathlib import Path

BIG_FILE = 64 << 20  # bytes: files above this are fingerprinted by size and mtime, not hashed


def file_sha256(path: str | Path) -> str:
    """The sha256 of a file's bytes (hex), read in 1 MiB blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def file_fingerprint(path: str | Path, big: int = BIG_FILE) -> str:
    """The sha256 of a file, or for a file over ``big`` bytes (a long video: hashing hours of
    it on every re-run costs minutes) ``size=<bytes>,mtime=<ns>``."""
    st = Path(path).stat()
    if st.st_size > big:
        return f"size={st.st_size},mtime={st.st_mtime_ns}"
    return file_sha256(path)
