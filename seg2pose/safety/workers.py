"""Chunks of the analysis in worker processes: forked, so the tracks and their motion (hundreds
of MB for an hour of traffic) are shared copy-on-write, not pickled; only each chunk's small
result comes back. Results come in the order of the chunks, so the merge (and the table) is
the same as with one process."""

from __future__ import annotations

import multiprocessing as mp
from collections.abc import Callable
from typing import Any

_FN: Callable[[Any], Any] | None = None  # the chunk function, seen by the forked workers


def _call(item):
    assert _FN is not None  # set before the pool forks
    return _FN(item)


def map_chunks(fn, items, workers: int) -> list:
    """[fn(i) for i in items], in ``workers`` forked processes when there are several chunks
    (one process where fork is not available)."""
    global _FN
    items = list(items)
    if workers <= 1 or len(items) < 2 or "fork" not in mp.get_all_start_methods():
        return [fn(i) for i in items]
    _FN = fn
    try:
        with mp.get_context("fork").Pool(min(workers, len(items))) as pool:
            return pool.map(_call, items, chunksize=1)
    finally:
        _FN = None
