"""Messages to the user, one way: ``say(msg)`` for progress and results, ``say(msg, kind=...)``
for a note or a warning. They go to standard error (standard output stays for a command's
result); the command layer may redirect them with ``set_sink`` (e.g. to collect them)."""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Literal

Kind = Literal["info", "note", "warning"]


def _stderr(msg: str, kind: Kind) -> None:
    print(msg if kind == "info" else f"{kind}: {msg}", file=sys.stderr, flush=True)


_sink: Callable[[str, Kind], None] = _stderr


def say(msg: str, kind: Kind = "info") -> None:
    """Tell the user ``msg`` (one line); ``kind`` "note" or "warning" prefixes it so."""
    _sink(msg, kind)


def warn_once(said: set, key: str, msg: str) -> None:
    """A warning said once per ``said`` set (e.g. once per run)."""
    if key not in said:
        said.add(key)
        say(msg, "warning")


def set_sink(sink: Callable[[str, Kind], None] | None) -> None:
    """Send messages to ``sink(msg, kind)`` instead of standard error (None: back to it)."""
    global _sink
    _sink = sink or _stderr
