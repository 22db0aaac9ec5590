"""Reading text and JSON input files with the project's error messages (file named, what
was expected), so every reader reports missing, non-UTF-8 or malformed files the same way."""

from __future__ import annotations

import json
from pathlib import Path

from seg2pose.core.errors import InputError


def read_text(path: str | Path, what: str = "file") -> str:
    """The UTF-8 text of ``path``; ``what`` names the file in the 'not found' message."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{what} not found", file=path)
    try:
        return path.read_bytes().decode("utf-8")
    except UnicodeDecodeError:
        raise InputError("not UTF-8 text", file=path) from None


def load_json(path: str | Path, what: str = "file"):
    """The parsed JSON of ``path``; syntax errors name the line."""
    path = Path(path)
    text = read_text(path, what)
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise InputError(f"invalid JSON: {e.msg}", file=path, line=e.lineno) from None
    except RecursionError:
        raise InputError("JSON nested too deeply", file=path) from None
