"""The schema language of s2p's files: what a field or a column accepts, declared once and used
by both the file's writer and its reader, so that a writer cannot produce what a reader refuses.

``Num`` is one numeric field or column (range, NaN allowed or not, integer or not), ``Table`` a
column table (its columns, the column that may not decrease, the key that a row holds once),
``Opt``/``Name``/``Text``/``OneOf``/``ListOf``/``DictOf``/``Record``/``Fn`` describe JSON
records (run.json, scene.json, the annotation journal's operations), and ``read_settings``
reads a settings object (``--set KEY=VALUE`` and scene.json's ``extra`` sections) against its
declared ranges. The declarations of the file types themselves are in ``io/schemas.py`` and
``io/scene_schema.py``.

Checks of columns are vectorised (millions of rows); errors are the project's one line
(``InputError``) naming the file, the line or record and the field, and what was expected.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from seg2pose.core.errors import InputError
from seg2pose.core.validate import safe_name


def _g(x: float) -> str:
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e16 else f"{x:g}"


@dataclass(frozen=True)
class Num:
    """A number a file holds: within [lo, hi] ((lo, hi] with ``lo_open``), finite unless
    ``nan`` (NaN, or JSON null, stands for "unknown"), an integer when ``integer``. ``unit``
    is said in messages (``metres``)."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    nan: bool = False
    integer: bool = False
    unit: str = ""

    def expected(self, column: bool = False) -> str:
        """What is accepted, as a message says it (``column``: of a column's values)."""
        if column:  # "x, y, z must be finite metres in [...]"
            what = "integers" if self.integer else f"finite {self.unit or 'numbers'}"
        else:
            what = "an integer" if self.integer else "a finite number"
        if self.lo is not None and self.hi is not None:
            what += f" in {'(' if self.lo_open else '['}{_g(self.lo)}, {_g(self.hi)}]"
        elif self.lo is not None:
            what += f" {'>' if self.lo_open else '>='} {_g(self.lo)}"
        elif self.hi is not None:
            what += f" <= {_g(self.hi)}"
        unit = f" {self.unit}" if self.unit and (self.integer or not column) else ""
        return what + unit + (" (or nan for unknown)" if self.nan else "")

    def ok(self, a) -> np.ndarray:
        """(N,) whether each row of ``a`` ((N,) or (N, k): a row is good when all its entries
        are) is accepted."""
        a = np.asarray(a)
        if a.dtype == object:
            a = a.astype(np.float64)
        if a.dtype.kind in "iub":  # integer columns: compare exactly (floats lose int64 digits)
            good = np.ones(a.shape, bool)
            if self.lo is not None:
                good &= (a > self.lo) if self.lo_open else (a >= self.lo)
            if self.hi is not None:
                good &= a <= self.hi
        else:
            a = a.astype(np.float64, copy=False)
            with np.errstate(invalid="ignore"):
                good = np.isfinite(a)
                if self.integer:
                    good &= np.floor(a) == a
                if self.lo is not None:
                    good &= (a > self.lo) if self.lo_open else (a >= self.lo)
                if self.hi is not None:
                    good &= a <= self.hi
                if self.nan:
                    good |= np.isnan(a)
        return np.asarray(good.all(axis=tuple(range(1, good.ndim))) if good.ndim > 1 else good)

    def _ok_scalar(self, v) -> bool:
        if isinstance(v, float) and math.isnan(v):
            return self.nan
        if isinstance(v, float) and not math.isfinite(v):
            return False
        if self.integer and isinstance(v, float) and not v.is_integer():
            return False
        if self.lo is not None and (v < self.lo or (self.lo_open and v == self.lo)):
            return False
        return self.hi is None or v <= self.hi

    def value(self, v, *, file=None, field: str | None = None, line: int | None = None):
        """A JSON value checked: an int for an integer field (true, 1.5 and 2.0 refused), a float
        otherwise (NaN for null when ``nan``)."""
        if v is None and self.nan:
            return math.nan
        if isinstance(v, bool) or not isinstance(v, (int, float)) or (
                self.integer and not isinstance(v, int)):
            shown = "true" if v is True else "false" if v is False else repr(v)
            raise InputError(f"expected {self.expected()}, got {shown[:40]}", file=file, field=field,
                             line=line)
        if isinstance(v, int) and not self.integer:
            try:
                v = float(v)
            except OverflowError:
                raise InputError(f"expected {self.expected()}, got an integer of {len(str(v))} digits",
                                 file=file, field=field, line=line) from None
        if not self._ok_scalar(v):
            raise InputError(f"expected {self.expected()}, got {repr(v)[:40]}", file=file,
                             field=field, line=line)
        return v


@dataclass(frozen=True)
class Table:
    """A column table's schema (poses.csv, views.csv, masks): ``columns`` name -> Num (a 2-D
    column's row is checked whole), ``ordered``: a column whose values never decrease down the
    file (files streamed frame by frame), ``unique``: key columns whose values a row holds once,
    rows with a negative last key (an untracked detection, track id -1) excepted."""

    what: str
    columns: Mapping[str, Num]
    ordered: str | None = None
    unique: tuple[str, ...] = ()
    row: str = "row"  # what a row is called in messages ("detection")

    def check(self, cols: Mapping[str, Any], *, file=None, lines: Sequence[int] | None = None) -> None:
        """Refuse the first bad row of ``cols`` (name -> array; a missing or None column is not
        checked) with one line naming ``file``, the row's line (``lines``: (N,) file lines; else
        the row's number, from 1, as a field) and the column."""
        rows = self.row

        def where(i: int) -> dict:
            if lines is not None:
                return {"line": int(lines[i])}
            return {"field": f"{rows} {i + 1}"}

        bad: list[tuple[int, str, str]] = []  # (row, column, message) of each failing check
        for name, spec in self.columns.items():
            a = cols.get(name)
            if a is None:
                continue
            good = spec.ok(a)
            if not good.all():
                i = int(np.argmin(good))
                v = np.asarray(a)[i]
                shown = v.tolist() if isinstance(v, np.ndarray) else v.item() if hasattr(v, "item") else v
                bad.append((i, name, f"{name} must be {spec.expected(column=True)}, got {shown!r}"))
        if self.ordered is not None and cols.get(self.ordered) is not None:
            f = np.asarray(cols[self.ordered])
            down = np.flatnonzero(f[1:] < f[:-1])
            if len(down):
                i = int(down[0]) + 1
                bad.append((i, self.ordered, f"{self.ordered} {f[i]} comes after {self.ordered} "
                                             f"{f[i - 1]}: {self.ordered}s must be in order"))
        if self.unique and all(cols.get(k) is not None for k in self.unique):
            dup = _first_duplicate([np.asarray(cols[k]) for k in self.unique])
            if dup is not None:
                i, j = dup
                say = {"track_id": "track"}.get
                last = self.unique[-1]
                key = " and ".join(f"{say(k, k)} {np.asarray(cols[k])[j]}" for k in self.unique[:-1])
                also = f"line {lines[i]}" if lines is not None else f"{rows} {i + 1}"
                bad.append((j, last, f"duplicate {rows}: {say(last, last)} {np.asarray(cols[last])[j]} "
                                     f"appears twice{' in ' + key if key else ''} (also {also})"))
        if bad:
            i, name, msg = min(bad)
            loc = where(i)
            # the message starts with the column's name: a line needs no field beside it
            raise InputError(msg, file=file, field=loc.get("field"), line=loc.get("line"))


def _first_duplicate(keys: list[np.ndarray]) -> tuple[int, int] | None:
    """(first row, the later row that repeats its key) of the earliest repeat, rows whose last
    key is negative excepted; None when every key is unique."""
    sel = np.flatnonzero(keys[-1] >= 0)
    if len(sel) < 2:
        return None
    order = sel[np.lexsort((sel, *[k[sel] for k in reversed(keys)]))]
    same = np.ones(len(order) - 1, bool)
    for k in keys:
        same &= k[order[1:]] == k[order[:-1]]
    hits = np.flatnonzero(same)
    if not len(hits):
        return None
    h = hits[np.argmin(order[hits + 1])]  # the earliest row that repeats a key
    return int(order[h]), int(order[h + 1])


# --- JSON records -------------------------------------------------------------------------------
@dataclass(frozen=True)
class Opt:
    """An optional field: absent or null allowed, else ``spec``."""

    spec: Any


@dataclass(frozen=True)
class Name:
    """A name that may become part of a file name (``core.validate.safe_name``)."""

    what: str = "name"


@dataclass(frozen=True)
class Text:
    """A string of at most ``max_len`` characters."""

    max_len: int = 1000


@dataclass(frozen=True)
class OneOf:
    values: tuple


@dataclass(frozen=True)
class ListOf:
    """A JSON list of ``spec`` items (``n``: exactly that many; at least ``min_len``); ``what``
    says in messages what is expected ("a non-empty list of cameras")."""

    spec: Any
    n: int | None = None
    max_len: int = 10_000_000
    min_len: int = 0
    what: str = ""


@dataclass(frozen=True)
class Record:
    """A JSON object: ``fields`` name -> spec; other keys pass unless ``closed``."""

    fields: Mapping[str, Any]
    closed: bool = False
    what: str = ""


@dataclass(frozen=True)
class DictOf:
    """A JSON object of any keys (each a ``key`` spec when given, e.g. ``Name``) -> ``spec``
    values; fields are named ``<field>.<key>``."""

    spec: Any
    key: Any = None
    what: str = ""


@dataclass(frozen=True)
class Fn:
    """A value checked by a reader's own function ``fn(v, file=..., field=...)`` (a camera's
    ``Camera.from_dict``, a time's parser); what it returns is the value as read."""

    fn: Callable[..., Any]


def check(v, spec, *, file=None, field: str = "", line: int | None = None):
    """``v`` checked against ``spec`` (Num, Name, Text, OneOf, ListOf, DictOf, Record, Fn, Opt, or a Python
    type such as ``dict`` / ``bool`` for "any value of that type"); returns the value as read
    (an int or float for Num)."""
    fld = field or None

    def bad(msg: str):
        return InputError(msg, file=file, field=fld, line=line)

    if isinstance(spec, Opt):
        return None if v is None else check(v, spec.spec, file=file, field=field, line=line)
    if isinstance(spec, Num):
        return spec.value(v, file=file, field=fld, line=line)
    if isinstance(spec, Name):
        return safe_name(v, file=file, field=fld, what=spec.what)
    if isinstance(spec, Text):
        if not isinstance(v, str) or len(v) > spec.max_len:
            raise bad(f"expected a text of at most {spec.max_len} characters, got {repr(v)[:40]}")
        return v
    if isinstance(spec, OneOf):
        if isinstance(v, bool) or v not in spec.values:
            names = [str(x) for x in spec.values]
            say = " or ".join([", ".join(names[:-1]), names[-1]] if len(names) > 1 else names)
            raise bad(f"expected {say}, got {repr(v)[:40]}")
        return v
    if isinstance(spec, Fn):
        return spec.fn(v, file=file, field=fld) if line is None else spec.fn(v, file=file, field=fld, line=line)
    if isinstance(spec, ListOf):
        if not isinstance(v, list) or not spec.min_len <= len(v) <= spec.max_len or (
                spec.n is not None and len(v) != spec.n):
            n = f" of {spec.n}" if spec.n is not None else ""
            raise bad(f"expected {spec.what or 'a list' + n}, got {repr(v)[:40]}")
        return [check(x, spec.spec, file=file, field=f"{field}[{i}]", line=line) for i, x in enumerate(v)]
    if isinstance(spec, DictOf):
        if not isinstance(v, dict):
            raise bad(f"expected {spec.what or 'an object'}, got {repr(v)[:40]}")
        pre = f"{field}." if field else ""
        for k in v if spec.key is not None else ():
            check(k, spec.key, file=file, field=f"{pre}{k}", line=line)
        return {k: check(x, spec.spec, file=file, field=f"{pre}{k}", line=line) for k, x in v.items()}
    if isinstance(spec, Record):
        if not isinstance(v, dict):
            raise bad(f"expected {spec.what or 'an object'}, got {repr(v)[:40]}")
        pre = f"{field}." if field else ""
        if spec.closed:
            extra = [k for k in v if k not in spec.fields]
            if extra:
                raise InputError(f"unknown field {str(extra[0])[:40]!r}; known: {', '.join(spec.fields)}",
                                 file=file, field=f"{pre}{extra[0]}", line=line)
        out = dict(v)
        for k, s in spec.fields.items():
            if k not in v and not isinstance(s, Opt):
                raise InputError(f"missing field '{k}'", file=file, field=f"{pre}{k}", line=line)
            out[k] = check(v.get(k), s, file=file, field=f"{pre}{k}", line=line)
        return out
    if isinstance(spec, type):
        if not isinstance(v, spec) or (spec is int and isinstance(v, bool)):
            raise bad(f"expected {spec.__name__}, got {repr(v)[:40]}")
        return v
    raise TypeError(f"not a schema: {spec!r}")


# --- settings -------------------------------------------------------------------------------------
def read_settings(obj, d: Mapping | None, limits: Mapping[str, Any], *, file: str | Path | None = None,
                  section: str = ""):
    """Settings object ``obj`` (a dataclass with its defaults) updated from ``d`` (scene.json's
    ``extra.<section>`` merged with ``--set KEY=VALUE``): an unknown key, a value of another type
    (2.5 for an integer, true for a number, nan) or one outside ``limits`` (name -> Num; a
    number field without a limit must be finite and >= 0; a str field: OneOf) is refused with
    one line naming ``extra.<section>.KEY``. Returns ``obj``."""
    known = {f.name: f for f in fields(obj)}
    for k, v in (d or {}).items():
        where = f"extra.{section}.{k}" if section else str(k)
        if k not in known:
            raise InputError(f"unknown setting {k!r}; known: {', '.join(sorted(known))}", file=file,
                             field=where)
        default = getattr(obj, k)
        spec = limits.get(k)
        if isinstance(default, bool):
            if not isinstance(v, bool):
                raise InputError(f"expected true or false, got {v!r}", file=file, field=where)
        elif isinstance(default, (int, float)):
            spec = spec or Num(lo=0)
            if isinstance(default, int) and not spec.integer:
                spec = Num(spec.lo, spec.hi, spec.lo_open, spec.nan, True, spec.unit)
            v = spec.value(v, file=file, field=where)
        elif spec is not None:
            v = check(v, spec, file=file, field=where)
        elif not isinstance(v, type(default)):
            raise InputError(f"expected {type(default).__name__}, got {v!r}", file=file, field=where)
        setattr(obj, k, v)
    for k, spec in limits.items():  # the defaults and values set in code obey the same limits
        v = getattr(obj, k)
        where = f"extra.{section}.{k}" if section else k
        if isinstance(spec, Num) and not spec.ok(np.array([float(v)]))[0]:
            raise InputError(f"expected {spec.expected()}, got {v!r}", file=file, field=where)
    return obj
