"""The annotation model: tracks of keyframes, spans, and the primitive operations that change them.

A track has an id (int >= 1), a class name, a box size (l, w, h metres, constant over the track),
an interpolation method (None = the class's default), keyframes ``{frame: Keyframe}`` and spans
``[(first, last, kind)]`` with kind ``occluded`` (still interpolated, flagged) or ``outside``
(not in view: interpolation stops), and reviewed spans ``[(first, last)]`` (frames the annotator
has watched and passed: their rows' provenance becomes ``reviewed``). z is never stored: it
comes from the ground surface.

Every change to the tracks is a list of *primitive operations*, plain JSON-able dicts, each of
which ``apply_op`` applies and answers with its exact inverse:

- ``{"op": "put_track", "id": 3, "track": {...} | None}``: create, replace or delete a track;
- ``{"op": "set_keyframes", "id": 3, "set": [[frame, x, y, heading, [flags]], ...],
  "del": [frame, ...]}``: upsert and delete keyframes;
- ``{"op": "set_fields", "id": 3, "fields": {"cls"|"size"|"interp"|"spans"|"reviewed"|"meta":
  value}}``.

The journal stores these (with absolute values, never "nudge by 2 cm"), so replaying it needs no
geometry and gives bit-identical floats (JSON writes floats with repr).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from seg2pose.core.errors import InputError, S2PError
from seg2pose.io import schemas as S
from seg2pose.io.schema import ListOf, Name, Opt, Text, check

SPAN_KINDS = ("occluded", "outside")
FLAG_RE = re.compile(r"^[a-z][a-z0-9_]{0,31}$")
# Keyframe flags the engine itself sets (others may be added by users: short identifiers)
FLAGS = {
    "estimate": "taken from a Seg2Pose run's estimate (pre-annotation), not yet checked",
    "accepted": "an estimate the annotator looked at and accepted (with the estimate flag)",
    "normal": "placed at a mask's normal position",
    "off_support": "more than SUPPORT_RADIUS from every ground point: z is extrapolated",
    "imported": "imported from another tool (T-Analyst)",
    "auto_heading": "heading follows the motion between the neighbouring keyframes (headings.py) "
                    "until the annotator sets it",
}


class EditError(S2PError):
    """An edit that cannot be done (unknown track, frame outside the scene, ...): nothing changed."""


class Keyframe(NamedTuple):
    """A placed pose: x, y metres (ground contact point), heading radians (counter-clockwise
    from +x), flags (sorted tuple of short identifiers, see ``FLAGS``)."""

    x: float
    y: float
    heading: float
    flags: tuple[str, ...] = ()


@dataclass
class Track:
    """One road user's annotation (see the module docstring)."""

    id: int
    cls: str
    size: tuple[float, float, float]
    interp: str | None = None
    keyframes: dict[int, Keyframe] = field(default_factory=dict)
    spans: list[tuple[int, int, str]] = field(default_factory=list)
    reviewed: list[tuple[int, int]] = field(default_factory=list)  # sorted, disjoint, inclusive
    meta: dict = field(default_factory=dict)  # free-form, JSON-able (e.g. {"run_track": 12})

    @property
    def frames(self) -> list[int]:
        """Keyframe frames, sorted."""
        return sorted(self.keyframes)

    @property
    def first(self) -> int | None:
        return min(self.keyframes) if self.keyframes else None

    @property
    def last(self) -> int | None:
        return max(self.keyframes) if self.keyframes else None

    def span_at(self, frame: int) -> str | None:
        """The kind of span covering ``frame`` (None = plain visible)."""
        for a, b, kind in self.spans:
            if a <= frame <= b:
                return kind
        return None

    def is_reviewed(self, frame: int) -> bool:
        return any(a <= frame <= b for a, b in self.reviewed)

    def to_dict(self) -> dict:
        return {"id": self.id, "cls": self.cls, "size": list(self.size), "interp": self.interp,
                "keyframes": [[f, k.x, k.y, k.heading, list(k.flags)]
                              for f, k in sorted(self.keyframes.items())],
                "spans": [list(s) for s in self.spans],
                "reviewed": [list(r) for r in self.reviewed], "meta": self.meta}

    @classmethod
    def from_dict(cls, d: dict) -> Track:
        l, w, h = (float(v) for v in d["size"])
        return cls(id=int(d["id"]), cls=str(d["cls"]), size=(l, w, h),
                   interp=d.get("interp"),
                   keyframes={int(r[0]): Keyframe(float(r[1]), float(r[2]), float(r[3]),
                                                  tuple(r[4]) if len(r) > 4 else ())
                              for r in d.get("keyframes", [])},
                   spans=[(int(a), int(b), str(k)) for a, b, k in d.get("spans", [])],
                   reviewed=[(int(a), int(b)) for a, b in d.get("reviewed", [])],
                   meta=dict(d.get("meta") or {}))

    def copy(self) -> Track:
        return Track(self.id, self.cls, self.size, self.interp, dict(self.keyframes),
                     list(self.spans), list(self.reviewed), dict(self.meta))


# --- spans ----------------------------------------------------------------------------------------
def mark_spans(spans: list[tuple[int, int, str]], first: int, last: int, kind: str
               ) -> list[tuple[int, int, str]]:
    """Spans after marking frames first..last (inclusive) as ``kind`` (``occluded``, ``outside``
    or ``visible``, which clears): sorted, non-overlapping, neighbours of one kind merged."""
    if kind not in SPAN_KINDS + ("visible",):
        raise EditError(f"unknown span kind {kind!r}; use one of {', '.join(SPAN_KINDS)} or visible")
    if last < first:
        raise EditError(f"span {first}..{last}: the last frame comes before the first")
    out = []
    for a, b, k in spans:  # cut the new range out of the old spans
        if b < first or a > last:
            out.append((a, b, k))
            continue
        if a < first:
            out.append((a, first - 1, k))
        if b > last:
            out.append((last + 1, b, k))
    if kind != "visible":
        out.append((first, last, kind))
    out.sort()
    merged: list[tuple[int, int, str]] = []
    for a, b, k in out:
        if merged and merged[-1][2] == k and merged[-1][1] + 1 >= a:
            merged[-1] = (merged[-1][0], max(merged[-1][1], b), k)
        else:
            merged.append((a, b, k))
    return merged


def mark_reviewed(reviewed: list[tuple[int, int]], first: int, last: int, on: bool
                  ) -> list[tuple[int, int]]:
    """Reviewed spans after marking frames first..last (inclusive) reviewed (``on``) or not:
    sorted, disjoint, touching spans merged."""
    spans = mark_spans([(a, b, "occluded") for a, b in reviewed], first, last,
                       "occluded" if on else "visible")
    return [(a, b) for a, b, _ in spans]


# --- primitive operations -------------------------------------------------------------------------
def keyframe_row(frame: int, k: Keyframe) -> list:
    """A keyframe as the journal's ``set_keyframes`` operation holds it."""
    return [int(frame), k.x, k.y, k.heading, list(k.flags)]


def check_flags(flags) -> tuple[str, ...]:
    flags = tuple(sorted(set(flags or ())))
    for f in flags:
        if not isinstance(f, str) or not FLAG_RE.match(f):
            raise EditError(f"bad keyframe flag {f!r}: expected a short lower-case identifier")
    return flags


def keyframe(x: float, y: float, heading: float, flags=()) -> Keyframe:
    """A validated keyframe (finite numbers, heading wrapped to [-pi, pi))."""
    x, y, heading = float(x), float(y), float(heading)
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(heading)):
        raise EditError(f"keyframe needs finite x, y, heading, got {x}, {y}, {heading}")
    heading = (heading + math.pi) % (2 * math.pi) - math.pi
    return Keyframe(x, y, heading, check_flags(flags))


def _track(tracks: dict[int, Track], tid: int) -> Track:
    try:
        return tracks[tid]
    except KeyError:
        raise EditError(f"no track {tid}") from None


def check_op(op) -> None:
    """One journal operation against its schema (``io.schemas.JOURNAL_OPS``): the same check
    when an edit is made (before it is journalled) and when the journal is replayed, so the
    journal never holds a record its replay refuses (a frame of -5 or 1.5, x of 1e300, a size
    of 0, an unknown span kind). Raises InputError (one line)."""
    if not isinstance(op, dict) or op.get("op") not in S.JOURNAL_OPS:
        raise InputError(f"expected an operation {' / '.join(S.JOURNAL_OPS)}, got {repr(op)[:60]}",
                         field="op")
    check(op, S.JOURNAL_OPS[op["op"]], field=op["op"])
    if op["op"] == "put_track" and op["track"] is not None:
        t = op["track"]
        for i, r in enumerate(t.get("keyframes") or []):
            S.keyframe_values(r, field=f"track.keyframes[{i}]")
        for i, sp in enumerate(t.get("spans") or []):
            S.check_span(sp, field=f"track.spans[{i}]")
        _check_reviewed(t.get("reviewed") or [], "track.reviewed")
    elif op["op"] == "set_keyframes":
        for i, r in enumerate(op.get("set") or []):
            S.keyframe_values(r, field=f"set[{i}]")
    elif op["op"] == "set_fields":
        for name, v in op["fields"].items():
            if name in _FIELDS:
                check(v, _FIELDS[name], field=f"fields.{name}")
            if name == "spans":
                for i, sp in enumerate(v):
                    S.check_span(sp, field=f"fields.spans[{i}]")
            elif name == "reviewed":
                _check_reviewed(v, "fields.reviewed")


def check_op_frames(op: dict, frame_range: tuple[int, int] | None) -> None:
    """The frames an operation (already ``check_op``'ed) places keyframes, spans and reviewed
    spans at lie within the scene's ``frame_range`` (inclusive; None: not known), as an edit's
    frames must (a replayed keyframe at frame 10^15 made interpolation ask for 7 PiB)."""
    if frame_range is None:
        return
    if op["op"] == "put_track":
        t = op["track"] or {}
        rows = [r[0] for r in t.get("keyframes") or []]
        rows += [f for sp in (t.get("spans") or []) + (t.get("reviewed") or []) for f in sp[:2]]
    elif op["op"] == "set_keyframes":
        rows = [r[0] for r in op.get("set") or []]
    else:
        f = op["fields"]
        rows = [x for sp in (f.get("spans") or []) + (f.get("reviewed") or []) for x in sp[:2]]
    bad = [x for x in rows if not frame_range[0] <= x <= frame_range[1]]
    if bad:
        raise InputError(f"frame {bad[0]} is outside the scene's frames {frame_range[0]}..{frame_range[1]}",
                         field=op["op"])


def _check_reviewed(spans: list, field: str) -> None:
    for i, (a, b) in enumerate(check(spans, ListOf(S.SPAN), field=field)):
        if b < a:
            raise InputError(f"span {a}..{b}: the last frame comes before the first", field=f"{field}[{i}]")


_FIELDS = {"cls": Name("class name"), "size": S.BOX_SIZE,
           "interp": Opt(Text(40)), "spans": list, "reviewed": list, "meta": dict}


def apply_op(tracks: dict[int, Track], op: dict) -> dict:
    """Apply one primitive operation to ``tracks`` (in place) and return its inverse. The
    operation is checked first (``check_op``): a bad one changes nothing."""
    check_op(op)
    kind, tid = op["op"], int(op["id"])
    if kind == "put_track":
        old = tracks.get(tid)
        new = op["track"]
        if new is None:
            tracks.pop(tid, None)
        else:
            tracks[tid] = Track.from_dict(new)
        return {"op": "put_track", "id": tid, "track": None if old is None else old.to_dict()}
    t = _track(tracks, tid)
    if kind == "set_keyframes":
        kfs = t.keyframes
        sets, dels = op.get("set", ()), op.get("del", ())
        if len(sets) == 1 and not dels:  # the common edit: one keyframe set (fast replay)
            r = sets[0]
            f = int(r[0])
            old = kfs.get(f)
            kfs[f] = Keyframe(float(r[1]), float(r[2]), float(r[3]),
                              tuple(r[4]) if len(r) > 4 else ())
            return {"op": "set_keyframes", "id": tid,
                    "set": [] if old is None else [keyframe_row(f, old)],
                    "del": [f] if old is None else []}
        touched = [int(r[0]) for r in op.get("set", ())] + [int(f) for f in op.get("del", ())]
        inv_set = [keyframe_row(f, kfs[f]) for f in dict.fromkeys(touched) if f in kfs]
        inv_del = [f for f in dict.fromkeys(touched) if f not in kfs]
        for f in op.get("del", ()):
            kfs.pop(int(f), None)
        for r in op.get("set", ()):
            kfs[int(r[0])] = Keyframe(float(r[1]), float(r[2]), float(r[3]),
                                      tuple(r[4]) if len(r) > 4 else ())
        return {"op": "set_keyframes", "id": tid, "set": inv_set, "del": inv_del}
    if kind == "set_fields":
        inv: dict[str, Any] = {}
        for name, value in op["fields"].items():
            if name == "cls":
                inv[name], t.cls = t.cls, str(value)
            elif name == "size":
                l, w, h = (float(v) for v in value)
                inv[name], t.size = list(t.size), (l, w, h)
            elif name == "interp":
                inv[name], t.interp = t.interp, value
            elif name == "spans":
                inv[name] = [list(s) for s in t.spans]
                t.spans = [(int(a), int(b), str(k)) for a, b, k in value]
            elif name == "reviewed":
                inv[name] = [list(r) for r in t.reviewed]
                t.reviewed = [(int(a), int(b)) for a, b in value]
            elif name == "meta":
                inv[name], t.meta = dict(t.meta), dict(value)
            else:
                raise EditError(f"unknown track field {name!r}")
        return {"op": "set_fields", "id": tid, "fields": inv}
    raise EditError(f"unknown operation {kind!r}")


def apply_ops(tracks: dict[int, Track], ops: list[dict]) -> list[dict]:
    """Apply operations in order; return the inverse list (to be applied in order too)."""
    inverse = [apply_op(tracks, op) for op in ops]
    inverse.reverse()
    return inverse


def op_tracks(ops: list[dict]) -> set[int]:
    """Ids of the tracks that operations touch."""
    return {int(op["id"]) for op in ops}
