"""Checks of single values and of paths read from files, with the project's error messages.

Every reader uses these so that a value is judged the same way everywhere: an integer field
takes only a JSON integer (not ``true``, not ``1280.7``), a number must be finite and inside a
stated range (the message says the range), and a name or path taken from a file's contents
can never reach outside the folder it belongs to.
"""

from __future__ import annotations

import math
import re
from pathlib import Path, PurePosixPath

from seg2pose.core.errors import InputError

# Plausibility ranges: far wider than any real recording, narrow enough that arithmetic on
# them cannot overflow (a frame time of 1/fps * 1e9 ns, a squared distance in metres, ...).
MAX_COORD = 1e6           # metres: world coordinates (1,000 km from the origin)
MAX_IMAGE_SIDE = 2 ** 20  # pixels
MAX_PIXEL_COORD = 1e7     # pixels: focal lengths and principal points
FPS_RANGE = (1e-3, 1e6)   # frames per second
MAX_ID = 2 ** 62          # frame numbers and track ids (int64 with room to spare)

_INT_TEXT = re.compile(r"^[+-]?[0-9]+$")  # int() also takes "1_4" and " 1 " and Unicode digits


def integer(v, *, file=None, field: str | None = None, lo: int | None = None,
            hi: int | None = None, line: int | None = None) -> int:
    """A JSON integer (not a bool, not a float such as 1.9 or 2.0) within [lo, hi]."""
    if isinstance(v, bool) or not isinstance(v, int):
        raise InputError(f"expected an integer{_range(lo, hi)}, got {_show(v)}", file=file,
                         field=field, line=line)
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        raise InputError(f"expected an integer{_range(lo, hi)}, got {v}", file=file, field=field,
                         line=line)
    return v


def int_text(s: str, *, file=None, field: str | None = None, line: int | None = None,
             lo: int | None = None, hi: int | None = None) -> int:
    """An integer written in a text file: plain ASCII digits with an optional sign only."""
    t = s.strip()
    if not _INT_TEXT.match(t) or len(t) > 20:
        raise InputError(f"expected an integer, got {s!r}", file=file, field=field, line=line)
    return integer(int(t), file=file, field=field, lo=lo, hi=hi, line=line)


def number(v, *, file=None, field: str | None = None, lo: float | None = None,
           hi: float | None = None, lo_open: bool = False, line: int | None = None) -> float:
    """A finite JSON number (int or float, not a bool) within [lo, hi] ((lo, hi] when
    ``lo_open``)."""
    rng = _range(lo, hi, lo_open)
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise InputError(f"expected a number{rng}, got {_show(v)}", file=file, field=field, line=line)
    try:
        f = float(v)
    except OverflowError:  # a JSON integer with hundreds of digits
        raise InputError(f"expected a number{rng}, got an integer of {len(str(v))} digits",
                         file=file, field=field, line=line) from None
    if not math.isfinite(f):
        raise InputError(f"expected a finite number{rng}, got {f}", file=file, field=field, line=line)
    if (lo is not None and (f < lo or (lo_open and f == lo))) or (hi is not None and f > hi):
        raise InputError(f"expected a number{rng}, got {f!r}", file=file, field=field, line=line)
    return f


def check_range(a, name: str, lo: float, hi: float, *, file=None, field: str | None = None) -> None:
    """All entries of the array ``a`` finite and within [lo, hi]."""
    import numpy as np

    a = np.asarray(a, dtype=np.float64)
    ok = np.isfinite(a) & (a >= lo) & (a <= hi)
    if not ok.all():
        bad = a.reshape(-1)[np.flatnonzero(~ok.reshape(-1))[0]]
        raise InputError(f"{name} must be finite and within [{lo:g}, {hi:g}], got {bad!r}",
                         file=file, field=field)


_BAD_NAME = re.compile(r"[/\\\x00-\x1f\x7f]")


def safe_name(v, *, file=None, field: str | None = None, what: str = "name") -> str:
    """A name that becomes part of a file name (cameras, classes, configurations, runs): a
    non-empty string without path separators or control characters, not starting with a dot
    (so not '.' or '..'), at most 100 characters."""
    if not isinstance(v, str):
        raise InputError(f"expected a {what} (a string), got {_show(v)}", file=file, field=field)
    if not v or len(v) > 100 or v.startswith(".") or _BAD_NAME.search(v) or v != v.strip():
        raise InputError(f"{what} {v!r} cannot be used in a file name: expected 1-100 characters "
                         "without '/', '\\', control characters, surrounding spaces or a "
                         "leading '.'", file=file, field=field)
    return v


def inside(root: str | Path, rel, *, file=None, field: str | None = None,
           what: str = "path") -> Path:
    """``root / rel`` for a relative path ``rel`` read from a file, refused unless it stays
    inside ``root``: no absolute paths, no '..', no backslashes, and (after following links
    that exist) still under ``root``."""
    if not isinstance(rel, str) or not rel or "\x00" in rel:
        raise InputError(f"expected a {what} relative to {root}, got {_show(rel)}", file=file,
                         field=field)
    p = PurePosixPath(rel)
    if p.is_absolute() or "\\" in rel or any(part == ".." for part in p.parts) or re.match(r"^[A-Za-z]:", rel):
        raise InputError(f"{what} {rel!r} leads outside {root}: expected a path inside that folder",
                         file=file, field=field)
    root = Path(root)
    out = root.joinpath(*p.parts)
    try:
        real_root = root.resolve()
        real = out.resolve()
    except (OSError, RuntimeError):  # a link loop
        raise InputError(f"{what} {rel!r} cannot be resolved", file=file, field=field) from None
    if real != real_root and real_root not in real.parents:
        raise InputError(f"{what} {rel!r} leads outside {root} (through a link)", file=file,
                         field=field)
    return out


def _range(lo, hi, lo_open: bool = False) -> str:
    def f(x):
        return str(x) if isinstance(x, int) else f"{x:g}"

    if lo is None and hi is None:
        return ""
    if hi is None:
        return f" {'>' if lo_open else '>='} {f(lo)}"
    if lo is None:
        return f" <= {f(hi)}"
    return f" in {'(' if lo_open else '['}{f(lo)}, {f(hi)}]"


def _show(v) -> str:
    r = repr(v) if not isinstance(v, bool) else ("true" if v else "false")
    return r if len(r) <= 40 else r[:37] + "..."
