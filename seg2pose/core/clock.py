"""UTC timestamps: ISO 8601 in records (run.json, lock holders, journals), compact in file names."""

from __future__ import annotations

import datetime as _dt


def utc_now(timespec: str = "seconds") -> str:
    """Now in UTC, ISO 8601 (``2026-12-02T05:01:02+00:00``; ``timespec`` as ``isoformat``)."""
    return _dt.datetime.now(_dt.UTC).isoformat(timespec=timespec)


def utc_stamp(microseconds: bool = False) -> str:
    """Now in UTC for a file name: ``20261202T050102`` (``...T050102123456`` with
    ``microseconds``)."""
    return _dt.datetime.now(_dt.UTC).strftime("%Y%m%dT%H%M%S" + ("%f" if microseconds else ""))
