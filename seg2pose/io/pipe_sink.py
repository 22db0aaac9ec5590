"""A path a library writes to, whose bytes this process writes into the real file.

Rerun 0.41's file sink, when the disk fills while it writes, stops without an error, and every
later flush, ``set_sinks`` or ``disconnect`` of the recording waits for it for ever (1 run in
about 12 on a full tmpfs; once in CI, 600 s). Given the write end of a pipe instead of the file,
the library never meets the disk: a thread copies the pipe into the file, and an OSError there
(the disk is full) is this process's to report, in the usual one line
(tests/system/test_full_disk.py fills a small tmpfs for real).

The library must write in order, never seek: an RRD stream does (its footer comes last).
"""

from __future__ import annotations

import os
import threading
from typing import IO

CHUNK = 1 << 20  # bytes per read of the pipe


class PipeSink:
    """``path`` (``/dev/fd/N``, the write end of a pipe) for the library to open and write;
    what comes through is written to ``f`` until the first OSError, after which the rest is
    read and dropped, so the library never blocks on a full pipe.

    Use: ``sink = PipeSink(f)``; the library writes ``sink.path``; once the library has closed
    it (for Rerun: ``disconnect``), ``sink.close()`` waits for the copy and raises its OSError.
    """

    def __init__(self, f: IO[bytes]) -> None:
        self._f = f
        self._r, self._w = os.pipe()  # not inherited by child processes (PEP 446)
        self.path = f"/dev/fd/{self._w}"
        self.error: OSError | None = None
        self._thread = threading.Thread(target=self._copy, name="pipe-sink", daemon=True)
        self._thread.start()

    def _copy(self) -> None:
        with os.fdopen(self._r, "rb", buffering=0) as src:
            while data := src.read(CHUNK):
                if self.error is not None:
                    continue  # drained, so the writer is never left waiting
                try:
                    self._f.write(data)
                except OSError as e:
                    self.error = e

    def close(self) -> None:
        """Close this end's copy of the write end, wait for the library's bytes to be copied
        (the library must have closed its own), and raise the copy's OSError if there was one."""
        if self._w >= 0:
            os.close(self._w)
            self._w = -1
        self._thread.join()
        if self.error is not None:
            raise self.error
