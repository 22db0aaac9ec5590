"""Shared pieces of the fuzz tests (tests/system/test_fuzz_*.py, hypothesis): settings that keep
them fast and stable (few examples, no deadline, derandomized), hostile values, and mutations
of a valid file (one field replaced, removed or swapped, a line dropped or repeated, the text
cut short). The property every importer keeps: refuse with the project's one-line error
(``importing``) or produce what every reader of it accepts."""

from __future__ import annotations

import contextlib
import json
import math
import tempfile
import warnings
from pathlib import Path

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

from seg2pose.core.errors import S2PError

FUZZ = settings(max_examples=40, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


HOSTILE_JSON = [None, True, False, 0, -1, 1.9, 2.0, -5.5, 1e308, -1e308, 10 ** 30, 2 ** 63,
                math.inf, -math.inf, math.nan, "", "x", "1", "../x", "/etc/passwd", "a/b", [], {},
                [1, 2], [[0, 0, 0]] * 3, {"a": 1}]


HOSTILE_TEXT = ["", "-1", "1_4", "\u0661", "1e400", "nan", "inf", "-inf", "true", "1.5", "0x10",
                "9" * 25, " ", "a,b", '"', "\x00", "\u00e9", "-0", "+3", "1e308", "../x"]


@contextlib.contextmanager
def folder():
    with tempfile.TemporaryDirectory() as d:
        yield Path(d)


def only_s2p_errors(fn):
    """Run fn(); return its result, or None when it raised S2PError in one line (anything else
    fails)."""
    try:
        return fn()
    except S2PError as e:
        one_line(e)
        return None


def json_paths(obj, prefix=()):
    yield prefix
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from json_paths(v, prefix + (k,))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from json_paths(v, prefix + (i,))


def mutate_json(data, obj):
    """One field of ``obj`` replaced by a hostile value or removed, two fields swapped, or
    the text truncated. Returns the new file text."""
    kind = data.draw(st.sampled_from(["replace", "delete", "swap", "truncate"]))
    text = json.dumps(obj)
    if kind == "truncate":
        return text[:data.draw(st.integers(0, max(0, len(text) - 1)))]
    paths = [p for p in json_paths(obj) if p]
    obj = json.loads(text)  # a copy
    p = data.draw(st.sampled_from(paths))
    parent = obj
    for k in p[:-1]:
        parent = parent[k]
    if kind == "replace":
        parent[p[-1]] = data.draw(st.sampled_from(HOSTILE_JSON))
    elif kind == "delete":
        del parent[p[-1]]
    else:
        q = data.draw(st.sampled_from(paths))
        qparent = obj
        try:
            for k in q[:-1]:
                qparent = qparent[k]
            parent[p[-1]], qparent[q[-1]] = qparent[q[-1]], parent[p[-1]]
        except (KeyError, IndexError, TypeError):
            pass  # the first change moved the second path
    return json.dumps(obj)


def mutate_text(data, text: str, sep: str | None) -> str:
    """One token replaced by a hostile one, a line removed, duplicated or swapped, or the
    text truncated."""
    kind = data.draw(st.sampled_from(["token", "token", "drop", "dup", "swap", "truncate"]))
    lines = text.splitlines()
    if kind == "truncate" or not lines:
        return text[:data.draw(st.integers(0, max(0, len(text) - 1)))]
    i = data.draw(st.integers(0, len(lines) - 1))
    if kind == "token":
        toks = lines[i].split(sep)
        j = data.draw(st.integers(0, len(toks) - 1))
        toks[j] = data.draw(st.sampled_from(HOSTILE_TEXT))
        lines[i] = (sep or " ").join(toks)
    elif kind == "drop":
        del lines[i]
    elif kind == "dup":
        lines.insert(i, lines[i])
    else:
        j = data.draw(st.integers(0, len(lines) - 1))
        lines[i], lines[j] = lines[j], lines[i]
    return "\n".join(lines) + "\n"


finite = st.floats(-1e5, 1e5, allow_nan=False, allow_subnormal=True)


FUZZ_FILES = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def fuzz_file(tmp_path, name, data, reader, writer=None, same=None):
    """Read fuzzed bytes: either the project's own error, or a result that survives its own
    round trip exactly (``writer`` then ``reader`` again, compared by ``same``)."""
    p = tmp_path / name
    p.write_bytes(data)
    try:
        got = reader(p)
    except S2PError as e:
        one_line(e)
        return None
    if writer is not None:
        q = tmp_path / f"again-{name}"
        writer(q, got)
        same(reader(q), got)
    return got


def text_like():
    # random bytes, and byte strings built from the formats' own alphabet (gets past decoding)
    alphabet = st.sampled_from(list(b"0123456789 ,.-\n#abcxyzO_PQ[]{}\":e") + [0, 255, 0xC3])
    return st.one_of(st.binary(max_size=300), st.lists(alphabet, max_size=300).map(bytes))


finite_m = st.floats(-1e6, 1e6, allow_nan=False)  # the readers' range for positions, metres


json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.floats() | st.text(max_size=5),
    lambda kids: st.lists(kids, max_size=4) | st.dictionaries(st.text(max_size=6), kids, max_size=4),
    max_leaves=20)



def one_line(e: S2PError) -> None:
    """The project's error as the CLI prints it: one non-empty line."""
    assert "\n" not in str(e) and str(e), repr(e)


def importing(fn):
    """fn() under the importer's rules: its result, or None after the project's own one-line
    error; a numpy warning (overflow, invalid value) is a failure, as any other exception."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        try:
            return fn()
        except S2PError as e:
            one_line(e)
            return None
