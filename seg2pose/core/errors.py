"""The project's own error types: every reader raises these, never a bare crash."""

from __future__ import annotations

from pathlib import Path


class S2PError(Exception):
    """Any error s2p reports to a user (the CLI prints it without a traceback)."""


class InputError(S2PError, ValueError):
    """Bad input: names the file, the line or field, and what was expected.

    >>> str(InputError("expected 6 fields", file="m.txt", line=3))
    'm.txt:3: expected 6 fields'
    """

    def __init__(self, message: str, *, file: str | Path | None = None,
                 line: int | None = None, field: str | None = None):
        self.message = message  # without the location, for re-raising with a better one
        self.file = str(file) if file is not None else None
        self.line = line
        self.field = field
        where = ""
        if self.file is not None:
            where = self.file
            if line is not None:
                where += f":{line}"
        if field is not None:
            where += (": " if where else "") + f"field '{field}'"
        super().__init__(f"{where}: {message}" if where else message)
